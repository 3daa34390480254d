"""The Python module cvt_engine (docs/python.md): configuration errors as exceptions that
name the key, runs with the same bits as the command line, progress callbacks that can stop
a run, the GIL released while the engine runs, sweeps with the command line's CSV, and the
documented example script.

    PYTHONPATH=build/python CVT_ENGINE_EXE=build/cvt-engine /usr/bin/python3 -m pytest tests/python
"""
import csv
import math
import json
import os
import subprocess
import sys
import threading
import time

import h5py
import numpy as np
import pytest

import cvt_engine as cvt

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
MINI = os.path.join(ROOT, "configs", "mini.toml")
EXE = os.environ.get("CVT_ENGINE_EXE", os.path.join(ROOT, "build", "cvt-engine"))
# What differs between two runs of the same inputs: the wall clock and the run's identity.
WALL_KEYS = {"wall_s", "us_per_step", "model_s_per_hour", "run_id"}


def cli(*args, cwd=None):
    return subprocess.run([EXE, *args], cwd=cwd, check=True, capture_output=True, text=True)


def observables(path):
    with h5py.File(path, "r") as f:
        return {name: np.asarray(f["observables"][name]["value"]) for name in f["observables"]}


def test_config_errors_name_the_key():
    with pytest.raises(cvt.ConfigError) as e:
        cvt.load_config(MINI, {"load.torqe": 3})
    assert e.value.key == "load.torqe" and "did you mean 'load.torque'" in e.value.reason
    assert "(from the overrides)" in str(e.value)
    with pytest.raises(cvt.ConfigError) as e:
        cvt.load_config(MINI, ["friction.f0=-0.1"])
    assert e.value.key == "friction.f0" and e.value.value == "-0.1"
    with pytest.raises(cvt.ConfigError) as e:
        cvt.run(MINI, t_end=-1.0)
    assert e.value.key == "run.t_end" and "the argument t_end" in str(e.value)
    with pytest.raises(cvt.ConfigError) as e:
        cvt.run(MINI, t_end=1e-3, threads=0)
    assert e.value.key == "threads"
    with pytest.raises(cvt.ConfigError) as e:
        cvt.run(MINI, t_end=1e-3, scheduler="fast")
    assert e.value.key == "scheduler"
    with pytest.raises(cvt.ConfigError) as e:
        cvt.load_config("no/such.toml")
    assert "no/such.toml" in str(e.value)
    assert isinstance(e.value, ValueError)


def test_every_bad_override_is_a_config_error():
    for bad in ({"load.torque": None}, {"load.torque": {"a": 1}}, {"load.torque": object()}, {3: 1.0},
                "load.torque=3", [None], ["load.torque=3", {"x": 1}], 5):
        with pytest.raises(cvt.ConfigError) as e:
            cvt.load_config(MINI, bad)
        assert e.value.key and e.value.reason, bad
    with pytest.raises(cvt.ConfigError) as e:
        cvt.run(MINI, t_end=1e-5, overrides={"friction.f0": None})
    assert e.value.key == "friction.f0" and "NoneType" in e.value.reason


def test_every_argument_is_checked_before_the_run(tmp_path):
    out = tmp_path / "never.h5"
    for kwargs, key in (({"progress": 5}, "progress"), ({"checkpoint_every": -1}, "checkpoint_every"),
                        ({"checkpoint_every": 2.5}, "checkpoint_every"), ({"progress_seconds": math.nan},
                                                                          "progress_seconds"),
                        ({"grain": 0}, "grain"), ({"quiet": "yes"}, "quiet"), ({"threads": True}, "threads"),
                        ({"scheduler": "fast"}, "scheduler")):
        with pytest.raises(cvt.ConfigError) as e:
            cvt.run(MINI, t_end=1e-5, out=out, **kwargs)
        assert e.value.key == key, kwargs
        assert not out.exists() and not (tmp_path / "never.h5.partial").exists(), kwargs
    with pytest.raises(cvt.ConfigError) as e:
        cvt.sweep(MINI, axes={"load.torque": 5}, out=tmp_path / "s")
    assert e.value.key == "axes['load.torque']"
    with pytest.raises(cvt.ConfigError) as e:
        cvt.sweep(MINI, axes={"load.torque": [5, None]}, out=tmp_path / "s")
    assert e.value.key == "load.torque"
    assert not (tmp_path / "s.csv").exists()


def test_config_reads_back_its_values():
    cfg = cvt.load_config(MINI, {"load.torque": 12.5, "controller.target_profile": [[0.0, 1.0], [0.01, 1.1]]})
    assert cvt.config_value(cfg, "load.torque") == 12.5
    assert cvt.config_value(cfg, "controller.target_profile") == [[0.0, 1.0], [0.01, 1.1]]
    again = cvt.parse_config(cfg.toml)  # the resolved text is a complete configuration
    assert again.toml == cfg.toml
    info = cvt.model_info(cfg)
    assert info["links"] == 30 and info["unknowns"] == 2 * info["coordinates"] + 6


def test_run_gives_the_same_bits_as_the_command_line(tmp_path):
    cli("run", MINI, "--t-end", "0.004", "--set", "load.torque=15", "--out", str(tmp_path / "cli.h5"), "--quiet",
        "--summary-json", str(tmp_path / "cli.json"))
    r = cvt.run(MINI, t_end=0.004, overrides={"load.torque": 15.0}, out=tmp_path / "py.h5")
    r2 = cvt.run(MINI, t_end=0.004, overrides=["load.torque=15"], threads=2)  # the flow graph, a temporary file
    a = observables(tmp_path / "cli.h5")
    assert set(a) == set(r.channels) - {"time"} == set(r2.channels) - {"time"}
    for name, value in a.items():
        assert np.array_equal(value, r.channels[name]), name
        assert np.array_equal(value, r2.channels[name]), name
    assert r.file == str(tmp_path / "py.h5") and r2.file is None
    with open(tmp_path / "cli.json") as f:
        js = json.load(f)
    for key, value in js.items():
        if key not in WALL_KEYS:
            assert r.summary[key] == value, key
    assert r.channels["time"][-1] == pytest.approx(0.004) and r.summary["status"] in ("steady", "not_steady", "slip")


def test_resume_continues_a_run_to_the_uninterrupted_bits(tmp_path):
    # A run to 2 ms, then resumed into its own file to 4 ms: the channels of one 4 ms run; a
    # resume into a new file holds the continuation alone.
    whole = cvt.run(MINI, t_end=0.004, out=tmp_path / "whole.h5")
    first = cvt.run(MINI, t_end=0.002, out=tmp_path / "parts.h5")
    assert first.summary["model_time"] == pytest.approx(0.002)
    r = cvt.resume(tmp_path / "parts.h5.ckpt", t_end=0.004)
    assert r.file == os.path.abspath(tmp_path / "parts.h5")
    for name, value in whole.channels.items():
        assert np.array_equal(value, r.channels[name]), name
    assert r.units["output_torque"] == "N m" and r.summary["units"]["input_torque"] == "N m"
    new = cvt.resume(tmp_path / "parts.h5.ckpt", t_end=0.006, out=tmp_path / "more.h5")
    assert new.channels["time"][0] == pytest.approx(0.004) and new.channels["time"][-1] == pytest.approx(0.006)
    with pytest.raises(cvt.ConfigError, match="t_end"):
        cvt.resume(tmp_path / "parts.h5.ckpt", t_end="soon")


def test_stepping_gives_the_runs_bits_and_takes_new_inputs():
    # Advanced in three pieces without changes: the channels of one run at each time.
    whole = cvt.run(MINI, t_end=0.003)
    sim = cvt.Simulation(MINI)
    h = sim.step
    times = whole.channels["time"]
    for t in (0.001, 0.002, 0.003):
        ch = sim.advance(round(t / h) * h)
        i = int(np.argmin(np.abs(times - t)))
        for name in ("input_torque", "output_torque", "clamping_force_driving", "energy_residual", "work_input"):
            assert ch[name] == whole.channels[name][i], (t, name)
    assert sim.state().shape == (cvt.model_info(MINI)["unknowns"],) and np.isfinite(sim.state()).all()
    # New inputs: the load torque steps, the drive speeds up, the clamping rises; the load
    # channel follows at once, the drive's speed within the drive spring's settling, and the
    # energy balance stays closed (its residual a small share of the input work).
    sim.set_load_torque(15.0)
    sim.set_drive_speed(250.0)
    sim.set_clamping(driving=12e3, driven=12e3, over=5e-4)
    ch = sim.advance(round(0.006 / h) * h)
    assert ch["load_torque"] == pytest.approx(15.0)
    assert ch["clamping_force_driving"] == pytest.approx(12e3)
    assert ch["input_speed"] == pytest.approx(250.0, rel=0.02)
    assert abs(ch["energy_residual"]) < 0.01 * ch["work_input"]
    with pytest.raises(cvt.ConfigError, match="before the simulation's time"):
        sim.advance(0.001)
    with pytest.raises(cvt.ConfigError, match="multiple of the step"):
        sim.advance(0.0061234567)
    with pytest.raises(cvt.ConfigError):
        sim.set_drive_speed(-1)


def test_results_convert_to_pandas_and_xarray_with_units(tmp_path):
    r = cvt.run(cvt.shipped_config("mini"), t_end=0.0005)
    pd = pytest.importorskip("pandas")
    df = r.to_pandas()
    assert isinstance(df, pd.DataFrame) and df.index.name == "time"
    assert np.array_equal(df["output_torque"].to_numpy(), r.channels["output_torque"])
    assert np.array_equal(df["sheave_position[1]"].to_numpy(), r.channels["sheave_position"][:, 1])
    assert df.attrs["units"]["output_torque"] == "N m" and df.attrs["units"]["time"] == "s"
    xr = pytest.importorskip("xarray")
    ds = r.to_xarray()
    assert isinstance(ds, xr.Dataset) and ds["time"].attrs["units"] == "s"
    assert ds["support_force"].attrs["units"] == "N" and ds["support_force"].dims == ("time", "support_force_index")


def test_progress_reaches_the_callback_which_can_stop_the_run():
    seen = []
    r = cvt.run(MINI, t_end=0.003, progress=seen.append, progress_seconds=0)
    assert seen and all(p["t_end"] == 0.003 and 0 < p["step"] <= p["steps"] for p in seen)
    assert [p["step"] for p in seen] == sorted(p["step"] for p in seen)
    assert not any(p["verifying"] for p in seen)
    assert r.summary["stopped"] == "t_end" and not r.summary["interrupted"]
    r = cvt.run(MINI, t_end=0.003, progress=lambda p: p["t"] < 0.001, progress_seconds=0)
    assert r.summary["stopped"] == "callback" and r.summary["interrupted"]
    assert 0.001 <= r.summary["model_time"] < 0.0015
    assert r.channels["time"][-1] == r.summary["model_time"]
    # A stop asked for at the last step stops nothing: the run ended, and is not continued.
    r = cvt.run(MINI, t_end=0.003, progress=lambda p: p["step"] < p["steps"], progress_seconds=0)
    assert r.summary["stopped"] == "t_end" and not r.summary["interrupted"]
    assert r.summary["model_time"] == pytest.approx(0.003)

    # run.verify's second integration reports as well, marked; stopping it leaves the means
    # unverified.
    seen = []
    r = cvt.run(MINI, t_end=0.003, overrides={"run.verify": True}, progress=seen.append, progress_seconds=0)
    verifying = [p for p in seen if p["verifying"]]
    assert verifying and not seen[0]["verifying"] and seen[-1]["verifying"]
    assert verifying[-1]["step"] == verifying[-1]["steps"] and "efficiency_numerical_error" in r.summary
    r = cvt.run(MINI, t_end=0.003, overrides={"run.verify": True}, progress=lambda p: not p["verifying"],
                progress_seconds=0)
    assert r.summary["stopped"] == "t_end" and "efficiency_numerical_error" not in r.summary
    assert any("stopped by the progress callback" in w for w in r.summary["warnings"])

    def fails(p):
        raise ZeroDivisionError("from the callback")
    with pytest.raises(ZeroDivisionError, match="from the callback"):
        cvt.run(MINI, t_end=0.003, progress=fails, progress_seconds=0)


def test_the_engine_runs_without_the_gil():
    ticks = []
    done = threading.Event()

    def count():
        while not done.is_set():
            ticks.append(time.monotonic())
            time.sleep(0.01)
    counter = threading.Thread(target=count)
    counter.start()
    t0 = time.monotonic()
    try:
        cvt.run(MINI, t_end=0.004)
    finally:
        done.set()
        counter.join()
    wall = time.monotonic() - t0
    # With the GIL held the counter would not tick at all until the run returns; free, it
    # ticks about every 10 ms (fewer on a loaded machine).
    during = [t for t in ticks if t0 + 0.1 * wall < t < t0 + 0.9 * wall]
    assert len(during) >= min(10, 0.1 * (0.8 * wall / 0.01)), (len(during), wall)


def test_sweep_gives_the_command_lines_rows(tmp_path):
    base = {"run.t_end": 0.004}
    rows = cvt.sweep(MINI, axes={"load.torque": [10, 15.5]}, overrides=base, out=tmp_path / "py")
    cli("sweep", MINI, "--axis", "load.torque=10,15.5", "--set", "run.t_end=0.004", "--out", str(tmp_path / "cli"))
    with open(tmp_path / "cli.csv") as f:
        expected = list(csv.DictReader(f))
    assert [r["load.torque"] for r in rows] == [10, 15.5]
    assert len(rows) == len(expected) == 2
    for got, want in zip(rows, expected):
        for key, text in want.items():
            if key != "wall_s":
                value = got[key]
                if isinstance(value, (int, float)):  # nan (a mean not verified) is nan in both
                    assert value == float(text) or (math.isnan(value) and math.isnan(float(text))), key
                else:
                    assert value == text, key
    assert all(r["status"] in ("steady", "not_steady", "slip") for r in rows)
    with pytest.raises(cvt.ConfigError) as e:  # every point checked before the first runs
        cvt.sweep(MINI, axes={"load.torque": [10, -1]}, out=tmp_path / "bad")
    assert e.value.key == "load.torque"
    assert not os.path.exists(tmp_path / "bad.csv")


def test_studies_check_their_arguments(tmp_path):
    with pytest.raises(cvt.ConfigError) as e:
        cvt.study_slip(MINI, clamping=[1.1e4, -5], out=tmp_path / "slip.csv")
    assert e.value.key == "clamping"
    with pytest.raises(cvt.ConfigError) as e:
        cvt.study_slip(MINI, clamping=[1.1e4], tolerance=0.9, out=tmp_path / "slip.csv")
    assert e.value.key == "tolerance"
    with pytest.raises(cvt.ConfigError) as e:
        cvt.study_shift(MINI, thrust_ratios=[1.1], window=0, out=tmp_path / "shift.csv")
    assert e.value.key == "window"


def test_the_efficiency_curve_example_runs(tmp_path):
    script = os.path.join(ROOT, "docs", "examples", "efficiency_curve.py")
    package = os.path.dirname(os.path.dirname(os.path.abspath(cvt.__file__)))
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=package)
    out = subprocess.run([sys.executable, script, "--loads", "8,14", "--t-end", "0.004", "--out", str(tmp_path / "eff")],
                         cwd=tmp_path, env=env, check=True, capture_output=True, text=True)
    assert os.path.getsize(tmp_path / "eff.png") > 10000
    assert "load 8 N m" in out.stdout and "load 14 N m" in out.stdout


@pytest.fixture
def python_sigint():
    """Python's own SIGINT handler, as in an interactive Python shell (a job started in the
    background of a shell inherits SIGINT ignored, and Python then leaves it so)."""
    import signal
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


def test_ctrl_c_stops_the_run_and_raises_keyboard_interrupt(tmp_path, python_sigint):
    import signal
    timer = threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        cvt.run(MINI, t_end=0.05, out=tmp_path / "stopped.h5")
    timer.join()
    with h5py.File(tmp_path / "stopped.h5", "r") as f:  # kept, complete up to the stop
        t = f["observables/output_torque/time"][()]
        assert 0 < t[-1] < 0.05
        assert f["summary"].attrs["stopped"] == "signal"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_stop_asked_once_holds_and_any_false_value_stops():
    calls = []

    def once(p):
        calls.append(p["step"])
        return len(calls) != 1  # False at the first call only
    r = cvt.run(MINI, t_end=0.003, progress=once, progress_seconds=0)
    assert r.summary["stopped"] == "callback" and r.summary["model_time"] < 0.003
    r = cvt.run(MINI, t_end=0.002, progress=lambda p: [], progress_seconds=0)  # [] is false
    assert r.summary["stopped"] == "callback"
    r = cvt.run(MINI, t_end=0.002, progress=lambda p: "yes", progress_seconds=0)
    assert r.summary["stopped"] == "t_end"

    class Undecided:
        def __bool__(self):
            raise ValueError("neither")
    with pytest.raises(ValueError, match="neither"):
        cvt.run(MINI, t_end=0.002, progress=lambda p: Undecided(), progress_seconds=0)


def test_runs_side_by_side_in_threads_give_their_own_bits(python_sigint):
    import signal
    results = {}

    def one(load):
        results[load] = cvt.run(MINI, t_end=0.002, overrides={"load.torque": load})
    threads = [threading.Thread(target=one, args=(load,)) for load in (5.0, 15.0)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for load in (5.0, 15.0):
        alone = cvt.run(MINI, t_end=0.002, overrides={"load.torque": load})
        for name, value in alone.channels.items():
            assert np.array_equal(value, results[load].channels[name]), (load, name)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # Ctrl-C works again


def test_snapshots_between_samples_hold_that_states_contact_forces(tmp_path):
    # A snapshot every 2.5 us with samples every 10 us, against samples every 2.5 us too:
    # the same snapshots, contact forces included.
    over = {"run.snapshot_interval": 2.5e-6, "load.torque": 12.0}
    cvt.run(MINI, t_end=0.002, overrides=over, out=tmp_path / "a.h5", channels=False)
    cvt.run(MINI, t_end=0.002, overrides={**over, "run.sample_interval": 2.5e-6}, out=tmp_path / "b.h5",
            channels=False)
    with h5py.File(tmp_path / "a.h5", "r") as a, h5py.File(tmp_path / "b.h5", "r") as b:
        for name in ("position", "link_tension", "pin_end_position", "pin_end_normal_force"):
            x, y = a[f"particles/chain/{name}/value"][()], b[f"particles/chain/{name}/value"][()]
            assert x.shape == y.shape and len(x) == 801, name
            assert np.array_equal(x, y), name
        assert (a["particles/chain/pin_end_normal_force/value"][-1] > 0).sum() > 10  # the chain is on the sheaves
