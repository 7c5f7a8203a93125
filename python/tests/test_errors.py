"""Bad arguments raise ValueError with the command line's own error line (the text after
`error: `), checked against the `mjsafe` binary for each function."""

import re

import pytest

import mjsafe
from conftest import cli_error, scenario

BICYCLE = scenario("bicycle_obstacle.toml")
MISSING = scenario("no_such_scenario.toml")


def same_error(call, *cli_args):
    with pytest.raises(ValueError) as raised:
        call()
    expected = cli_error(*cli_args)
    got = str(raised.value)
    # An unknown kind lists the known ones: in this process also the kinds registered from
    # Python (mjsafe.register_filter), after the built-ins the command line lists.
    if "unknown kind" in expected:
        assert got.startswith(expected) and re.fullmatch(r"(, `\w+`)*", got[len(expected):]), got
    else:
        assert got == expected
    assert "\n" not in expected
    return expected


@pytest.mark.parametrize("set_, flag", [
    ({"delays.nope": 0.4}, "delays.nope=0.4"),
    ({"nope": 1}, "nope=1"),
    ({"duration": "long"}, 'duration="long"'),
    ({"delays.steering": -0.1}, "delays.steering=-0.1"),
    ({"seed": 2**70}, f"seed={2**70}"),
    ({"filter": {"kind": "gamma_m", "l0": 4.0}}, 'filter={kind = "gamma_m", l0 = 4.0}'),
    ({"filter": {"kind": "no_such_filter"}}, 'filter={kind = "no_such_filter"}'),
    ({"obstacles.0.radius": [1, 2]}, "obstacles.0.radius=[1, 2]"),
])
def test_run_refuses_what_run_refuses(set_, flag):
    same_error(lambda: mjsafe.run(BICYCLE, set=set_), "run", BICYCLE, "--set", flag, "--out", "/tmp/never.mcap")


def test_a_missing_scenario_is_the_clis_error():
    message = same_error(lambda: mjsafe.run(MISSING), "run", MISSING)
    assert "no_such_scenario.toml" in message


def test_an_output_the_cli_refuses_is_refused(tmp_path):
    # Never over a file that is not a log (here the scenario itself).
    same_error(lambda: mjsafe.run(BICYCLE, out=BICYCLE), "run", BICYCLE, "--out", BICYCLE)
    text = tmp_path / "notes.txt"
    text.write_text("mine")
    same_error(lambda: mjsafe.run(BICYCLE, out=text), "run", BICYCLE, "--out", str(text))
    assert text.read_text() == "mine"


def test_read_log_refuses_what_analyze_refuses(tmp_path):
    same_error(lambda: mjsafe.read_log(BICYCLE), "analyze", BICYCLE)
    same_error(lambda: mjsafe.read_log(tmp_path / "none.mcap"), "analyze", str(tmp_path / "none.mcap"))


def test_sweep_refuses_what_sweep_refuses(tmp_path):
    out = str(tmp_path / "never")
    same_error(lambda: mjsafe.sweep(BICYCLE, grid={"delays.steering": [0.1, 0.2]}, set={"nope": 1}),
               "sweep", BICYCLE, "--grid", "delays.steering=0.1,0.2", "--set", "nope=1", "--no-logs", "--out", out)
    same_error(lambda: mjsafe.sweep(BICYCLE, random={"delays.steering": (0.0, 0.4)}),
               "sweep", BICYCLE, "--range", "delays.steering=0.0..0.4", "--no-logs", "--out", out)
    same_error(lambda: mjsafe.sweep(BICYCLE, random={"delays.steering": (0.4, 0.0)}, draws=2),
               "sweep", BICYCLE, "--range", "delays.steering=0.4..0.0", "--random", "2", "--no-logs", "--out", out)
    same_error(lambda: mjsafe.sweep(BICYCLE),
               "sweep", BICYCLE, "--no-logs", "--out", out)
    same_error(lambda: mjsafe.sweep(BICYCLE, grid={"delays.steering": [0.1]}, threads=0),
               "sweep", BICYCLE, "--grid", "delays.steering=0.1", "--threads", "0", "--no-logs", "--out", out)
    same_error(lambda: mjsafe.sweep(BICYCLE, grid={"delays.steering": [0.1], "delays.steering ": [0.2]}),
               "sweep", BICYCLE, "--grid", "delays.steering=0.1", "--grid", "delays.steering =0.2", "--no-logs",
               "--out", out)
    # An output directory that is a file.
    same_error(lambda: mjsafe.sweep(BICYCLE, grid={"delays.steering": [0.1]}, out=BICYCLE),
               "sweep", BICYCLE, "--grid", "delays.steering=0.1", "--out", BICYCLE)


def test_falsify_refuses_what_falsify_refuses(tmp_path):
    out = str(tmp_path / "never")
    ranges = {"delays.steering": (0.0, 0.3)}
    same_error(lambda: mjsafe.falsify(BICYCLE, ranges={"delays.steering": (0.3, 0.1)}),
               "falsify", BICYCLE, "--range", "delays.steering=0.3..0.1", "--out", out)
    same_error(lambda: mjsafe.falsify(BICYCLE, ranges=ranges, objective="min_hh"),
               "falsify", BICYCLE, "--range", "delays.steering=0.0..0.3", "--objective", "min_hh", "--out", out)
    same_error(lambda: mjsafe.falsify(BICYCLE, ranges=ranges, threshold=float("nan")),
               "falsify", BICYCLE, "--range", "delays.steering=0.0..0.3", "--threshold", "NaN", "--out", out)
    same_error(lambda: mjsafe.falsify(BICYCLE, ranges=ranges, baseline_no_stall=True),
               "falsify", BICYCLE, "--range", "delays.steering=0.0..0.3", "--baseline-no-stall", "--out", out)
    same_error(lambda: mjsafe.falsify(BICYCLE, ranges=ranges, baseline={"delays.brake": 0.0}),
               "falsify", BICYCLE, "--range", "delays.steering=0.0..0.3", "--baseline", "delays.brake=0.0",
               "--out", out)
    same_error(lambda: mjsafe.falsify(BICYCLE, ranges=ranges, set={"nope": 1}),
               "falsify", BICYCLE, "--range", "delays.steering=0.0..0.3", "--set", "nope=1", "--out", out)
    same_error(lambda: mjsafe.falsify(BICYCLE, ranges=ranges, budget=0),
               "falsify", BICYCLE, "--range", "delays.steering=0.0..0.3", "--budget", "0", "--out", out)


def test_arguments_of_the_wrong_shape_are_value_errors():
    with pytest.raises(ValueError, match=r"expected \(lo, hi\) or \(lo, hi, step\)"):
        mjsafe.falsify(BICYCLE, ranges={"delays.steering": (0.0,)})
    with pytest.raises(ValueError, match="expected a list of values"):
        mjsafe.sweep(BICYCLE, grid={"delays.steering": 0.1})
    with pytest.raises(ValueError, match="expected a dict"):
        mjsafe.run(BICYCLE, set=["delays.steering=0.1"])
