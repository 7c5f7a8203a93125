"""Requirements (STL formulas over a run's signals, docs/requirements.md) against an independent
monitor: RTAMT's discrete-time offline monitor, with its sampling period set to the log's step,
on the signals rebuilt here from the log's tables (read by Python `mcap`-free pandas through
mjsafe.read_log) with the documented semantics — one sample per /state row, every other table
held from its latest row at or before the sample (pandas merge_asof). Also: the in-memory
analysis (online monitors) gives the log's analysis (offline reader), the CLI gate and errors."""

import math

import numpy as np
import pandas as pd
import pytest

import mjsafe
from conftest import cli, cli_error, scenario

rtamt = pytest.importorskip("rtamt")

GAMMA_M = scenario("bicycle_obstacle_gamma_m.toml")
BICYCLE = scenario("bicycle_obstacle.toml")

# name: (mjsafe formula, RTAMT formula over the same signals renamed to identifiers, signals)
FORMULAS = {
    "clear": ("always obstacle_0.h >= 0", "always (h >= 0)", {"h": ("/barrier", "obstacle_0.h")}),
    "fast": ("eventually[0, 5] speed > 3.5", "eventually[0, 5] (speed > 3.5)", {"speed": ("/state", "speed")}),
    "brakes": (
        "always (obstacle_0.clearance < 3 implies acceleration.filtered < 0)",
        "always ((c < 3) implies (a < 0))",
        {"c": ("/barrier", "obstacle_0.clearance"), "a": ("/command/issued", "acceleration.filtered")},
    ),
    "reacts": (
        "always (active > 0.5 implies eventually[0, 0.5] abs(x2) > 0.2)",
        "always ((active > 0.5) implies (eventually[0, 0.5] (abs(x2) > 0.2)))",
        {"active": ("/filter", "active"), "x2": ("/state", "x2")},
    ),
    # (RTAMT's bounded until costs about n w² here: a short window keeps it to seconds.)
    "lane": (
        "(abs(x2) < 4) until[0, 0.1] x1 > -19.9",
        "(abs(x2) < 4) until[0, 0.1] (x1 > -19.9)",
        {"x2": ("/state", "x2"), "x1": ("/state", "x1")},
    ),
    "past": (
        "always (x1 > 5 implies once[0, 2] steering.correction != 0)",
        "always ((x1 > 5) implies (once[0, 2] (corr !== 0)))",
        {"x1": ("/state", "x1"), "corr": ("/filter", "steering.correction")},
    ),
}


def signal(tables, topic, column):
    """`column` of `topic` on the /state grid, each sample the latest row at or before it."""
    grid = tables["/state"][["time"]]
    table = tables[topic][["time", column]].astype({column: float})
    # Rows of one time: the last one holds (a topic logs at most one row per time).
    table = table.drop_duplicates("time", keep="last")
    merged = pd.merge_asof(grid, table, on="time", direction="backward", allow_exact_matches=True)
    return merged[column].to_numpy(dtype=float)


def rtamt_robustness(text, signals, step):
    spec = rtamt.StlDiscreteTimeSpecification()
    for name in signals:
        spec.declare_var(name, "float")
    spec.spec = text
    spec.set_sampling_period(int(round(step * 1e9)), "ns", 0.1)
    spec.parse()
    n = len(next(iter(signals.values())))
    dataset = {"time": [i * step for i in range(n)]}
    dataset.update({name: list(values) for name, values in signals.items()})
    return spec.evaluate(dataset)[0][1]


@pytest.mark.parametrize("path", [GAMMA_M, BICYCLE])
def test_requirements_against_rtamt_on_the_logs_signals(tmp_path, path):
    log = str(tmp_path / "run.mcap")
    require = {name: f for name, (f, _, _) in FORMULAS.items()}
    # 6 s: past the obstacle's appearance (2.75 s) and bicycle_obstacle's collision (3.68 s).
    result = mjsafe.run(path, out=log, require=require, set={"duration": 6.0})
    reported = result.metrics["req"]
    assert set(reported) == set(FORMULAS)
    tables = result.tables()
    step = float(np.median(np.diff(tables["/state"]["time"])))
    assert step == pytest.approx(0.002)
    for name, (_, text, columns) in FORMULAS.items():
        signals = {var: signal(tables, topic, column) for var, (topic, column) in columns.items()}
        assert all(not np.isnan(v).any() for v in signals.values()), name
        expected = rtamt_robustness(text, signals, step)
        assert reported[name] == pytest.approx(expected, abs=1e-9), name
    # Not all trivially satisfied or violated: the formulas tell the runs apart.
    assert min(reported.values()) < 0 < max(reported.values())


def test_online_analysis_is_the_logs_analysis(tmp_path):
    # Without a log, the run is analysed in memory as it goes (bounded formulas monitored
    # online); `analyze` of the log evaluates the same requirements from the file.
    require = {name: f for name, (f, _, _) in FORMULAS.items()}
    require["offline_only"] = "eventually[0, 5] always speed > 2.9"
    in_memory = mjsafe.run(GAMMA_M, require=require)
    logged = mjsafe.run(GAMMA_M, require=require, out=str(tmp_path / "run.mcap"))
    assert in_memory.metrics["req"] == logged.metrics["req"]
    assert mjsafe.read_log(logged.log).metrics["req"] == logged.metrics["req"]


def test_scenario_requirements_cli_gate_and_analyze_require(tmp_path):
    text = open(GAMMA_M).read().replace('../models/', str(scenario("../models")) + "/")
    text += '\n[[requirements]]\nname = "clear"\nformula = "always obstacle_0.h >= 0"\n'
    path = tmp_path / "with_requirement.toml"
    path.write_text(text)
    log = tmp_path / "run.mcap"
    done = cli("run", str(path), "--out", str(log), "--fail-on-violation")
    assert "requirement clear: satisfied" in done.stdout
    # The log carries the requirement: analyze evaluates it again, and --require adds one.
    out = cli("analyze", "--json", str(log), "--require", "slow=always speed < 3.2").stdout
    import json

    req = json.loads(out)[0]["req"]
    assert set(req) == {"clear", "slow"} and req["clear"] > 0 and req["slow"] > 0
    # Exit 5 on a violation, 1 when it cannot be evaluated.
    violated = cli("run", str(path), "--out", str(tmp_path / "v.mcap"), "--require", "fast=eventually[0,5] speed > 3.5",
                   "--fail-on-violation", ok=False)
    assert violated.returncode == 5, violated.stderr
    # It never went faster than 3.5 m/s within [0, 5] s: certain when the window closed.
    assert "violated: fast (-0.5000 at t = 5.000 s)" in violated.stderr
    unknown = cli("run", str(path), "--out", str(tmp_path / "u.mcap"), "--require", "typo=always speeed > 0",
                  "--fail-on-violation", ok=False)
    assert unknown.returncode == 1 and "unknown signal `speeed`" in unknown.stderr


@pytest.mark.parametrize(
    "flag, message",
    [
        ("no_equals", "expected NAME=FORMULA"),
        ("bad name=always x1 > 0", "expected a name of 1 to 64 letters"),
        ("n=always[0,3 x1 > 0", "column 12: expected `]`"),
        ("n=always[0, 0.0031] x1 > 0", "is not a whole number of steps of 0.002 s"),
    ],
)
def test_bad_requirements_are_one_line_errors(flag, message):
    line = cli_error("run", GAMMA_M, "--require", flag)
    assert message in line and "\n" not in line


def test_ambiguous_and_unknown_signals_are_refused_before_the_run():
    # Checked on a short run before the run itself (issue "first hour"): an ambiguous or unknown
    # signal is one error naming the requirement and the signal, not an absent value afterwards.
    with pytest.raises(ValueError, match=r"requirement `t`: signal `time` is a column of several tables: write one of `/state.time`"):
        mjsafe.run(GAMMA_M, require={"t": "always time > -1"})
    with pytest.raises(ValueError, match=r"requirement `u`: unknown signal `nope`"):
        mjsafe.run(GAMMA_M, require={"u": "always nope > 0"})
    r = mjsafe.run(GAMMA_M, require={"q": "always /state.time > -1"})
    assert r.metrics["req"] == {"q": pytest.approx(1.0)}


def test_falsify_minimises_a_requirements_robustness(tmp_path):
    # The γm bicycle keeps h >= 0 at its own delays; a longer steering delay breaks it.
    found = mjsafe.falsify(
        GAMMA_M,
        ranges={"delays.steering": (0.2, 1.0, 0.01)},  # whole multiples of the 2 ms step
        objective="req.clear",
        require={"clear": "always obstacle_0.h >= 0"},
        budget=24,
        seed=1,
        threads=1,
        out=str(tmp_path / "search"),
    )
    assert found.counterexamples, found.evaluations
    own = mjsafe.read_log(found.log).metrics["req"]["clear"]
    assert own < 0 and own == pytest.approx(found.reproduced)
    # What the search cost: its runs, and on one thread its own work beside them.
    assert found.threads == 1 and found.run_seconds > 0
    assert found.own_seconds == max(found.wall_seconds - found.run_seconds, 0.0)


def test_sweep_reports_each_requirement_as_a_column():
    summary = mjsafe.sweep(
        GAMMA_M,
        grid={"delays.steering": [0.2, 0.6]},
        set={"duration": 6.0},
        require={"clear": "always obstacle_0.h >= 0"},
    )
    assert list(summary["delays.steering"]) == [0.2, 0.6]
    # Each row's req.clear is the robustness of that run alone.
    for steering, value in zip(summary["delays.steering"], summary["req.clear"]):
        alone = mjsafe.run(GAMMA_M, set={"duration": 6.0, "delays.steering": steering}, require={"clear": "always obstacle_0.h >= 0"})
        assert value == alone.metrics["req"]["clear"]
        assert value == pytest.approx(alone.metrics["min_h"], abs=1e-12)  # always h >= 0 is min h


def test_a_violated_requirement_says_when_it_first_failed(tmp_path):
    """`req_violated_at`: for `always h >= 0`, the first sample at which h < 0 — found here in
    the log's /barrier table with pandas, and the collision MuJoCo's contacts report (the
    circles' h < 0 is the hulls' contact); for `eventually[0, 2] ψ` never met, 2 s; a
    satisfied requirement has none, with its reason."""
    r = mjsafe.run(BICYCLE, tables=True, require={
        "clear": "always obstacle_0.h >= 0", "quick": "eventually[0, 2] speed > 10", "slow": "always speed < 100"})
    barrier = r.tables()["/barrier"]
    first = barrier.loc[barrier["obstacle_0.h"] < 0, "time"].iloc[0]
    at = r.metrics["req_violated_at"]
    assert at["clear"] == pytest.approx(first, abs=1e-9)
    assert at["clear"] == pytest.approx(r.collision["time"], abs=2e-3)
    assert at["quick"] == pytest.approx(2.0, abs=1e-9)
    assert "slow" not in at and r.metrics["missing"]["req_violated_at.slow"] == "not violated (ρ ≥ 0)"
    shell = cli("run", BICYCLE, "--out", str(tmp_path / "r.mcap"), "--require", "clear=always obstacle_0.h >= 0").stdout
    assert f"requirement clear: VIOLATED at t = {first:.3f} s" in shell, shell
