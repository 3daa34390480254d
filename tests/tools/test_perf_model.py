#!/usr/bin/python3
"""tools/perf_model.py on synthetic profiles whose split into serial and parallel parts is
known: the calibration recovers it, the prediction follows Amdahl's law per section with
its cap, and bad input exits with a message.

    /usr/bin/python3 tests/tools/test_perf_model.py [-v]
"""
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
TOOL = os.path.join(HERE, "..", "..", "tools", "perf_model.py")
spec = importlib.util.spec_from_file_location("perf_model", TOOL)
pm = importlib.util.module_from_spec(spec)
spec.loader.exec_module(pm)

# Known parts [us per step]: (serial part, parallel work, cap).
TRUE = {"chain forces": (10.0, 200.0, 84), "W solves": (30.0, 100.0, 2), "integrator update": (20.0, 0.0, 1)}


def profile(threads, sync=0.0):
    rows = []
    for name, (s, w, cap) in TRUE.items():
        rows.append({"name": name, "us_per_step": s + w / min(threads, cap)})
    if threads > 1:
        rows.append({"name": "scheduling", "us_per_step": sync})
    total = sum(r["us_per_step"] for r in rows)
    rows.append({"name": "total", "us_per_step": total})
    return {"header": {"threads": threads, "us_per_step": total}, "rows": rows}


class PerfModel(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.mkdtemp()
        self.one = os.path.join(self.dir, "one.json")
        self.four = os.path.join(self.dir, "four.json")
        with open(self.one, "w") as f:
            json.dump(profile(1), f)
        with open(self.four, "w") as f:
            json.dump(profile(4, sync=6.0), f)

    def test_calibration_recovers_the_parts(self):
        _, s = pm.rows(self.one)
        _, p = pm.rows(self.four)
        model = pm.calibrate(s, p, 4, 84)
        for name, (ts, tw, cap) in TRUE.items():
            ms, mw, mcap = model[name]
            self.assertEqual(mcap, cap)
            self.assertAlmostEqual(ms, ts, places=9)
            self.assertAlmostEqual(mw, tw, places=9)

    def test_prediction_is_amdahl_per_section(self):
        _, s = pm.rows(self.one)
        _, p = pm.rows(self.four)
        model = pm.calibrate(s, p, 4, 84)
        for threads in (1, 2, 8, 16):
            want = sum(ts + tw / min(threads, cap) for ts, tw, cap in TRUE.values())
            if threads > 1:
                want += 6.0 * (threads.bit_length() - 1) / 2 * (2.0 if threads > 14 else 1.0)
            self.assertAlmostEqual(pm.predict(model, 6.0, 4, threads, 14, 2.0), want, places=9)
        # The two-sweep and master parts bound the speed-up: (10 + 200 + 30 + 100 + 20) / (10 + 30 + 50 + 20).
        self.assertLess(pm.predict(model, 0.0, 4, 1, 14, 2.0) / pm.predict(model, 0.0, 4, 10**6, 14, 2.0), 360 / 110 + 1e-9)

    def test_segments_cap_the_block_lu_at_their_count(self):
        # The same profiles read as those of the block LU on 8 segments: W solves' parallel
        # work divides over up to 8 threads; the other sections keep their caps.
        _, s = pm.rows(self.one)
        _, p = pm.rows(self.four)
        model = pm.calibrate(s, p, 4, 84, segments=8)
        self.assertEqual(model["W solves"][2], 8)
        self.assertEqual(model["chain forces"][2], 84)
        self.assertEqual(model["integrator update"][2], 1)
        self.assertEqual(pm.cap_of("W factorization", 84, 0), 2)
        self.assertEqual(pm.cap_of("W factorization", 84, 12), 12)
        two = pm.calibrate(s, p, 4, 84)
        self.assertLess(pm.predict(model, 0.0, 4, 8, 14, 2.0), pm.predict(two, 0.0, 4, 8, 14, 2.0))

    def test_command_line(self):
        out = subprocess.run([sys.executable, TOOL, self.one, self.four, "--threads", "1,4", "--step", "1e-6"],
                             capture_output=True, text=True)
        self.assertEqual(out.returncode, 0, out.stderr)
        self.assertIn("min per model s", out.stdout)
        bad = subprocess.run([sys.executable, TOOL, self.four, self.one], capture_output=True, text=True)
        self.assertNotEqual(bad.returncode, 0)
        self.assertIn("serial profile first", bad.stderr)
        self.assertNotIn("Traceback", bad.stderr)


if __name__ == "__main__":
    unittest.main()
