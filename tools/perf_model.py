#!/usr/bin/python3
"""The cost model of one step (docs/performance.md): calibrated on two profiles of the same
run (`cvt-engine run --profile-json`), one serial and one on the flow graph with P0 threads,
it predicts the time per step on P threads.

Each profile row (section) is split into a part that runs in parallel on at most `cap`
threads and a part that does not: T(1) = s + w, T(P0) = s + w / min(P0, cap), so
w = (T(1) - T(P0)) / (1 - 1 / min(P0, cap)), s = T(1) - w (both kept >= 0). The caps: the
block LU of W runs as two sweeps (factorization and solves: 2), or with
`integrator.w_segments` = S as S segments (`--lu-segments S`: S; both profiles taken with
that key, so that the LU's serial part, the reduced system, is in the calibration); the evaluations, the status
update and the W assembly and stiffness run over the joints (cap: the links); the
integrator's vector update and the output run on the master (1). The flow graph's own cost
("scheduling") is a synchronization cost per step that grows like log2 of the threads (a
join tree), times `--socket-factor` for the threads beyond the first socket.

    tools/perf_model.py serial.json two.json --threads 1,2,4,8,14,28 --cores-per-socket 14 \\
        --step 8.333333333333333e-7
"""
import argparse
import json
import math
import sys

TWO_SWEEPS = {"W factorization", "W solves"}
MASTER = {"integrator update", "output", "rest"}
SYNC = "scheduling"


def rows(path):
    with open(path) as f:
        p = json.load(f)
    return p["header"], {r["name"]: r["us_per_step"] for r in p["rows"] if r["name"] != "total"}


def cap_of(name, links, segments=0):
    if name in TWO_SWEEPS:
        return segments if segments >= 3 else 2
    if name in MASTER:
        return 1
    return links


def calibrate(serial, parallel, p0, links, segments=0):
    """Per section: (serial part s, parallel work w, cap) in us per step."""
    model = {}
    for name, t1 in serial.items():
        if name == SYNC:
            continue
        cap = cap_of(name, links, segments)
        c0 = min(p0, cap)
        tp = parallel.get(name, t1)
        if c0 <= 1:
            model[name] = (t1, 0.0, cap)
            continue
        w = min(t1, max(0.0, (t1 - tp) / (1 - 1 / c0)))
        model[name] = (t1 - w, w, cap)
    return model


def predict(model, sync0, p0, p, cores_per_socket, socket_factor):
    t = sum(s + w / min(p, cap) for s, w, cap in model.values())
    if p > 1 and p0 > 1:
        sync = sync0 * math.log2(p) / math.log2(p0)
        if p > cores_per_socket:
            sync *= socket_factor
        t += sync
    return t


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("serial", help="profile JSON of the serial run")
    ap.add_argument("parallel", help="profile JSON of the same run on the flow graph with P0 threads")
    ap.add_argument("--threads", default="1,2,4,8,14,28", help="thread counts to predict")
    ap.add_argument("--cores-per-socket", type=int, default=14)
    ap.add_argument("--socket-factor", type=float, default=2.0,
                    help="synchronization cost beyond one socket, relative to within (default 2)")
    ap.add_argument("--links", type=int, default=84, help="the chain's links (the widest parallel loop)")
    ap.add_argument("--lu-segments", type=int, default=0,
                    help="the block LU's segments (integrator.w_segments) of both profiles; 0: two sweeps")
    ap.add_argument("--step", type=float, default=0.0, help="mean step [s]: also print minutes per model second")
    a = ap.parse_args(argv)
    h1, serial = rows(a.serial)
    h2, parallel = rows(a.parallel)
    if h1["threads"] != 1 or h2["threads"] < 2:
        sys.exit("perf_model: give a serial profile first and one with 2 or more threads second")
    p0 = h2["threads"]
    model = calibrate(serial, parallel, p0, a.links, a.lu_segments)
    sync0 = parallel.get(SYNC, 0.0)
    print(f"calibrated on {h1['us_per_step']:.1f} us per step serial and {h2['us_per_step']:.1f} on {p0} threads")
    print(f"{'section':24s} {'serial part':>12s} {'parallel':>10s} {'cap':>5s}")
    for name, (s, w, cap) in model.items():
        print(f"{name:24s} {s:12.1f} {w:10.1f} {cap:5d}")
    print(f"{'scheduling (sync)':24s} {sync0:12.1f} {'':>10s} {'log2':>5s}")
    t1 = predict(model, sync0, p0, 1, a.cores_per_socket, a.socket_factor)
    print(f"\n{'threads':>7s} {'us/step':>9s} {'speed-up':>9s}" + (f" {'min per model s':>16s}" if a.step > 0 else ""))
    for p in [int(x) for x in a.threads.split(",")]:
        t = predict(model, sync0, p0, p, a.cores_per_socket, a.socket_factor)
        line = f"{p:7d} {t:9.1f} {t1 / t:9.2f}"
        if a.step > 0:
            line += f" {t * 1e-6 / a.step / 60:16.2f}"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
