"""mjsafe.run and mjsafe.read_log against the command line: the same metrics as `mjsafe analyze
--json`, the same summary as `mjsafe run --json`, the same tables as `mjsafe export`, and the
same bytes from the same inputs."""

import json
import math
import threading
import time

import numpy as np
import pandas as pd
import pytest

import mjsafe
from conftest import analyze_json, cli, export_tables, scenario

# 3 s of the Ch. 4 bicycle: it collides at 3.68 s with the delay-free filter, so shorter runs
# below keep the obstacle in view; every topic that is a table has rows.
BICYCLE = scenario("bicycle_obstacle.toml")
GAMMA_M = scenario("bicycle_obstacle_gamma_m.toml")
# A sensor and actuator dynamics: the optional topics (/state/measured, /command/actuated).
OBSERVED = {
    "duration": 3.0,
    "sensing": {"noise_std": [0.1, 0.1, 0.01, 0.1]},
    "actuator_dynamics.steering": {"rate_limit": 2.0},
}


def test_run_metrics_are_analyze_json_of_its_log(tmp_path):
    log = str(tmp_path / "run.mcap")
    r = mjsafe.run(BICYCLE, set={"delays.steering": 0.4}, out=log)
    assert r.log == log
    assert r.metrics == analyze_json(log)
    assert r.min_h == r.metrics["min_h"] and r.min_h < 0
    assert set(r.collision) == {"time", "with", "depth"}
    assert r.collision["with"] == "obstacle_0"
    assert r.error is None and r.metrics["complete"] is True


def test_run_reports_what_run_json_prints(tmp_path):
    log = str(tmp_path / "run.mcap")
    r = mjsafe.run(GAMMA_M, set={"duration": 4.0}, out=log)
    other = str(tmp_path / "cli.mcap")
    printed = json.loads(cli("run", GAMMA_M, "--set", "duration=4.0", "--out", other, "--json").stdout)
    assert r.collision == printed["collision"] is None
    assert r.min_h == printed["min_h"] > 0
    assert r.error == printed["error"] is None
    assert (r.steps, r.simulated_time) == (printed["steps"], printed["simulated_time"])
    assert r.real_time_factor > 0


def test_without_out_nothing_is_written_and_the_metrics_are_the_logs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    memory = mjsafe.run(BICYCLE, set={"duration": 5.0})
    assert list(tmp_path.iterdir()) == []
    assert memory.log is None and memory.metrics["file"] == "(in memory)"
    logged = mjsafe.run(BICYCLE, set={"duration": 5.0}, out=str(tmp_path / "a.mcap"))
    assert {**memory.metrics, "file": None} == {**logged.metrics, "file": None}
    assert memory.collision == logged.collision is not None


def test_two_runs_give_the_same_bytes_and_read_log_gives_the_run_metrics(tmp_path):
    a, b = str(tmp_path / "a.mcap"), str(tmp_path / "b.mcap")
    ra = mjsafe.run(GAMMA_M, set={"duration": 3.0}, out=a)
    mjsafe.run(GAMMA_M, set={"duration": 3.0}, out=b)
    assert open(a, "rb").read() == open(b, "rb").read()
    log = mjsafe.read_log(a)
    assert log.metrics == ra.metrics == analyze_json(a)


def test_tables_are_the_export_tables(tmp_path):
    log = str(tmp_path / "obs.mcap")
    r = mjsafe.run(GAMMA_M, set=OBSERVED, out=log)
    exported = export_tables(log, tmp_path / "csv")
    assert set(exported) == {"/state", "/command/issued", "/command/applied", "/barrier", "/filter",
                             "/event", "/prediction", "/state/measured", "/command/actuated"}
    kept = mjsafe.run(GAMMA_M, set=OBSERVED, tables=True)
    assert kept.log is None
    for tables in (r.tables(), mjsafe.read_log(log).tables(), kept.tables()):
        assert set(tables) == set(exported)
        for topic, frame in exported.items():
            assert list(tables[topic].columns) == list(frame.columns)
            assert tables[topic].columns[0] == "time"
            # Exact values, dtypes included (NaN equal to NaN).
            pd.testing.assert_frame_equal(tables[topic], frame, check_exact=True)
    # The exact doubles: the state's last row bit for bit.
    last = kept.tables()["/state"].iloc[-1]
    assert last["x1"] == exported["/state"].iloc[-1]["x1"]


def test_a_run_without_a_log_or_kept_tables_has_no_tables():
    r = mjsafe.run(BICYCLE, set={"duration": 1.0})
    with pytest.raises(ValueError, match="tables=True"):
        r.tables()


def test_set_takes_python_values_as_set_takes_toml(tmp_path):
    # A table as a dict, floats, ints and strings: the same run as the command line's --set.
    python = mjsafe.run(BICYCLE, set={
        "duration": 4,
        "filter": {"kind": "gamma_m", "l0": 4.0, "l1": 4.0, "m": 50.0},
        "plant": "ode",
    }, out=str(tmp_path / "py.mcap"))
    other = str(tmp_path / "cli.mcap")
    cli("run", BICYCLE, "--set", "duration=4", "--set", "filter={kind='gamma_m', l0=4.0, l1=4.0, m=50.0}",
        "--set", "plant=ode", "--out", other)
    assert {**python.metrics, "file": None} == {**analyze_json(other), "file": None}
    assert python.metrics["filter_label"] == analyze_json(other)["filter_label"]


@pytest.mark.parametrize("value, text", [
    (True, "true"),
    (np.bool_(False), "false"),
    (3, "3"),
    (np.int64(-7), "-7"),
    (2**70, str(2**70)),  # TOML's parser says it is too large (below)
    (0.4, "0.4"),
    (4.0, "4.0"),
    (np.float64(1e300), "1e300"),
    (1e-7, "1e-7"),
    (math.nan, "nan"),
    (math.inf, "inf"),
    ("gamma_m", '"gamma_m"'),
    ('say "hi"\n', '"say \\"hi\\"\\n"'),
    ([1, 2.5, "a"], '[1, 2.5, "a"]'),
    ((0.0, 1.0), "[0.0, 1.0]"),
    ({"kind": "none", "a b": [1]}, '{kind = "none", "a b" = [1]}'),
])
def test_python_values_become_toml_text(value, text):
    assert mjsafe.toml_value(value) == text


def test_values_without_a_toml_form_are_refused():
    # A value of a type TOML has no form for: TypeError; a list that contains itself: ValueError.
    with pytest.raises(TypeError, match="a NoneType has no TOML value"):
        mjsafe.run(BICYCLE, set={"duration": None})
    nested = []
    nested.append(nested)
    with pytest.raises(ValueError, match="nested more than"):
        mjsafe.run(BICYCLE, set={"x": nested})
    with pytest.raises(TypeError, match="a key is a dotted str"):
        mjsafe.run(BICYCLE, set={1: 2})


def test_run_releases_the_gil():
    # A Python thread keeps running while a run steps (the GIL is released for the Rust work).
    ticks = []
    stop = threading.Event()

    def tick():
        while not stop.is_set():
            ticks.append(time.perf_counter())
            time.sleep(0.001)

    t = threading.Thread(target=tick)
    t.start()
    try:
        started = time.perf_counter()
        mjsafe.run(BICYCLE, set={"duration": 120.0})
        ended = time.perf_counter()
    finally:
        stop.set()
        t.join()
    during = [x for x in ticks if started < x < ended]
    assert ended - started > 0.05
    # With the GIL held the thread could not tick at all during the run.
    assert len(during) >= 10, (len(during), ended - started)


CTRL_C_CHILD = """
import signal, sys, time
import mjsafe
# Python's own Ctrl-C handler, even when the test runner was started with SIGINT ignored.
signal.signal(signal.SIGINT, signal.default_int_handler)
path, log, what = sys.argv[1], sys.argv[2], sys.argv[3]
started = time.monotonic()
try:
    if what == "run":
        mjsafe.run(path, set={"duration": 3000.0}, out=log)
    else:
        mjsafe.sweep(path, grid={"delays.steering": [0.1, 0.2, 0.3, 0.4]}, set={"duration": 3000.0}, threads=2)
    print("finished", flush=True)
except KeyboardInterrupt:
    print(f"interrupted after {time.monotonic() - started:.1f} s", flush=True)
    again = mjsafe.run(path, set={"duration": 1.0})
    print("next run:", again.error, flush=True)
"""


@pytest.mark.parametrize("what", ["run", "sweep"])
def test_ctrl_c_stops_a_long_call_and_the_next_one_runs(tmp_path, what):
    import signal
    import subprocess
    import sys

    log = tmp_path / "long.mcap"
    child = subprocess.Popen(
        [sys.executable, "-c", CTRL_C_CHILD, BICYCLE, str(log), what],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(2.0)  # well inside the run (3000 s of simulation: minutes)
    child.send_signal(signal.SIGINT)
    out, err = child.communicate(timeout=60)
    assert child.returncode == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("interrupted after"), out
    assert float(lines[0].split()[2]) < 30.0
    assert lines[1] == "next run: None", "the stop request is withdrawn once the call returned"
    if what == "run":
        metrics = analyze_json(str(log))
        assert metrics["complete"] is False and metrics["error"] == "interrupted by a signal"
