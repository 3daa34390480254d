#!/usr/bin/python3
"""Every command the documentation shows is run: the code blocks and command spans of
README.md, docs/*.md and docs/notes/*.md, and the examples of `cvt-engine --help` and of
every subcommand's `--help`. A change of defaults, options or file names that breaks a
published recipe then fails here.

    /usr/bin/python3 tests/tools/test_doc_commands.py --engine build/cvt-engine          # first model ms
    /usr/bin/python3 tests/tools/test_doc_commands.py --engine build/cvt-engine --full   # short ones in full
    /usr/bin/python3 tests/tools/test_doc_commands.py --engine build/cvt-engine --list   # what is found, and how it runs

Each documented command is run, shortened to its first model milliseconds (SHORTEN below
says how, per kind of command), or skipped with a reason (SKIP, and the rules in
`classify`); a command that is neither fails the test, and so does an entry of SKIP or
RECIPES that no longer matches a documented command. The commands of one document run in
order, in one folder that looks like the repository's root (build/, configs/, tools/,
docs/, tests/ link to the real ones; cvt-engine is on PATH), so that a command finds the
files the commands before it wrote. A command passes when it exits with its documented
code (0 unless RECIPES says otherwise) and the file it names with -o/--out or `>` exists.

With --full, the commands of FULL run as documented (no shortening): the ones that take a
few minutes at most; the others are shortened as without --full.
"""
import argparse
import concurrent.futures
import glob
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
import tomllib

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
DOCS = ["README.md"] + sorted(glob.glob(os.path.join(ROOT, "docs", "*.md"))) + \
    sorted(glob.glob(os.path.join(ROOT, "docs", "notes", "*.md")))

# Model time of a shortened run [s]: a multiple of every shipped step (2.5e-6, 8.33e-7) and of
# the sample interval (1e-5). Still inside the start-up of the reference models.
SHORT = 5e-5

# How each kind of command is shortened (fast mode). `--set` is repeatable and the last one
# wins; every other option is given once, so an option the command has is replaced, not
# added twice.
SHORTEN = {
    "run":                [("--t-end", SHORT)],   # --resume: the checkpoint's time + SHORT
    "sweep":              [("--set", f"run.t_end={SHORT}")],
    "study slip":         [("--set", f"run.t_end={SHORT}")],
    "study shift":        [("--steady-bound", SHORT), ("--settle", 1e-5), ("--window", 2e-5)],
    "study integrators":  [("--t-warm", 1e-5), ("--t-sample", 2e-5)],
    "scale":              [("--steps", 4), ("--repeat", 1), ("--warmup", 1e-5)],
    "modes":              [("--at", 1e-5)],       # only an --at later than that; see RECIPES
    "example":            [("--t-end", SHORT)],   # docs/examples/*.py: each run's bound
}

# Commands that are not run, each with its reason (the normalized text, as --list prints it).
SKIP = {
    "make test": "the whole test suite, of which this test is a part",
    "make run && make view": "make view serves until stopped; make run is run (RECIPES)",
    "make video OUT=results.h5 VIDEO=run.webm":
        "make installs packages first (make deps); the command it runs is the next line's "
        "tools/cvt_view.py --video, which is run",
    "make plots": "make installs packages first (make deps); the plots are run as tools/cvt_plot.py "
                  "(CvtPlotTest, and the tools/cvt_plot.py commands here)",
    "make plots OUT=ref20.h5 PLOTS=fig": "as make plots",
    "make plots STUDY=study.csv": "as make plots",
    "make plots INTEGRATORS=int.csv": "as make plots",
    "/usr/bin/python3 tests/tools/test_cvt_plot.py [-v]": "the ctest CvtPlotTest runs this command",
    "make: these Debian packages are missing, and this user cannot install them (not root, no sudo):":
        "what make prints, not a command (MakeDepsTest checks it)",
    "build/schedule_bench --benchmark_repetitions=5":
        "a benchmark program (make bench): timings, not a recipe with an outcome",
}

# Commands run in another form than shown, each with why: `run` the commands run instead
# (in order), `shell` a shell variable they need, `setup` commands run before it
# (files the document means but does not make), `rc` the documented exit code, `fast` text
# replacements of fast mode, `server` a command that serves until stopped: it passes when it
# prints its address; `needs` a path that `make deps` makes (without it the command is
# reported as not run), `full_only` a command that runs with --full only.
RECIPES = {
    "make run": dict(
        why="make also installs packages and builds; this is the command its run target runs",
        run=["build/cvt-engine run configs/reference-steady.toml --out results.h5 --scheduler flowgraph --threads 2"]),
    "/usr/bin/python3 tools/cvt_check.py results.h5 --from 0.060 --to 0.100": dict(
        why="the window of the full make run; a shortened run is checked over its own end",
        fast=[("--from 0.060 --to 0.100", f"--from {SHORT / 2} --to {SHORT}")]),
    "build/cvt-engine run --resume ref25.h5.ckpt --t-end 6.5e-3 --out p.h5 [--scheduler flowgraph --threads 2]": dict(
        why="the bracket is optional: both forms, from the run the table names",
        setup=["build/cvt-engine run configs/reference.toml --t-end 2.5e-3 --out ref25.h5"],
        run=["build/cvt-engine run --resume ref25.h5.ckpt --t-end 6.5e-3 --out p.h5",
             "build/cvt-engine run --resume ref25.h5.ckpt --t-end 6.5e-3 --out p.h5 --scheduler flowgraph --threads 2"]),
    "build/cvt-engine run --resume RUNNING.ckpt --t-end 6.5e-3 --out p.h5 --step 2.5e-6 "
    "--set integrator.w_k_every=32 --scheduler flowgraph --threads T": dict(
        why="RUNNING.ckpt is the running state of performance.md 1.1, T a thread count",
        setup=["build/cvt-engine run configs/reference.toml --t-end 2.5e-3 --out ref25.h5"],
        run=["build/cvt-engine run --resume ref25.h5.ckpt --t-end 6.5e-3 --out p.h5 --step 2.5e-6 "
             "--set integrator.w_k_every=32 --scheduler flowgraph --threads 2"]),
    "build/cvt-engine run --resume RUNNING.ckpt --t-end 6.5e-3 --out p.h5 --step 2.5e-6 "
    "--set integrator.w_k_every=32 [--scheduler flowgraph --threads T] --profile-json w_T.json": dict(
        why="RUNNING.ckpt is the running state of section 1.1 (ref25.h5.ckpt), T a thread count; "
            "the bracket is optional: both forms",
        run=["build/cvt-engine run --resume ref25.h5.ckpt --t-end 6.5e-3 --out p.h5 --step 2.5e-6 "
             "--set integrator.w_k_every=32 --profile-json w_1.json",
             "build/cvt-engine run --resume ref25.h5.ckpt --t-end 6.5e-3 --out p.h5 --step 2.5e-6 "
             "--set integrator.w_k_every=32 --scheduler flowgraph --threads 2 --profile-json w_2.json"]),
    "build/cvt-engine run --resume study-cache/study-KEY.ckpt --t-end 4.5e-3 --out p.h5 $OLD "
    "--profile-json serial.json": dict(
        why="KEY is the cache key of the study before it: its one running state in study-cache/",
        run=["build/cvt-engine run --resume study-cache/study-*.ckpt --t-end 4.5e-3 "
             "--out p.h5 $OLD --profile-json serial.json"]),
    "build/cvt-engine run --resume study-cache/study-KEY.ckpt --t-end 4.5e-3 --out p.h5 $OLD "
    "--scheduler flowgraph --threads 2 --profile-json two.json": dict(
        why="KEY as above",
        run=["build/cvt-engine run --resume study-cache/study-*.ckpt --t-end 4.5e-3 "
             "--out p.h5 $OLD --scheduler flowgraph --threads 2 --profile-json two.json"]),
    "build/cvt-engine scale CONFIG --threads 1,2,4,8,16 --layouts native,'package:2 numa:1 core:8 pu:1' "
    "--out study.csv": dict(
        why="CONFIG: the reference model",
        run=["build/cvt-engine scale configs/reference.toml --threads 1,2,4,8,16 "
             "--layouts native,'package:2 numa:1 core:8 pu:1' --out study.csv"]),
    "build/cvt-engine study integrators configs/reference.toml --methods ros34pw2 "
    "--w-steps ros34pw2@2.5e-6:8:32,ros34pw2@3.3333333333333333e-6:4:32 --perturb 1e-14 --seed S": dict(
        why="S: a seed",
        run=["build/cvt-engine study integrators configs/reference.toml --methods ros34pw2 "
             "--w-steps ros34pw2@2.5e-6:8:32,ros34pw2@3.3333333333333333e-6:4:32 --perturb 1e-14 --seed 1"]),
    "build/cvt-engine study integrators configs/reference.toml --methods ros34pw2 "
    "--w-steps ros34pw2@1e-6:8:64,ros34pw2@9.0909090909e-7:8:64,ros34pw2@8.3333333333e-7:8:64 "
    "--set integrator.w_shafts=false --perturb 1e-14 --seed $s --scheduler flowgraph --threads 2": dict(
        why="the body of a loop over the seeds: its first seed",
        shell="s=1", run=["build/cvt-engine study integrators configs/reference.toml --methods ros34pw2 "
             "--w-steps ros34pw2@1e-6:8:64,ros34pw2@9.0909090909e-7:8:64,ros34pw2@8.3333333333e-7:8:64 "
             "--set integrator.w_shafts=false --perturb 1e-14 --seed $s --scheduler flowgraph --threads 2"]),
    "/usr/bin/python3 tools/cvt_plot.py integrators study.csv -o integrators.png": dict(
        why="the study it draws is the synopsis above it; the study's default run makes study.csv",
        setup=["build/cvt-engine study integrators configs/reference.toml -o study.csv"]),
    "tools/cvt_view.py run.h5 --port 0 --no-browser": dict(
        why="run.h5 is any run with snapshots; the viewer serves until stopped",
        setup=["build/cvt-engine run configs/mini.toml --t-end 2e-4 -o run.h5"], server=True,
        needs="tools/viewer/node_modules"),
    "tools/cvt_view.py run.h5 --video run.webm --fps 30 --size 1280x720": dict(
        why="the viewer's libraries come with make deps", needs="tools/viewer/node_modules"),
    "cvt-engine run configs/reference-steady.toml --t-end 2 -o job.h5 --threads $SLURM_CPUS_PER_TASK "
    "--max-wall 23:55:00 --continue": dict(
        why="the body of an sbatch script: Slurm sets SLURM_CPUS_PER_TASK", shell="SLURM_CPUS_PER_TASK=2"),
    "cvt-engine sweep configs/reference-steady.toml --points map-points.csv --set controller.enabled=true -o map "
    "--array --threads 2 --max-wall 1:59:00": dict(
        why="a job array's task: Slurm sets SLURM_ARRAY_TASK_ID", shell="export SLURM_ARRAY_TASK_ID=0"),
    "cvt-engine sweep configs/reference-steady.toml --points map-points.csv --set controller.enabled=true -o map --gather": dict(
        why="only task 0 of the array ran here: the gather names the missing points and exits 75", rc=75),
    "PYTHONPATH=build/python docs/examples/optimize_clamping.py --load 15 --json opt.json": dict(
        why="a bisection on the slip verdict of runs until steady: a shortened run never slips, "
            "so its bracket holds no change of sign; run in full only", full_only=True),
}

# Run as documented with --full: the commands that take a few minutes at most on 2 cores.
FULL = {
    "build/cvt-engine run configs/reference.toml",
    "build/cvt-engine run configs/ratio-2.0.toml --profile",
    "build/cvt-engine run configs/reference.toml --t-end 20e-3 -o long.h5",
    "build/cvt-engine study integrators configs/mini.toml --t-warm 1e-4 --t-sample 2e-4 "
    "--set ramp.time=1e-4 --methods rk4,trbdf2 --tols 0.1 --out mini.csv",
    "build/cvt-engine scale configs/reference.toml --threads 1,2 --out scaling.csv",
    "cvt-engine scale configs/reference.toml --threads 1,2 --out scaling.csv",
    "cvt-engine modes configs/mini.toml --at 1e-3 --count 5",
    "cvt-engine sweep configs/mini.toml --axis load.torque=5,10 --axis clamping.driving=1.1e4,1.2e4 --out sweep",
    "mpirun --oversubscribe -np 3 cvt-engine sweep configs/mini.toml --axis load.torque=5,10 "
    "--axis clamping.driving=1.13e4,1.25e4 --set run.t_end=0.05 --out mini-sweep",
    "cvt-engine study shift configs/mini.toml --set clamping.driving=1.13e4 --thrust-ratios 0.9,1.13,1.4 "
    "--speeds 104.7,209.4 --window 5e-3 --settle 1e-3 --steady-bound 0.05 --out mini-shift.csv",
    "PYTHONPATH=build/python docs/examples/efficiency_curve.py --out eff",
    "PYTHONPATH=build/python docs/examples/optimize_clamping.py --load 15 --json opt.json",
    "build/cvt-engine run configs/reference.toml --t-end 0.1 --scheduler flowgraph --threads 2",
    "c++ -std=c++20 -O2 -DEIGEN_MAX_ALIGN_BYTES=32 -DEIGEN_MAX_STATIC_ALIGN_BYTES=32 -I. -I/usr/include/eigen3 "
    "tests/engine/ode/example_hires.cpp build/libcvt_ode.a -o example_hires -lsundials_cvode -lsundials_arkode "
    "-lsundials_nvecserial -lsundials_sunlinsoldense -lsundials_sunmatrixdense",
}

SUBCOMMANDS = ("run", "graph", "topology", "scale", "modes", "study", "sweep", "--version", "--help")
ENV = r"""[A-Z_][A-Z0-9_]*=(?:"[^"]*"|'[^']*'|\S+)"""
COMMAND = re.compile(r"^(?:\$\s+)?(?:(?:" + ENV + r")\s+)*(?:build/\S+|cvt-engine\s+(?:" +
                     "|".join(re.escape(s) for s in SUBCOMMANDS) + r")\b|mpirun\s|mpiexec\s|srun\s|"
                     r"tools/\S+\.py\b|docs/examples/\S+\.py\b|/usr/bin/python3\s|python3\s|make\b|"
                     r"c\+\+\s|export\s+" + ENV + r"$|" + ENV + r"$)")
INLINE = re.compile(r"`((?:build/cvt-engine|/usr/bin/python3) [^`]+|cvt-engine (?:run|graph|topology|scale|"
                    r"modes|study \w+|sweep) configs/[^`]+)`")


def normalize(text):
    return " ".join(text.split())


def strip_comment(line):
    return re.sub(r"\s+#(\s.*)?$", "", line)


def blocks_of(text):
    """(line number, line) of the lines in fenced and indented code blocks, and the files a
    block shows (a block whose first line is `# NAME.csv`)."""
    lines, files, fenced, current = [], {}, False, None
    for n, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            current = None
            continue
        code = fenced or (line.startswith("    ") and not line.lstrip().startswith("|"))
        if not code:
            current = None
            continue
        m = re.match(r"\s*# (\S+\.csv)\s*$", line)
        if m:
            current = files.setdefault(m.group(1), [])
            continue
        if current is not None and line.strip():
            if line.strip() != "...":
                current.append(line.strip())
            continue
        lines.append((n, line))
    return lines, {name: "\n".join(rows) + "\n" for name, rows in files.items()}


def commands_of(text):
    """The commands of a document in order: (line, command), continuation lines joined."""
    lines, files = blocks_of(text)
    found, i = [], 0
    while i < len(lines):
        n, line = lines[i]
        stripped = line.strip()
        if COMMAND.match(stripped):
            while stripped.endswith("\\") and i + 1 < len(lines):
                i += 1
                stripped = stripped[:-1] + " " + lines[i][1].strip()
            found.append((n, normalize(strip_comment(stripped)).removeprefix("$ ")))
        i += 1
    code_lines = {n for n, _ in lines}
    for n, line in enumerate(text.splitlines(), 1):
        if n in code_lines:
            continue
        for m in INLINE.finditer(line):
            found.append((n, normalize(m.group(1))))
    found.sort(key=lambda c: c[0])
    return found, files


def help_commands(engine):
    """The examples at the end of `cvt-engine --help` and of every subcommand's --help."""
    def examples(args):
        out = subprocess.run([engine] + args + ["--help"], capture_output=True, text=True).stdout
        found, inside = [], False
        for line in out.splitlines():
            if line.startswith("Example:"):
                inside = True
                line = line[len("Example:"):]
            elif not (inside and line.startswith(" ")):
                inside = False
            if inside and line.strip():
                found.append(normalize(line))
        return found, out

    found, top = examples([])
    subs = re.findall(r"^  (\w+)\s", top.split("Subcommands:")[-1], re.M)
    for sub in subs:
        more, text = examples([sub])
        found += more
        if "Subcommands:" in text:
            for inner in re.findall(r"^  (\w+)\s", text.split("Subcommands:")[-1], re.M):
                found += examples([sub, inner])[0]
    return [(0, c) for c in dict.fromkeys(found)]


def kind_of(command):
    """The kind of a command: an engine subcommand ('run', 'study slip', ...), 'tool',
    'example', 'make', 'srun', 'bench', 'compile', 'shell' (a variable for the next ones)."""
    if re.match(r"(export\s+)?" + ENV + "$", command):
        return "shell"
    words = re.sub(r"^(?:" + ENV + r"\s+)+", "", command).split()
    first = words[0]
    if first in ("make", "srun", "c++"):
        return {"c++": "compile"}.get(first, first)
    if first in ("mpirun", "mpiexec") or first.endswith("cvt-engine"):
        sub = words[words.index(next(w for w in words if w.endswith("cvt-engine"))) + 1:]
        if not sub:
            return "engine"
        return "study " + sub[1] if sub[0] == "study" and len(sub) > 1 else sub[0]
    if first.startswith("build/") and first.endswith("_bench"):
        return "bench"
    if first.startswith("docs/examples/"):
        return "example"
    return "tool"


def classify(command):
    """('run', recipe) or ('skip', reason)."""
    if command in SKIP:
        return "skip", SKIP[command]
    if command in RECIPES:
        return "run", RECIPES[command]
    kind = kind_of(command)
    if "..." in command.split() or " .. " in command or command.endswith(" ..."):
        return "skip", "elided (...): a form, not a command"
    if "[" in command or re.search(r"(?<![$\w/=.-])[A-Z][A-Z0-9_]*(?:\.\w+)?(?![\w=])", command):
        return "skip", "a synopsis: placeholders in capitals or [options]"
    if kind == "srun":
        return "skip", "Slurm is not installed here; the same sweep runs under mpirun"
    if kind == "bench":
        return "skip", "a benchmark program (make bench): timings, not a recipe with an outcome"
    if kind == "make":
        return "unclassified", "make: says neither SKIP nor RECIPES"
    return "run", {}


def set_option(command, name, value):
    """The command with `name value` replaced, or added before any redirection."""
    parts = re.split(r"( > | && | \| )", command, maxsplit=1)
    head, rest = parts[0], "".join(parts[1:])
    if name != "--set":
        pattern = re.compile(re.escape(name) + r"(?:=|\s+)(\S+)")
        if pattern.search(head):
            return pattern.sub(f"{name} {value}", head) + rest
    return f"{head} {name} {value}".rstrip() + rest


def option_value(command, *names):
    for name in names:
        m = re.search(r"(?:^|\s)" + re.escape(name) + r"(?:=|\s+)(\S+)", command)
        if m:
            return m.group(1)
    return None


def config_t_end(command):
    """run.t_end of the configuration file a run command names (its --set first), or None."""
    words = shlex.split(command)
    for i, w in enumerate(words):
        if w == "--set" and i + 1 < len(words) and words[i + 1].startswith("run.t_end="):
            return float(words[i + 1].split("=", 1)[1])
    config = next((w for w in words if w.endswith(".toml")), None)
    if config is None or not os.path.exists(os.path.join(ROOT, config)):
        return None
    with open(os.path.join(ROOT, config), "rb") as f:
        return tomllib.load(f).get("run", {}).get("t_end")


class Folder:
    """A folder that looks like the repository's root; the model end time of each run file."""

    def __init__(self, path, engine):
        self.path = path
        os.makedirs(path)
        links = {"build": os.path.dirname(os.path.abspath(engine))}
        for name in ("configs", "tools", "docs", "tests", "engine", "modules", "graph", "numa"):
            links[name] = os.path.join(ROOT, name)
        for name, target in links.items():
            os.symlink(target, os.path.join(path, name))
        self.ends = {}      # run file -> model time its checkpoint is at (fast mode)
        self.shell = ""     # variables set by earlier lines of the document

    def record(self, command, kind):
        """The end time of a run that is not shortened: the command's --t-end, else its
        configuration's run.t_end."""
        if kind != "run" or "--resume" in command:
            return
        end = option_value(command, "--t-end")
        if end is None:
            end = config_t_end(command)
        if end is not None:
            self.ends[option_value(command, "-o", "--out") or "results.h5"] = float(end)

    def shorten(self, command, kind):
        if kind == "run":
            resume = option_value(command, "--resume")
            if resume:
                base = resume[:-len(".ckpt")] if resume.endswith(".ckpt") else resume
                start = self.ends.get(base, 1e-5 if "study-cache" in resume else 0.0)
                end = round(start + SHORT, 12)
                out = option_value(command, "-o", "--out") or base
            else:
                end, out = SHORT, option_value(command, "-o", "--out") or "results.h5"
            self.ends[out] = end
            return set_option(command, "--t-end", f"{end:g}")
        if kind == "modes":
            at = option_value(command, "--at")
            if at is not None and float(at) > 1e-5:
                command = set_option(command, "--at", "1e-5")
            if "configs/reference" in command and "--no-jacobian" not in command:
                command = set_option(command, "--no-jacobian", "")   # 105 s of eigenvalues
            return command
        for name, value in SHORTEN.get(kind, []):
            command = set_option(command, name, f"{value:g}" if isinstance(value, float) else value)
        return command


def expected_files(command, kind):
    first = re.split(r" && | \| ", command)[0]
    files = []
    m = re.search(r" > (\S+)", first)
    if m:
        files.append(m.group(1))
    out = option_value(first, "-o", "--out")
    if kind == "sweep" and re.search(r"\s--(point|array)\b", first):
        files.append((out or "sweep") + ".points")  # a job array's task writes its row there
    elif kind == "sweep" and " --gather" not in first:
        files.append((out or "sweep") + ".csv")
    elif kind in ("run", "scale", "study slip", "study shift", "study integrators", "tool") and out:
        if kind != "tool" or out.endswith((".png", ".gif", ".webm", ".csv")):
            files.append(out)
    elif kind == "run" and "--resume" not in first:
        files.append("results.h5")
    return files


def run_one(folder, command, recipe, full, env, log):
    """Runs one documented command (or its recipe); returns a failure message or None."""
    kind = kind_of(command)
    for pre in recipe.get("setup", []):
        failure = run_one(folder, pre, {}, full, env, log)
        if failure:
            return f"its set-up `{pre}`: {failure}"
    if recipe.get("full_only") and not full:
        log(f"    not run without --full: {recipe['why']}")
        return None
    if "needs" in recipe and not os.path.exists(os.path.join(ROOT, recipe["needs"])):
        log(f"    NOT RUN: {recipe['needs']} is missing (make deps)")
        return None
    forms = recipe.get("run", [command])
    for form in forms:
        actual = form
        if full and command in FULL:
            folder.record(actual, kind_of(form))
        else:
            for old, new in recipe.get("fast", []):
                actual = actual.replace(old, new)
            actual = folder.shorten(actual, kind_of(form))
        script = folder.shell + (recipe["shell"] + "; " if "shell" in recipe else "") + actual
        t0 = time.monotonic()
        if recipe.get("server"):
            proc = subprocess.Popen(["bash", "-c", "exec " + script], cwd=folder.path, env=env,
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            address = None
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and proc.poll() is None:
                line = proc.stdout.readline()
                if "http://" in line:
                    address = line.strip()
                    break
            proc.terminate()
            proc.wait(timeout=10)
            log(f"    {actual}\n      served: {address} ({time.monotonic() - t0:.1f} s)")
            if not address:
                return "printed no address within 60 s"
            continue
        done = subprocess.run(["bash", "-c", script], cwd=folder.path, env=env, capture_output=True,
                              text=True, timeout=3600 if full else 600)
        wall = time.monotonic() - t0
        log(f"    {actual}\n      exit {done.returncode}, {wall:.1f} s")
        rc = recipe.get("rc", 0)
        if done.returncode != rc:
            tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-8:])
            return f"`{actual}` exited {done.returncode} (documented: {rc}):\n{tail}"
        for name in expected_files(actual, kind_of(form)):
            if not os.path.exists(os.path.join(folder.path, name)):
                return f"`{actual}` wrote no {name}"
    return None


def run_document(source, commands, files, tmp, engine, full, env):
    """Runs the commands of one document in order; (its log, commands run, failures)."""
    folder = Folder(os.path.join(tmp, re.sub(r"\W", "_", source)), engine)
    for name, content in files.items():
        with open(os.path.join(folder.path, name), "w") as f:
            f.write(content)
    log, ran, failures = [f"== {source}"], 0, []
    for line, command in commands:
        verdict, recipe = classify(command)
        if verdict != "run":
            continue
        if kind_of(command) == "shell":
            folder.shell += command + "; "
            continue
        ran += 1
        log.append(f"  {source}:{line}: {command}")
        try:
            failure = run_one(folder, command, recipe, full, env, log.append)
        except subprocess.TimeoutExpired as e:
            failure = f"timed out after {e.timeout} s"
        if failure:
            log.append(f"  FAILED: {failure}")
            failures.append(f"{source}:{line}: `{command}`: {failure}")
    return "\n".join(log) + "\n", ran, failures


def collect(engine):
    """[(source, [(line, command)], files)] for every document and for the --help texts."""
    found = []
    for path in DOCS:
        with open(os.path.join(ROOT, path), encoding="utf-8") as f:
            commands, files = commands_of(f.read())
        found.append((os.path.relpath(os.path.join(ROOT, path), ROOT), commands, files))
    found.append(("cvt-engine --help", help_commands(engine), {}))
    return found


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--engine", default=os.path.join(ROOT, "build", "cvt-engine"))
    ap.add_argument("--full", action="store_true", help="run the commands of FULL as documented")
    ap.add_argument("--list", action="store_true", help="list the commands and what is done with each")
    ap.add_argument("--only", help="only the documents whose name contains one of these (comma-separated)")
    ap.add_argument("--jobs", type=int, default=2, help="documents run side by side (default 2)")
    args = ap.parse_args()
    engine = os.path.abspath(args.engine)
    sources = collect(engine)
    if args.only:
        sources = [s for s in sources if any(part in s[0] for part in args.only.split(","))]

    failures, seen, counts = [], set(), {"run": 0, "skip": 0}
    for source, commands, _ in sources:
        for line, command in commands:
            seen.add(command)
            verdict, detail = classify(command)
            if verdict == "unclassified":
                failures.append(f"{source}:{line}: `{command}`: neither run nor skipped ({detail})")
            elif verdict == "skip" or args.list:
                counts[verdict] += verdict == "skip"
                if args.list:
                    how = detail if verdict == "skip" else (detail.get("why") or f"kind {kind_of(command)}")
                    print(f"{source}:{line}: {verdict}: {command}\n    {how}")
    if not args.only:
        for table, name in ((SKIP, "SKIP"), (RECIPES, "RECIPES"), (FULL, "FULL")):
            for command in table:
                if command not in seen:
                    failures.append(f"{name} names a command no document shows: `{command}`")
    if args.list:
        for failure in failures:
            print("FAIL " + failure)
        return 1 if failures else 0

    env = dict(os.environ)
    env["PATH"] = os.path.dirname(engine) + os.pathsep + env.get("PATH", "")
    env.update(MPLBACKEND="Agg", OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMP_WAIT_POLICY="passive", PYTHONUNBUFFERED="1")
    t_start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="doc-commands-") as tmp:
        # The documents are independent of each other: two at a time, each in its own folder.
        with concurrent.futures.ThreadPoolExecutor(max_workers=args.jobs) as pool:
            jobs = [pool.submit(run_document, source, commands, files, tmp, engine, args.full, env)
                    for source, commands, files in sources]
            for job in jobs:
                text, ran, failed = job.result()
                print(text, end="", flush=True)
                counts["run"] += ran
                failures += failed
    print(f"\n{counts['run']} commands run, {counts['skip']} skipped, {len(failures)} failed, "
          f"{time.monotonic() - t_start:.0f} s")
    for failure in failures:
        print("FAIL " + failure)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
