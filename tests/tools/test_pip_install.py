#!/usr/bin/python3
"""`pip install .` into a fresh virtual environment (Debian's python3-venv; it sees Debian's
NumPy through --system-site-packages), from no package index: the package imports from
another folder without PYTHONPATH, carries its type information (py.typed, stubs) and the
shipped configurations, runs, and converts its result to pandas and xarray with units where
those are installed.

    /usr/bin/python3 tests/tools/test_pip_install.py [--prebuilt build/python/cvt_engine] [-v]

With --prebuilt the backend packs that built package (CVT_PIP_PACKAGE_DIR) instead of
building the extension again (the fast suite); without it, it builds with CMake (the slow
suite: minutes).
"""
import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import unittest

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
PREBUILT = None


@unittest.skipIf(subprocess.run([sys.executable, "-c", "import venv, ensurepip"], capture_output=True).returncode,
                 "python3-venv is not installed")
class PipInstall(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="cvt-pip-")
        cls.venv = os.path.join(cls.dir, "venv")
        subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", cls.venv], check=True)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        if PREBUILT:
            env["CVT_PIP_PACKAGE_DIR"] = os.path.abspath(PREBUILT)
        cls.install = subprocess.run([os.path.join(cls.venv, "bin", "pip"), "install", "--no-index", ROOT],
                                     env=env, capture_output=True, text=True, timeout=3600)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.dir)

    def python(self, code):
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        elsewhere = os.path.join(self.dir, "elsewhere")
        os.makedirs(elsewhere, exist_ok=True)
        return subprocess.run([os.path.join(self.venv, "bin", "python"), "-c", textwrap.dedent(code)], cwd=elsewhere,
                              env=env, capture_output=True, text=True, timeout=600)

    def test_it_installs_and_imports_from_another_folder(self):
        self.assertEqual(self.install.returncode, 0, self.install.stdout + self.install.stderr)
        r = self.python("""
            import os, cvt_engine as cvt
            here = os.path.dirname(cvt.__file__)
            print(here)
            assert "site-packages" in here, here
            for f in ("py.typed", "__init__.pyi", "_core.pyi"):
                assert os.path.isfile(os.path.join(here, f)), f
            assert os.path.isfile(cvt.shipped_config("mini"))
            print(cvt.__version__)
        """)
        self.assertEqual(r.returncode, 0, r.stdout + r.stderr)

    def test_the_readme_example_runs_and_converts_with_units(self):
        self.assertEqual(self.install.returncode, 0, self.install.stdout + self.install.stderr)
        r = self.python("""
            import cvt_engine as cvt
            r = cvt.run(cvt.shipped_config("mini"), overrides={"load.torque": 15}, t_end=0.002)
            print(r.summary["status"], r.summary["units"]["input_torque"], r.units["output_torque"])
            assert r.summary["units"]["input_torque"] == "N m" and r.units["output_torque"] == "N m"
            try:
                import pandas
            except ImportError:
                print("no pandas")
            else:
                df = r.to_pandas()
                assert df.index.name == "time" and df.attrs["units"]["sheave_position[1]"] == "m", df.attrs
                assert len(df) == len(r.channels["time"])
            try:
                import xarray
            except ImportError:
                print("no xarray")
            else:
                ds = r.to_xarray()
                assert ds["output_torque"].attrs["units"] == "N m" and ds["time"].attrs["units"] == "s"
                assert ds["plate_tension"].dims[1] == "plate_tension_index"
        """)
        self.assertEqual(r.returncode, 0, r.stdout + r.stderr)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--prebuilt")
    args, rest = ap.parse_known_args()
    PREBUILT = args.prebuilt
    unittest.main(argv=[sys.argv[0]] + rest)
