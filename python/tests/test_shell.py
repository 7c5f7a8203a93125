"""Python filters from the shell (`python -m mjsafe --load FILE …`, issue "first hour"): the
mjsafe command line in a Python process that loaded the user's module, so that a filter
written in Python goes everywhere a built-in goes — run, sweep files, falsify and the replay of
its counterexample — and a file that needs a Python kind says what to load."""

import json
import subprocess
import sys
import textwrap

import pandas as pd
import pytest

import mjsafe
from conftest import ROOT, cli, scenario

MODULE = textwrap.dedent('''
    import mjsafe


    class ShellCbfQp:
        """(4.9) in numpy: one projection per constraint a + b·u >= 0 (one constraint here)."""

        label = "shell CBF-QP (4.9)"

        def __init__(self, params):
            self.barrier_form = {"l0": params["l0"], "l1": params["l1"]}
            self.uses_prediction = False

        def filter_channel(self, t, channel, state, nominal, constraints):
            u = nominal.copy()
            for a, b in constraints:
                mu = a + b @ u
                if mu < 0 and b @ b > 0:
                    u = u - mu / (b @ b) * b
            return float(u[channel])


    mjsafe.register_filter("shell_cbf_qp", ShellCbfQp)
''')

FILTER = 'filter={kind="shell_cbf_qp", l0=4.0, l1=4.0}'


def shell(*args, ok=True):
    done = subprocess.run([sys.executable, "-m", "mjsafe", *args], cwd=ROOT, capture_output=True, text=True)
    if ok:
        assert done.returncode == 0, done.stderr
    return done


@pytest.fixture()
def module(tmp_path):
    path = tmp_path / "my_filters.py"
    path.write_text(MODULE)
    return str(path)


def test_a_python_filter_runs_from_the_shell_like_the_built_in(module, tmp_path):
    ours = shell("--load", module, "run", scenario("bicycle_obstacle.toml"), "--set", FILTER, "--json",
                 "--out", str(tmp_path / "a.mcap"))
    built_in = cli("run", scenario("bicycle_obstacle.toml"), "--set", 'filter={kind="cbf_qp", l0=4.0, l1=4.0}',
                   "--json", "--out", str(tmp_path / "b.mcap"))
    a, b = json.loads(ours.stdout), json.loads(built_in.stdout)
    assert a["min_h"] == pytest.approx(b["min_h"], abs=1e-9)
    assert a["collision"]["time"] == b["collision"]["time"]
    # Without the module the kind is unknown, as it is to the binary.
    missing = shell("run", scenario("bicycle_obstacle.toml"), "--set", FILTER, ok=False)
    assert missing.returncode == 1 and "unknown kind `shell_cbf_qp`" in missing.stderr


def test_a_counterexample_of_a_python_filter_replays_from_the_shell(module, tmp_path):
    mjsafe.register_filter("shell_cbf_qp", _load(module).ShellCbfQp)
    found = mjsafe.falsify(scenario("bicycle_obstacle_gamma_m.toml"), ranges={"delays.acceleration": (0.5, 2.0, 0.1)},
                           set={"filter": {"kind": "shell_cbf_qp", "l0": 4.0, "l1": 4.0}}, budget=8, seed=1,
                           out=str(tmp_path / "f"))
    assert found.counterexamples
    counterexample = str(tmp_path / "f" / "counterexample.toml")
    text = open(counterexample).read()
    assert f"# mjsafe-load: {module}" in text
    # The binary alone says exactly what to load; the shell with the module replays it.
    plain = cli("run", counterexample, ok=False)
    assert plain.returncode == 1
    assert f"python -m mjsafe --load {module} run" in plain.stderr, plain.stderr
    replay = shell("--load", module, "run", counterexample, "--json", "--out", str(tmp_path / "r.mcap"))
    assert json.loads(replay.stdout)["min_h"] == pytest.approx(found.reproduced, abs=1e-12)


def test_a_sweep_file_over_a_python_filter_gives_one_summary_from_the_shell_and_from_python(module, tmp_path):
    sweep_file = tmp_path / "python.sweep.toml"
    sweep_file.write_text(textwrap.dedent(f'''
        scenario = "{scenario("bicycle_obstacle.toml")}"
        set = ['{FILTER}', "duration=6.0"]
        [[grid]]
        key = "delays.steering"
        values = [0.0, 0.1]
        with = [{{ key = "delays.acceleration", values = [0.0, 0.2] }}]
    '''))
    shell("--load", module, "sweep", "--sweep", str(sweep_file), "--out", str(tmp_path / "s"), "--no-logs")
    from_shell = pd.read_csv(tmp_path / "s" / "summary.csv")
    # The summary records which file defined the Python kind it sweeps.
    assert json.loads((tmp_path / "s" / "summary.json").read_text())["python_kinds"] == {"shell_cbf_qp": module}
    mjsafe.register_filter("shell_cbf_qp", _load(module).ShellCbfQp)
    from_python = mjsafe.sweep(sweep_file=str(sweep_file))
    assert len(from_shell) == len(from_python) == 2
    for column in ["delays.steering", "min_h", "collision_time", "filter_active_fraction"]:
        assert from_shell[column].tolist() == pytest.approx(from_python[column].tolist(), nan_ok=True), column


def _load(path):
    import runpy
    return type("Module", (), runpy.run_path(path))
