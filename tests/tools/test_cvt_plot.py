#!/usr/bin/python3
"""Runs every subcommand of tools/cvt_plot.py on synthetic inputs in the documented formats.

    /usr/bin/python3 tests/tools/test_cvt_plot.py [-v]

Builds, in a temporary directory, a run file (observables including the newer channels
plate_tension, chain_torsion_angle and running_efficiency, chain snapshots, the resolved
TOML, a /profile group), a --profile-json file and a scaling study as CSV and JSON; checks
that each subcommand exits 0 and writes a non-trivial PNG or GIF (with --out and with -o),
and that bad input (missing file, channel, column, group) exits 2 with a message and no
Python traceback. The history figure is also built in-process (the tool imported as a
module) to check its panels and their order, what they draw (slip in %, sheave positions
in mm), the fixed efficiency axis and its out-of-range note, and the strand tensions from
snapshots with known tensions. Set CVT_PLOT_KEEP=DIR to keep the figures in DIR.
"""
import argparse
import importlib.util
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


def SLIP(t):
    return -0.005 * np.minimum(t / 3e-3, 1)


def SHEAVE(t):
    return 2e-4 * np.minimum(t / 2e-3, 1)


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
    # What the engine writes for the engineer's panels (dimensionless unit "1", as the engine does).
    ch("speed_ratio", 1.01 + 0.001 * osc, "1")
    ch("geometric_ratio", 1.0 + 0.0005 * t / t[-1], "1")
    ch("slip", SLIP(t), "1")
    ch("clamping_force_driving", 8e3 * np.minimum(t / 2e-3, 1), "N")
    ch("clamping_force_driven", 1e4 * np.minimum(t / 2e-3, 1), "N")
    ch("sheave_position", np.stack([-SHEAVE(t), SHEAVE(t)], axis=1), "m")
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
    # As cvt-engine writes them: attributes (the fixed-string variant: older datasets).
    if fixed_strings:
        f["parameters/config"] = CONFIG
        f["parameters/version"] = "test"
    else:
        f.create_group("parameters").attrs["config"] = CONFIG
        f["parameters"].attrs["version"] = "test"
    if with_profile:
        header, rows = profile_rows()
        p = f.create_group("profile")
        for k, v in header.items():
            # cvt-engine writes the counts as integers; the fixed-string variant checks doubles too.
            p.attrs[k] = float(v) if fixed_strings and not isinstance(v, str) else v
        names = [r["name"] for r in rows]
        if fixed_strings:
            p["name"] = np.array([n.encode() for n in names], dtype="S32")
        else:
            p.attrs.create("rows", data=names, dtype=h5py.string_dtype())
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
        # The CSVs of `cvt-engine study integrators` (columns as engine/studies/integrators.cpp writes them).
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


def load_tool():
    spec = importlib.util.spec_from_file_location("cvt_plot", TOOL)
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


def write_channels(path, channels, snapshots=None, config=CONFIG):
    """A run file with the given {name: (time, value, unit)} and optional (time, pos, tension)."""
    with h5py.File(path, "w") as f:
        for name, (t, v, unit) in channels.items():
            f[f"observables/{name}/time"] = t
            f[f"observables/{name}/value"] = v
            f[f"observables/{name}/value"].attrs["unit"] = unit
        if snapshots is not None:
            ts, pos, ten = snapshots
            f["particles/chain/position/time"] = ts
            f["particles/chain/position/value"] = pos
            f["particles/chain/link_tension/time"] = ts
            f["particles/chain/link_tension/value"] = ten
        if config is not None:
            f["parameters/config"] = config


def strand_layout_tensions(pos, R=0.02, upper=3000.0, lower=1000.0, arc=9999.0):
    """Tension of link i from where its first joint lies: `upper` on the top straight strand
    (y = R), `lower` on the bottom one (y = -R), `arc` on the pulleys."""
    y = pos[..., 1]
    return np.where(np.isclose(y, R), upper, np.where(np.isclose(y, -R), lower, arc))


FIRST_PANELS = ["Speed ratio and geometric ratio", "Slip", "Torques", "Clamping forces", "Sheave positions",
                "Efficiency", "Strand tensions"]
DETAIL_PANELS = ["Link tension", "Plate tension", "Pin axial force", "Chain torsion angle", "Support forces",
                 "Shaft speeds"]


class HistoryFigureTest(unittest.TestCase):
    """The history figure built in-process: panels, order, what each draws."""

    @classmethod
    def setUpClass(cls):
        cls.m = load_tool()
        cls.dir = tempfile.mkdtemp(prefix="cvt_plot_hist_")
        cls.run_h5 = os.path.join(cls.dir, "run.h5")
        write_run(cls.run_h5)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.dir, ignore_errors=True)

    def figure(self, path, **kw):
        f = h5py.File(path, "r")
        self.addCleanup(f.close)
        fig, skipped = self.m.history_figure(f, **kw)
        self.addCleanup(self.m.plt.close, fig)
        axes = {ax.get_title(): ax for ax in fig.axes if ax.get_visible()}
        titles = [ax.get_title() for ax in fig.axes if ax.get_visible()]
        return fig, skipped, axes, titles

    def panel(self, axes, prefix):
        hit = [ax for title, ax in axes.items() if title.startswith(prefix)]
        self.assertEqual(len(hit), 1, f"{prefix}: {list(axes)}")
        return hit[0]

    def test_panels_in_order(self):
        _, skipped, _, titles = self.figure(self.run_h5)
        self.assertEqual(skipped, [])
        want = FIRST_PANELS + DETAIL_PANELS
        self.assertEqual(len(titles), len(want), titles)
        for title, prefix in zip(titles, want):
            self.assertTrue(title.startswith(prefix), f"{title!r} where {prefix!r} belongs: {titles}")

    def test_panel_list_function(self):
        with h5py.File(self.run_h5, "r") as f:
            titles = [p.title for p in self.m.history_panels(f) if p.present]
        self.assertEqual([next(w for w in FIRST_PANELS + DETAIL_PANELS if t.startswith(w)) for t in titles],
                         FIRST_PANELS + DETAIL_PANELS)

    def test_ratio_slip_sheave_clamping_contents(self):
        _, _, axes, _ = self.figure(self.run_h5)
        ratio = self.panel(axes, "Speed ratio")
        labels = [l.get_label() for l in ratio.get_lines()]
        self.assertTrue(any("speed ratio" in x for x in labels) and any("geometric" in x for x in labels), labels)
        slip = self.panel(axes, "Slip")
        self.assertIn("%", slip.get_ylabel())
        y = np.concatenate([l.get_ydata() for l in slip.get_lines() if len(l.get_ydata()) > 2])
        self.assertAlmostEqual(float(np.min(y)), 100 * float(np.min(SLIP(np.arange(600) * 1e-5))), places=9)
        sheave = self.panel(axes, "Sheave positions")
        self.assertIn("[mm]", sheave.get_ylabel())
        ys = [l.get_ydata() for l in sheave.get_lines()]
        self.assertEqual(len(ys), 2)
        self.assertAlmostEqual(float(np.max(ys[1])), 0.2, places=9)  # 2e-4 m drawn as 0.2 mm
        self.assertAlmostEqual(float(np.min(ys[0])), -0.2, places=9)
        clamp = self.panel(axes, "Clamping forces")
        self.assertIn("[kN]", clamp.get_ylabel())
        self.assertEqual(sorted(round(float(np.max(l.get_ydata())), 6) for l in clamp.get_lines()), [8.0, 10.0])
        torques = self.panel(axes, "Torques")
        self.assertEqual(len(torques.get_lines()), 3)

    def eff_file(self, name, running, inst=None, works=True):
        t = np.arange(500) * 1e-5
        ch = {"running_efficiency": (t, running(t), "1"), "input_speed": (t, 200 + 0 * t, "rad/s")}
        if inst is not None:
            ch["efficiency"] = (t, inst(t), "1")
        if works:
            p_in = 2000.0
            ch["work_input"] = (t, p_in * t, "J")
            ch["work_dissipated"] = (t, 0.03 * p_in * t, "J")
        path = os.path.join(self.dir, name)
        write_channels(path, ch)
        return path

    def eff_note(self, ax):
        return [x.get_text() for x in ax.texts if x.get_gid() == "efficiency-note"]

    def test_efficiency_fixed_axis_and_note_in_transient(self):
        # A start-up like a real run's: the running efficiency at 88 for 2 ms, then 0.95.
        path = self.eff_file("eff_transient.h5", lambda t: np.where(t < 2e-3, 88.0, 0.95),
                             inst=lambda t: np.where(t < 1e-3, -6000.0, 0.96))
        _, _, axes, _ = self.figure(path)
        ax = self.panel(axes, "Efficiency")
        lo, hi = ax.get_ylim()
        self.assertAlmostEqual(lo, -0.1)
        self.assertAlmostEqual(hi, 1.1)
        note = self.eff_note(ax)
        self.assertEqual(len(note), 1, [x.get_text() for x in ax.texts])
        self.assertIn("not meaningful", note[0])
        self.assertIn("88", note[0])
        self.assertIn("-6e+03", note[0])
        self.assertIn("running: 0-1.99 ms", note[0])
        # The running efficiency is drawn (off the axis while it is 88) and its span shaded.
        self.assertTrue(any("running" in l.get_label() for l in ax.get_lines()))
        self.assertGreaterEqual(len(ax.patches), 1)

    def test_efficiency_in_range_has_no_note(self):
        path = self.eff_file("eff_steady.h5", lambda t: 0.95 + 0.01 * np.sin(t * 5e3),
                             inst=lambda t: 0.9 + 0.05 * np.sin(t * 7e3))
        _, _, axes, _ = self.figure(path)
        ax = self.panel(axes, "Efficiency")
        self.assertEqual(tuple(round(x, 9) for x in ax.get_ylim()), (-0.1, 1.1))
        self.assertEqual(self.eff_note(ax), [])
        self.assertEqual(len(ax.patches), 0)
        labels = [l.get_label() for l in ax.get_lines()]
        self.assertTrue(any("engine" in x for x in labels), labels)  # running_efficiency shown
        self.assertTrue(any("ΔW_diss" in x for x in labels), labels)

    def test_efficiency_outside(self):
        t = np.arange(10) * 1.0
        v = np.array([0.5, 1.2, 1.3, 0.9, 0.9, -0.2, 0.5, np.nan, 0.5, 2.0])
        mask, spans, ext = self.m.efficiency_outside(t, v)
        self.assertEqual(list(np.nonzero(mask)[0]), [1, 2, 5, 9])
        self.assertEqual(spans, [(1.0, 2.0), (5.0, 5.0), (9.0, 9.0)])
        self.assertEqual(ext, 2.0)
        self.assertEqual(self.m.efficiency_outside(t, np.full(10, 0.97))[1], [])

    def test_strand_tensions_from_snapshots(self):
        a, R = 0.06, 0.02
        pos = chain_positions(7, 60, a=a, R=R)
        ten = strand_layout_tensions(pos, R)
        up, lo, nu, nl = self.m.strand_tensions(pos, ten, a)
        np.testing.assert_allclose(up, 3000.0)
        np.testing.assert_allclose(lo, 1000.0)
        self.assertTrue(np.all(nu >= 3) and np.all(nl >= 3), (nu, nl))
        # A link whose tension changes only on the pulleys leaves the strand means alone.
        ten2 = np.where(ten == 9999.0, -5e5, ten)
        np.testing.assert_allclose(self.m.strand_tensions(pos, ten2, a)[0], 3000.0)

    def test_strand_panel_tight_slack_and_demand(self):
        # Lower strand the tighter one here: the panel calls it tight; demand = |M_out| / R2.
        a, R = 0.06, 0.02
        S = 6
        ts = np.arange(S) * 1e-4
        pos = chain_positions(S, 60, a=a, R=R)
        ten = strand_layout_tensions(pos, R, upper=800.0, lower=2500.0)
        t = np.arange(60) * 1e-5
        path = os.path.join(self.dir, "strands.h5")
        write_channels(path, {"output_torque": (t, -10.0 + 0 * t, "N m"), "input_speed": (t, 200 + 0 * t, "rad/s")},
                       snapshots=(ts, pos, ten))
        with h5py.File(path, "r") as f:
            s = self.m.read_strands(f)
        self.assertFalse(s["tight_is_upper"])
        np.testing.assert_allclose(s["tight"], 2500.0)
        np.testing.assert_allclose(s["slack"], 800.0)
        np.testing.assert_allclose(s["demand"], 10.0 / R, rtol=1e-9)
        _, _, axes, _ = self.figure(path)
        ax = self.panel(axes, "Strand tensions")
        lines = {l.get_label(): l.get_ydata() for l in ax.get_lines()}
        self.assertIn("tight (lower) strand", lines)
        np.testing.assert_allclose(lines["tight (lower) strand"], 2.5)  # kN
        np.testing.assert_allclose(lines["tight - slack"], 1.7)

    def test_no_snapshots_skips_strand_panel_with_note(self):
        path = os.path.join(self.dir, "nosnap.h5")
        write_run(path)
        with h5py.File(path, "a") as f:
            del f["particles"]
        fig, skipped, _, titles = self.figure(path)
        self.assertFalse(any(x.startswith("Strand") for x in titles), titles)
        self.assertEqual([p.title.split(" (")[0] for p in skipped], ["Strand tensions"])
        notes = [x.get_text() for x in fig.texts if x.get_gid() == "skipped-note"]
        self.assertEqual(len(notes), 1)
        self.assertIn("snapshots", notes[0])
        p = subprocess.run([PYTHON, TOOL, "history", path, "-o", os.path.join(self.dir, "nosnap.png")],
                           capture_output=True, text=True, timeout=300)
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertIn("Strand tensions", p.stderr)
        self.assertIn("snapshots", p.stderr)


class StudyFiguresTest(unittest.TestCase):
    """The figures of cvt-engine sweep, study slip and study shift from their CSV files."""

    SWEEP_HEAD = ("load.torque,clamping.driving,status,speed_ratio,geometric_ratio,slip,input_torque,output_torque,"
                  "efficiency,input_speed,output_speed,load_torque,clamping_force_driving,clamping_force_driven,"
                  "model_time,point,reason,wall_s\n")

    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="cvt_plot_studies_")
        self.addCleanup(shutil.rmtree, self.dir, True)

    def write(self, name, text):
        path = os.path.join(self.dir, name)
        with open(path, "w") as fh:
            fh.write(text)
        return path

    def plot(self, *args):
        return subprocess.run([PYTHON, TOOL, *args], capture_output=True, text=True, timeout=300)

    def sweep_csv(self):
        rows = []
        for i, (m, f1) in enumerate([(m, f) for m in (5, 10, 15) for f in (1.1e4, 1.2e4, 1.3e4)]):
            st = "slip" if m == 15 and f1 == 1.1e4 else "steady"
            rows.append(f"{m},{f1},{st},1.0,0.99,0.01,{m * 1.2},{m},{0.8 + 0.001 * m},209.4,207,{m},{f1},1e4,0.03,"
                        f"{i},,1.5\n")
        return self.write("sweep.csv", self.SWEEP_HEAD + "".join(rows))

    def test_sweep_contours_over_two_keys_and_thrust_ratio(self):
        path = self.sweep_csv()
        for extra in ([], ["--column", "thrust_ratio"], ["--all"]):
            out = os.path.join(self.dir, "sweep-%d.png" % len(extra))
            p = self.plot("sweep", path, *extra, "-o", out)
            self.assertEqual(p.returncode, 0, p.stderr)
            self.assertTrue(os.path.getsize(out) > 0)
        mod = load_tool()
        rows = mod._read_csv(path, mod.SWEEP_RESULTS)
        self.assertEqual(len(rows), 9)

    def test_sweep_where_slices_a_map_over_more_keys(self):
        path = self.sweep_csv()
        out = os.path.join(self.dir, "slice.png")
        p = self.plot("sweep", path, "--where", "clamping.driving=1.2e4", "-o", out)  # load.torque alone
        self.assertEqual(p.returncode, 0, p.stderr)
        self.assertIn("over 3 points", self.plot_title(path, "clamping.driving=12000"))
        for bad, why in (("clamping.driving=9e9", "no point"), ("nokey=1", "KEY=VALUE"), ("load.torque", "KEY=VALUE")):
            p = self.plot("sweep", path, "--where", bad, "-o", out)
            self.assertEqual(p.returncode, 2, bad)
            self.assertIn(why, p.stderr)

    def plot_title(self, path, where):
        mod = load_tool()
        captured = {}
        real = mod.save
        mod.save = lambda fig, out: captured.setdefault("title", fig.axes[0].get_title())
        try:
            mod.cmd_sweep(mod.argparse.Namespace(file=path, column="efficiency", x=None, y=None, all=False,
                                                 where=[where], out="unused.png"))
        finally:
            mod.save = real
        return captured["title"]

    def test_sweep_over_one_key_and_bad_column(self):
        one = self.write("one.csv", self.SWEEP_HEAD.replace("load.torque,", "") +
                         "1.1e4,steady,1,1,0,1,1,0.9,1,1,1,1.1e4,1e4,0.1,0,,1\n"
                         "1.2e4,not_steady,1,1,0,1,1,0.91,1,1,1,1.2e4,1e4,0.1,1,\"shifting, a reason\",1\n")
        p = self.plot("sweep", one, "-o", os.path.join(self.dir, "one.png"))
        self.assertEqual(p.returncode, 0, p.stderr)
        p = self.plot("sweep", one, "--column", "nonsense", "-o", os.path.join(self.dir, "bad.png"))
        self.assertEqual(p.returncode, 2)
        self.assertIn("no column nonsense", p.stderr)
        p = self.plot("sweep", self.write("empty.csv", "a,b\n"), "-o", os.path.join(self.dir, "e.png"))
        self.assertEqual(p.returncode, 2)

    def test_slip_and_shift(self):
        slip = self.write("slip.csv", "clamping_force_driving,clamping_force_driven,ratio,slip_torque,theory_torque,"
                          "slip_over_theory,slips_at,runs,note,wall_s\n"
                          "25000,30000,1,200,256.8,0.78,204,8,,100\n37000,30000,1,250,308,0.81,255,8,,100\n")
        p = self.plot("slip", slip, "-o", os.path.join(self.dir, "slip.png"))
        self.assertEqual(p.returncode, 0, p.stderr)
        shift = self.write("shift.csv", "input_speed,thrust_ratio,ln_thrust_ratio,shift_rate,steady_thrust_ratio,"
                           "ratio_start,ratio_end,steady_status,wall_s\n"
                           "104.7,0.9,-0.105,0.29,1.13,1,1.005,steady,3\n104.7,1.4,0.336,-0.59,1.13,1,0.996,steady,3\n"
                           "209.4,0.9,-0.105,0.79,1.13,1,1.006,steady,3\n209.4,1.4,0.336,-0.86,1.13,1,0.992,steady,3\n")
        p = self.plot("shift", shift, "-o", os.path.join(self.dir, "shift.png"))
        self.assertEqual(p.returncode, 0, p.stderr)
        p = self.plot("shift", slip, "-o", os.path.join(self.dir, "x.png"))  # not a shift study
        self.assertEqual(p.returncode, 2)
        self.assertIn("missing column", p.stderr)


class ShortOutTest(unittest.TestCase):
    """-o is --out in every subcommand."""

    ARGS = {"history": ["RUN.h5"], "profile": ["RUN.h5"], "scaling": ["STUDY.csv"],
            "spectrogram": ["RUN.h5", "output_torque"], "animate": ["RUN.h5"], "integrators": ["STUDY.csv"],
            "sweep": ["SWEEP.csv"], "slip": ["SLIP.csv"], "shift": ["SHIFT.csv"]}

    def test_every_subcommand_parses_o(self):
        ap = load_tool().build_parser()
        sub = next(x for x in ap._actions if isinstance(x, argparse._SubParsersAction))
        self.assertEqual(set(sub.choices), set(self.ARGS), "a subcommand without a case here")
        for cmd, args in self.ARGS.items():
            a = ap.parse_args([cmd, *args, "-o", "/tmp/x-short.png"])
            self.assertEqual(a.out, "/tmp/x-short.png", cmd)
            b = ap.parse_args([cmd, *args, "--out", "/tmp/x-long.png"])
            self.assertEqual(b.out, "/tmp/x-long.png", cmd)

    def test_o_writes_the_file(self):
        d = tempfile.mkdtemp(prefix="cvt_plot_o_")
        self.addCleanup(shutil.rmtree, d, True)
        run = os.path.join(d, "run.h5")
        write_run(run)
        study = os.path.join(d, "study.csv")
        with open(study, "w") as fh:
            fh.write(",".join(SCALING_COLUMNS) + "\n")
            for r in scaling_rows():
                fh.write(",".join(str(r[k]) for k in SCALING_COLUMNS) + "\n")
        for cmd, args, out in [("history", [run], "h.png"), ("profile", [run], "p.png"), ("scaling", [study], "s.png"),
                               ("spectrogram", [run, "output_torque"], "sp.png"),
                               ("animate", [run, "--every", "10"], "c.gif")]:
            p = subprocess.run([PYTHON, TOOL, cmd, *args, "-o", os.path.join(d, out)], capture_output=True,
                               text=True, timeout=300)
            self.assertEqual(p.returncode, 0, p.stderr)
            self.assertTrue(os.path.getsize(os.path.join(d, out)) > 1000, cmd)


if __name__ == "__main__":
    unittest.main()
