#!/usr/bin/python3
"""`make deps` for a user without root: with a package missing it names the package, says
how to get it and stops before apt-get (exit non-zero); with nothing missing it runs
nothing and succeeds. Run as root, the checks run as the user `nobody` (runuser); run by a
user with password-less sudo, they are skipped (that user can install).

    /usr/bin/python3 tests/tools/test_make_deps.py [-v]
"""
import os
import shutil
import subprocess
import tempfile
import time
import unittest

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")


def as_plain_user(cmd):
    if os.getuid() == 0:
        return ["runuser", "-u", "nobody", "--"] + cmd
    return cmd


def can_sudo():
    if os.getuid() == 0 or shutil.which("sudo") is None:
        return False
    return subprocess.run(["sudo", "-n", "true"], capture_output=True).returncode == 0


@unittest.skipIf(can_sudo(), "this user has password-less sudo: make deps would install")
@unittest.skipIf(os.getuid() == 0 and shutil.which("runuser") is None, "root without runuser")
class MakeDepsWithoutRoot(unittest.TestCase):
    def setUp(self):
        # The Makefile and its installer in a folder `nobody` can read, with a viewer whose
        # libraries are already there (so that npm is not run).
        self.dir = tempfile.mkdtemp(prefix="cvt-make-deps-")
        os.chmod(self.dir, 0o755)
        shutil.copy(os.path.join(ROOT, "Makefile"), self.dir)
        os.makedirs(os.path.join(self.dir, "tools", "viewer", "node_modules"))
        shutil.copy(os.path.join(ROOT, "tools", "install_packages.sh"), os.path.join(self.dir, "tools"))
        open(os.path.join(self.dir, "tools", "viewer", "package-lock.json"), "w").close()
        stamp = os.path.join(self.dir, "tools", "viewer", "node_modules", ".package-lock.json")
        open(stamp, "w").close()
        later = time.time() + 10
        os.utime(stamp, (later, later))
        for d, _, files in os.walk(self.dir):
            os.chmod(d, 0o755)
            for f in files:
                os.chmod(os.path.join(d, f), 0o755)

    def tearDown(self):
        shutil.rmtree(self.dir)

    def make_deps(self, packages):
        return subprocess.run(as_plain_user(["make", "deps", "PACKAGES=" + packages]), cwd=self.dir,
                              capture_output=True, text=True, timeout=120)

    def test_a_missing_package_is_named_and_make_stops(self):
        r = self.make_deps("cmake cvt-engine-no-such-package")
        self.assertNotEqual(r.returncode, 0, r.stdout + r.stderr)
        self.assertIn("cannot install", r.stderr)
        self.assertIn("apt-get install --no-install-recommends cvt-engine-no-such-package", r.stderr)
        self.assertNotIn("cmake", r.stderr.split("missing")[1].split("Ask")[0], "an installed package is listed")
        self.assertIn("docs/install.md", r.stderr)
        self.assertNotIn("installing:", r.stdout)

    def test_nothing_missing_runs_nothing(self):
        r = self.make_deps("cmake make")
        self.assertEqual(r.returncode, 0, r.stdout + r.stderr)
        self.assertEqual(r.stdout + r.stderr, "")


if __name__ == "__main__":
    unittest.main()
