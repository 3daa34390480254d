#!/usr/bin/python3
"""The house rules of docs/architecture.md that a program can check.

    tools/check_house.py               # exit 1 on a broken rule, naming the file and line
    tools/check_house.py --root DIR    # check another copy of the tree
    tools/check_house.py --dot         # the include graph between the folders, as GraphViz
    tools/check_house.py --list        # every function and class it measured, with its length

1. Layers: every source folder (a folder under engine/, modules/, graph/ or numa/ that
   holds .cpp or .hpp files) has a row in LAYERS, and includes only itself and the folders
   its row lists (each of which sits below it), so the data flows one way and there are
   no cycles between folders.
2. Short functions: no function (free function, method, operator, member defined inside
   its class, lambda; in a .cpp or a .hpp) longer than MAX_FUNCTION lines, no constructor
   longer than MAX_CONSTRUCTOR lines, no class, struct or union longer than MAX_CLASS
   lines, each measured from the line of its name to its closing brace.

The functions and classes come from universal-ctags (Debian package universal-ctags),
a parser that follows the braces whatever the layout of a signature, run once more for
each #elif and #else branch. Exit codes: 0 all
rules hold, 1 a rule is broken, 2 the check could not run (the message says why).
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
SOURCE_TOPS = ("engine", "modules", "graph", "numa")
SUFFIXES = (".cpp", ".hpp")

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
    "engine/wmethod": ["graph", "engine/rhs", "modules", "engine/model", "engine/ode", "numa", "engine/base"],
    "engine": ["engine/wmethod", "graph", "engine/rhs", "modules", "engine/model", "engine/ode", "engine/io", "numa",
               "engine/base"],
    "engine/studies": ["engine", "engine/wmethod", "graph", "engine/rhs", "modules", "engine/model", "engine/ode",
                       "engine/io", "numa", "engine/base"],
    "engine/cli": ["engine/studies", "engine", "engine/wmethod", "graph", "engine/rhs", "modules", "engine/model",
                   "engine/ode", "engine/io", "numa", "engine/base"],
    "engine/python": ["engine/studies", "engine", "engine/wmethod", "graph", "engine/rhs", "modules", "engine/model",
                      "engine/ode", "engine/io", "numa", "engine/base"],
}
MAX_FUNCTION = 120
MAX_CONSTRUCTOR = 60
MAX_CLASS = 400
CTAGS_PACKAGE = "universal-ctags"


class CannotCheck(Exception):
    """The check could not run: a missing tool or an answer it cannot read."""


def main(argv):
    args = parse_args(argv[1:])
    try:
        files = source_files(args.root)
        if args.dot:
            print_dot(args.root, files)
            return 0
        if args.list:
            for t in sorted(ctags(args.root, files), key=lambda t: (t["path"], t["line"])):
                print(f"{t['path']}:{t['line']}-{t['end']}: {t['end'] - t['line'] + 1} lines, "
                      f"{what_and_limit(t)[0]} {qualified(t)}")
            return 0
        broken, seen = check(args.root, files)
    except CannotCheck as e:
        print(f"check_house: cannot check: {e}")
        return 2
    for line in broken:
        print(line)
    print(f"check_house: {seen['files']} files, {seen['folders']} source folders, "
          f"{seen['functions']} functions ({seen['constructors']} constructors), {seen['lambdas']} lambdas, "
          f"{seen['classes']} classes; {len(broken)} broken rules")
    return 1 if broken else 0


def parse_args(argv):
    p = argparse.ArgumentParser(description="Check the house rules of docs/architecture.md.")
    p.add_argument("--root", default=ROOT, help="the tree to check (default: this checkout)")
    p.add_argument("--dot", action="store_true", help="print the include graph between folders")
    p.add_argument("--list", action="store_true", help="print every function and class measured")
    return p.parse_args(argv)


def check(root, files):
    """All broken rules, each a line 'where: what', and what was seen."""
    folders = sorted({os.path.dirname(f) for f in files})
    broken = [f"{folder}/: a source folder with no row in LAYERS (tools/check_house.py); "
              f"give it its place in docs/architecture.md, 'The layers'"
              for folder in folders if folder not in LAYERS]
    for src, line, inc, target in includes(root, files):
        if target != os.path.dirname(src) and target not in LAYERS.get(os.path.dirname(src), []):
            broken.append(f"{src}:{line}: includes {inc}, but {os.path.dirname(src)}/ may not include "
                          f"{target}/ (docs/architecture.md, 'The layers')")
    tags = ctags(root, files)
    broken += too_long(tags)
    functions = [t for t in tags if t["kind"] == "function" and not is_lambda(t)]
    lambdas = [t for t in tags if is_lambda(t)]
    seen = {"files": len(files), "folders": len(folders), "functions": len(functions),
            "constructors": sum(is_constructor(t) for t in functions), "lambdas": len(lambdas),
            "classes": len(tags) - len(functions) - len(lambdas)}
    return broken, seen


# --- the layers -------------------------------------------------------------------------

def source_files(root):
    """Every .cpp and .hpp under the source folders, relative to root, sorted."""
    found = []
    for top in SOURCE_TOPS:
        for dirpath, dirnames, names in os.walk(os.path.join(root, top)):
            dirnames.sort()
            found += [os.path.relpath(os.path.join(dirpath, n), root) for n in sorted(names) if n.endswith(SUFFIXES)]
    if not found:
        raise CannotCheck(f"no .cpp or .hpp files under {', '.join(SOURCE_TOPS)} of {root}")
    return found


def includes(root, files):
    """(file, line, the include as written, the folder it names) for each #include "..."."""
    for src in files:
        with open(os.path.join(root, src), errors="replace") as f:
            for number, text in enumerate(f, 1):
                inc = quoted_include(text)
                if inc is None:
                    continue
                here = os.path.join(os.path.dirname(src), inc)
                if not os.path.exists(os.path.join(root, inc)) and os.path.exists(os.path.join(root, here)):
                    inc_folder = os.path.dirname(os.path.normpath(here))
                else:
                    inc_folder = os.path.dirname(os.path.normpath(inc))
                yield src, number, inc, inc_folder


def quoted_include(text):
    s = text.strip()
    if not s.startswith("#"):
        return None
    s = s[1:].lstrip()
    if not s.startswith("include"):
        return None
    s = s[len("include"):].strip()
    if not s.startswith('"'):
        return None
    end = s.find('"', 1)
    return s[1:end] if end > 1 else None


def print_dot(root, files):
    pairs = sorted({(os.path.dirname(src), target) for src, _, _, target in includes(root, files)
                    if os.path.dirname(src) != target})
    print("digraph layers {\n  rankdir=BT;")
    for a, b in pairs:
        print(f'  "{a}" -> "{b}";')
    print("}")


# --- the sizes --------------------------------------------------------------------------

def ctags(root, files):
    """The function definitions (lambdas included) and the classes, structs and unions of
    the files, each a dict with path, line, end, kind, name and scope, as universal-ctags
    reads them. ctags follows only the first branch of an #if inside a class, so a file is
    read again once for each #elif and #else branch in it (branch_variants)."""
    exe = ctags_exe()
    tags = {}
    for tag in run_ctags(exe, root, files):
        tags.setdefault(tag_key(tag), tag)
    variants = {f: list(branch_variants(read(root, f))) for f in files}
    for k in range(max(map(len, variants.values()))):
        with tempfile.TemporaryDirectory() as tmp:
            these = [f for f in files if k < len(variants[f])]
            for f in these:
                os.makedirs(os.path.join(tmp, os.path.dirname(f)), exist_ok=True)
                with open(os.path.join(tmp, f), "w") as out:
                    out.write(variants[f][k])
            for tag in run_ctags(exe, tmp, these):
                tags.setdefault(tag_key(tag), tag)
    if not any(t["kind"] == "function" for t in tags.values()):
        raise CannotCheck("ctags found no function at all")
    return list(tags.values())


def ctags_exe():
    exe = shutil.which("ctags")
    if exe is None:
        raise CannotCheck(f"ctags is not installed; install the Debian package {CTAGS_PACKAGE} "
                          f"(apt-get install {CTAGS_PACKAGE}, or `make deps`)")
    version = subprocess.run([exe, "--version"], capture_output=True, text=True).stdout
    if "Universal Ctags" not in version:
        raise CannotCheck(f"{exe} is not universal-ctags; install the Debian package {CTAGS_PACKAGE}")
    return exe


def run_ctags(exe, root, files):
    cmd = [exe, "--options=NONE", "--language-force=C++", "--kinds-C++=fcsu", "--fields=+neZ",
           "--extras=+F", "--output-format=json", "-f", "-", "-L", "-"]
    run = subprocess.run(cmd, cwd=root, input="\n".join(files) + "\n", capture_output=True, text=True)
    if run.returncode != 0:
        raise CannotCheck(f"{' '.join(cmd)} exited {run.returncode}: {run.stderr.strip()} "
                          f"(the JSON output needs the Debian package {CTAGS_PACKAGE})")
    for text in run.stdout.splitlines():
        tag = json.loads(text)
        if tag.get("_type") != "tag":
            continue
        if "end" not in tag:
            raise CannotCheck(f"{tag['path']}:{tag['line']}: ctags found no closing brace for {tag['kind']} "
                              f"{tag['name']}, so its length is unknown")
        yield tag


def tag_key(tag):
    return tag["path"], tag["line"], tag["kind"], tag["name"], tag.get("scope")


def read(root, path):
    with open(os.path.join(root, path), errors="replace") as f:
        return f.read()


def directive(line):
    """'if', 'else' or 'endif' for a conditional directive line (#if, #ifdef and #ifndef are
    'if', #elif and #else are 'else'), else None."""
    s = line.strip()
    if not s.startswith("#"):
        return None
    word = s[1:].lstrip().split(None, 1)[0] if s[1:].strip() else ""
    return {"if": "if", "ifdef": "if", "ifndef": "if", "elif": "else", "else": "else", "endif": "endif"}.get(word)


class Group:
    """An #if group: the lines of its directives (#if, each #elif and #else, #endif) and
    the group and branch it sits in."""
    def __init__(self, start, parent):
        self.directives = [start]
        self.parent = parent  # (group, branch) or None

    def branch_of(self, line):
        return sum(d < line for d in self.directives[:-1]) - 1


def conditional_groups(text):
    """The #if groups of the text that have an #elif or an #else."""
    groups, stack = [], []
    for number, line in enumerate(text.split("\n")):
        d = directive(line)
        if d == "if":
            parent = (stack[-1], len(stack[-1].directives) - 1) if stack else None
            stack.append(Group(number, parent))
        elif d in ("else", "endif") and stack:
            stack[-1].directives.append(number)
            if d == "endif":
                group = stack.pop()
                if len(group.directives) > 2:
                    groups.append(group)
    return groups


def branch_variants(text):
    """One text per further branch (#elif, #else) of each #if group: the text with that
    branch, and the branches of the groups around it that hold it, left as plain code on
    the same lines, and those groups' directives and other branches blanked."""
    for group in conditional_groups(text):
        for branch in range(1, len(group.directives) - 1):
            lines = text.split("\n")
            g, b = group, branch
            while g is not None:
                d = g.directives
                for number in range(d[0], d[-1] + 1):
                    if number in d or g.branch_of(number) != b:
                        lines[number] = ""
                g, b = g.parent if g.parent else (None, None)
            yield "\n".join(lines)


def too_long(tags):
    for t in sorted(tags, key=lambda t: (t["path"], t["line"])):
        n = t["end"] - t["line"] + 1
        what, limit = what_and_limit(t)
        if n > limit:
            yield f"{t['path']}:{t['line']}: {what} {qualified(t)} is {n} lines long, over the limit of {limit}"


def what_and_limit(tag):
    if tag["kind"] != "function":
        return tag["kind"], MAX_CLASS
    if is_lambda(tag):
        return "lambda in", MAX_FUNCTION
    if is_constructor(tag):
        return "constructor", MAX_CONSTRUCTOR
    return "function", MAX_FUNCTION


def is_lambda(tag):
    return tag["kind"] == "function" and tag["name"].startswith("__anon")


def is_constructor(tag):
    scope = tag.get("scope", "")
    return tag["kind"] == "function" and tag.get("scopeKind") in ("class", "struct") and \
        scope.split("::")[-1] == tag["name"]


def qualified(tag):
    """The name with its scope, the anonymous namespaces left out."""
    parts = [p for p in tag.get("scope", "").split("::") + [tag["name"]] if p and not p.startswith("__anon")]
    return "::".join(parts) or "(file scope)"


if __name__ == "__main__":
    sys.exit(main(sys.argv))
