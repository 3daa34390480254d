#!/usr/bin/python3
"""A run's file read by an H5MD 1.1 checker written from the specification (H5MD 1.1,
de Buyl et al., Comput. Phys. Commun. 185 (2014) 1546, and the units module), not from the
engine's code: the /h5md group, every time-dependent element of /observables and
/particles, the particles group's box, the units; then the engine's own promises on top:
the step datasets count the integrator's steps, a continued file keeps them rising, and
the file records its provenance.

    /usr/bin/python3 tests/tools/test_h5md.py --engine build/cvt-engine [-v]
"""
import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib
import unittest

import h5py
import numpy as np

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
ENGINE = None


def h5md_problems(f):
    """What in the open h5py.File f breaks H5MD 1.1 (an empty list: a conforming file)."""
    bad = []

    def string_attr(obj, name, where):
        if name not in obj.attrs:
            bad.append(f"{where}: no attribute '{name}'")
            return None
        v = obj.attrs[name]
        if not isinstance(v, (str, bytes)):
            bad.append(f"{where}@{name}: not a string ({type(v).__name__})")
        return v

    def version_attr(obj, where, major=None):
        v = obj.attrs.get("version")
        if v is None:
            bad.append(f"{where}: no attribute 'version'")
            return
        a = np.asarray(v)
        if a.shape != (2,) or a.dtype.kind not in "iu":
            bad.append(f"{where}@version: must be an integer [2], is {a.dtype}{list(a.shape)}")
        elif major is not None and a[0] != major:
            bad.append(f"{where}@version: major {a[0]}, the checker reads {major}")

    # The H5MD group: version [1, x], author (name, optional email), creator (name, version).
    if "h5md" not in f or not isinstance(f["h5md"], h5py.Group):
        return ["no /h5md group"]
    h = f["h5md"]
    version_attr(h, "/h5md", major=1)
    for sub, names in (("author", ["name"]), ("creator", ["name", "version"])):
        if sub not in h:
            bad.append(f"/h5md: no group '{sub}'")
            continue
        for n in names:
            string_attr(h[sub], n, f"/h5md/{sub}")
    units = False
    if "modules" in h:
        for name, mod in h["modules"].items():
            version_attr(mod, f"/h5md/modules/{name}")
            if name == "units":
                units = True
                if "system" in mod.attrs:
                    string_attr(mod, "system", "/h5md/modules/units")

    def element(g, where, particles_n=None):
        """A time-dependent element: value, step (integer), optional time; same lengths."""
        if "value" not in g or not isinstance(g["value"], h5py.Dataset):
            bad.append(f"{where}: no dataset 'value'")
            return
        value = g["value"]
        if "step" not in g:
            bad.append(f"{where}: no dataset 'step'")
            return
        step = g["step"]
        if step.dtype.kind not in "iu":
            bad.append(f"{where}/step: not an integer dataset ({step.dtype})")
        if step.ndim == 1:
            if step.shape[0] != value.shape[0]:
                bad.append(f"{where}: step has {step.shape[0]} rows, value {value.shape[0]}")
            s = step[:]
            if s.size > 1 and not np.all(np.diff(s) > 0):
                bad.append(f"{where}/step: not strictly increasing")
        elif step.ndim != 0:
            bad.append(f"{where}/step: neither [variable] nor scalar")
        if "time" in g:
            time = g["time"]
            if time.ndim == 1:
                if time.shape[0] != value.shape[0]:
                    bad.append(f"{where}: time has {time.shape[0]} rows, value {value.shape[0]}")
                if time.dtype.kind != "f":
                    bad.append(f"{where}/time: not a float dataset")
                t = time[:]
                if t.size > 1 and not np.all(np.diff(t) >= 0):
                    bad.append(f"{where}/time: decreasing")
            if units and "unit" in time.attrs and not isinstance(time.attrs["unit"], (str, bytes)):
                bad.append(f"{where}/time@unit: not a string")
        if units and "unit" in value.attrs and not isinstance(value.attrs["unit"], (str, bytes)):
            bad.append(f"{where}/value@unit: not a string")
        if particles_n is not None and (value.ndim < 2 or value.shape[1] != particles_n):
            bad.append(f"{where}/value: not [variable][N]... with the group's N = {particles_n}")

    # Particles: every group holds a box (dimension, boundary) and per-particle elements.
    for name, g in f.get("particles", {}).items():
        where = f"/particles/{name}"
        if "box" not in g:
            bad.append(f"{where}: no box group")
            continue
        box = g["box"]
        dim = box.attrs.get("dimension")
        if dim is None or np.asarray(dim).dtype.kind not in "iu" or np.asarray(dim).shape != ():
            bad.append(f"{where}/box@dimension: not an integer scalar")
            continue
        raw = box.attrs.get("boundary")
        boundary = [] if raw is None else [b.decode() if isinstance(b, bytes) else str(b) for b in np.atleast_1d(raw)]
        if len(boundary) != int(dim) or any(b not in ("periodic", "none") for b in boundary):
            bad.append(f"{where}/box@boundary: not {int(dim)} of 'periodic' or 'none'")
        if "periodic" in boundary and "edges" not in box:
            bad.append(f"{where}/box: periodic without edges")
        n = None
        for ename, e in g.items():
            if ename == "box" or not isinstance(e, h5py.Group):
                continue
            if n is None and "value" in e and e["value"].ndim >= 2:
                n = e["value"].shape[1]
            element(e, f"{where}/{ename}", particles_n=n)
        if "position" in g and g["position"]["value"].shape[-1] != int(dim):
            bad.append(f"{where}/position/value: last dimension is not the box's {int(dim)}")

    # Observables: elements, possibly in nested groups.
    def observables(g, where):
        for name, e in g.items():
            if isinstance(e, h5py.Group):
                if "value" in e:
                    element(e, f"{where}/{name}")
                else:
                    observables(e, f"{where}/{name}")
    if "observables" in f:
        observables(f["observables"], "/observables")
    return bad


class H5mdChecker(unittest.TestCase):
    """The checker itself finds what is wrong (a checker that passes everything is no check)."""

    def test_it_finds_a_broken_file(self):
        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "bad.h5")
            with h5py.File(path, "w") as f:
                f.create_group("h5md").attrs["version"] = np.array([1.0, 1.0])
                f["h5md"].create_group("creator").attrs["name"] = "x"
                g = f.create_group("observables/a")
                g["value"] = np.zeros(3)
                g["step"] = np.array([0.0, 2.0, 1.0])
                g["time"] = np.zeros(2)
                f.create_group("particles/p/position")["value"] = np.zeros((2, 5, 3))
            with h5py.File(path, "r") as f:
                text = "\n".join(h5md_problems(f))
        for says in ("/h5md@version: must be an integer", "no group 'author'", "/h5md/creator: no attribute 'version'",
                     "/observables/a/step: not an integer", "not strictly increasing", "time has 2 rows",
                     "/particles/p: no box group"):
            self.assertIn(says, text)


class RunFile(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="cvt-h5md-")
        cls.mini = os.path.join(ROOT, "configs", "mini.toml")
        with open(cls.mini, "rb") as fh:
            cls.h = tomllib.load(fh)["integrator"]["step"]
        run = lambda *a: subprocess.run([ENGINE, "run", cls.mini, "-q", *a], cwd=cls.dir, capture_output=True,
                                        text=True, timeout=600)
        r = run("--t-end", "0.0012", "--set", "run.snapshot_interval=1e-4", "-o", "whole.h5")
        assert r.returncode == 0, r.stderr
        # The same run in two parts: to 0.6 ms, then continued into its own file.
        r = run("--t-end", "0.0006", "--set", "run.snapshot_interval=1e-4", "-o", "parts.h5")
        assert r.returncode == 0, r.stderr
        r = subprocess.run([ENGINE, "run", "--resume", "parts.h5.ckpt", "--t-end", "0.0012", "-q"], cwd=cls.dir,
                           capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.dir)

    def test_a_run_file_is_h5md(self):
        for name in ("whole.h5", "parts.h5"):
            with h5py.File(os.path.join(self.dir, name), "r") as f:
                self.assertEqual(h5md_problems(f), [], name)
                self.assertEqual(list(f["h5md"].attrs["version"]), [1, 1])
                self.assertEqual(f["h5md/creator"].attrs["name"], "cvt-engine")

    def test_steps_count_the_integrators_steps(self):
        with h5py.File(os.path.join(self.dir, "parts.h5"), "r") as f:
            for path in ("observables/input_torque", "observables/plate_tension", "particles/chain/position"):
                t, s = f[path + "/time"][:], f[path + "/step"][:]
                np.testing.assert_array_equal(s, np.rint(t / self.h).astype(np.int64), err_msg=path)
                self.assertEqual(f[path + "/time"].attrs["unit"], "s")
            with h5py.File(os.path.join(self.dir, "whole.h5"), "r") as w:
                np.testing.assert_array_equal(f["observables/input_torque/step"][:], w["observables/input_torque/step"][:])

    def test_the_file_says_where_it_came_from_and_its_units(self):
        with h5py.File(os.path.join(self.dir, "whole.h5"), "r") as f:
            p = f["parameters/provenance"].attrs
            for key in ("version", "commit", "compiler", "flags", "instruction_set", "host", "topology"):
                self.assertTrue(isinstance(p[key], str) and p[key], key)
            self.assertIn(p["tree_clean"], (0, 1))
            self.assertIn(p["instruction_set"], p["flags"])
            for name in ("running_radius_driving", "running_radius_driven", "closure_residual"):
                d = f["parameters/geometry/" + name]
                self.assertEqual(d.attrs["unit"], "m")
                self.assertTrue(np.isfinite(d[()]).all())
            import json
            units = json.loads(f["summary"].attrs["units"])
            self.assertEqual(units["input_torque"], "N m")
            self.assertEqual(units["efficiency"], "1")
            for name in units:
                self.assertTrue(name in f["summary"].attrs or name.endswith("_numerical_error"), name)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--engine", default=os.path.join(ROOT, "build", "cvt-engine"))
    args, rest = ap.parse_known_args()
    ENGINE = os.path.abspath(args.engine)
    unittest.main(argv=[sys.argv[0]] + rest)
