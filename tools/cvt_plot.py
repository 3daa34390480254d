#!/usr/bin/python3
"""Plots of cvt-engine results (Debian's python3-h5py, python3-matplotlib, python3-numpy).

Figures of a run:

    /usr/bin/python3 tools/cvt_plot.py history RUN.h5 [--from T0] [--to T1] [-o history.png]
    /usr/bin/python3 tools/cvt_plot.py spectrogram RUN.h5 CHANNEL [--column K] [--nperseg N] [-o FILE.png]
    /usr/bin/python3 tools/cvt_plot.py animate RUN.h5 [--every K] [--fps F] [-o chain.gif]

Performance figures:

    /usr/bin/python3 tools/cvt_plot.py profile RUN.h5|PROFILE.json [-o profile.png]
    /usr/bin/python3 tools/cvt_plot.py scaling STUDY.csv|STUDY.json [-o scaling.png]
    /usr/bin/python3 tools/cvt_plot.py integrators STUDY.csv [--curves STUDY-curves.csv] [-o integrators.png]

history: first what a transmission engineer looks at (speed ratio with the geometric ratio,
slip, input/output/load torque, clamping forces, sheave positions, efficiency on a fixed
axis around [0, 1], tight and slack strand tension from the snapshots), then the tracked
link and pin, chain torsion, supports and shaft speeds (like Fig. 8 of Orlov et al. 2015).
spectrogram: short-time Fourier transform of one output channel. animate: the chain in
the plane of the pulleys from the snapshots, links coloured by tension, as a GIF.
profile: share of each module in the run time (their Fig. 5) with the spread of busy time
over threads. scaling: speedup against threads with the ideal line and the fitted Amdahl
curve, per-module speedups and buffer zero+gather against compute time (their Fig. 9;
Orlov et al. 2016, Figs. 8-11). integrators: the integrator study (`cvt-engine study
integrators`, Orlov et al. 2016 Figs. 12-17): one-step error against h, the sample curves
of each method's chosen run against the reference, and wall time and RHS evaluations of
every run tried. -o is short for --out everywhere. docs/plots.md describes every panel.
Exit codes: 0 success, 2 bad input (missing file, group, channel or column; a message on
stderr names it).
"""
import argparse
import csv
import importlib.util
import json
import math
import os
import sys

PROG = "cvt_plot"

try:
    import numpy as np
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError as e:  # matplotlib >= 3.3 needs Pillow as well
    sys.exit(f"{PROG}: {e}: install Debian's python3-numpy and python3-matplotlib (with python3-pil) "
             "and run this with /usr/bin/python3")


class UserError(Exception):
    """Bad input from the user: reported as one line on stderr, exit code 2."""


def warn(msg):
    print(f"{PROG}: {msg}", file=sys.stderr)


# ---------------------------------------------------------------------------- input

def as_str(x):
    if isinstance(x, bytes):
        return x.decode("utf-8", "replace")
    if isinstance(x, np.ndarray) and x.shape == ():
        return as_str(x[()])
    if isinstance(x, np.bytes_):
        return bytes(x).decode("utf-8", "replace")
    return str(x)


def open_h5(path):
    try:
        import h5py
    except ImportError:
        raise UserError("h5py is missing: install Debian's python3-h5py and use /usr/bin/python3")
    if not os.path.exists(path):
        raise UserError(f"{path}: no such file")
    try:
        return h5py.File(path, "r")
    except OSError as e:
        # A run in progress or killed: the file is still open for writing (SWMR).
        try:
            return h5py.File(path, "r", swmr=True)
        except OSError:
            raise UserError(f"{path}: cannot open as HDF5: {e}")


def channels(f):
    g = f.get("observables")
    return sorted(g.keys()) if g is not None else []


def has_channel(f, name):
    return f"observables/{name}/value" in f and f"observables/{name}/time" in f


def window_mask(t, t0=None, t1=None):
    """Samples of t inside [t0, t1] (either end open when None)."""
    m = np.ones(len(t), dtype=bool)
    if t0 is not None:
        m &= t >= t0
    if t1 is not None:
        m &= t <= t1
    return m


def read_channel(f, name, t0=None, t1=None):
    """(time [s], value [T] or [T][k], unit) of /observables/NAME, cut to [t0, t1]."""
    if not has_channel(f, name):
        avail = ", ".join(channels(f)) or "none"
        raise UserError(f"{f.filename}: no channel '{name}' (channels: {avail})")
    t = np.asarray(f[f"observables/{name}/time"][:], dtype=float)
    d = f[f"observables/{name}/value"]
    v = np.asarray(d[:], dtype=float)
    n = min(len(t), len(v))  # a file still being written may differ by a row
    t, v = t[:n], v[:n]
    unit = as_str(d.attrs.get("unit", "")) if "unit" in d.attrs else ""
    m = window_mask(t, t0, t1)
    return t[m], v[m], unit


def read_config(f):
    """The resolved TOML of the run as a dict ({} if absent or unreadable)."""
    import tomllib
    g = f.get("parameters")
    if g is not None and "config" in g.attrs:
        text = as_str(g.attrs["config"])
    elif "parameters/config" in f:  # files that hold it as a dataset
        text = as_str(f["parameters/config"][()])
    else:
        return {}
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        warn(f"{f.filename}: /parameters@config is not valid TOML ({e}); using defaults")
        return {}


# SI prefixes so that axes read "kN" or "mrad" instead of 1e4 or 2e-3.
_PREFIXABLE = {"N", "m", "rad", "J", "W", "s"}


def scaled(values, unit):
    """(factor, unit label) so that values * factor lie around 1..1000."""
    if unit not in _PREFIXABLE:
        return 1.0, unit
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    m = float(np.max(np.abs(v))) if v.size else 0.0
    if m == 0.0:
        return 1.0, unit
    for f, p in ((1e-6, "M"), (1e-3, "k"), (1.0, ""), (1e3, "m"), (1e6, "µ")):
        if m * f >= 1.0:
            return f, p + unit
    return 1e6, "µ" + unit


def ylabel(what, unit):
    """'what [unit]'; '[-]' for a dimensionless quantity (unit "-" or "1" in the file)."""
    if unit in ("-", "1"):
        return f"{what} [-]"
    return f"{what} [{unit}]" if unit else what


def save(fig, out):
    d = os.path.dirname(os.path.abspath(out))
    if not os.path.isdir(d):
        raise UserError(f"{out}: directory {d} does not exist")
    fig.savefig(out, dpi=110)
    plt.close(fig)
    print(f"{PROG}: wrote {out}")


# -------------------------------------------------------------------------- history

SUPPORT_LABELS = ["shaft 1, bearing at -l_b", "shaft 1, bearing at +l_b",
                  "shaft 2, bearing at -l_b", "shaft 2, bearing at +l_b"]


# Time axis of the history: (factor from s, unit), ms unless the window spans 2 s or more.
TIME = [1e3, "ms"]


def _envelope(t, v, most=20000):
    """At most `most` points: the min and max of each bucket in time order, so that peaks of
    a long run (10^5-10^6 samples) still show without drawing every sample."""
    n = len(t)
    if n <= most:
        return t, v
    k = math.ceil(n / (most // 2))
    m = (n // k) * k
    tb, vb = t[:m].reshape(-1, k), v[:m].reshape(-1, k)
    i = np.arange(len(tb))
    fin = np.isfinite(vb)
    lo = np.argmin(np.where(fin, vb, np.inf), axis=1)
    hi = np.argmax(np.where(fin, vb, -np.inf), axis=1)
    first, second = np.minimum(lo, hi), np.maximum(lo, hi)
    tt = np.stack([tb[i, first], tb[i, second]], axis=1).ravel()
    vv = np.stack([vb[i, first], vb[i, second]], axis=1).ravel()
    return np.concatenate([tt, t[m:]]), np.concatenate([vv, v[m:]])


def _lines(ax, t, v, unit, labels=None, what="", **kw):
    v = _finite(v)
    fac, u = scaled(v, unit)
    if v.ndim == 1:
        ax.plot(*_envelope(t * TIME[0], v * fac), lw=0.9, label=labels[0] if labels else None, **kw)
    else:
        k = v.shape[1]
        colors = plt.cm.viridis(np.linspace(0, 0.9, k)) if k > 4 else [None] * k
        # Columns that coincide (symmetric plates, the bearings of a shaft) stay visible.
        styles = ["-", "--", "-.", ":"] if k <= 4 else ["-"]
        for j in range(k):
            lab = labels[j] if labels and j < len(labels) else f"{j + 1}"
            ax.plot(*_envelope(t * TIME[0], v[:, j] * fac), lw=0.9 if k > 4 else 1.1, color=colors[j],
                    ls=styles[j % len(styles)], label=lab, **kw)
    ax.set_ylabel(ylabel(what, u))
    return fac, u


def _windowed_ratio(f, num, den, t0, t1, window):
    """(num(t) - num(t - w)) / (den(t) - den(t - w)) of two cumulative channels (works)."""
    t, wd, _ = read_channel(f, den)
    tn, wn, _ = read_channel(f, num)
    n = min(len(t), len(tn))
    t, wd, wn = t[:n], wd[:n], wn[:n]
    if n < 3:
        return None
    span = (t1 if t1 is not None else t[-1]) - (t0 if t0 is not None else t[0])
    w = window if window else 0.2 * span
    w = max(w, 3 * float(np.median(np.diff(t))))
    j = np.searchsorted(t, t - w)  # start of each window
    ok = (t - t[0] >= w * 0.999) & (j < np.arange(n))
    dd = wd - wd[j]
    dn = wn - wn[j]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(ok & (np.abs(dd) > 0), dn / dd, np.nan)
    m = window_mask(t, t0, t1)
    return t[m], r[m], w


# Efficiency axis: fixed, a little beyond [0, 1], so that a transient (where P_out / P_in can
# reach 50 or -6000) does not squash the steady part.
EFF_RANGE = (-0.1, 1.1)


class Panel:
    """One panel of the history figure: `present` says whether the file has its data, `missing`
    why not (for the note), `draw(ax)` draws it and returns False when the window is empty."""

    def __init__(self, title, draw, present, missing="", time_channel=None):
        self.title, self.draw, self.present, self.missing = title, draw, present, missing
        self.time_channel = time_channel


def _finite(v):
    v = np.asarray(v, dtype=float)
    return np.where(np.isfinite(v), v, np.nan)


def _spans(t, mask):
    """[(t_start, t_end)] of the runs of True in mask."""
    out = []
    i, n = 0, len(mask)
    while i < n:
        if mask[i]:
            j = i
            while j + 1 < n and mask[j + 1]:
                j += 1
            out.append((float(t[i]), float(t[j])))
            i = j + 1
        else:
            i += 1
    return out


def efficiency_outside(t, v, lo=0.0, hi=1.0):
    """Where an efficiency curve leaves [lo, hi]: (mask, spans [(t0, t1)], extreme value or None)."""
    v = np.asarray(v, dtype=float)
    fin = np.isfinite(v)
    out = fin & ((v < lo) | (v > hi))
    if not np.any(out):
        return out, [], None
    ext = v[out][np.argmax(np.abs(v[out] - 0.5))]
    return out, _spans(t, out), float(ext)


def _fmt_spans(spans, most=3):
    s = [f"{a * TIME[0]:.3g}-{b * TIME[0]:.3g}" if b > a else f"{a * TIME[0]:.3g}" for a, b in spans[:most]]
    more = f" and {len(spans) - most} more" if len(spans) > most else ""
    return ", ".join(s) + more + f" {TIME[1]}"


def centre_distance(f, pos0=None):
    """geometry.centre_distance of the run's config; estimated from a snapshot if absent."""
    geo = read_config(f).get("geometry", {})
    if "centre_distance" in geo:
        return float(geo["centre_distance"])
    if pos0 is None:
        return float("nan")
    dist = float(np.ptp(pos0[:, 0])) - 2 * _wrap_radius(pos0, float(np.min(pos0[:, 0])))
    warn(f"{f.filename}: no geometry.centre_distance in /parameters/config; estimated {dist * 1e3:.1f} mm")
    return dist


def strand_tensions(pos, ten, dist):
    """Mean link tension of the upper (y > 0) and lower (y < 0) free strand in each snapshot.

    pos [S][N][3] joint centres, ten [S][N] link tensions (link i joins joints i and i + 1),
    dist the centre distance (driving pulley at x = 0, driven at x = dist). A link counts for a
    strand when its midpoint lies in the middle 60 % of the span (0.2 dist < x < 0.8 dist), as in
    tools/cvt_check.py: away from where the chain runs onto or off a pulley. Returns
    (upper [S], lower [S], links in upper [S], links in lower [S]); NaN where a strand has no link.
    """
    pos = np.asarray(pos, dtype=float)
    ten = np.asarray(ten, dtype=float)
    mid = 0.5 * (pos + np.roll(pos, -1, axis=1))
    x, y = mid[..., 0], mid[..., 1]
    free = (x > 0.2 * dist) & (x < 0.8 * dist)
    up, lo = free & (y > 0), free & (y < 0)
    nu, nl = up.sum(axis=1), lo.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mu = np.where(nu > 0, np.where(up, ten, 0).sum(axis=1) / nu, np.nan)
        ml = np.where(nl > 0, np.where(lo, ten, 0).sum(axis=1) / nl, np.nan)
    return mu, ml, nu, nl


def has_snapshots(f):
    return all(f"particles/chain/{g}/{d}" in f for g in ("position", "link_tension") for d in ("time", "value"))


def read_strands(f, t0=None, t1=None):
    """Strand tensions from the snapshots in [t0, t1]: dict with time, tight, slack (mean link
    tension [N]), tight_is_upper, and demand = |output_torque| / R2 at the snapshot times (R2 the
    wrap radius on the driven pulley) or None without output_torque. None without snapshots."""
    if not has_snapshots(f):
        return None
    ts = np.asarray(f["particles/chain/position/time"][:], dtype=float)
    P, T = f["particles/chain/position/value"], f["particles/chain/link_tension/value"]
    S = min(len(ts), P.shape[0], T.shape[0], len(f["particles/chain/link_tension/time"]))
    idx = np.nonzero(window_mask(ts[:S], t0, t1))[0]
    if len(idx) == 0:
        return dict(time=np.zeros(0), tight=np.zeros(0), slack=np.zeros(0), tight_is_upper=True, demand=None)
    pos = np.asarray(P[idx.tolist()], dtype=float)
    ten = np.asarray(T[idx.tolist()], dtype=float)
    dist = centre_distance(f, pos[0])
    up, lo, _, _ = strand_tensions(pos, ten, dist)
    # The tight strand is the one with the higher tension over the window (the upper one when the
    # driving pulley pulls it in); the names stay fixed so that the lines do not swap.
    tight_is_upper = not (np.nanmean(lo) > np.nanmean(up)) if np.any(np.isfinite(up)) or np.any(np.isfinite(lo)) else True
    tight, slack = (up, lo) if tight_is_upper else (lo, up)
    demand = None
    if has_channel(f, "output_torque"):
        tm, m, _ = read_channel(f, "output_torque")
        if len(tm):
            r2 = np.array([_wrap_radius(p, dist) for p in pos])
            with np.errstate(invalid="ignore", divide="ignore"):
                demand = np.abs(np.interp(ts[idx], tm, m)) / r2
    return dict(time=ts[idx], tight=tight, slack=slack, tight_is_upper=tight_is_upper, demand=demand)


def history_panels(f, t0=None, t1=None, eff_window=None):
    """The panels of the history figure in their order, present in the file or not."""
    panels = []

    def channel_panel(title, names, draw):
        miss = [n for n in names if not has_channel(f, n)]
        present = len(miss) < len(names)
        first = next((n for n in names if has_channel(f, n)), names[0])
        panels.append(Panel(title, draw, present, f"channel {miss[0]} not in the file" if miss else "", first))

    def simple(title, name, what, labels=None, scale=None):
        def draw(ax):
            t, v, u = read_channel(f, name, t0, t1)
            if len(t) == 0:
                return False
            if scale is not None:
                fac, u2 = scale
                _lines(ax, t, v * fac, "", labels, what)
                ax.set_ylabel(ylabel(what, u2))
            else:
                _lines(ax, t, v, u, labels, what)
            if v.ndim == 2 and 1 < v.shape[1] <= 6:
                ax.legend(fontsize=7, ncol=2, loc="best")
            elif v.ndim == 2:  # many lines: name the first and the last, the colours run between
                h = ax.get_lines()
                ax.legend([h[0], h[-1]], [h[0].get_label(), h[-1].get_label()], fontsize=7, ncol=2,
                          loc="best", title=f"{v.shape[1]} lines, dark to light", title_fontsize=7)
            return True
        channel_panel(title, [name], draw)

    def group(title, names, what, labels, ncol=1):
        def draw(ax):
            present = [n for n in names if has_channel(f, n)]
            vals = [(n, read_channel(f, n, t0, t1)) for n in present]
            vals = [(n, x) for n, x in vals if len(x[0])]
            if not vals:
                return False
            # The geometric ratio is 0 while no pin touches a sheave (the start from rest): undefined.
            vals = [(n, (t, np.where(v > 0, v, np.nan), u) if n == "geometric_ratio" else (t, v, u))
                    for n, (t, v, u) in vals]
            allv = np.concatenate([v.ravel() for _, (_, v, _) in vals])
            fac, uu = scaled(allv, vals[0][1][2])
            for n, (t, v, _) in vals:
                i = names.index(n)  # solid, dashed, dash-dot: lines that coincide stay visible
                ax.plot(*_envelope(t * TIME[0], _finite(v) * fac), lw=1.1, ls=["-", "--", "-."][i % 3],
                        color=f"C{i}", label=labels[i])
            ax.set_ylabel(ylabel(what, uu))
            ax.legend(fontsize=7, loc="best", ncol=ncol)
            return True
        channel_panel(title, names, draw)

    # -- what an engineer looks at first
    group("Speed ratio and geometric ratio", ["speed_ratio", "geometric_ratio"], "ratio",
          ["speed ratio ω_in / ω_out", "geometric ratio R2 / R1"])

    def draw_slip(ax):
        t, v, _ = read_channel(f, "slip", t0, t1)
        if len(t) == 0:
            return False
        if has_channel(f, "geometric_ratio"):  # undefined while the geometric ratio is
            tg, g, _ = read_channel(f, "geometric_ratio", t0, t1)
            if len(tg) == len(t):
                v = np.where(g > 0, v, np.nan)
        ax.axhline(0, color="0.5", lw=0.7)
        ax.plot(*_envelope(t * TIME[0], _finite(v) * 100), lw=0.9, color="C3")
        ax.set_ylabel("slip [%]")
        return True
    channel_panel("Slip = 1 - geometric ratio / speed ratio (> 0: the driven pulley lags)", ["slip"], draw_slip)

    group("Torques", ["input_torque", "output_torque", "load_torque"], "torque",
          ["input (drive spring)", "output (load spring)", "load"])
    group("Clamping forces", ["clamping_force_driving", "clamping_force_driven"], "clamping force",
          ["driving pulley (F1)", "driven pulley (F2)"])
    simple("Sheave positions", "sheave_position", "axial position w", ["driving pulley", "driven pulley"],
           scale=(1e3, "mm"))

    def draw_eff(ax):
        curves = []  # (label, t, v, style): drawn, and checked against [0, 1]
        if has_channel(f, "efficiency"):
            t, v, _ = read_channel(f, "efficiency", t0, t1)
            if len(t):
                curves.append(("instantaneous P_out / P_in", t, v, dict(lw=0.6, color="0.55", alpha=0.7),
                               "instantaneous"))
        main = None
        if has_channel(f, "running_efficiency"):
            t, v, _ = read_channel(f, "running_efficiency", t0, t1)
            # The engine writes 0 until W_in has grown over a window: not a value, leave it out.
            v = v.copy()
            nz = np.nonzero(v != 0)[0]
            v[: nz[0] if len(nz) else len(v)] = np.nan
            main = ("running ΔW_out / ΔW_in (engine)", t, v, "running")
        elif has_channel(f, "work_input") and has_channel(f, "work_output"):
            r = _windowed_ratio(f, "work_output", "work_input", t0, t1, eff_window)
            if r is not None:
                main = (f"running ΔW_out / ΔW_in over {r[2] * 1e3:.3g} ms", r[0], r[1], "running")
        if main is not None and len(main[1]):
            curves.append((*main[:3], dict(lw=1.4, color="C3"), main[3]))
        # Losses alone: blind to energy moving in and out of the torsion springs and inertias.
        if has_channel(f, "work_dissipated") and has_channel(f, "work_input"):
            r = _windowed_ratio(f, "work_dissipated", "work_input", t0, t1, eff_window)
            if r is not None and len(r[0]):
                curves.append((f"1 - ΔW_diss / ΔW_in over {r[2] * 1e3:.3g} ms", r[0], 1 - r[1],
                               dict(lw=1.2, ls="--", color="C0"), "1 - ΔW_diss / ΔW_in"))
        if not curves:
            return False
        for y in (0.0, 1.0):
            ax.axhline(y, color="0.4", lw=0.6, ls=":")
        shaded = False
        notes = []
        for label, t, v, style, short in curves:
            v = _finite(v)
            ax.plot(*_envelope(t * TIME[0], v), label=label, **style)
            _, spans, ext = efficiency_outside(t, v)
            if not spans:
                continue
            notes.append(f"{short}: {_fmt_spans(spans)} (extreme {ext:.3g})")
            if style.get("color") == "C3":  # shade where the main curve is out (the others swing more)
                for a_, b_ in spans:
                    ax.axvspan(a_ * TIME[0], b_ * TIME[0], color="C1", alpha=0.15, lw=0,
                               label=None if shaded else "running efficiency outside [0, 1]")
                    shaded = True
        ax.set_ylim(*EFF_RANGE)
        ax.set_ylabel("efficiency [-]")
        if notes:
            ax.text(0.01, 0.03, f"Outside [0, 1]: not meaningful there (transient); axis cut at "
                    f"{EFF_RANGE[0]:g} .. {EFF_RANGE[1]:g}\n" + "\n".join(notes), transform=ax.transAxes,
                    fontsize=7, va="bottom", color="0.15", bbox=dict(fc="w", ec="0.7", alpha=0.75, pad=2),
                    gid="efficiency-note")
        ax.legend(fontsize=7, loc="lower right", framealpha=0.9)
        return True
    have_eff = [n for n in ("running_efficiency", "efficiency", "work_input") if has_channel(f, n)]
    panels.append(Panel("Efficiency", draw_eff, bool(have_eff), "channels running_efficiency, efficiency "
                        "and work_input not in the file", have_eff[0] if have_eff else None))

    def draw_strands(ax):
        s = read_strands(f, t0, t1)
        if s is None or len(s["time"]) == 0:
            return False
        tt = s["time"] * TIME[0]
        allv = np.concatenate([s["tight"], s["slack"]] + ([s["demand"]] if s["demand"] is not None else []))
        fac, u = scaled(allv, "N")
        up = "upper" if s["tight_is_upper"] else "lower"
        lo = "lower" if s["tight_is_upper"] else "upper"
        ax.plot(tt, s["tight"] * fac, "o-", ms=3, lw=1, color="C3", label=f"tight ({up}) strand")
        ax.plot(tt, s["slack"] * fac, "o-", ms=3, lw=1, color="C0", label=f"slack ({lo}) strand")
        ax.plot(tt, (s["tight"] - s["slack"]) * fac, "s-", ms=3, lw=1, color="C2", label="tight - slack")
        if s["demand"] is not None:
            ax.plot(tt, s["demand"] * fac, "x--", ms=4, lw=1, color="k",
                    label="|output torque| / R2 (what the torque needs)")
        ax.set_ylabel(ylabel("mean link tension", u))
        top = np.nanmax(np.abs(allv)) * fac if np.any(np.isfinite(allv)) else 1.0
        ax.set_ylim(top=1.5 * top if top > 0 else 1.0)  # the top third for the legend
        ax.legend(fontsize=7, loc="upper left", ncol=2)
        return True
    panels.append(Panel("Strand tensions (mean over the free strand, from the snapshots)", draw_strands,
                        has_snapshots(f), "no /particles/chain snapshots in the file (run.snapshot_interval = 0)"))

    # -- the details: tracked link and pin, chain, supports, speeds
    simple("Link tension (tracked link)", "link_tension", "tension")
    simple("Plate tension (plates of the tracked link)", "plate_tension", "tension",
           labels=[f"plate {j + 1}" for j in range(64)])
    simple("Pin axial force (tracked pin)", "pin_axial_force", "axial force", ["half a", "half b"])
    simple("Chain torsion angle", "chain_torsion_angle", "angle")
    simple("Support forces", "support_force", "force", SUPPORT_LABELS)
    group("Shaft speeds", ["input_speed", "output_speed", "load_speed"], "speed",
          ["input (shaft 1)", "output (shaft 2)", "load"])
    return panels


def history_figure(f, t0=None, t1=None, eff_window=None, name=None):
    """(figure, panels left out) of the history of the open run file f."""
    if not channels(f):
        raise UserError(f"{f.filename}: no /observables group (not a cvt-engine run?)")
    panels = history_panels(f, t0, t1, eff_window)
    avail = [p for p in panels if p.present]
    skipped = [p for p in panels if not p.present]
    spans = [read_channel(f, p.time_channel, t0, t1)[0] for p in avail if p.time_channel]
    span = max((float(x[-1] - x[0]) for x in spans if len(x)), default=0.0)
    TIME[:] = [1e3, "ms"] if span < 2.0 else [1.0, "s"]
    if not avail:
        raise UserError(f"{f.filename}: none of the history channels is present")
    ncol = 2
    nrow = math.ceil(len(avail) / ncol)
    foot = 0.35 if skipped else 0.0
    fig, axes = plt.subplots(nrow, ncol, figsize=(13, 2.7 * nrow + 0.8 + foot), sharex=True, squeeze=False)
    drawn_any = False
    for ax, p in zip(axes.ravel(), avail):
        ok = p.draw(ax)
        drawn_any |= ok
        ax.set_title(p.title, fontsize=10)
        ax.grid(alpha=0.3)
        if not ok:
            ax.text(0.5, 0.5, "no samples in the window", ha="center", va="center", transform=ax.transAxes)
    for ax in axes.ravel()[len(avail):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel(f"time [{TIME[1]}]")
        ax.xaxis.set_tick_params(labelbottom=True)
    if len(avail) % ncol and nrow > 1:
        axes[-2][-1].set_xlabel(f"time [{TIME[1]}]")
        axes[-2][-1].xaxis.set_tick_params(labelbottom=True)
    if not drawn_any:
        plt.close(fig)
        raise UserError(f"{f.filename}: no samples in the window [{t0}, {t1}] s")
    fig.suptitle(f"{name or os.path.basename(f.filename)}: time histories" + _cfg_note(f), fontsize=12)
    if skipped:
        fig.text(0.01, 0.005, "Not shown: " + "; ".join(f"{p.title.split(' (')[0]} ({p.missing})" for p in skipped),
                 fontsize=8, color="0.3", va="bottom", wrap=True, gid="skipped-note")
    h = fig.get_figheight()
    fig.tight_layout(rect=(0, foot / h, 1, 1 - 0.3 / h))
    return fig, skipped


def cmd_history(a):
    f = open_h5(a.file)
    fig, skipped = history_figure(f, a.t0, a.t1, a.eff_window, os.path.basename(a.file))
    for p in skipped:
        warn(f"history: skipping panel '{p.title}': {p.missing} ({a.file})")
    save(fig, a.out)


def _cfg_note(f):
    c = read_config(f)
    try:
        return (f"  ({c['chain']['links']} links, load {c['load']['torque']:g} N m, "
                f"clamping {c['clamping']['driving'] / 1e3:g}/{c['clamping']['driven'] / 1e3:g} kN, "
                f"tracked link {c['run'].get('tracked_link', 0)}, pin {c['run'].get('tracked_pin', 0)})")
    except (KeyError, TypeError):
        return ""


# -------------------------------------------------------------------------- profile

PROFILE_COLUMNS = ["calls", "wall_s", "us_per_step", "percent", "busy_min_s", "busy_avg_s",
                   "busy_max_s", "imbalance_percent"]
HEADER_KEYS = ["steps", "us_per_step", "model_s_per_hour", "threads", "numa_nodes", "scheduler", "wall_s"]


def _is_hdf5(path):
    with open(path, "rb") as fh:
        return fh.read(8) == b"\x89HDF\r\n\x1a\n"


def _looks_like_json(path):
    with open(path, "rb") as fh:
        return fh.read(64).lstrip()[:1] == b"{"


def load_profile(path):
    """(header dict, list of row dicts) from a --profile-json file or a run's /profile group."""
    if not os.path.exists(path):
        raise UserError(f"{path}: no such file")
    if not _is_hdf5(path):
        try:
            with open(path) as fh:
                d = json.load(fh)
        except (OSError, json.JSONDecodeError) as e:
            raise UserError(f"{path}: neither HDF5 nor JSON ({e})")
        if not isinstance(d, dict) or "rows" not in d or not isinstance(d["rows"], list):
            raise UserError(f"{path}: no 'rows' list (not a --profile-json file?)")
        header = d.get("header", {})
        rows = d["rows"]
        for i, r in enumerate(rows):
            miss = [k for k in ["name"] + PROFILE_COLUMNS if k not in r]
            if miss:
                raise UserError(f"{path}: row {i} lacks {', '.join(miss)}")
        return header, rows
    f = open_h5(path)
    g = f.get("profile")
    if g is None:
        raise UserError(f"{path}: no /profile group (was the run profiled?)")
    header = {k: (as_str(g.attrs[k]) if k == "scheduler" else g.attrs[k].item() if hasattr(g.attrs[k], "item") else g.attrs[k])
              for k in HEADER_KEYS if k in g.attrs}
    miss = [k for k in PROFILE_COLUMNS if k not in g] + ([] if "rows" in g.attrs or "name" in g else ["rows"])
    if miss:
        raise UserError(f"{path}: /profile lacks {', '.join(miss)}")
    names = [as_str(x) for x in (g.attrs["rows"] if "rows" in g.attrs else g["name"][:])]
    cols = {k: np.asarray(g[k][:], dtype=float) for k in PROFILE_COLUMNS}
    rows = [dict(name=n, **{k: float(cols[k][i]) for k in PROFILE_COLUMNS}) for i, n in enumerate(names)]
    return header, rows


# tab10 without its grey (grey is the total bar), then tab20's light tones.
_PALETTE = [plt.cm.tab10(i) for i in (0, 1, 2, 3, 4, 5, 6, 8, 9)] + [plt.cm.tab20(i) for i in (1, 3, 5, 7, 9, 11)]


def _int(x):
    """Counts come as doubles from the HDF5 attributes: 2.0 threads reads 2."""
    try:
        return int(x) if float(x) == int(x) else x
    except (TypeError, ValueError):
        return x


def cmd_profile(a):
    header, rows = load_profile(a.file)
    if not rows:
        raise UserError(f"{a.file}: the profile has no rows")
    total = [r for r in rows if r["name"] == "total"]
    mods = [r for r in rows if r["name"] != "total"]
    fig = plt.figure(figsize=(14, 10))
    gs = fig.add_gridspec(2, 2, width_ratios=[1.2, 1.0], height_ratios=[1.0, 0.85])
    ax1, ax2, ax3 = fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[0, 1]), fig.add_subplot(gs[1, :])
    # Fig. 5 of the paper: one bar per module, percent of the whole run, "Rk4Step" = 100 %.
    bars = mods + total
    names = [r["name"] for r in bars]
    pct = [r["percent"] for r in bars]
    colors = [_PALETTE[i % len(_PALETTE)] for i in range(len(mods))] + ["0.45"] * len(total)
    y = np.arange(len(bars))
    ax1.barh(y, pct, color=colors)
    for yi, p, r in zip(y, pct, bars):
        ax1.text(p + 1, yi, f"{p:.1f} %  ({r['us_per_step']:.3g} µs/step)", va="center", fontsize=8)
    ax1.set_yticks(y, names)
    ax1.invert_yaxis()
    ax1.set_xlim(0, max(max(pct), 100) * 1.45)
    ax1.set_xlabel("share of the run's wall time [%]")
    ax1.set_title("Load distribution between modules", fontsize=10)
    ax1.grid(axis="x", alpha=0.3)

    share = np.array([max(r["percent"], 0.0) for r in mods])
    if share.sum() > 0:
        frac = 100 * share / share.sum()
        wedges, _ = ax2.pie(share, colors=colors[:len(mods)], startangle=90, counterclock=False,
                            wedgeprops=dict(ec="w", lw=0.8))
        for w, p in zip(wedges, frac):
            if p >= 4:
                ang = np.deg2rad((w.theta1 + w.theta2) / 2)
                ax2.text(0.7 * np.cos(ang), 0.7 * np.sin(ang), f"{p:.0f} %", ha="center", va="center",
                         fontsize=9, color="w", weight="bold")
        ax2.legend(wedges, [f"{r['name']} ({p:.1f} %)" for r, p in zip(mods, frac)], fontsize=8,
                   loc="center left", bbox_to_anchor=(1.0, 0.5), frameon=False)
        ax2.set_title("Shares of the modules (without total)", fontsize=10)
    else:
        ax2.set_visible(False)

    # Spread of busy time over the threads: min / avg / max, in µs per step.
    steps = float(header.get("steps", 0) or 0)
    per = 1e6 / steps if steps > 0 else 1.0
    unit = "µs per step" if steps > 0 else "s"
    busy = [r for r in mods if r["busy_max_s"] > 0]
    if busy:
        yb = np.arange(len(busy))
        avg = np.array([r["busy_avg_s"] for r in busy]) * per
        lo = avg - np.array([r["busy_min_s"] for r in busy]) * per
        hi = np.array([r["busy_max_s"] for r in busy]) * per - avg
        ax3.barh(yb, avg, color=[colors[mods.index(r)] for r in busy], alpha=0.8, label="average over threads")
        ax3.errorbar(avg, yb, xerr=[lo, hi], fmt="none", ecolor="k", capsize=4, lw=1, label="min .. max")
        for yi, r, v, h in zip(yb, busy, avg, hi):
            ax3.text(v + h + 0.02 * (avg + hi).max(), yi, f"imbalance {r['imbalance_percent']:.1f} %",
                     va="center", fontsize=8)
        ax3.set_yticks(yb, [r["name"] for r in busy])
        ax3.invert_yaxis()
        ax3.set_xlim(0, (avg + hi).max() * 1.5)
        ax3.set_xlabel(f"busy time per thread [{unit}]")
        ax3.legend(fontsize=8, loc="lower right")
    else:
        ax3.text(0.5, 0.5, "no busy times in the profile", ha="center", va="center", transform=ax3.transAxes)
    ax3.set_title("Busy time per thread: min / avg / max", fontsize=10)
    ax3.grid(axis="x", alpha=0.3)

    h = header
    parts = []
    if "steps" in h:
        parts.append(f"{int(h['steps'])} steps")
    if "us_per_step" in h:
        parts.append(f"{float(h['us_per_step']):.1f} µs/step")
    if "model_s_per_hour" in h:
        parts.append(f"{float(h['model_s_per_hour']):.3g} model s/h")
    if "scheduler" in h:
        th, nn = _int(h.get("threads", "?")), _int(h.get("numa_nodes", "?"))
        parts.append(f"{h['scheduler']}, {th} thread{'' if th == 1 else 's'}, {nn} NUMA node{'' if nn == 1 else 's'}")
    if "wall_s" in h:
        parts.append(f"wall {float(h['wall_s']):.1f} s")
    fig.suptitle(f"{os.path.basename(a.file)}: run-time profile\n" + ", ".join(parts), fontsize=11)
    fig.tight_layout()
    save(fig, a.out)


# -------------------------------------------------------------------------- scaling

SCALING_COLUMNS = ["scheduler", "layout", "threads", "steps", "repeat", "us_per_step", "speedup", "efficiency",
                   "chain_us", "chain_speedup", "pulley_us", "pulley_speedup", "zero_gather_us", "compute_us",
                   "amdahl_serial_fraction"]
_TEXT = {"scheduler", "layout"}


def _num(x):
    """A number of a study; an empty cell (not measured) is NaN and drops out of the lines."""
    return float("nan") if x is None or (isinstance(x, str) and not x.strip()) else float(x)


def load_scaling(path):
    if not os.path.exists(path):
        raise UserError(f"{path}: no such file")
    title = ""
    try:
        if _looks_like_json(path):
            with open(path) as fh:
                d = json.load(fh)
            if not isinstance(d, dict) or not isinstance(d.get("rows"), list):
                raise UserError(f"{path}: no 'rows' list (not a scaling study?)")
            raw = d["rows"]
            title = str(d.get("config", ""))
        else:
            with open(path, newline="") as fh:
                raw = list(csv.DictReader(fh))
    except (OSError, json.JSONDecodeError, csv.Error, UnicodeDecodeError) as e:
        raise UserError(f"{path}: cannot read: {e}")
    if not raw:
        raise UserError(f"{path}: no rows")
    miss = [k for k in SCALING_COLUMNS if k not in raw[0]]
    if miss:
        raise UserError(f"{path}: missing column(s) {', '.join(miss)}")
    rows = []
    for i, r in enumerate(raw):
        try:
            rows.append({k: (str(r[k]) if k in _TEXT else _num(r[k])) for k in SCALING_COLUMNS})
        except (TypeError, ValueError) as e:
            raise UserError(f"{path}: row {i + 1}: {e}")
    bad = [i + 1 for i, r in enumerate(rows) if not (np.isfinite(r["threads"]) and r["threads"] >= 1)]
    if bad:
        raise UserError(f"{path}: row(s) {', '.join(map(str, bad[:5]))}: threads must be a number >= 1")
    return title, rows


def _median_by_threads(rows, key):
    th = sorted({r["threads"] for r in rows})
    return np.array(th), np.array([np.median([r[key] for r in rows if r["threads"] == n]) for n in th])


def cmd_scaling(a):
    title, rows = load_scaling(a.file)
    groups = {}
    for r in rows:
        groups.setdefault((r["scheduler"], r["layout"]), []).append(r)
    nmax = max(r["threads"] for r in rows)
    fig, (ax1, ax2, ax3) = plt.subplots(1, 3, figsize=(17, 5.5))
    xs = np.linspace(1, nmax, 200)
    for ax in (ax1, ax2):
        ax.plot([1, nmax], [1, nmax], color="0.5", ls=":", lw=1, label="ideal")
    for i, ((sched, layout), g) in enumerate(sorted(groups.items())):
        c = plt.cm.tab10(i % 10)
        name = sched if layout in ("", "-", "default") else f"{sched} / {layout}"
        th, sp = _median_by_threads(g, "speedup")
        ax1.plot(th, sp, "o-", color=c, label=name)
        if len({r["repeat"] for r in g}) > 1:
            ax1.plot([r["threads"] for r in g], [r["speedup"] for r in g], ".", color=c, alpha=0.35, ms=4)
        s = g[0]["amdahl_serial_fraction"]
        if np.isfinite(s) and 0 <= s <= 1:
            ax1.plot(xs, 1 / (s + (1 - s) / xs), "--", color=c, lw=1, label=f"Amdahl fit, serial fraction {s:.3f}")
        th, cs = _median_by_threads(g, "chain_speedup")
        ax2.plot(th, cs, "o-", color=c, label=f"{name}: chain forces")
        th, ps = _median_by_threads(g, "pulley_speedup")
        ax2.plot(th, ps, "s--", color=c, mfc="none", label=f"{name}: pulley contact")
        th, zg = _median_by_threads(g, "zero_gather_us")
        th, cu = _median_by_threads(g, "compute_us")
        ax3.plot(th, cu, "o-", color=c, label=f"{name}: compute")
        if np.any(zg > 0):
            ax3.plot(th, zg, "s--", color=c, mfc="none", label=f"{name}: buffer zero + gather")
    ticks = sorted({int(r["threads"]) for r in rows})
    for ax in (ax1, ax2, ax3):
        ax.set_xlabel("threads")
        ax.set_xticks(ticks if len(ticks) <= 16 else ticks[:: math.ceil(len(ticks) / 16)])
        ax.grid(alpha=0.3)
        # Above the ideal line there is room on the speedup panels.
        ax.legend(fontsize=7, loc="upper left" if ax is not ax3 else "best")
    ax1.set_ylabel("speedup of a whole step [-]")
    ax1.set_title("Whole RK4 step", fontsize=10)
    ax2.set_ylabel("speedup of the module [-]")
    ax2.set_title("Modules: chain forces, pulley contact", fontsize=10)
    ax3.set_ylabel("time per step [µs]")
    ax3.set_title("Thread-local buffers: zero + gather vs compute", fontsize=10)
    pos = [r[k] for r in rows for k in ("zero_gather_us", "compute_us") if r[k] > 0]
    if pos and max(pos) / min(pos) > 30:
        ax3.set_yscale("log")
    else:
        ax3.set_ylim(bottom=0)
    ax1.set_ylim(bottom=0)
    ax2.set_ylim(bottom=0)
    base = os.path.basename(a.file)
    fig.suptitle(f"{base}: scaling" + (f" ({title})" if title else "")
                 + "  (lines: median over repeats, dots: single repeats)", fontsize=11)
    fig.tight_layout()
    save(fig, a.out)


# ---------------------------------------------------------------------- spectrogram

def cmd_spectrogram(a):
    from matplotlib import mlab
    f = open_h5(a.file)
    t, v, unit = read_channel(f, a.channel, a.t0, a.t1)
    if v.ndim == 2:
        k = v.shape[1]
        col = 0 if a.column is None else a.column
        if not 0 <= col < k:
            raise UserError(f"{a.channel} has {k} columns (0..{k - 1}); --column {col} is out of range")
        v = v[:, col]
        label = f"{a.channel}[{col}]"
    else:
        if a.column not in (None, 0):
            raise UserError(f"{a.channel} has one column; --column {a.column} is out of range")
        label = a.channel
    good = np.isfinite(v)
    t, v = t[good], v[good]
    if len(t) < 16:
        raise UserError(f"{a.channel}: {len(t)} samples in the window, too few for a spectrogram (need 16)")
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        raise UserError(f"{a.channel}: time is not increasing")
    fs = 1.0 / dt
    n = a.nperseg or max(16, min(256, 2 ** int(math.log2(len(v) / 8))))
    if n > len(v):
        raise UserError(f"--nperseg {n} is longer than the {len(v)} samples in the window")
    nover = int(a.overlap * n) if a.overlap is not None else (3 * n) // 4
    nover = min(max(nover, 0), n - 1)
    P, freqs, tt = mlab.specgram(v, NFFT=n, Fs=fs, noverlap=nover, detrend=a.detrend,
                                 window=mlab.window_hanning, mode="psd")
    tt = tt + t[0]
    khz = freqs[-1] > 2000
    fsc, funit = (1e-3, "kHz") if khz else (1.0, "Hz")
    db = 10 * np.log10(np.maximum(P, np.max(P) * 1e-30 if np.max(P) > 0 else 1e-300))
    vmax = float(np.max(db))
    vmin = vmax - a.range_db
    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(11, 7.5), sharex=True,
                                   gridspec_kw=dict(height_ratios=[1, 2.2]))
    fac, u = scaled(v, unit)
    ax0.plot(t * 1e3, v * fac, lw=0.8)
    ax0.set_ylabel(ylabel(label, u))
    ax0.grid(alpha=0.3)
    ax0.set_title(f"{os.path.basename(a.file)}: {label}", fontsize=11)
    dtt = (tt[1] - tt[0]) if len(tt) > 1 else n * dt
    edges_t = np.concatenate([tt - dtt / 2, [tt[-1] + dtt / 2]]) * 1e3
    df = freqs[1] - freqs[0]
    edges_f = np.concatenate([freqs - df / 2, [freqs[-1] + df / 2]]) * fsc
    edges_f[0] = max(edges_f[0], 0)
    m = ax1.pcolormesh(edges_t, edges_f, db, vmin=vmin, vmax=vmax, cmap="magma", shading="flat")
    cu = (f"({unit})²/Hz" if " " in unit else f"{unit}²/Hz") if unit not in ("", "-", "1") else "1/Hz"
    fig.colorbar(m, ax=ax1, label=f"power spectral density [dB re 1 {cu}]", pad=0.01)
    ax1.set_ylabel(f"frequency [{funit}]")
    ax1.set_xlabel("time [ms]")
    ax1.set_title(f"STFT: Hann window of {n} samples ({n * dt * 1e3:.3g} ms, Δf = {df * fsc:.3g} {funit}), "
                  f"{nover} overlap, {a.detrend} trend removed, fs = {fs * fsc:.4g} {funit}", fontsize=10)
    if a.fmax:
        ax1.set_ylim(0, a.fmax * fsc)
    # Align the signal panel with the spectrogram (the colorbar takes width from ax1 only).
    fig.tight_layout()
    p0, p1 = ax0.get_position(), ax1.get_position()
    ax0.set_position([p1.x0, p0.y0, p1.width, p0.height])
    save(fig, a.out)


# -------------------------------------------------------------------------- animate

def _wrap_radius(P, cx):
    """Mean distance of the joints on the far side of a pulley centre (cx, 0) from it."""
    x, y = P[:, 0], P[:, 1]
    side = x < cx if cx <= 0 else x > cx
    if not np.any(side):
        return float("nan")
    return float(np.mean(np.hypot(x[side] - cx, y[side])))


def cmd_animate(a):
    from matplotlib import animation
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Circle
    f = open_h5(a.file)
    if "particles/chain/position/value" not in f:
        raise UserError(f"{a.file}: no /particles/chain/position snapshots (run with run.snapshot_interval > 0)")
    ts = np.asarray(f["particles/chain/position/time"][:], dtype=float)
    P = f["particles/chain/position/value"]
    if P.ndim != 3 or P.shape[2] < 2:
        raise UserError(f"{a.file}: /particles/chain/position/value has shape {P.shape}, expected [S][N][3]")
    S = min(len(ts), P.shape[0])
    T = None
    if "particles/chain/link_tension/value" in f:
        T = f["particles/chain/link_tension/value"]
        S = min(S, T.shape[0])
    if S == 0:
        raise UserError(f"{a.file}: no snapshots")
    idx = np.arange(0, S, max(1, a.every))
    if a.t0 is not None:
        idx = idx[ts[idx] >= a.t0]
    if a.t1 is not None:
        idx = idx[ts[idx] <= a.t1]
    if len(idx) == 0:
        raise UserError(f"no snapshot in the window [{a.t0}, {a.t1}] s")
    pos = np.asarray(P[idx.tolist()], dtype=float)
    ten = np.asarray(T[idx.tolist()], dtype=float) if T is not None else None
    sh = read_config(f).get("sheave", {})
    dist = centre_distance(f, pos[0])
    r_out = float(sh.get("outer_radius", np.nan))
    r_hub = float(sh.get("hub_radius", np.nan))
    centres = [(0.0, 0.0), (dist, 0.0)]

    fig, ax = plt.subplots(figsize=(9, 5.2))
    ax.set_aspect("equal")
    mm = 1e3
    for (cx, cy), name in zip(centres, ("driving", "driven")):
        if np.isfinite(r_out):
            ax.add_patch(Circle((cx * mm, cy * mm), r_out * mm, fc="0.85", ec="0.55", lw=0.8, alpha=0.45,
                                label="sheave outer radius" if name == "driving" else None))
        if np.isfinite(r_hub):
            ax.add_patch(Circle((cx * mm, cy * mm), r_hub * mm, fc="0.7", ec="0.45", lw=0.8, alpha=0.6,
                                label="hub" if name == "driving" else None))
        ax.plot(cx * mm, cy * mm, "k+", ms=10)
        ax.text(cx * mm, cy * mm - 0.35 * (r_hub if np.isfinite(r_hub) else 0.01) * mm - 1.0, name,
                ha="center", va="top", fontsize=8)
    wraps = [Circle((cx * mm, cy * mm), 1, fill=False, ls="--", ec="C0", lw=1,
                    label="wrap radius (mean over the joints beyond the centre)" if i == 0 else None)
             for i, (cx, cy) in enumerate(centres)]
    for w in wraps:
        ax.add_patch(w)
    if ten is not None:
        lo, hi = np.nanpercentile(ten, [1, 99])
        if not hi > lo:
            hi = lo + 1
        tfac, tunit = scaled(np.array([lo, hi]), "N")
        norm = plt.Normalize(lo * tfac, hi * tfac)
    lc = LineCollection([], lw=3, cmap="plasma", norm=norm if ten is not None else None,
                        color=None if ten is not None else "k")
    ax.add_collection(lc)
    joints, = ax.plot([], [], "o", ms=2.2, color="k")
    tracked, = ax.plot([], [], "o", ms=7, mfc="none", mec="C2", mew=2, label="joint 0")
    if ten is not None:
        fig.colorbar(lc, ax=ax, label=f"link tension [{tunit}]", shrink=0.8, pad=0.02)
    allp = pos[:, :, :2].reshape(-1, 2)
    pad = 0.08 * dist
    xr = [min(allp[:, 0].min(), -r_out if np.isfinite(r_out) else 0) - pad,
          max(allp[:, 0].max(), dist + r_out if np.isfinite(r_out) else dist) + pad]
    yr = [min(allp[:, 1].min(), -r_out if np.isfinite(r_out) else 0) - pad,
          max(allp[:, 1].max(), r_out if np.isfinite(r_out) else 0) + pad]
    ax.set_xlim(xr[0] * mm, xr[1] * mm)
    ax.set_ylim(yr[0] * mm, yr[1] * mm)
    ax.set_xlabel("x [mm] (driving pulley at 0, driven pulley at the centre distance)")
    ax.set_ylabel("y [mm]")
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.13), ncol=4, fontsize=7, frameon=False)
    ttl = ax.set_title("")

    def frame(i):
        p = pos[i][:, :2] * mm
        seg = np.stack([p, np.roll(p, -1, axis=0)], axis=1)  # link i joins joint i and i+1
        lc.set_segments(seg)
        if ten is not None:
            lc.set_array(ten[i] * tfac)
        joints.set_data(p[:, 0], p[:, 1])
        tracked.set_data([p[0, 0]], [p[0, 1]])
        r = [_wrap_radius(pos[i], cx) for cx, _ in centres]
        for w, ri in zip(wraps, r):
            w.set_radius(ri * mm if np.isfinite(ri) else 0)
        ttl.set_text(f"{os.path.basename(a.file)}: t = {ts[idx[i]] * 1e3:.3f} ms   "
                     f"wrap radii R1 = {r[0] * mm:.2f} mm, R2 = {r[1] * mm:.2f} mm")
        return lc, joints, tracked, ttl, *wraps

    fig.tight_layout()
    frame(0)
    have_pil = importlib.util.find_spec("PIL") is not None
    if have_pil and a.out.lower().endswith(".gif"):
        d = os.path.dirname(os.path.abspath(a.out))
        if not os.path.isdir(d):
            raise UserError(f"{a.out}: directory {d} does not exist")
        anim = animation.FuncAnimation(fig, frame, frames=len(idx), blit=False)
        anim.save(a.out, writer=animation.PillowWriter(fps=a.fps), dpi=a.dpi)
        plt.close(fig)
        print(f"{PROG}: wrote {a.out} ({len(idx)} frames)")
        return
    if not have_pil:
        warn("Pillow (Debian's python3-pil) is missing: writing PNG frames instead of a GIF")
    stem = os.path.splitext(a.out)[0]
    os.makedirs(stem + "_frames", exist_ok=True)
    for i in range(len(idx)):
        frame(i)
        fig.savefig(os.path.join(stem + "_frames", f"frame_{i:05d}.png"), dpi=a.dpi)
    plt.close(fig)
    print(f"{PROG}: wrote {len(idx)} frames to {stem}_frames/")


# ----------------------------------------------------------------------------- main

class Parser(argparse.ArgumentParser):
    def error(self, message):
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")


# ---------------------------------------------------------------------- integrators

INTEGRATOR_COLUMNS = ["part", "method", "param_kind", "param", "h", "err_pos_m", "status", "deviation_percent",
                      "wall_s", "rhs_evals", "chosen"]


def load_integrators(path):
    if not os.path.exists(path):
        raise UserError(f"{path}: no such file")
    try:
        with open(path, newline="") as fh:
            raw = list(csv.DictReader(fh))
    except (OSError, csv.Error, UnicodeDecodeError) as e:
        raise UserError(f"{path}: cannot read: {e}")
    if not raw:
        raise UserError(f"{path}: no rows")
    miss = [k for k in INTEGRATOR_COLUMNS if k not in raw[0]]
    if miss:
        raise UserError(f"{path}: missing column(s) {', '.join(miss)} (not an integrator study?)")
    return raw


def cmd_integrators(a):
    rows = load_integrators(a.file)
    curves = a.curves
    if curves is None:
        base = a.file[:-4] if a.file.endswith(".csv") else a.file
        curves = base + "-curves.csv"
    cur = None
    if os.path.exists(curves):
        with open(curves, newline="") as fh:
            cr = list(csv.reader(fh))
        if len(cr) > 1:
            cur = (cr[0], np.array([[_num(x) for x in r] for r in cr[1:]]))
    elif a.curves is not None:
        raise UserError(f"{curves}: no such file")
    one = [r for r in rows if r["part"] == "one_step"]
    if one:  # part (a) only when the study ran it (--one-step)
        fig, ax = plt.subplots(1, 3, figsize=(17, 5.2))
        for m in dict.fromkeys(r["method"] for r in one):
            rr = [r for r in one if r["method"] == m]
            h = np.array([_num(r["h"]) for r in rr])
            e = np.array([_num(r["err_pos_m"]) for r in rr])
            ax[0].loglog(h, e, "o-", label=m)
        ax[0].set_xlabel("step h [s]")
        ax[0].set_ylabel("position error after one step [m]")
        ax[0].set_title("(a) one-step error against RK4, h = 2e-9 s")
        ax[0].grid(True, which="both", alpha=0.3)
        ax[0].legend(fontsize=8)
    else:
        fig, two = plt.subplots(1, 2, figsize=(12, 5.2))
        ax = [None, two[0], two[1]]
    if cur is not None:
        head, data = cur
        t = (data[:, 0] - data[0, 0]) * 1e3
        ax[1].plot(t, data[:, 1], "k-", lw=2.5, alpha=0.4, label="reference RK4")
        for k in range(2, len(head)):
            ax[1].plot(t, data[:, k], "-", lw=1, label=head[k])
        ax[1].legend(fontsize=8)
    ax[1].set_xlabel("time from the running state [ms]")
    ax[1].set_ylabel("axial force in the pin half [N]")
    ax[1].set_title("(b) sample curve, each method's chosen run")
    ax[1].grid(True, alpha=0.3)
    runs = [r for r in rows if r["part"] == "curve"]
    devs = [_num(r["deviation_percent"]) for r in runs]
    devs = [x for x in devs if np.isfinite(x) and x > 0]
    ax_top = 3 * max(devs + [1.0])
    timeouts = False
    for m in dict.fromkeys(r["method"] for r in runs):
        rr = [r for r in runs if r["method"] == m]
        w = np.array([_num(r["wall_s"]) for r in rr])
        d = np.array([_num(r["deviation_percent"]) for r in rr])
        line, = ax[2].loglog(w, np.where(np.isfinite(d), d, np.nan), "o-", label=m)
        for r, wi, di in zip(rr, w, d):
            if r["chosen"] == "1" and np.isfinite(di):
                ax[2].plot([wi], [di], "*", ms=14, color=line.get_color())
        # Runs stopped by --max-wall: an x at the wall time projected to the whole window.
        if cur is not None and "steps" in rr[0] and "mean_h_s" in rr[0]:
            window = cur[1][-1, 0] - cur[1][0, 0]
            for r, wi in zip(rr, w):
                reached = _num(r["steps"]) * _num(r["mean_h_s"])
                if r["status"] == "timeout" and reached > 0 and np.isfinite(reached):
                    ax[2].plot([wi * window / reached], [ax_top], "x", ms=10, mew=2, color=line.get_color())
                    timeouts = True
    ax[2].axhline(1.0, color="k", ls="--", lw=0.8)
    if timeouts:
        ax[2].text(0.02, 0.98, "x: stopped by --max-wall, at its wall time projected to the window",
                   transform=ax[2].transAxes, va="top", fontsize=8)
    ax[2].set_xlabel("wall time [s]")
    ax[2].set_ylabel("deviation from the reference [% of its range]")
    ax[2].set_title("(c) accuracy against cost (star: chosen)")
    ax[2].grid(True, which="both", alpha=0.3)
    if runs:
        ax[2].legend(fontsize=8)
    fig.tight_layout()
    save(fig, a.out)



def _read_csv(path, need):
    if not os.path.exists(path):
        raise UserError(f"{path}: no such file")
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, csv.Error, UnicodeDecodeError) as e:
        raise UserError(f"{path}: cannot read: {e}")
    if not rows:
        raise UserError(f"{path}: no rows")
    miss = [k for k in need if k not in rows[0]]
    if miss:
        raise UserError(f"{path}: missing column(s) {', '.join(miss)}")
    return rows


SWEEP_RESULTS = ("status", "speed_ratio", "geometric_ratio", "slip", "input_torque", "output_torque", "efficiency")


def cmd_sweep(a):
    """A sweep's CSV: one axis -> the column against it; two axes -> filled contours of the
    column over the grid (steady points only; the others marked by their status)."""
    rows = _read_csv(a.file, SWEEP_RESULTS)
    cols = list(rows[0].keys())
    keys = cols[:cols.index("status")]
    for r in rows:  # derived: the thrust ratio F1/F2 (the thrust map, with the ratio controller on)
        f2 = _num(r.get("clamping_force_driven"))
        r["thrust_ratio"] = _num(r.get("clamping_force_driving")) / f2 if f2 else float("nan")
    if a.column not in rows[0]:
        raise UserError(f"{a.file}: no column {a.column}")
    for w in a.where or []:  # a slice of a map over more than two keys
        key, sep, value = w.partition("=")
        if not sep or key not in keys:
            raise UserError(f"--where {w}: give KEY=VALUE with KEY one of {', '.join(keys)}")
        rows = [r for r in rows if _num(r[key]) == _num(value)]
        if not rows:
            raise UserError(f"--where {w}: no point of {a.file} has {key} = {value}")
    x_key = a.x or keys[0]
    y_key = a.y or (keys[1] if len(keys) > 1 and keys[1] != x_key else None)
    steady = [r for r in rows if r["status"] == "steady" or (a.all and r["status"] == "not_steady")]
    fig, ax = plt.subplots(figsize=(8, 6))
    marks = {"not_steady": ("o", "tab:orange"), "slip": ("x", "tab:red"), "blow_up": ("*", "k"), "error": ("s", "grey")}
    if y_key is None:
        for st, rs in [("steady", steady)] + [(k, [r for r in rows if r["status"] == k]) for k in marks]:
            if rs:
                m, c = marks.get(st, ("o", "tab:blue"))
                ax.plot([_num(r[x_key]) for r in rs], [_num(r[a.column]) for r in rs], m, color=c, label=st)
        ax.set_xlabel(x_key), ax.set_ylabel(a.column), ax.legend()
    else:
        xs = sorted({_num(r[x_key]) for r in rows}); ys = sorted({_num(r[y_key]) for r in rows})
        Z = np.full((len(ys), len(xs)), np.nan)
        for r in steady:
            Z[ys.index(_num(r[y_key])), xs.index(_num(r[x_key]))] = _num(r[a.column])
        if np.isfinite(Z).sum() >= 4 and len(xs) > 1 and len(ys) > 1:
            cs = ax.contourf(xs, ys, Z, levels=12, cmap="viridis")
            ax.clabel(ax.contour(xs, ys, Z, levels=cs.levels[::2], colors="w", linewidths=0.6), fmt="%.3g", fontsize=8)
            fig.colorbar(cs, ax=ax, label=a.column + (" (steady and not_steady points)" if a.all else " (steady points)"))
        for st, (m, c) in [("steady", ("o", "w"))] + list(marks.items()):
            rs = [r for r in rows if r["status"] == st]
            if rs:
                ax.plot([_num(r[x_key]) for r in rs], [_num(r[y_key]) for r in rs], m, color=c, mec="k", label=st)
        ax.set_xlabel(x_key), ax.set_ylabel(y_key), ax.legend(loc="best", fontsize=8)
    n_steady = sum(r["status"] == "steady" for r in rows)
    where = "".join(f", {w}" for w in a.where or [])
    ax.set_title(f"{a.column} over {len(rows)} points ({n_steady} steady): {os.path.basename(a.file)}{where}")
    save(fig, a.out)


def cmd_slip(a):
    """study slip: the slip torque against the clamping force, beside 2 f0 min(F1, F2) R2 / cos(beta)."""
    rows = _read_csv(a.file, ("clamping_force_driving", "ratio", "slip_torque", "theory_torque", "slips_at"))
    fig, ax = plt.subplots(figsize=(8, 6))
    for ratio in sorted({_num(r["ratio"]) for r in rows}):
        rs = sorted([r for r in rows if _num(r["ratio"]) == ratio], key=lambda r: _num(r["clamping_force_driving"]))
        F = np.array([_num(r["clamping_force_driving"]) for r in rs]) / 1e3
        lo = np.array([_num(r["slip_torque"]) for r in rs]); hi = np.array([_num(r["slips_at"]) for r in rs])
        th = np.array([_num(r["theory_torque"]) for r in rs])
        ax.errorbar(F, 0.5 * (lo + hi), yerr=0.5 * (hi - lo), fmt="o-", capsize=4,
                    label=f"simulated slip limit, ratio {ratio:g} (held .. slipped)")
        ax.plot(F, th, "k--", label=f"2 f0 min(F1, F2) R2 / cos(beta), ratio {ratio:g}")
    ax.set_xlabel("clamping force F1 [kN]"), ax.set_ylabel("load torque [N m]")
    ax.set_ylim(bottom=0), ax.legend(fontsize=8), ax.grid(alpha=0.3)
    ax.set_title("slip limit: largest load torque without gross slip")
    save(fig, a.out)


def cmd_shift(a):
    """study shift: d(ratio)/dt against ln(F1/F2) at each input speed; and divided by the speed."""
    rows = _read_csv(a.file, ("input_speed", "ln_thrust_ratio", "shift_rate", "steady_thrust_ratio"))
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(14, 5.5))
    for w in sorted({_num(r["input_speed"]) for r in rows}):
        rs = sorted([r for r in rows if _num(r["input_speed"]) == w], key=lambda r: _num(r["ln_thrust_ratio"]))
        x = np.array([_num(r["ln_thrust_ratio"]) for r in rs]); y = np.array([_num(r["shift_rate"]) for r in rs])
        ax1.plot(x, y, "o-", label=f"input speed {w:g} rad/s")
        ax2.plot(x, y / w, "o-", label=f"input speed {w:g} rad/s")
    for ax in (ax1, ax2):
        ax.axhline(0, color="k", lw=0.5), ax.grid(alpha=0.3), ax.legend(fontsize=8)
        ax.set_xlabel("ln(F1 / F2) after the step")
    ln0 = np.log(_num(rows[0]["steady_thrust_ratio"]))
    ax1.axvline(ln0, color="grey", ls=":", label="steady F1/F2")
    ax1.set_ylabel("d(geometric ratio)/dt [1/s]"), ax2.set_ylabel("d(ratio)/dt / input speed [1/rad]")
    ax1.set_title("shift rate after a step in the thrust ratio")
    ax2.set_title("divided by the input speed (published: one line)")
    save(fig, a.out)


def build_parser():
    ap = Parser(prog=PROG, description=__doc__.split("\n\n")[0],
                epilog="See docs/plots.md for what every panel shows.")
    sub = ap.add_subparsers(dest="cmd", metavar="COMMAND", parser_class=Parser)
    sub.required = True

    def window(p):
        p.add_argument("--from", dest="t0", type=float, default=None, metavar="T0", help="start of the window [s]")
        p.add_argument("--to", dest="t1", type=float, default=None, metavar="T1", help="end of the window [s]")

    p = sub.add_parser("history", help="time histories: ratio, slip, torques, clamping, sheaves, efficiency, strand "
                       "tensions, then the tracked link and pin, torsion, supports, speeds")
    p.add_argument("file", metavar="RUN.h5")
    window(p)
    p.add_argument("--eff-window", type=float, default=None, metavar="S",
                   help="window of ΔW_out / ΔW_in (files without running_efficiency) and of 1 - ΔW_diss / ΔW_in [s] "
                        "(default 20 %% of the plotted span)")
    p.add_argument("-o", "--out", default="history.png", help="output image (default history.png)")
    p.set_defaults(func=cmd_history)

    p = sub.add_parser("profile", help="module shares of the run time (a run's /profile or --profile-json)")
    p.add_argument("file", metavar="PROFILE", help="RUN.h5 with a /profile group, or PROFILE.json")
    p.add_argument("-o", "--out", default="profile.png", help="output image (default profile.png)")
    p.set_defaults(func=cmd_profile)

    p = sub.add_parser("scaling", help="speedup against threads from a scaling study (CSV or JSON)")
    p.add_argument("file", metavar="STUDY", help="STUDY.csv or STUDY.json")
    p.add_argument("-o", "--out", default="scaling.png", help="output image (default scaling.png)")
    p.set_defaults(func=cmd_scaling)

    p = sub.add_parser("spectrogram", help="short-time Fourier transform of one channel")
    p.add_argument("file", metavar="RUN.h5")
    p.add_argument("channel", metavar="CHANNEL", help="name under /observables, e.g. output_torque")
    p.add_argument("--column", type=int, default=None, metavar="K", help="column of a [T][k] channel (default 0)")
    p.add_argument("--nperseg", type=int, default=None, metavar="N",
                   help="samples per FFT segment (default: a power of 2, at most 256 and 1/8 of the samples)")
    p.add_argument("--overlap", type=float, default=None, metavar="F", help="overlap as a fraction of a segment (default 0.75)")
    p.add_argument("--fmax", type=float, default=None, metavar="HZ", help="upper end of the frequency axis [Hz]")
    p.add_argument("--range-db", type=float, default=80.0, metavar="DB", help="dynamic range of the colour scale (default 80 dB)")
    p.add_argument("--detrend", choices=["linear", "mean", "none"], default="linear",
                   help="removed from each segment before the FFT (default linear: a ramp leaks less)")
    window(p)
    p.add_argument("-o", "--out", default=None, help="output image (default spectrogram-CHANNEL.png)")
    p.set_defaults(func=cmd_spectrogram)

    p = sub.add_parser("animate", help="the chain and pulleys from the snapshots, as a GIF")
    p.add_argument("file", metavar="RUN.h5")
    p.add_argument("--every", type=int, default=1, metavar="K", help="every K-th snapshot (default 1)")
    p.add_argument("--fps", type=float, default=10.0, metavar="F", help="frames per second of the GIF (default 10)")
    p.add_argument("--dpi", type=int, default=80, help="resolution of the frames (default 80)")
    window(p)
    p.add_argument("-o", "--out", default="chain.gif", help="output GIF (default chain.gif; PNG frames without Pillow)")
    p.set_defaults(func=cmd_animate)

    p = sub.add_parser("integrators", help="integrator study: one-step error, sample curves, accuracy against cost")
    p.add_argument("file", metavar="STUDY", help="the CSV of `cvt-engine study integrators --out`")
    p.add_argument("--curves", default=None, help="the curves CSV (default: STUDY-curves.csv)")
    p.add_argument("-o", "--out", default="integrators.png", help="output image (default integrators.png)")
    p.set_defaults(func=cmd_integrators)

    p = sub.add_parser("sweep", help="a sweep's CSV: a column against one axis, or contours over two (efficiency map)")
    p.add_argument("file", metavar="SWEEP.csv")
    p.add_argument("--column", default="efficiency",
                   help="the column drawn (default efficiency; thrust_ratio: F1/F2 of the means, the thrust map)")
    p.add_argument("--x", default=None, metavar="KEY", help="the x axis key (default the first)")
    p.add_argument("--y", default=None, metavar="KEY", help="the y axis key (default the second, if any)")
    p.add_argument("--all", action="store_true", help="contour the not_steady points too (default: steady only)")
    p.add_argument("--where", action="append", metavar="KEY=VALUE",
                   help="only the points with this value of a key (repeatable): a slice of a map over more keys")
    p.add_argument("-o", "--out", default="sweep.png", help="output image (default sweep.png)")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("slip", help="study slip: slip torque against clamping force, beside the Coulomb limit")
    p.add_argument("file", metavar="SLIP.csv")
    p.add_argument("-o", "--out", default="slip.png", help="output image (default slip.png)")
    p.set_defaults(func=cmd_slip)

    p = sub.add_parser("shift", help="study shift: shift rate against ln(F1/F2) at each input speed")
    p.add_argument("file", metavar="SHIFT.csv")
    p.add_argument("-o", "--out", default="shift.png", help="output image (default shift.png)")
    p.set_defaults(func=cmd_shift)
    return ap


def main(argv=None):
    ap = build_parser()
    a = ap.parse_args(argv)
    if a.cmd == "spectrogram" and a.out is None:
        a.out = f"spectrogram-{a.channel}.png"
    for k in ("every", "nperseg"):
        if getattr(a, k, None) is not None and getattr(a, k) < 1:
            ap.error(f"--{k} must be at least 1")
    if getattr(a, "fps", 1) <= 0:
        ap.error("--fps must be positive")
    try:
        a.func(a)
    except UserError as e:
        warn(f"{a.cmd}: {e}")
        return 2
    except OSError as e:  # I/O while reading or writing (disk full, permissions)
        warn(f"{a.cmd}: {e}")
        return 1
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
