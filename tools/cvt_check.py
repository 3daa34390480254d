#!/usr/bin/python3
"""Checks a cvt-engine result against CVT theory over a time window.

    /usr/bin/python3 tools/cvt_check.py results.h5 [--from T0] [--to T1]

Prints the window means of input, output and load torque, speed ratio against the
geometric ratio (creep), the efficiency as 1 - dissipated / input work over the window
(insensitive to energy swinging in and out of the torsion springs), the mean link tension
of the two free strands over the window (the last snapshot's, for a file without the
strand channels) against the difference the transmitted torque demands (T_tight - T_slack
= M_out / R2), and the meshing frequency: the strongest line of the output torque's spectrum near the rate at which links enter the
driving pulley, omega_in R1 / pitch.
"""
import argparse
import sys

import h5py
import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file")
    ap.add_argument("--from", dest="t0", type=float, default=None, help="window start [s] (default: 50 %% of the run)")
    ap.add_argument("--to", dest="t1", type=float, default=None, help="window end [s] (default: end of the run)")
    a = ap.parse_args()
    try:
        f = h5py.File(a.file, "r")
    except OSError as e:
        sys.exit(f"cvt_check: cannot open {a.file}: {e}")
    o = f["observables"]
    t = o["input_speed/time"][:]
    t0 = a.t0 if a.t0 is not None else 0.5 * t[-1]
    t1 = a.t1 if a.t1 is not None else t[-1]
    i0, i1 = np.searchsorted(t, t0), np.searchsorted(t, t1, side="right") - 1
    if i1 <= i0:
        sys.exit(f"cvt_check: empty window [{t0}, {t1}] (run covers [{t[0]}, {t[-1]}])")
    w = slice(i0, i1 + 1)
    v = lambda k: o[k + "/value"][:]
    d = lambda k: v(k)[i1] - v(k)[i0]
    Min, Mout, Mload = v("input_torque")[w].mean(), v("output_torque")[w].mean(), v("load_torque")[w].mean()
    # The geometric ratio is 0 (undefined) while no pin touches a sheave: the mean of the
    # samples above 0, as the run's summary takes it.
    g = v("geometric_ratio")[w]
    ratio, geo = v("speed_ratio")[w].mean(), (g[g > 0].mean() if (g > 0).any() else float("nan"))
    print(f"window {t[i0]*1e3:.2f} .. {t[i1]*1e3:.2f} ms ({i1 - i0 + 1} samples)")
    print(f"  torque in / out / load      {Min:8.2f} / {Mout:8.2f} / {Mload:8.2f} N m   (out/load {Mout / Mload:.3f})")
    print(f"  speed ratio / geometric     {ratio:.5f} / {geo:.5f}   (creep {100 * (ratio / geo - 1):+.3f} %)")
    print(f"  efficiency 1 - D/W_in       {1 - d('work_dissipated') / d('work_input'):.4f}")
    print(f"  energy residual / W_in      {v('energy_residual')[i1] / v('work_input')[i1]:.2e} (whole run)")
    cfg = f["parameters"].attrs["config"] if "config" in f["parameters"].attrs else f["parameters/config"][()]
    cfg = cfg.decode() if isinstance(cfg, bytes) else str(cfg)
    key = lambda name: float([l for l in cfg.splitlines() if l.strip().startswith(name + " ")][0].split("=")[1].split("#")[0])
    R1 = float(np.ravel(f["parameters/geometry/running_radius_driving"][()])[0]) \
        if "parameters/geometry/running_radius_driving" in f else None
    if R1 is not None and i1 - i0 > 64:
        f_mesh = v("input_speed")[w].mean() * R1 / key("pitch")
        x = v("output_torque")[w] - Mout
        F = np.abs(np.fft.rfft(x * np.hanning(x.size)))
        fr = np.fft.rfftfreq(x.size, (t[i1] - t[i0]) / (i1 - i0))
        band = (fr > 0.5 * f_mesh) & (fr < 1.5 * f_mesh)
        if band.any():
            peak = fr[band][np.argmax(F[band])]
            print(f"  meshing frequency           {peak:.0f} Hz in the output torque against omega_in R1 / pitch = "
                  f"{f_mesh:.0f} Hz ({100 * (peak / f_mesh - 1):+.1f} %; resolution {fr[1]:.0f} Hz)")
    if "strand_tension_upper" in o:
        up, lo = v("strand_tension_upper")[w].mean(), v("strand_tension_lower")[w].mean()
        print(f"  strands (window means)      upper {up:.0f} N, lower {lo:.0f} N: difference {abs(up - lo):.0f} N")
        # The driven pulley's running radius of the placement.
        if "parameters/geometry/running_radius_driven" in f:
            R2_run = float(np.ravel(f["parameters/geometry/running_radius_driven"][()])[0])
            print(f"    output torque / R2 = {Mout:.1f} / {R2_run*1e3:.1f} mm = {Mout / R2_run:.0f} N "
                  f"({100 * (abs(up - lo) / (Mout / R2_run) - 1):+.1f} %)")
    elif "particles/chain/position" in f:
        P = f["particles/chain/position/value"][-1]
        T = f["particles/chain/link_tension/value"][-1]
        ts = f["particles/chain/position/time"][-1]
        a_dist = key("centre_distance")
        x, y = P[:, 0], P[:, 1]
        mid = (x > 0.2 * a_dist) & (x < 0.8 * a_dist)
        up, lo = T[mid & (y > 0)], T[mid & (y < 0)]
        k = np.searchsorted(t, ts)
        k = min(k, len(t) - 1)
        R2 = np.sqrt(((P[:, 0] - a_dist) ** 2 + P[:, 1] ** 2))[x > a_dist].mean()
        M = v("output_torque")[k]
        print(f"  strands at t = {ts*1e3:.2f} ms: upper {up.mean():.0f} N ({up.size} links), lower {lo.mean():.0f} N ({lo.size} links)")
        print(f"    difference {abs(up.mean() - lo.mean()):.0f} N; output torque / R2 = {M:.1f} / {R2*1e3:.1f} mm = {M / R2:.0f} N")


if __name__ == "__main__":
    main()
