"""cvt-engine from Python: configurations, runs, sweeps and studies (docs/python.md).

    import cvt_engine as cvt
    r = cvt.run("configs/mini.toml", overrides={"load.torque": 15}, until_steady=True, t_end=0.1)
    r.summary["efficiency"], r.channels["output_torque"]

Every call is the library call `cvt-engine` makes for the same command line, so the same
inputs give the same bits. The engine runs with the GIL released; a progress callback or a
log takes it back for its call.
"""
import csv
import json
import math
import os
import shutil
import signal
import tempfile
import tomllib

import numpy as np

from . import _core
from ._core import BlowUpError, Config, ConfigError, OutputError

__version__ = _core.version
__all__ = ["Config", "ConfigError", "BlowUpError", "OutputError", "Result", "load_config", "parse_config",
           "run", "resume", "Simulation", "sweep", "study_slip", "study_shift", "model_info", "config_value", "read_channels", "read_units",
           "shipped_config"]


def _text(value):
    """A Python value as the TOML text of an override (floats to 17 digits: the same bits)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, str):
        return value
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_text(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} ({type(value).__name__}) as a configuration value")


def _value(key, value):
    """The TOML text of key's value; ConfigError for one that is no configuration value
    (None, a dict, an object)."""
    try:
        return _text(value)
    except TypeError:
        raise _error(key, repr(value), f"not a configuration value ({type(value).__name__}): give a number, "
                                       "a string, a bool or a list of them") from None


def _override(key, value):
    """"key=value" for a dict's entry."""
    if not isinstance(key, str):
        raise _error("overrides", repr(key), "a key must be a string 'section.key'")
    return f"{key}={_value(key, value)}"


def _overrides(overrides):
    """{"load.torque": 15} or ["load.torque=15"] as the list of "key=value" texts; ConfigError
    for anything else."""
    if overrides is None:
        return []
    if isinstance(overrides, dict):
        return [_override(k, v) for k, v in overrides.items()]
    if isinstance(overrides, str) or not isinstance(overrides, (list, tuple)):
        raise _error("overrides", repr(overrides), "give a dict {key: value} or a list of 'key=value' texts")
    for o in overrides:
        if not isinstance(o, str):
            raise _error("overrides", repr(o), "each entry of the list must be a 'key=value' text")
    return list(overrides)


def _integer(name, value, least):
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < least:
        raise _error(name, value, f"must be an integer >= {least}")
    return int(value)


def _nonnegative(name, value):
    if not isinstance(value, (int, float, np.number)) or isinstance(value, bool) or not (
            math.isfinite(value) and value >= 0):
        raise _error(name, value, "must be a finite number >= 0")
    return float(value)


def _flag(name, value):
    if not isinstance(value, (bool, np.bool_)):
        raise _error(name, value, "must be True or False")
    return bool(value)


def _callable_or_none(name, value):
    if value is not None and not callable(value):
        raise _error(name, repr(value), "must be a callable or None")
    return value


def _path(name, value, none_ok=False):
    if value is None and none_ok:
        return None
    if not isinstance(value, (str, os.PathLike)) or not os.fspath(value):
        raise _error(name, repr(value), "must be a non-empty path")
    return os.fspath(value)


def _error(key, value, reason):
    e = ConfigError(f"configuration error: {key} = {value}: {reason}")
    e.key, e.value, e.reason = key, str(value), reason
    return e


def load_config(path, overrides=None):
    """The configuration of a TOML file with overrides applied and every key validated.

    Raises ConfigError (a ValueError) naming the key, its value and why (.key, .value, .reason).
    """
    return _core.load_config(os.fspath(path), _overrides(overrides), {"*": "the overrides"})


def parse_config(text, overrides=None, origin="<string>"):
    """As load_config, from TOML text."""
    return _core.parse_config(text, _overrides(overrides), origin, {"*": "the overrides"})


def config_value(config, key):
    """The value of "section.key" in a configuration (its resolved TOML)."""
    table = tomllib.loads(config.toml)
    for part in key.split("."):
        if not isinstance(table, dict) or part not in table:
            raise KeyError(key)
        table = table[part]
    return table


def model_info(config):
    """links, coordinates, unknowns (counts), the running radii [m] and the closure residual [m]."""
    return _core.model_info(_config(config, None, {}))


def _config(config, overrides, shortcuts):
    """A Config from a path or a Config, with overrides (shortcuts: {key: argument name})."""
    ov = _overrides(overrides)
    for key, value in shortcuts.items():
        if value is not None:
            ov.append(f"{key}={_text(value)}")
    names = {k: n for k, n in _SHORTCUT_NAMES.items() if shortcuts.get(k) is not None}
    names["*"] = "the overrides"
    if isinstance(config, Config):
        return _core.parse_config(config.toml, ov, "<config>", names) if ov else config
    return _core.load_config(os.fspath(config), ov, names)


_SHORTCUT_NAMES = {"run.t_end": "the argument t_end", "run.until_steady": "the argument until_steady",
                   "integrator.step": "the argument step", "integrator.method": "the argument method"}


def _schedule(scheduler, threads, grain=4):
    """The schedule's arguments checked (ConfigError), before anything runs."""
    threads = _integer("threads", threads, 1)
    _integer("grain", grain, 1)
    if scheduler is None:
        scheduler = "serial" if threads == 1 else "flowgraph"
    if scheduler not in ("serial", "flowgraph", "paper-omp"):
        raise _error("scheduler", repr(scheduler), "must be one of serial, flowgraph, paper-omp")
    return scheduler, threads


class Result:
    """A finished run: summary (dict, the keys of docs/output.md /summary; its "units" entry
    gives each entry's unit), channels (dict of NumPy arrays, "time" [s] among them), units
    (each channel's SI unit, "1" for a ratio), file (the HDF5 file, or None when it was
    temporary)."""

    def __init__(self, summary, channels, file, units=None):
        self.summary, self.channels, self.file = summary, channels, file
        self.units = dict(units or {})

    def to_pandas(self):
        """The channels as a pandas DataFrame indexed by time [s]: a column per scalar channel,
        NAME[i] per entry of a vector channel; df.attrs["units"] maps each column to its unit.
        Needs pandas (Debian's python3-pandas)."""
        try:
            import pandas as pd
        except ImportError as e:
            raise ImportError("Result.to_pandas needs pandas (apt-get install python3-pandas)") from e
        cols, units = {}, {}
        for name, v in self.channels.items():
            if name == "time":
                continue
            if v.ndim == 1:
                cols[name], units[name] = v, self.units.get(name, "")
            else:
                for i in range(v.shape[1]):
                    cols[f"{name}[{i}]"], units[f"{name}[{i}]"] = v[:, i], self.units.get(name, "")
        df = pd.DataFrame(cols, index=pd.Index(self.channels["time"], name="time"))
        df.attrs["units"] = {"time": "s", **units}
        return df

    def to_xarray(self):
        """The channels as an xarray Dataset over the coordinate time [s]; a vector channel
        has a second dimension NAME_index; every variable's attrs["units"] is its unit.
        Needs xarray (Debian's python3-xarray)."""
        try:
            import xarray as xr
        except ImportError as e:
            raise ImportError("Result.to_xarray needs xarray (apt-get install python3-xarray)") from e
        data = {}
        for name, v in self.channels.items():
            if name == "time":
                continue
            dims = ("time",) if v.ndim == 1 else ("time", f"{name}_index")
            data[name] = xr.DataArray(v, dims=dims, attrs={"units": self.units.get(name, "")})
        return xr.Dataset(data, coords={"time": ("time", self.channels["time"], {"units": "s"})},
                          attrs={k: v for k, v in self.summary.items() if isinstance(v, (int, float, str))})

    def __repr__(self):
        s = self.summary
        return (f"<cvt_engine.Result t = {s['model_time']:.6g} s, {s['status']}, efficiency {s['efficiency']:.4f}, "
                f"{len(self.channels)} channels>")


def read_units(path):
    """The unit of each channel of a run's file: {name: "N m", ...} ("time": "s")."""
    import h5py
    with h5py.File(path, "r") as f:
        obs = f["observables"]
        out = {"time": "s"}
        for name in obs:
            out[name] = str(obs[name]["value"].attrs.get("unit", ""))
    return out


def shipped_config(name):
    """The path of a configuration shipped with cvt-engine ("mini", "reference-steady", ...:
    the files of the repository's configs/), wherever the package is installed from."""
    here = os.path.dirname(os.path.abspath(__file__))
    for folder in (os.path.join(here, "configs"),  # a wheel (pip install .), build/python
                   os.path.join(here, "..", "..", "..", "..", "share", "cvt-engine", "configs")):  # cmake --install
        path = os.path.normpath(os.path.join(folder, name + ".toml"))
        if os.path.isfile(path):
            return path
    raise _error("name", repr(name), "no such shipped configuration")


def read_channels(path):
    """The channels of a run's file: {"time": [T] in s, name: [T] or [T][k], ...} as NumPy
    arrays, each in its SI unit (read_units gives them)."""
    import h5py
    with h5py.File(path, "r") as f:
        obs = f["observables"]
        out = {"time": np.asarray(obs[next(iter(obs))]["time"])}
        for name in obs:
            out[name] = np.asarray(obs[name]["value"])
    return out


def run(config, *, overrides=None, t_end=None, until_steady=None, step=None, method=None, out=None,
        threads=1, scheduler=None, grain=4, quiet=True, progress=None, progress_seconds=3.0,
        checkpoint_every=50000, channels=True):
    """Runs a simulation (as `cvt-engine run`) and returns a Result.

    config: a path or a Config; overrides: {key: value} or ["key=value", ...];
    t_end [s], until_steady, step [s], method: as --t-end, --until-steady, --step, --method.
    out: the HDF5 file to keep (None: a temporary file, removed after the channels are read).
    threads > 1 runs the flow graph (the same bits for any thread count).
    quiet: no lines on stdout/stderr (warnings are in summary["warnings"] all the same).
    progress: a callable given a dict (step, steps, t [s], t_end [s], wall_s [s], eta_s [s],
            verifying: run.verify's second integration)
    every progress_seconds [s of wall time]; returning a false value stops the run at the
    next step where the W matrix is rebuilt (summary["stopped"] == "callback").
    checkpoint_every: steps between checkpoints to OUT.ckpt (0: only at the end).
    Ctrl-C stops the run the same way and raises KeyboardInterrupt; the file is kept.
    Raises ConfigError for a bad key or argument (every one checked before the run starts),
    BlowUpError when the state blows up or the integration fails numerically, OutputError
    when the file cannot be written.
    """
    cfg = _config(config, overrides, {"run.t_end": t_end, "run.until_steady": until_steady,
                                      "integrator.step": step, "integrator.method": method})
    return _run(cfg, out, None, threads, scheduler, grain, quiet, progress, progress_seconds, checkpoint_every,
                channels)


def resume(checkpoint, *, t_end=None, out=None, overrides=None, threads=1, scheduler=None, grain=4, quiet=True,
           progress=None, progress_seconds=3.0, checkpoint_every=50000, channels=True):
    """Continues a run from its checkpoint (as `cvt-engine run --resume`) and returns a Result.

    checkpoint: FILE.ckpt of a run; t_end [s]: where to go (beyond the first run's run.t_end).
    Without out the continuation is appended to the run's own file (the one the checkpoint
    names), which then equals an uninterrupted run bit for bit, and the Result covers the
    whole run; with out a new file holds the continuation alone. Every other argument is
    run's. Raises ConfigError, BlowUpError, OutputError as run does.
    """
    checkpoint = _path("checkpoint", checkpoint)
    cfg, own = _core.checkpoint_config(checkpoint, _overrides(overrides), {"*": "the overrides"})
    if t_end is not None:
        cfg = _core.parse_config(cfg.toml, [f"run.t_end={_text(_value('t_end', t_end))}"], checkpoint,
                                 {"run.t_end": "the argument t_end"})
    append = out is None
    return _run(cfg, own if append else out, (checkpoint, append), threads, scheduler, grain, quiet, progress,
                progress_seconds, checkpoint_every, channels)


def _run(cfg, out, resuming, threads, scheduler, grain, quiet, progress, progress_seconds, checkpoint_every,
         channels):
    scheduler, threads = _schedule(scheduler, threads, grain)
    quiet, channels = _flag("quiet", quiet), _flag("channels", channels)
    progress = _callable_or_none("progress", progress)
    progress_seconds = _nonnegative("progress_seconds", progress_seconds)
    checkpoint_every = _integer("checkpoint_every", checkpoint_every, 0)
    out = _path("out", out, none_ok=True)
    tmp = None
    if out is None:
        tmp = tempfile.mkdtemp(prefix="cvt_engine_")
        path = os.path.join(tmp, "run.h5")
    else:
        path = out
    resume_path, append = resuming or ("", False)
    try:
        text, stop_signal = _core.run(cfg, path, scheduler, threads, grain, quiet, progress,
                                      progress_seconds, checkpoint_every, resume_path, append)
        summary = json.loads(text)
        ch = read_channels(path) if channels and not stop_signal else {}
        units = read_units(path) if channels and not stop_signal else {}
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    if stop_signal:
        # The engine caught SIGINT or SIGTERM and stopped the run at a step (the file kept);
        # now Python's own handler acts on it: KeyboardInterrupt for Ctrl-C, the end of the
        # process for SIGTERM (unless the program handles it, when the run's result returns).
        signal.raise_signal(stop_signal)
    return Result(summary, ch, None if tmp else path, units)


class Simulation:
    """A simulation stepped from Python, for co-simulation (docs/python.md, "Stepping").

        sim = cvt.Simulation(cvt.shipped_config("mini"))
        ch = sim.advance(0.01)            # to t = 0.01 s: the channels there (dict)
        sim.set_load_torque(15.0)         # N m, from now on
        ch = sim.advance(0.02)

    The model starts from rest, as a run. advance(t) takes the configured steps to t [s] (a
    multiple of the step, .step [s]) and returns the channels at t: time [s], the speeds
    [rad/s], torques [N m], clamping forces, link and strand tensions [N], sheave positions
    [m], powers [W], works and the energy residual [J], the ratios and efficiency [1].
    Between advances the inputs may change: set_drive_speed (rad/s, a step),
    set_load_torque (N m, a step), set_clamping (N, linear over `over` seconds). Without
    changes the trajectory is that of run() to the same time, bit for bit. Raises ConfigError for a bad argument and
    BlowUpError when the state blows up.
    """

    def __init__(self, config, *, overrides=None, threads=1, scheduler=None, grain=4):
        scheduler, threads = _schedule(scheduler, threads, grain)
        self._s = _core.Stepper(_config(config, overrides, {}), scheduler, threads, grain)

    @property
    def time(self):
        """The simulation's time [s]."""
        return self._s.time

    @property
    def step(self):
        """The integration step [s]: advance() goes to multiples of it."""
        return self._s.step

    def advance(self, t):
        """Steps to time t [s] and returns the channels there (dict)."""
        self._s.advance(_nonnegative("t", t))
        return self._s.channels()

    def channels(self):
        """The channels at the current time (dict; units as in advance)."""
        return self._s.channels()

    def state(self):
        """The state vector y (positions, then velocities, then the auxiliary integrals)."""
        return np.asarray(self._s.state())

    def set_drive_speed(self, omega):
        """The drive's speed omega_in [rad/s] from now on (a step; its angle stays continuous)."""
        self._s.set_input("drive_speed", _nonnegative("omega", omega), 0.0)

    def set_load_torque(self, torque):
        """The load torque M0 [N m] from now on (a step)."""
        self._s.set_input("load_torque", _nonnegative("torque", torque), 0.0)

    def set_clamping(self, driving=None, driven=None, over=1e-4):
        """The clamping forces F1 (driving), F2 (driven) [N], each reached linearly over
        `over` [s] from its present value (a force's rate enters the energy balance)."""
        for name, value in (("clamping_driving", driving), ("clamping_driven", driven)):
            if value is not None:
                self._s.set_input(name, _nonnegative(name, value), _nonnegative("over", over))


def _number(text):
    try:
        x = float(text)
    except ValueError:
        return text
    return int(x) if x.is_integer() and "." not in text and "e" not in text.lower() else x


def _rows(path):
    with open(path, newline="") as f:
        return [{k: _number(v) for k, v in row.items()} for row in csv.DictReader(f)]


def _log(log, quiet):
    if log is not None:
        return log
    return None if quiet else print


def sweep(config=None, *, axes=None, points=None, out="sweep", overrides=None, from_checkpoint=None,
          keep_runs=False, warm_ramp=None, continuation=False, threads=1, scheduler=None, grain=4, quiet=True,
          log=None):
    """Operating points, each run until steady (as `cvt-engine sweep`); returns OUT.csv's rows
    as dicts (the keys, status, speed_ratio [1], input_torque [N m], input_speed [rad/s],
    clamping_force_driving [N], efficiency [1], model_time [s], ...: docs/studies.md; OUT.h5's
    /results carry each column's unit).

    axes: {key: [values]} (a full grid, the first key slowest); points: a CSV file of points.
    from_checkpoint: start every point from a steady state's checkpoint (then config is None).
    continuation: maps by continuation (as --continuation): a point that differs from others in
    load.torque only starts from the steady state of the nearest load among them, its
    load ramped over warm_ramp [s] (None: the point's steady window, two torsion periods; also
    for from_checkpoint); the row's from_point names it.
    A sweep started again with the same out skips the points OUT.csv holds.
    log: a callable given each progress line (default: silent when quiet, else print).
    """
    scheduler, threads = _schedule(scheduler, threads, grain)
    if axes is not None and not isinstance(axes, dict):
        raise _error("axes", repr(axes), "give a dict {key: [values]}")
    ax = []
    for k, vals in (axes or {}).items():
        if isinstance(vals, (str, bytes)) or not isinstance(vals, (list, tuple, np.ndarray)):
            raise _error(f"axes[{k!r}]", repr(vals), "give a list of values")
        ax.append(f"{k}=" + ",".join(_value(k, v) for v in vals))
    log = _callable_or_none("log", log)
    _core.sweep(_path("config", config, True) or "", _path("from_checkpoint", from_checkpoint, True) or "",
                _overrides(overrides), ax, _path("points", points, True) or "", _path("out", out),
                _flag("keep_runs", keep_runs), -1.0 if warm_ramp is None else _nonnegative("warm_ramp", warm_ramp),
                _flag("continuation", continuation), scheduler, threads, grain,
                _log(log, _flag("quiet", quiet)))
    return _rows(os.fspath(out) + ".csv")


def _positive(name, values):
    if isinstance(values, (str, bytes)) or not isinstance(values, (list, tuple, np.ndarray)):
        raise _error(name, repr(values), "give a list of positive numbers")
    for v in values:
        if not (isinstance(v, (int, float, np.number)) and math.isfinite(v) and v > 0):
            raise _error(name, v, "must be a positive number")
    return [float(v) for v in values]


def study_slip(config, *, clamping, thrust_ratio=0.0, ratios=None, tolerance=0.02, out="slip.csv",
               overrides=None, threads=1, scheduler=None, grain=4, quiet=True, log=None):
    """The slip limit (as `cvt-engine study slip`): for each clamping.driving value [N] the
    largest load torque held without gross slip, by bisection; rows as dicts (slip_torque,
    slips_at, theory_torque, runs, ...). thrust_ratio 0: the configuration's F1/F2."""
    scheduler, threads = _schedule(scheduler, threads, grain)
    if not 1e-4 <= _nonnegative("tolerance", tolerance) <= 0.5:
        raise _error("tolerance", tolerance, "must be in [1e-4, 0.5]")
    if _nonnegative("thrust_ratio", thrust_ratio):
        _positive("thrust_ratio", [thrust_ratio])
    return _core.study_slip(_path("config", config), _overrides(overrides), _positive("clamping", clamping),
                            float(thrust_ratio), [_value("ratios", r) for r in (ratios or [])],
                            float(tolerance), _path("out", out), scheduler, threads, grain,
                            _log(_callable_or_none("log", log), _flag("quiet", quiet)))


def study_shift(config, *, thrust_ratios, speeds=None, settle=2e-3, window=1e-2, steady_bound=0.3,
                out="shift.csv", overrides=None, threads=1, scheduler=None, grain=4, quiet=True, log=None):
    """The shift rate (as `cvt-engine study shift`): from the steady state at each input speed,
    a step to each F1/F2; rows as dicts (shift_rate [1/s], ln_thrust_ratio, ...)."""
    scheduler, threads = _schedule(scheduler, threads, grain)
    _nonnegative("settle", settle)
    _positive("window", [window])
    _positive("steady_bound", [steady_bound])
    return _core.study_shift(_path("config", config), _overrides(overrides), _positive("thrust_ratios", thrust_ratios),
                             _positive("speeds", speeds or []), float(settle), float(window), float(steady_bound),
                             _path("out", out), scheduler, threads, grain,
                             _log(_callable_or_none("log", log), _flag("quiet", quiet)))
