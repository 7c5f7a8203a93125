"""mjsafe.sweep and mjsafe.falsify against `mjsafe sweep` and `mjsafe falsify`: the same summary
table, the same evaluations and counterexample, whatever the thread count."""

import threading
import time
from pathlib import Path

import pandas as pd
import pytest

import mjsafe
from conftest import cli, scenario

BICYCLE = scenario("bicycle_obstacle.toml")
GAMMA_M = scenario("bicycle_obstacle_gamma_m.toml")


def read_csv(path: Path) -> pd.DataFrame:
    exact = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}
    return pd.read_csv(path, **exact)


def test_sweep_is_the_summary_csv_of_the_cli(tmp_path):
    frame = mjsafe.sweep(
        BICYCLE,
        grid={"delays.acceleration": [0.5, 1.5], "filter": [{"kind": "cbf_qp", "l0": 4.0, "l1": 4.0},
                                                            {"kind": "gamma_m", "l0": 4.0, "l1": 4.0, "m": 50.0}]},
        random={"delays.steering": (0.0, 0.4, 0.1)},
        draws=2,
        seed=3,
        set={"duration": 5.0},
        threads=2,
    )
    out = tmp_path / "cli"
    cli("sweep", BICYCLE, "--grid", "delays.acceleration=0.5,1.5",
        "--grid", 'filter={kind = "cbf_qp", l0 = 4.0, l1 = 4.0},{kind = "gamma_m", l0 = 4.0, l1 = 4.0, m = 50.0}',
        "--range", "delays.steering=0.0..0.4:0.1", "--random", "2", "--seed", "3",
        "--set", "duration=5.0", "--no-logs", "--out", str(out))
    expected = read_csv(out / "summary.csv")
    assert len(frame) == 8
    assert list(frame.columns[:5]) == ["index", "log", "delays.acceleration", "filter", "delays.steering"]
    assert "min_h" in frame.columns and "error" in frame.columns
    pd.testing.assert_frame_equal(frame, expected, check_exact=True)
    # The result does not depend on the thread count.
    one = mjsafe.sweep(
        BICYCLE,
        grid={"delays.acceleration": [0.5, 1.5], "filter": [{"kind": "cbf_qp", "l0": 4.0, "l1": 4.0},
                                                            {"kind": "gamma_m", "l0": 4.0, "l1": 4.0, "m": 50.0}]},
        random={"delays.steering": (0.0, 0.4, 0.1)}, draws=2, seed=3, set={"duration": 5.0}, threads=1)
    pd.testing.assert_frame_equal(one, frame, check_exact=True)


def test_sweep_with_out_keeps_logs_and_summary(tmp_path):
    out = tmp_path / "grid"
    frame = mjsafe.sweep(BICYCLE, grid={"delays.steering": [0.0, 0.2]}, set={"duration": 2.0}, out=out)
    assert sorted(p.name for p in out.iterdir()) == [
        "bicycle_obstacle-000.mcap", "bicycle_obstacle-001.mcap", "summary.csv", "summary.json"]
    pd.testing.assert_frame_equal(frame, read_csv(out / "summary.csv"), check_exact=True)
    assert list(frame["log"]) == ["bicycle_obstacle-000.mcap", "bicycle_obstacle-001.mcap"]
    # Each row's metrics are its log's.
    log = mjsafe.read_log(out / "bicycle_obstacle-001.mcap")
    assert frame.loc[1, "min_h"] == log.metrics["min_h"]


def test_sweep_releases_the_gil():
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
        mjsafe.sweep(BICYCLE, grid={"delays.steering": [0.0, 0.1, 0.2, 0.3]}, set={"duration": 30.0}, threads=1)
        ended = time.perf_counter()
    finally:
        stop.set()
        t.join()
    assert len([x for x in ticks if started < x < ended]) >= 10


# The Ch. 4 bicycle with (4.67) over start x, obstacle offset and acceleration delay
# (tests/falsify.rs: a violation within 40 runs with seed 1).
GAMMA_M_BOX = {
    "vehicle.initial_state.0": (-26, -16),
    "obstacles.0.centre.1": (-3, 3),
    "delays.acceleration": (0.5, 2.0, 0.1),
}
GAMMA_M_RANGES = ["--range", "vehicle.initial_state.0=-26.0..-16.0", "--range", "obstacles.0.centre.1=-3.0..3.0",
                  "--range", "delays.acceleration=0.5..2.0:0.1"]


def without_search_line(text: str) -> str:
    return "\n".join(l for l in text.splitlines() if not l.startswith("# search:"))


def test_falsify_finds_what_the_cli_finds_and_its_scenario_reproduces_it(tmp_path):
    found = mjsafe.falsify(GAMMA_M, ranges=GAMMA_M_BOX, budget=40, seed=1, threads=2)
    out = tmp_path / "cli"
    cli("falsify", GAMMA_M, *GAMMA_M_RANGES, "--budget", "40", "--seed", "1", "--out", str(out))
    pd.testing.assert_frame_equal(found.evaluations, read_csv(out / "evaluations.csv"), check_exact=True)
    assert found.out is None and found.log is None and not found.interrupted
    [values] = found.counterexamples
    assert list(values) == list(GAMMA_M_BOX)
    assert values["delays.acceleration"] in {round(0.5 + 0.1 * k, 1) for k in range(16)}
    assert without_search_line(found.scenario_toml) == without_search_line((out / "counterexample.toml").read_text())
    assert found.scenario_toml.count("# search: mjsafe.falsify(") == 1
    # The values, as overrides, and the scenario text alone give the search's run.
    violation = found.evaluations[found.evaluations["violation"]].iloc[0]
    assert mjsafe.run(GAMMA_M, set=values).min_h == violation["min_h"] == found.reproduced < 0
    written = tmp_path / "counterexample.toml"
    written.write_text(found.scenario_toml)
    assert mjsafe.run(written).min_h == found.reproduced


def test_falsify_with_out_baseline_and_worst_writes_the_cli_outputs(tmp_path):
    out = tmp_path / "search"
    baseline = {"delays.steering": 0.0, "delays.acceleration": 0.0,
                "filter": {"kind": "cbf_qp", "l0": 4.0, "l1": 4.0}}
    found = mjsafe.falsify(GAMMA_M, ranges=GAMMA_M_BOX, baseline=baseline, budget=16, seed=2, worst=True,
                           baseline_threshold=-0.5, out=out)
    names = sorted(p.name for p in out.iterdir())
    assert {"evaluations.csv", "evaluations.json"} <= set(names)
    pd.testing.assert_frame_equal(found.evaluations, read_csv(out / "evaluations.csv"), check_exact=True)
    assert len(found.evaluations) >= 16 and found.evaluations["baseline"].notna().any()
    cli_out = tmp_path / "cli"
    cli("falsify", GAMMA_M, *GAMMA_M_RANGES, "--baseline", "delays.steering=0.0", "--baseline",
        "delays.acceleration=0.0", "--baseline", 'filter={kind = "cbf_qp", l0 = 4.0, l1 = 4.0}',
        "--budget", "16", "--seed", "2", "--worst", "--baseline-threshold", "-0.5", "--out", str(cli_out))
    pd.testing.assert_frame_equal(found.evaluations, read_csv(cli_out / "evaluations.csv"), check_exact=True)
    if found.counterexamples:
        assert found.log == str(out / "counterexample.mcap")
        assert (out / "counterexample.toml").read_text() == found.scenario_toml
    else:
        assert found.scenario_toml is None and found.log is None


def test_falsify_counterexamples_are_the_cli_failure_modes_each_with_its_log(tmp_path):
    rare = {"vehicle.initial_state.0": (-50.0, -10.0), "obstacles.0.centre.1": (-3.0, 3.0),
            "delays.acceleration": (0.5, 2.0, 0.1)}
    baseline = {"delays.steering": 0.0, "delays.acceleration": 0.0,
                "filter": {"kind": "cbf_qp", "l0": 4.0, "l1": 4.0}}
    out = tmp_path / "search"
    found = mjsafe.falsify(GAMMA_M, ranges=rare, baseline=baseline, budget=240, seed=1, counterexamples=3,
                           out=out)
    assert len(found.counterexamples) == 3 == len(found.logs) == len(found.scenario_tomls)
    assert found.logs == [str(out / n) for n in ("counterexample.mcap", "counterexample-2.mcap",
                                                 "counterexample-3.mcap")]
    assert found.log == found.logs[0] and found.reproduced == found.reproduced_all[0]
    # Each failure mode's values, run as overrides, give the min h its own log reproduced.
    for values, reproduced in zip(found.counterexamples, found.reproduced_all):
        assert mjsafe.run(GAMMA_M, set=values).min_h == reproduced < 0
    cli_out = tmp_path / "cli"
    cli("falsify", GAMMA_M, "--range", "vehicle.initial_state.0=-50..-10", "--range", "obstacles.0.centre.1=-3..3",
        "--range", "delays.acceleration=0.5..2.0:0.1", "--baseline", "delays.steering=0.0", "--baseline",
        "delays.acceleration=0.0", "--baseline", 'filter={kind = "cbf_qp", l0 = 4.0, l1 = 4.0}',
        "--budget", "240", "--seed", "1", "--counterexamples", "3", "--out", str(cli_out))
    pd.testing.assert_frame_equal(found.evaluations, read_csv(cli_out / "evaluations.csv"), check_exact=True)
    assert (cli_out / "counterexample-3.toml").exists()
    # Random search, by name.
    uniform = mjsafe.falsify(GAMMA_M, ranges=rare, baseline=baseline, budget=16, seed=1, method="random")
    assert set(uniform.evaluations["method"]) == {"random search"}


def test_falsify_says_how_many_qualified_and_when_it_proved_nothing():
    """A baseline threshold no run reaches: no candidate qualifies, so finding nothing proves
    nothing — the result says so (as the shell's "none of the N candidates qualified"), with a
    warning the user cannot miss; a search with qualified candidates counts them."""
    with pytest.warns(UserWarning, match="none of the 4 candidates qualified.*proves nothing about the box"):
        found = mjsafe.falsify(GAMMA_M, ranges={"delays.acceleration": (0.5, 0.7, 0.1)},
                               baseline={"obstacles.0.centre.1": 0.0}, baseline_threshold=1000.0, budget=4)
    assert (found.runs, found.qualified, found.proves_nothing) == (4, 0, True)
    assert not found.counterexamples and "4 runs, 0 qualified" in repr(found)
    tested = mjsafe.falsify(GAMMA_M, ranges={"delays.acceleration": (0.5, 0.7, 0.1)},
                            baseline={"obstacles.0.centre.1": 0.0}, baseline_threshold=-1000.0, budget=4)
    assert tested.qualified == tested.runs == len(tested.evaluations) and not tested.proves_nothing
