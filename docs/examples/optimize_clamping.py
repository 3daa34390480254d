#!/usr/bin/python3
"""The smallest clamping force that carries a load without gross slip, found with SciPy
from steady-state runs, and checked against the slip study (docs/python.md).

    PYTHONPATH=build/python docs/examples/optimize_clamping.py              # mini, 15 N m: about 3.5 min
    PYTHONPATH=build/python docs/examples/optimize_clamping.py --load 12 --slip 0.03 --json opt.json

F1 is the unknown; F2 = F1 / (F1/F2 of the configuration), so the thrust ratio, and with it
the ratio the pulleys hold, stays the configuration's. Each evaluation is a run until steady
(bound --t-end) at the given load; its slip (creep) 1 - geometric / speed ratio is the
constraint, with the run summary's verdict: a run whose status is "slip" (gross slip, or
the creep growing across the window, docs/output.md) fails whatever its slip. A run that
slips stops as soon as the verdict holds, so its slip says only "slipped": the search is
a bisection on that verdict (scipy.optimize.bisect), whose number of runs is known before
it starts. The script prints the efficiency of every run: the runs that held show whether
the smallest force that holds is also the most efficient. Then `study_slip` at the force
found must give a slip limit equal to the load: the same question asked from the other
side. Every run takes the engine's defaults: no integrator key is set.
"""
import argparse
import json
import os
import time

import numpy as np
from scipy.optimize import bisect

import cvt_engine as cvt

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")

ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("--config", default=os.path.join(ROOT, "configs", "mini.toml"))
ap.add_argument("--load", type=float, default=15.0, help="load torque [N m]")
ap.add_argument("--thrust-ratio", type=float, default=1.13, help="F1/F2, kept [1]")
ap.add_argument("--slip", type=float, default=0.05, help="the slip bound (0.05: gross slip, as the slip study)")
ap.add_argument("--bracket", default="6e3,14e3", help="F1 interval to search [N]")
ap.add_argument("--t-end", type=float, default=0.03, help="bound on each run [s]")
ap.add_argument("--xtol", type=float, default=0.01, help="relative tolerance on F1")
ap.add_argument("--threads", type=int, default=os.cpu_count())
ap.add_argument("--json", help="write the result here as well")
ap.add_argument("--figure", default="optimize-clamping.png", help="the runs and the optimum drawn here")
ap.add_argument("--study-out", default="optimize-slip.csv", help="the slip study's CSV")
args = ap.parse_args()

runs = []  # every evaluation: F1, slip, efficiency, status, wall time


def steady_run(f1):
    over = {"clamping.driving": f1, "clamping.driven": f1 / args.thrust_ratio, "load.torque": args.load}
    return cvt.run(args.config, overrides=over, until_steady=True, t_end=args.t_end, threads=args.threads,
                   channels=False)


def slip_excess(f1):
    """The slip of the steady run at clamping F1 minus the bound (> 0: too little clamping)."""
    s = steady_run(f1).summary
    runs.append({"clamping_driving": f1, "slip": s["slip"], "efficiency": s["efficiency"], "status": s["status"],
                 "output_torque": s["output_torque"], "wall_s": s["wall_s"]})
    # A run that slipped stops as soon as the verdict holds: its power ratio is no efficiency.
    eff = "     -" if s["status"] == "slip" else f"{s['efficiency']:.4f}"
    print(f"  F1 = {f1:8.1f} N: {s['status']:10s} slip {100 * s['slip']:+6.2f} %  efficiency {eff}"
          f"  output {s['output_torque']:.2f} N m  ({s['wall_s']:.1f} s)", flush=True)
    # The summary's verdict first: "slip" (gross, or creep growing across the window) fails
    # whatever the slip's value at the stop.
    return max(s["slip"] - args.slip, 1e-3) if s["status"] == "slip" else s["slip"] - args.slip


lo, hi = (float(x) for x in args.bracket.split(","))
print(f"smallest F1 (F1/F2 = {args.thrust_ratio}) holding {args.load} N m with slip <= {100 * args.slip:g} %, "
      f"{os.path.basename(args.config)}:")
t0 = time.time()
bisect(slip_excess, lo, hi, xtol=args.xtol * lo)
wall_opt = time.time() - t0
# The optimum: the smallest force that held (bisect's last midpoint may be one that slipped).
held = [r for r in runs if r["status"] != "slip" and r["slip"] <= args.slip]
best = min(held, key=lambda r: r["clamping_driving"])
f_opt = best["clamping_driving"]
print(f"optimum F1 = {f_opt:.1f} N (F2 = {f_opt / args.thrust_ratio:.1f} N), efficiency {best['efficiency']:.4f}, "
      f"after {len(runs)} simulations, {wall_opt:.0f} s (the best efficiency of the {len(held)} that held: "
      f"{max(r['efficiency'] for r in held):.4f})")
print(f"the slip study at F1 = {f_opt:.1f} N:")
t1 = time.time()
study = cvt.study_slip(args.config, clamping=[f_opt], thrust_ratio=args.thrust_ratio, tolerance=0.03,
                       overrides={"run.t_end": args.t_end}, out=args.study_out, threads=args.threads,
                       log=lambda line: print("  " + line, flush=True))[0]
wall_study = time.time() - t1
print(f"  holds {study['slip_torque']:.2f} N m, slips at {study['slips_at']:.2f} N m ({study['runs']} runs, "
      f"{wall_study:.0f} s) against the load {args.load} N m: "
      f"{100 * (study['slip_torque'] / args.load - 1):+.1f} %")
result = {"load": args.load, "thrust_ratio": args.thrust_ratio, "slip_bound": args.slip, "optimum": f_opt,
          "simulations": len(runs), "wall_s": wall_opt, "runs": runs, "study": study, "study_wall_s": wall_study,
          "efficiency_at_optimum": best["efficiency"],
          "efficiency_slope": float(np.polyfit([r["clamping_driving"] for r in held],
                                               [r["efficiency"] for r in held], 1)[0]) if len(held) > 1 else None}
if args.json:
    with open(args.json, "w") as f:
        json.dump(result, f, indent=1)

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt

ev = sorted(runs, key=lambda r: r["clamping_driving"])
ok = [r for r in ev if r in held]
fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
for r in ev:
    a1.plot(r["clamping_driving"] / 1e3, 100 * r["slip"], "o" if r in held else "x",
            color="tab:blue" if r in held else "tab:red")
a1.axhline(100 * args.slip, color="0.5", ls="--", lw=1)
a1.axvline(f_opt / 1e3, color="tab:green", lw=1.5, label=f"optimum {f_opt / 1e3:.2f} kN")
a1.set_xlabel("clamping force F1 [kN]")
a1.set_ylabel("slip (creep) at the end [%]")
a1.set_title(f"{args.load:g} N m: held (o), slipped (x)")
a1.legend()
a2.plot([r["clamping_driving"] / 1e3 for r in ok], [r["efficiency"] for r in ok], "o-", color="tab:blue")
a2.axvline(f_opt / 1e3, color="tab:green", lw=1.5)
a2.set_xlabel("clamping force F1 [kN]")
a2.set_ylabel("efficiency of the runs that held")
a2.set_title(f"slip study at the optimum: holds {study['slip_torque']:.2f}, slips at {study['slips_at']:.2f} N m",
             fontsize=10)
for a in (a1, a2):
    a.grid(alpha=0.3)
fig.tight_layout()
fig.savefig(args.figure, dpi=110)
print(f"wrote {args.figure}")
