#!/usr/bin/python3
"""tools/check_house.py on small trees written here: it passes a clean tree, counting every
function in it, and fails on each broken rule, naming the file, the line, the name, the
length and the limit.

    /usr/bin/python3 tests/tools/test_check_house.py [-v]
"""
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
TOOL = os.path.normpath(os.path.join(HERE, "..", "..", "tools", "check_house.py"))


def lines(n, text="  s += 1.0;"):
    return "\n".join([text] * n)


# A tree with one file in each of three layers, each upper one including the one below.
# Its functions, in the order they appear: now, Clock::Clock, Clock::tick, Clock::operator<,
# Thing::Thing, Thing::mass (a signature over three lines), twice (static), law: eight
# functions (a declaration and `= default` have no body).
CLEAN = {
    "engine/base/timing.hpp": """#pragma once
namespace cvt {
inline double now() { return 0.0; }
struct Clock {
  Clock() : t(now()) {}
  void tick() {
    t += 1.0;
  }
  bool operator<(const Clock& o) const { return t < o.t; }
  double t;
};
}  // namespace cvt
""",
    "engine/model/thing.hpp": """#pragma once
#include "engine/base/timing.hpp"
namespace cvt {
class Thing {
 public:
  Thing();
  ~Thing();
  double mass(double density,
              double volume,
              double scale) const;
};
}  // namespace cvt
""",
    "engine/model/thing.cpp": """#include "engine/model/thing.hpp"
namespace cvt {
namespace {
static double twice(double x) { return 2.0 * x; }
}  // namespace
Thing::Thing() {
  now();
}
Thing::~Thing() = default;
double Thing::mass(double density,
                   double volume,
                   double scale) const {
  return twice(density * volume * scale);
}
}  // namespace cvt
""",
    "modules/law.cpp": """#include "engine/model/thing.hpp"
namespace cvt {
double law(const Thing& thing) {
  return thing.mass(1.0, 2.0, 3.0);
}
}  // namespace cvt
""",
}
CLEAN_FUNCTIONS = 8


def long_function(body_lines):
    """A function whose signature spans three lines and whose length, from its name to its
    closing brace, is body_lines + 6."""
    return f"""namespace cvt {{
double long_sum(double a,
                double b,
                double c) {{
  double s = a + b + c;
{lines(body_lines)}
  return s;
}}
}}  // namespace cvt
"""


class CheckHouse(unittest.TestCase):
    def setUp(self):
        if shutil.which("ctags") is None:
            self.fail("ctags is missing: install the Debian package universal-ctags")
        self.root = tempfile.mkdtemp()
        self.addCleanup(shutil.rmtree, self.root)
        self.write(CLEAN)

    def write(self, files):
        for path, text in files.items():
            full = os.path.join(self.root, path)
            os.makedirs(os.path.dirname(full), exist_ok=True)
            with open(full, "w") as f:
                f.write(text)

    def check(self, env=None):
        run = subprocess.run([sys.executable, TOOL, "--root", self.root], capture_output=True, text=True, env=env)
        return run.returncode, run.stdout + run.stderr

    def assert_fails_naming(self, *words):
        rc, out = self.check()
        self.assertEqual(rc, 1, out)
        broken = [line for line in out.splitlines() if all(w in line for w in words)]
        self.assertEqual(len(broken), 1, f"no single line with {words} in:\n{out}")

    def test_a_clean_tree_passes_with_every_function_counted(self):
        rc, out = self.check()
        self.assertEqual(rc, 0, out)
        self.assertIn(f" {CLEAN_FUNCTIONS} functions", out)
        self.assertIn("0 broken rules", out)

    def test_a_function_over_120_lines_with_a_signature_over_three_lines_fails(self):
        self.write({"engine/model/long.cpp": long_function(124)})
        self.assert_fails_naming("engine/model/long.cpp:2:", "long_sum", "130 lines", "120")

    def test_a_function_of_exactly_120_lines_passes(self):
        self.write({"engine/model/long.cpp": long_function(114)})
        rc, out = self.check()
        self.assertEqual(rc, 0, out)
        self.write({"engine/model/long.cpp": long_function(115)})
        self.assert_fails_naming("engine/model/long.cpp:2:", "long_sum", "121 lines")

    def test_a_lambda_over_120_lines_fails_even_outside_a_function(self):
        self.write({"engine/model/lambda.cpp": "namespace cvt {\nconst auto stepper = [](double s) {\n"
                    + lines(125) + "\n  return s;\n};\n}  // namespace cvt\n"})
        self.assert_fails_naming("engine/model/lambda.cpp:2:", "lambda", "128 lines", "120")

    def test_a_constructor_over_60_lines_fails_out_of_its_class_and_inside_it(self):
        self.write({"engine/model/thing.cpp": CLEAN["engine/model/thing.cpp"].replace(
            "Thing::Thing() {\n", "Thing::Thing() {\n" + lines(67, "  now();") + "\n")})
        self.assert_fails_naming("engine/model/thing.cpp:6:", "constructor", "Thing::Thing", "70 lines", "60")
        self.write({"engine/model/thing.cpp": CLEAN["engine/model/thing.cpp"]})
        self.write({"engine/base/timing.hpp": CLEAN["engine/base/timing.hpp"].replace(
            "  Clock() : t(now()) {}\n", "  Clock() : t(now()) {\n" + lines(68, "    tick();") + "\n  }\n")})
        self.assert_fails_naming("engine/base/timing.hpp:5:", "constructor", "Clock::Clock", "70 lines", "60")

    def test_a_long_constructor_in_the_else_branch_of_a_class_fails(self):
        # ctags itself reads only the first branch of an #if inside a class.
        self.write({"engine/base/timing.hpp": CLEAN["engine/base/timing.hpp"].replace(
            "  Clock() : t(now()) {}\n", "#if defined(FAST)\n  Clock() : t(0.0) {}\n#else\n  Clock() : t(now()) {\n"
            + lines(68, "    tick();") + "\n  }\n#endif\n")})
        self.assert_fails_naming("engine/base/timing.hpp:8:", "constructor", "Clock::Clock", "70 lines", "60")

    def test_a_class_over_400_lines_fails(self):
        members = "\n".join(f"  double m{i};" for i in range(448))
        self.write({"engine/model/big.hpp": f"#pragma once\nnamespace cvt {{\nclass Big {{\n{members}\n}};\n}}\n"})
        self.assert_fails_naming("engine/model/big.hpp:3:", "class", "Big", "450 lines", "400")

    def test_a_source_folder_missing_from_the_layers_fails(self):
        self.write({"engine/newpart/part.hpp": "#pragma once\nnamespace cvt {\ninline int part() { return 1; }\n}\n"})
        self.assert_fails_naming("engine/newpart/", "LAYERS")

    def test_an_include_against_the_layers_fails(self):
        self.write({"modules/law.hpp": "#pragma once\nnamespace cvt {\ndouble law();\n}\n"})
        self.write({"engine/model/thing.cpp": CLEAN["engine/model/thing.cpp"].replace(
            '#include "engine/model/thing.hpp"\n', '#include "engine/model/thing.hpp"\n#include "modules/law.hpp"\n')})
        self.assert_fails_naming("engine/model/thing.cpp:2:", "modules/law.hpp", "may not include")

    def test_without_ctags_it_names_the_package_and_fails(self):
        empty = tempfile.mkdtemp()
        self.addCleanup(shutil.rmtree, empty)
        rc, out = self.check(env=dict(os.environ, PATH=empty))
        self.assertEqual(rc, 2, out)
        self.assertIn("universal-ctags", out)


if __name__ == "__main__":
    unittest.main()
