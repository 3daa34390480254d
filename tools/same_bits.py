#!/usr/bin/python3
"""Fingerprints of short runs, to show that a refactor keeps the bits.

    tools/same_bits.py run BUILD/cvt-engine OUT.json [OPTION ...]   # run the cases, write their fingerprints
    tools/same_bits.py compare BEFORE.json AFTER.json     # exit 1 if any fingerprint differs

The cases: 500 RK4 steps and 2000 ROS34PW2 steps of configs/reference.toml, each serial and
on two flow-graph threads, and each run in two halves (the second half resumed from the
first half's checkpoint, appending to the same file); then every shipped configuration with
its own method and step, serial and on two threads, through the start-up into the running
step (integrator.settle_time = 2e-4 s, t_end = 4e-4 s), and RK4 on the mini model. A fingerprint is the SHA-256 of every
dataset's bytes (shape and type included) and attribute in the output file, apart from what
depends on the wall clock (/profile, wall-time attributes), and of the final checkpoint's
datasets. Build the binary before and after the change with the same flags. OPTIONs are added
to every run (`--set integrator.fixed_steps=true`: a behaviour that a key turns off).
"""
import hashlib
import json
import os
import subprocess
import sys
import tempfile

import h5py
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
CONFIG = os.path.join(HERE, "..", "configs", "reference.toml")

RK4 = ["--method", "rk4", "--step", "1e-8", "--set", "run.sample_interval=1e-7",
       "--set", "run.snapshot_interval=1e-6"]
ROS = ["--method", "ros34pw2", "--step", "1e-6", "--set", "run.sample_interval=1e-5",
       "--set", "run.snapshot_interval=1e-4"]
SERIAL = ["--scheduler", "serial"]
THREADS2 = ["--scheduler", "flowgraph", "--threads", "2"]

# name -> (options, t_end of the whole run)
CASES = {
    "rk4-500-serial": (RK4 + SERIAL, "5e-6"),
    "rk4-500-threads2": (RK4 + THREADS2, "5e-6"),
    "ros34pw2-2000-serial": (ROS + SERIAL, "2e-3"),
    "ros34pw2-2000-threads2": (ROS + THREADS2, "2e-3"),
}
# every shipped configuration with its own integrator: the start-up's ROS2 sub-steps, then the
# method's running step (no settling phase after 2e-4 s)
SHIPPED = ["mini", "ratio-0.5", "ratio-2.0", "reference-shift", "reference-steady", "reference"]
OWN = ["--set", "integrator.settle_time=2e-4", "--set", "run.sample_interval=1e-5",
       "--set", "run.snapshot_interval=1e-4"]
for cfg in SHIPPED:
    CASES[f"{cfg}-own-serial"] = (OWN + SERIAL, "4e-4", cfg)
    CASES[f"{cfg}-own-threads2"] = (OWN + THREADS2, "4e-4", cfg)
CASES["mini-rk4-serial"] = (RK4 + SERIAL, "5e-6", "mini")

# resumed: the first half to t_half, then --resume to the end (t_half at a multiple of w_k_every)
RESUMED = {
    "rk4-500-resumed": (RK4 + SERIAL, "2.5e-6", "5e-6"),
    "ros34pw2-2000-resumed": (ROS + THREADS2, "1.024e-3", "2e-3"),
}

# what a run may differ in without a change of its numbers: the wall clock, the random run
# id, and the file names (the runs write into a new temporary folder each time)
WALL_CLOCK = ("wall", "elapsed", "seconds_per", "steps_per_second", "us_per", "per_hour", "date", "created",
              "host", "run_id", "output")


def wall_clock(name):
    low = name.lower()
    return any(w in low for w in WALL_CLOCK)


def fingerprint_h5(path):
    out = {}
    with h5py.File(path, "r") as f:
        def attrs(name, obj):
            for key, value in sorted(obj.attrs.items()):
                if wall_clock(key):
                    continue
                out[f"{name}@{key}"] = hashlib.sha256(repr(np.asarray(value).tolist()).encode()).hexdigest()

        def visit(name, obj):
            if name.split("/")[0] == "profile" or wall_clock(name.split("/")[-1]):
                return
            attrs(name, obj)
            if isinstance(obj, h5py.Dataset):
                data = np.ascontiguousarray(obj[()])
                h = hashlib.sha256(f"{data.dtype.str}{data.shape}".encode())
                h.update(data.tobytes())
                out[name] = h.hexdigest()

        attrs("/", f)
        f.visititems(visit)
    return out


def run(exe, args):
    cmd = [exe, "run"] + args + ["-q"]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"same_bits: {' '.join(cmd)} exited {res.returncode}:\n{res.stderr}")


def fingerprints(exe, extra=()):
    result = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (opts, t_end, *cfg) in CASES.items():
            out = os.path.join(tmp, name + ".h5")
            config = os.path.join(HERE, "..", "configs", cfg[0] + ".toml") if cfg else CONFIG
            run(exe, [config] + opts + list(extra) + ["--t-end", t_end, "-o", out, "--checkpoint-every", "0"])
            result[name] = fingerprint_h5(out) | {"checkpoint:" + k: v for k, v in fingerprint_h5(out + ".ckpt").items()}
        for name, (opts, t_half, t_end) in RESUMED.items():
            out = os.path.join(tmp, name + ".h5")
            run(exe, [CONFIG] + opts + list(extra) + ["--t-end", t_half, "-o", out, "--checkpoint-every", "0"])
            run(exe, ["--resume", out + ".ckpt", "--t-end", t_end, "--checkpoint-every", "0"])
            result[name] = fingerprint_h5(out) | {"checkpoint:" + k: v for k, v in fingerprint_h5(out + ".ckpt").items()}
    return result


def compare(before, after):
    bad = 0
    for case in sorted(set(before) | set(after)):
        a, b = before.get(case, {}), after.get(case, {})
        diff = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        print(f"{case}: {'same bits' if not diff else f'{len(diff)} differ'} ({len(b)} fingerprints)")
        for k in diff[:20]:
            print(f"    {k}: {'missing before' if k not in a else 'missing after' if k not in b else 'differs'}")
        bad += bool(diff)
    return bad


def main(argv):
    if len(argv) >= 4 and argv[1] == "run":
        with open(argv[3], "w") as f:
            json.dump(fingerprints(argv[2], argv[4:]), f, indent=1, sort_keys=True)
        return 0
    if len(argv) == 4 and argv[1] == "compare":
        with open(argv[2]) as f, open(argv[3]) as g:
            return 1 if compare(json.load(f), json.load(g)) else 0
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv))
