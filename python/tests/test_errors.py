"""Bad argument values raise ValueError with the command line's own error line (the text after
`error: `), checked against the `mjsafe` binary for each function; arguments of the wrong
Python type raise TypeError naming the argument and the type it must be."""

import re

import pytest

import mjsafe
from conftest import ROOT, cli_error, scenario

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
    same_error(lambda: mjsafe.falsify(BICYCLE, ranges=ranges, counterexamples=101),
               "falsify", BICYCLE, "--range", "delays.steering=0.0..0.3", "--counterexamples", "101", "--out", out)
    with pytest.raises(ValueError, match=r"falsify: method: expected one of guided, cmaes, random, found \"annealing\""):
        mjsafe.falsify(BICYCLE, ranges=ranges, method="annealing")


def test_a_range_of_the_wrong_length_is_a_value_error():
    with pytest.raises(ValueError, match=r'ranges\["delays.steering"\]: expected \(lo, hi\) or \(lo, hi, step\)'):
        mjsafe.falsify(BICYCLE, ranges={"delays.steering": (0.0,)})
    with pytest.raises(ValueError, match=r"expected \(lo, hi\) or \(lo, hi, step\)"):
        mjsafe.sweep(BICYCLE, random={"delays.steering": [0.0, 0.1, 0.2, 0.3]}, draws=1)


def test_negative_or_too_large_counts_are_value_errors():
    with pytest.raises(ValueError, match=r"sweep\(\): argument 'draws' must be an integer in 0..=2\^64 - 1, found -1"):
        mjsafe.sweep(BICYCLE, random={"delays.steering": (0.0, 0.4)}, draws=-1)
    with pytest.raises(ValueError, match=r"argument 'seed'"):
        mjsafe.sweep(BICYCLE, grid={"delays.steering": [0.1]}, seed=2**64)
    with pytest.raises(ValueError, match=r"argument 'threads'"):
        mjsafe.sweep(BICYCLE, grid={"delays.steering": [0.1]}, threads=-2)
    with pytest.raises(ValueError, match=r"falsify\(\): argument 'budget'"):
        mjsafe.falsify(BICYCLE, ranges={"delays.steering": (0.0, 0.3)}, budget=-5)


class Passes:
    barrier_form = None

    def __init__(self, params):
        pass

    def filter_channel(self, t, channel, state, nominal, constraints):
        return None

    def input(self, t, state):
        return [0.0, 0.0]


RANGES = {"delays.steering": (0.0, 0.3)}

# (call, the start of the TypeError's message): a wrong Python type names the argument and the
# type it must be, for every function of the package.
WRONG_TYPES = [
    (lambda: mjsafe.run(123), "run(): argument 'path' must be a str or os.PathLike, not int"),
    (lambda: mjsafe.run(BICYCLE, set=[1, 2]), "run(): argument 'set' must be a dict of dotted keys to values or None, not list"),
    (lambda: mjsafe.run(BICYCLE, set=["delays.steering=0.1"]), "run(): argument 'set' must be a dict"),
    (lambda: mjsafe.run(BICYCLE, set={"duration": None}), 'set["duration"]: a NoneType has no TOML value'),
    (lambda: mjsafe.run(BICYCLE, set={"filter": {"kind": object()}}), 'set["filter"]["kind"]: a object has no TOML value'),
    (lambda: mjsafe.run(BICYCLE, set={1: 2}), "set: a key is a dotted str"),
    (lambda: mjsafe.run(BICYCLE, out=7), "run(): argument 'out' must be a str or os.PathLike or None, not int"),
    (lambda: mjsafe.run(BICYCLE, tables="yes"), "run(): argument 'tables' must be a bool, not str"),
    (lambda: mjsafe.sweep(None), "sweep(): argument 'path' must be a str or os.PathLike, not NoneType"),
    (lambda: mjsafe.sweep(BICYCLE, draws="x"), "sweep(): argument 'draws' must be an int, not str"),
    (lambda: mjsafe.sweep(BICYCLE, draws=2.0), "sweep(): argument 'draws' must be an int, not float"),
    (lambda: mjsafe.sweep(BICYCLE, seed=True), "sweep(): argument 'seed' must be an int, not bool"),
    (lambda: mjsafe.sweep(BICYCLE, threads="2"), "sweep(): argument 'threads' must be an int or None, not str"),
    (lambda: mjsafe.sweep(BICYCLE, grid=[("delays.steering", [0.1])]), "sweep(): argument 'grid' must be a dict of dotted keys to lists of values or None, not list"),
    (lambda: mjsafe.sweep(BICYCLE, grid={"delays.steering": 0.1}), 'grid["delays.steering"]: expected a list of values, not a float'),
    (lambda: mjsafe.sweep(BICYCLE, random={"delays.steering": "0..1"}, draws=1), 'random["delays.steering"]: expected (lo, hi) or (lo, hi, step) of numbers'),
    (lambda: mjsafe.sweep(BICYCLE, random={"delays.steering": ("a", "b")}, draws=1), 'random["delays.steering"]: expected (lo, hi)'),
    (lambda: mjsafe.sweep(BICYCLE, random=(0.0, 1.0)), "sweep(): argument 'random' must be a dict of dotted keys to (lo, hi) or (lo, hi, step) or None, not tuple"),
    (lambda: mjsafe.sweep(BICYCLE, set="delays.steering=0.1"), "sweep(): argument 'set' must be a dict"),
    (lambda: mjsafe.sweep(BICYCLE, grid={"delays.steering": [0.1]}, out=1.5), "sweep(): argument 'out' must be a str or os.PathLike or None, not float"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=None), "falsify(): argument 'ranges' must be a dict of dotted keys to (lo, hi) or (lo, hi, step), not NoneType"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=[("delays.steering", (0.0, 0.3))]), "falsify(): argument 'ranges' must be a dict"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, budget="many"), "falsify(): argument 'budget' must be an int, not str"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, seed=1.0), "falsify(): argument 'seed' must be an int, not float"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, objective=3), "falsify(): argument 'objective' must be a str, not int"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, threshold="0"), "falsify(): argument 'threshold' must be a real number (int or float), not str"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, worst=1), "falsify(): argument 'worst' must be a bool, not int"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, baseline=["gamma_m"]), "falsify(): argument 'baseline' must be a dict"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, baseline={"filter": None}), 'baseline["filter"]: a NoneType has no TOML value'),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, set=[1, 2]), "falsify(): argument 'set' must be a dict"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, baseline_threshold=None), "falsify(): argument 'baseline_threshold' must be a real number"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, compare_random="no"), "falsify(): argument 'compare_random' must be a bool, not str"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, threads=[2]), "falsify(): argument 'threads' must be an int or None, not list"),
    (lambda: mjsafe.falsify(BICYCLE, ranges=RANGES, out=0), "falsify(): argument 'out' must be a str or os.PathLike or None, not int"),
    (lambda: mjsafe.read_log(None), "read_log(): argument 'path' must be a str or os.PathLike, not NoneType"),
    (lambda: mjsafe.read_log(3.5), "read_log(): argument 'path' must be a str or os.PathLike, not float"),
    (lambda: mjsafe.register_filter(3, Passes), "register_filter(): argument 'kind' must be a str, not int"),
    (lambda: mjsafe.register_filter("passes", Passes({})), "register_filter(): argument 'cls' must be a class, not Passes"),
    (lambda: mjsafe.register_filter("passes", object), "register_filter: expected a class with a method filter_channel"),
    (lambda: mjsafe.register_filter("passes", type("Labelled", (Passes,), {"label": 3})), "register_filter: expected `label` to be a str"),
    (lambda: mjsafe.register_nominal(b"passes", Passes), "register_nominal(): argument 'kind' must be a str, not bytes"),
    (lambda: mjsafe.register_nominal("passes", "Passes"), "register_nominal(): argument 'cls' must be a class, not str"),
    (lambda: mjsafe.register_nominal("passes", object), "register_nominal: expected a class with a method input"),
    (lambda: mjsafe.toml_value(None), "value: a NoneType has no TOML value"),
    (lambda: mjsafe.toml_value({"a": {1, 2}}), 'value["a"]: a set has no TOML value'),
]


@pytest.mark.parametrize("call, message", WRONG_TYPES, ids=[m[:60] for _, m in WRONG_TYPES])
def test_an_argument_of_the_wrong_type_is_a_type_error(call, message):
    with pytest.raises(TypeError) as raised:
        call()
    assert str(raised.value).startswith(message), str(raised.value)
    assert "\n" not in str(raised.value)


def test_a_right_type_with_a_bad_value_is_a_value_error_with_the_cli_s_line(tmp_path):
    # (run, sweep, falsify and read_log: above.) A range's unknown key: the command line's
    # own error line.
    same_error(lambda: mjsafe.falsify(BICYCLE, ranges={"nope": (0.0, 1.0)}),
               "falsify", BICYCLE, "--range", "nope=0.0..1.0", "--out", str(tmp_path / "never"))
    with pytest.raises(ValueError, match="letters, digits"):
        mjsafe.register_nominal("no-dashes", Passes)


def test_a_mujoco_error_ends_the_run_not_the_interpreter():
    """MuJoCo raising an error inside a step (tests/data/pebbles.xml: contacts overflow its
    stack at t ≈ 6.3 s) used to end the process; now the run stops with MuJoCo's message, and
    the interpreter, the next run and a sweep's other runs go on."""
    path = str(ROOT / "tests" / "data" / "mujoco_error.toml")
    stopped = mjsafe.run(path)
    assert stopped.error is not None and "MuJoCo stopped the step" in stopped.error and "Stack overflow" in stopped.error
    assert stopped.metrics["complete"] is False and 6.0 < stopped.simulated_time < 6.6
    clear = mjsafe.run(path, set={"vehicle.initial_state.1": 30.0})
    assert clear.error is None and clear.simulated_time == 8.0
    summary = mjsafe.sweep(path, grid={"vehicle.initial_state.1": [30.0, 0.0, -30.0]}, threads=2)
    assert summary["error"].isna().tolist() == [True, False, True]
    assert "Stack overflow" in summary["error"][1]
