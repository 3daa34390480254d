#!/usr/bin/python3
"""The house rules of docs/architecture.md that a program can check.

    tools/check_house.py          # exit 1 on a broken rule, naming the file and line
    tools/check_house.py --dot    # the include graph between the folders, as GraphViz

1. Layers: a folder may include itself and the folders listed for it in LAYERS (each of
   which sits below it), so the data flows one way and there are no cycles between folders.
2. Short functions: no function in engine/, modules/, graph/ or numa/ longer than
   MAX_LINES lines (from its signature to its closing brace; the house style puts a
   function's closing brace at the indentation of its signature).
"""
import os
import re
import sys

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")

# folder -> the folders it may include (bottom to top)
LAYERS = {
    "engine/base": [],
    "engine/io": ["engine/base"],
    "engine/ode": ["engine/base"],
    "numa": [],
    "engine/model": ["engine/base", "engine/io"],
    "modules": ["engine/model", "engine/base"],
    "engine/rhs": ["modules", "engine/model", "engine/ode", "engine/io", "engine/base"],
    "graph": ["engine/rhs", "modules", "engine/model", "engine/ode", "numa", "engine/base"],
    "engine/wmethod": ["graph", "engine/rhs", "modules", "engine/model", "engine/ode", "engine/base"],
    "engine": ["engine/wmethod", "graph", "engine/rhs", "modules", "engine/model", "engine/ode", "engine/io",
               "engine/base"],
    "engine/studies": ["engine", "engine/wmethod", "graph", "engine/rhs", "modules", "engine/model", "engine/ode",
                       "engine/io", "numa", "engine/base"],
    "engine/cli": ["engine/studies", "engine", "engine/wmethod", "graph", "engine/rhs", "modules", "engine/model",
                   "engine/ode", "engine/io", "numa", "engine/base"],
    "engine/python": ["engine/studies", "engine", "engine/wmethod", "graph", "engine/rhs", "modules", "engine/model",
                      "engine/ode", "engine/io", "numa", "engine/base"],
}
MAX_LINES = 120
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def edges():
    for folder in LAYERS:
        path = os.path.join(ROOT, folder)
        for name in sorted(os.listdir(path)):
            if not name.endswith((".cpp", ".hpp")):
                continue
            with open(os.path.join(path, name)) as f:
                for inc in INCLUDE.findall(f.read()):
                    yield f"{folder}/{name}", folder, os.path.dirname(inc), inc


SIGNATURE = re.compile(r"^( {0,2})(?![ }#/])(?!(?:namespace|struct|class|enum|union|template|typedef|using|return|if|for|while|switch|else|do)\b)[^;=]*\)\s*(?:const\s*)?(?:noexcept\s*)?(?:override\s*)?(?:->\s*[\w:<>]+\s*)?(?::.*)?\{\s*$")


def long_functions():
    for folder in ("engine", "modules", "graph", "numa"):
        for dirpath, _, names in os.walk(os.path.join(ROOT, folder)):
            for name in sorted(names):
                if not name.endswith((".cpp", ".hpp")):
                    continue
                path = os.path.join(dirpath, name)
                with open(path) as f:
                    lines = f.read().split("\n")
                i = 0
                while i < len(lines):
                    m = SIGNATURE.match(lines[i])
                    if m:
                        close = m.group(1) + "}"
                        j = i + 1
                        while j < len(lines) and not (lines[j].startswith(close) and
                                                      (len(lines[j]) == len(close) or lines[j][len(close)] in ";) /")):
                            j += 1
                        if j - i + 1 > MAX_LINES:
                            yield os.path.relpath(path, ROOT), i + 1, j - i + 1, lines[i].strip()
                        i = j
                    i += 1


def main(argv):
    if "--dot" in argv:
        pairs = sorted({(a, b) for _, a, b, _ in edges() if a != b})
        print("digraph layers {\n  rankdir=BT;")
        for a, b in pairs:
            print(f'  "{a}" -> "{b}";')
        print("}")
        return 0
    bad = [(src, inc) for src, a, b, inc in edges() if b != a and b not in LAYERS.get(a, [])]
    for src, inc in bad:
        print(f"{src}: includes {inc}, which its folder may not (docs/architecture.md)")
    unknown = sorted(set(os.path.dirname(i) for _, _, _, i in edges()) - set(LAYERS))
    if unknown:
        print(f"includes of folders that have no layer: {unknown}")
    long = list(long_functions())
    for path, line, n, sig in long:
        print(f"{path}:{line}: {n} lines, over {MAX_LINES}: {sig}")
    print(f"check_house: {len(bad)} includes against the layers, {len(long)} functions over {MAX_LINES} lines")
    return 1 if bad or unknown or long else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
