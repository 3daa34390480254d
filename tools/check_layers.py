#!/usr/bin/python3
"""The include graph between the source folders, against the layers of docs/architecture.md.

    tools/check_layers.py          # exit 1 on an include that its folder may not make
    tools/check_layers.py --dot    # the folder graph as GraphViz

A folder may include itself and the folders listed for it in LAYERS (each of which sits
below it), so the data flows one way and there are no cycles between folders.
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
}
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
    if any(f not in LAYERS for f in set(os.path.dirname(i) for _, _, _, i in edges())):
        unknown = sorted(set(os.path.dirname(i) for _, _, _, i in edges()) - set(LAYERS))
        print(f"includes of unknown folders: {unknown}")
        return 1
    print(f"check_layers: {'ok' if not bad else f'{len(bad)} includes against the layers'}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
