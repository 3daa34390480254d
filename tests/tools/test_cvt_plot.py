#!/usr/bin/python3
"""Runs every subcommand of tools/cvt_plot.py on synthetic inputs in the documented formats.

    /usr/bin/python3 tests/tools/test_cvt_plot.py [-v]

Builds, in a temporary directory, a run file (observables including the newer channels
plate_tension, chain_torsion_angle and running_efficiency, chain snapshots, the resolved
TOML, a /profile group), a --profile-json file and a scaling study as CSV and JSON; checks
that each subcommand exits 0 and writes a non-trivial PNG or GIF, and that bad input
(missing file, channel, column, group) exits 2 with a message and no Python traceback.
Set CVT_PLOT_KEEP=DIR to keep the figures in DIR.
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

import h5py
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
TOOL = os.path.join(HERE, "..", "..", "tools", "cvt_plot.py")
PYTHON = sys.executable or "/usr/bin/python3"

CONFIG = """\
[geometry]
centre_distance = 0.06
ratio = 1.0
[chain]
links = 30
pitch = 8.0e-3
plates_per_link = 4
[sheave]
outer_radius = 0.035
hub_radius = 0.010
[load]
torque = 10.0
[clamping]
driving = 10.0e3
driven = 10.0e3
[run]
tracked_pin = 0
tracked_link = 0
"""

PROFILE_ROWS = ["chain forces", "pulley contact", "other forces", "inertia decomposition", "accelerations",
                "integrator update", "contact status", "output", "scheduling", "rest", "total"]
PROFILE_SHARE = [58.0, 18.0, 2.0, 7.0, 5.0, 3.0, 2.0, 1.0, 1.5, 2.5, 100.0]


def profile_rows(steps=1000, threads=2):
    wall = 0.25
    rows = []
    for name, p in zip(PROFILE_ROWS, PROFILE_SHARE):
        w = wall * p / 100
        busy = w if name in ("chain forces", "pulley contact") else (w / threads if name != "total" else 0.0)
        rows.append(dict(name=name, calls=4 * steps if name != "total" else steps, wall_s=w,
                         us_per_step=w / steps * 1e6, percent=p, busy_min_s=0.9 * busy, busy_avg_s=busy,
                         busy_max_s=1.1 * busy, imbalance_percent=10.0 if busy else 0.0))
    header = dict(steps=steps, us_per_step=wall / steps * 1e6, model_s_per_hour=0.15, threads=threads,
                  numa_nodes=1, scheduler="flowgraph", wall_s=wall)
    return header, rows


def chain_positions(S, N, a=0.06, R=0.02):
    """Joint centres of a chain around two pulleys of radius R at (0,0) and (a,0), moving."""
    L = 2 * np.pi * R + 2 * a
    out = np.zeros((S, N, 3))
    for s in range(S):
        u = (np.arange(N) / N + 0.01 * s) % 1.0 * L
        x = np.empty(N)
        y = np.empty(N)
        top = u < a
        x[top], y[top] = u[top], R
        arc2 = (u >= a) & (u < a + np.pi * R)
        ph = (u[arc2] - a) / R
        x[arc2], y[arc2] = a + R * np.sin(ph), R * np.cos(ph)
        bot = (u >= a + np.pi * R) & (u < 2 * a + np.pi * R)
        x[bot], y[bot] = a - (u[bot] - a - np.pi * R), -R
        arc1 = u >= 2 * a + np.pi * R
        ph = (u[arc1] - 2 * a - np.pi * R) / R
        x[arc1], y[arc1] = -R * np.sin(ph), -R * np.cos(ph)
        out[s, :, 0], out[s, :, 1] = x, y
    return out


def write_run(path, with_new=True, with_profile=True, fixed_strings=False):
    rng = np.random.default_rng(1)
    T = 600
    t = np.arange(T) * 1e-5
    f = h5py.File(path, "w")

    def ch(name, value, unit):
        g = f.create_group(f"observables/{name}")
        g["time"] = t
        g["value"] = value
        g["value"].attrs["unit"] = unit

    osc = np.sin(2 * np.pi * 2e3 * t) + 0.3 * np.sin(2 * np.pi * (5e3 + 4e6 * t) * t)
    ch("input_speed", 209.4 + 0.5 * osc, "rad/s")
    ch("output_speed", 207.0 + 0.5 * osc, "rad/s")
    ch("load_speed", 206.5 + 0.2 * osc, "rad/s")
    ch("input_torque", 10 + 2 * osc, "N m")
    ch("output_torque", 9.5 + 2 * osc + 0.1 * rng.standard_normal(T), "N m")
    ch("load_torque", np.minimum(t / 2e-3, 1) * 10, "N m")
    ch("efficiency", 0.97 + 0.05 * osc, "-")
    ch("link_tension", 3000 + 1500 * np.sin(2 * np.pi * 700 * t), "N")
    ch("pin_axial_force", np.stack([200 * osc, -180 * osc], axis=1), "N")
    ch("support_force", np.stack([5000 + 100 * k + 50 * osc for k in range(4)], axis=1), "N")
    P_in = 10 * 209.4 * np.minimum(t / 1e-3 + 0.01, 1)
    ch("work_input", np.cumsum(P_in) * 1e-5, "J")
    ch("work_output", np.cumsum(0.96 * P_in * (1 + 0.02 * osc)) * 1e-5, "J")
    if with_new:
        ch("plate_tension", np.stack([750 + 40 * k + 300 * np.sin(2 * np.pi * 700 * t + k) for k in range(4)],
                                     axis=1), "N")
        ch("chain_torsion_angle", 2e-3 * np.sin(2 * np.pi * 900 * t), "rad")
        ch("running_efficiency", 0.96 + 0.01 * np.exp(-t / 1e-3), "-")
    S, N = 31, 30
    ts = np.arange(S) * 2e-4
    g = f.create_group("particles/chain")
    g["position/time"] = ts
    g["position/value"] = chain_positions(S, N)
    g["position/value"].attrs["unit"] = "m"
    g["link_tension/time"] = ts
    g["link_tension/value"] = 2000 + 1000 * np.sin(np.linspace(0, 2 * np.pi, N))[None, :] + 10 * np.arange(S)[:, None]
    f["parameters/config"] = CONFIG
    f["parameters/version"] = "test"
    if with_profile:
        header, rows = profile_rows()
        p = f.create_group("profile")
        for k, v in header.items():
            # cvt-engine writes the counts as doubles; the fixed-string variant checks that too.
            p.attrs[k] = float(v) if fixed_strings and not isinstance(v, str) else v
        names = [r["name"] for r in rows]
        if fixed_strings:
            p["name"] = np.array([n.encode() for n in names], dtype="S32")
        else:
            p.create_dataset("name", data=names, dtype=h5py.string_dtype())
        for k in ["calls", "wall_s", "us_per_step", "percent", "busy_min_s", "busy_avg_s", "busy_max_s",
                  "imbalance_percent"]:
            p[k] = np.array([r[k] for r in rows], dtype=np.int64 if k == "calls" else float)
    f.close()


SCALING_COLUMNS = ("scheduler,layout,threads,steps,repeat,us_per_step,speedup,efficiency,chain_us,chain_speedup,"
                   "pulley_us,pulley_speedup,zero_gather_us,compute_us,amdahl_serial_fraction").split(",")


def scaling_rows():
    rows = []
    for sched, layout, s, zg in [("flowgraph", "compact", 0.05, 0.0), ("flowgraph", "spread", 0.08, 0.0),
                                 ("paper-omp", "compact", 0.42, 1.0)]:
        for n in [1, 2, 4, 8, 12, 16]:
            for rep in range(3):
                noise = 1 + 0.02 * (rep - 1)
                sp = 1 / (s + (1 - s) / n) * noise
                base = 230.0
                eff_c, eff_p = 1 / (1 + s * 0.1 * (n - 1)), 1 / (1 + s * 0.3 * (n - 1))  # worse with s
                rows.append(dict(scheduler=sched, layout=layout, threads=n, steps=2000, repeat=rep,
                                 us_per_step=base / sp, speedup=sp, efficiency=sp / n, chain_us=170 / (eff_c * n),
                                 chain_speedup=eff_c * n, pulley_us=20 / (eff_p * n), pulley_speedup=eff_p * n,
                                 zero_gather_us=zg * (2 + 1.5 * n), compute_us=170 * (1 + 0.02 * n + s * 0.05 * n),
                                 amdahl_serial_fraction=s))
    return rows


class CvtPlotTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="cvt_plot_test_")
        cls.run_h5 = os.path.join(cls.dir, "run.h5")
        write_run(cls.run_h5)
        cls.old_h5 = os.path.join(cls.dir, "old.h5")  # channels of today's engine only, no profile
        write_run(cls.old_h5, with_new=False, with_profile=False)
        cls.fixed_h5 = os.path.join(cls.dir, "fixed.h5")
        write_run(cls.fixed_h5, fixed_strings=True)
        header, rows = profile_rows(steps=500, threads=4)
        cls.prof_json = os.path.join(cls.dir, "profile.json")
        with open(cls.prof_json, "w") as fh:
            json.dump(dict(header=header, rows=rows), fh)
        srows = scaling_rows()
        cls.study_csv = os.path.join(cls.dir, "study.csv")
        with open(cls.study_csv, "w") as fh:
            fh.write(",".join(SCALING_COLUMNS) + "\n")
            for r in srows:
                fh.write(",".join(str(r[k]) for k in SCALING_COLUMNS) + "\n")
        cls.study_json = os.path.join(cls.dir, "study.json")
        with open(cls.study_json, "w") as fh:
            json.dump(dict(config="configs/reference.toml", rows=srows), fh)

    @classmethod
    def tearDownClass(cls):
        keep = os.environ.get("CVT_PLOT_KEEP")
        if keep:
            os.makedirs(keep, exist_ok=True)
            for n in os.listdir(cls.dir):
                if n.endswith((".png", ".gif")):
                    shutil.copy(os.path.join(cls.dir, n), keep)
        shutil.rmtree(cls.dir, ignore_errors=True)

    def plot(self, *args):
        p = subprocess.run([PYTHON, TOOL, *args], capture_output=True, text=True, timeout=300)
        self.assertNotIn("Traceback", p.stderr, p.stderr)
        return p

    def ok(self, out, *args, magic=b"\x89PNG", min_bytes=10000):
        out = os.path.join(self.dir, out)
        p = self.plot(*args, "--out", out)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertTrue(os.path.isfile(out), out)
        self.assertGreater(os.path.getsize(out), min_bytes)
        with open(out, "rb") as fh:
            self.assertEqual(fh.read(len(magic)), magic)
        return p

    def fails(self, *args, expect):
        p = self.plot(*args, "--out", os.path.join(self.dir, "never.png"))
        self.assertEqual(p.returncode, 2, p.stderr)
        self.assertIn(expect, p.stderr)
        self.assertFalse(os.path.exists(os.path.join(self.dir, "never.png")))
        return p

    def test_history(self):
        p = self.ok("history.png", "history", self.run_h5)
        self.assertNotIn("skipping", p.stderr)

    def test_history_window(self):
        self.ok("history_window.png", "history", self.run_h5, "--from", "1e-3", "--to", "4e-3")

    def test_history_long_run(self):
        # 3 s of samples (3e5 rows), 12 plates: drawn as a min/max envelope, time axis in s.
        path = os.path.join(self.dir, "long.h5")
        T = 300000
        t = np.arange(T) * 1e-5
        osc = np.sin(2 * np.pi * 40 * t) + 0.2 * np.sin(2 * np.pi * 1500 * t)
        with h5py.File(path, "w") as f:
            for name, value, unit in [("link_tension", 3000 + 1000 * osc, "N"),
                                      ("plate_tension", np.stack([250 + 10 * k + 80 * osc for k in range(12)], 1), "N"),
                                      ("work_input", np.cumsum(2000 * (1 + 0.1 * osc)) * 1e-5, "J"),
                                      ("work_output", np.cumsum(1900 * (1 + 0.1 * osc)) * 1e-5, "J")]:
                f[f"observables/{name}/time"] = t
                f[f"observables/{name}/value"] = value
                f[f"observables/{name}/value"].attrs["unit"] = unit
        self.ok("history_long.png", "history", path)

    def test_history_skips_absent_channels(self):
        p = self.ok("history_old.png", "history", self.old_h5)
        for name in ("plate_tension", "chain_torsion_angle"):
            self.assertIn(name, p.stderr)
        self.assertIn("skipping", p.stderr)

    def test_profile_from_run(self):
        self.ok("profile_h5.png", "profile", self.run_h5)

    def test_profile_fixed_strings(self):
        self.ok("profile_fixed.png", "profile", self.fixed_h5)

    def test_profile_from_json(self):
        self.ok("profile_json.png", "profile", self.prof_json)

    def test_scaling_csv(self):
        self.ok("scaling_csv.png", "scaling", self.study_csv)

    def test_scaling_json(self):
        self.ok("scaling_json.png", "scaling", self.study_json)

    def test_spectrogram(self):
        self.ok("spectrogram.png", "spectrogram", self.run_h5, "output_torque")

    def test_spectrogram_column(self):
        self.ok("spectrogram_col.png", "spectrogram", self.run_h5, "support_force", "--column", "2",
                "--nperseg", "64")

    def test_animate(self):
        self.ok("chain.gif", "animate", self.run_h5, "--every", "3", "--fps", "5", magic=b"GIF8")

    def test_integrators(self):
        # The CSVs of `cvt-engine study integrators` (columns as engine/study_integrators.cpp writes them).
        head = ("part,method,param_kind,param,h,err_pos_m,err_vel_m_s,status,deviation_percent,wall_s,rhs_evals,"
                "jac_evals,lu_factorizations,steps,rejected,newton_iterations,newton_failures,mean_h_s,jac_s,lu_s,"
                "solve_s,chosen\n")
        study = os.path.join(self.dir, "integrators.csv")
        with open(study, "w") as fh:
            fh.write(head)
            for m in ("rk4", "trbdf2"):
                for h in (1e-8, 1e-7, 1e-6):
                    fh.write(f"one_step,{m},h,{h},{h},{h ** 3 * 1e12},{h * 1e3},,,,,,,,,,,,,,,\n")
            fh.write("curve,rk4,h,5e-8,,,,ok,0.5,1.2,80000,0,0,20000,0,0,0,5e-8,0,0,0,1\n")
            fh.write("curve,trbdf2,tol,1,,,,ok,5.8,20,5600,21,74,76,21,400,20,2.6e-6,1,15,2,0\n")
            fh.write("curve,trbdf2,tol,0.1,,,,timeout,,120,56000,210,700,760,210,4000,200,,10,100,10,0\n")
        with open(os.path.join(self.dir, "integrators-curves.csv"), "w") as fh:
            fh.write("t_s,reference,rk4\n")
            for k in range(50):
                fh.write(f"{3e-4 + k * 1e-5},{-10.0 * k},{-10.0 * k + 0.1}\n")
        self.ok("integrators.png", "integrators", study)
        self.fails("integrators", self.study_csv, expect="missing column")

    def test_missing_channel(self):
        self.fails("spectrogram", self.run_h5, "no_such_channel", expect="no_such_channel")

    def test_missing_column(self):
        self.fails("spectrogram", self.run_h5, "support_force", "--column", "4", expect="--column 4")

    def test_missing_file(self):
        missing = os.path.join(self.dir, "absent.h5")
        for cmd in (["history", missing], ["spectrogram", missing, "output_torque"], ["animate", missing],
                    ["profile", missing], ["scaling", os.path.join(self.dir, "absent.csv")]):
            self.fails(*cmd, expect="no such file")

    def test_missing_profile_group(self):
        self.fails("profile", self.old_h5, expect="/profile")

    def test_bad_scaling_columns(self):
        bad = os.path.join(self.dir, "bad.csv")
        with open(bad, "w") as fh:
            fh.write("scheduler,threads,speedup\nserial,1,1.0\n")
        self.fails("scaling", bad, expect="missing column")

    def test_not_hdf5(self):
        self.fails("history", self.study_csv, expect="cannot open")


if __name__ == "__main__":
    unittest.main()
