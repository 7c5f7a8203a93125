"""mjsafe.scorecard: the command line's scorecard as a DataFrame, equal to `mjsafe scorecard`'s
scorecard.json; a filter registered from Python scored like a built-in; bad arguments."""

import json

import pandas as pd
import pytest

import mjsafe
from conftest import ROOT, cli

QUICK = str(ROOT / "suites" / "quick.toml")


class PassThrough:
    """No filter at all, written in Python: the nominal goes through unchanged."""

    label = "Python pass-through"

    def __init__(self, params):
        self.barrier_form = {"l0": 4.0, "l1": 4.0}
        self.uses_prediction = False

    def filter_channel(self, t, channel, state, nominal, constraints):
        return float(nominal[channel])


def test_the_frame_equals_the_command_lines_scorecard(tmp_path):
    frame = mjsafe.scorecard(["gamma_m", {"kind": "none"}], suite=QUICK, out=tmp_path / "py")
    cli("scorecard", "--suite", QUICK, "--filter", "gamma_m", "--filter", '{ kind = "none" }',
        "--out", str(tmp_path / "cli"))
    ours = frame.attrs["scorecard"]
    theirs = json.loads((tmp_path / "cli" / "scorecard.json").read_text())
    assert (tmp_path / "py" / "report.html").is_file()
    assert len(frame) == 2 * len(theirs["items"])
    for item in theirs["items"]:
        for column, cell in enumerate(item["cells"]):
            row = frame[(frame["item"] == item["name"]) & (frame["filter"] == theirs["filters"][column]["name"])]
            assert len(row) == 1
            assert row["status"].iloc[0] == cell["status"]
            assert row["detail"].iloc[0] == cell["detail"]
            if cell.get("score") is not None:
                assert row["score"].iloc[0] == cell["score"]
    assert ours["ncap"] == theirs["ncap"] and ours["overall"] == theirs["overall"]
    # The command line's layout.
    table = frame.pivot(index="item", columns="filter", values="status")
    assert table.loc["bicycle_obstacle", "gamma_m"] == "pass"
    assert table.loc["bicycle_obstacle", '{ kind = "none" }'] == "fail"


def test_a_python_filter_is_scored_like_the_built_in_it_equals():
    mjsafe.register_filter("py_pass_through", PassThrough)
    frame = mjsafe.scorecard([{"kind": "py_pass_through"}, {"kind": "none"}], suite=QUICK, threads=2)
    card = frame.attrs["scorecard"]
    assert card["filters"][0]["label"] == "Python pass-through"
    python, built_in = frame.iloc[0::2].reset_index(drop=True), frame.iloc[1::2].reset_index(drop=True)
    for column in ["status", "score", "figure_value"]:
        pd.testing.assert_series_equal(python[column], built_in[column], check_names=False)
    # Euro NCAP: the same colours point by point (the nominal hits the CCRs target).
    for item in card["items"]:
        colours = [[p["colour"] for p in cell.get("points", [])] for cell in item["cells"]]
        assert colours[0] == colours[1], item["name"]
    assert "fail" in python["status"].tolist()


def test_bad_arguments_are_one_clear_error():
    with pytest.raises(TypeError, match="filters"):
        mjsafe.scorecard("gamma_m", suite=QUICK)
    with pytest.raises(ValueError, match="keep_logs"):
        mjsafe.scorecard(["gamma_m"], suite=QUICK, keep_logs="some")
    with pytest.raises(ValueError, match="expected a preset of"):
        mjsafe.scorecard(["no_such_preset"], suite=QUICK)
    with pytest.raises(ValueError, match="nope.toml"):
        mjsafe.scorecard(["gamma_m"], suite="nope.toml")
