"""CommonRoad worlds from Python (docs/commonroad.md): a file runs as `mjsafe run FILE.xml`
does, `set=` overrides its defaults, and `sweep(scenarios=…)` runs a set, one row per file."""

import re

import pytest

import mjsafe
from conftest import ROOT

DATA = ROOT / "data" / "commonroad"


def test_a_commonroad_file_runs_with_overrides():
    r = mjsafe.run(DATA / "USA_US101-4_1_T-1.xml", set={"filter.kind": "none", "duration": 5.0})
    # The nominal alone runs into the car ahead in this jam (tests/commonroad.rs: with γm it does not).
    assert r.collision
    assert r.metrics["scenario"] == "USA_US101-4_1_T-1"


def test_sweep_over_scenarios_gives_one_row_per_file():
    files = sorted(DATA.glob("USA_*.xml"))
    table = mjsafe.sweep(scenarios=[str(DATA / "USA_*.xml")], set={"duration": 0.5})
    expected = sorted(re.search(r'benchmarkID="([^"]+)"', f.read_text()).group(1) for f in files)
    assert sorted(table["scenario"]) == expected
    assert list(table["commonroad.file"]) == [f'"{f.name}"' for f in files]


def test_bad_scenarios_are_one_clear_error():
    with pytest.raises(ValueError, match="names no file"):
        mjsafe.sweep(scenarios=[str(DATA / "*.nothing")])
    with pytest.raises(TypeError, match="scenarios"):
        mjsafe.sweep(scenarios=str(DATA / "a.xml"))


def test_env_steps_a_commonroad_world():
    # The default reward needs a goal disc; a CommonRoad goal is a region of polygons.
    with pytest.raises(ValueError, match="no \\[goal\\] disc"):
        mjsafe.Env(DATA / "ZAM_Tutorial-1_1_T-1.xml")
    np = pytest.importorskip("numpy")
    env = mjsafe.Env(DATA / "ZAM_Tutorial-1_1_T-1.xml", reward=lambda observation, info: 0.0)
    observation, _ = env.reset(seed=0)
    assert env.state_names == ["x1", "x2", "heading", "speed"]
    start = observation.copy()
    for _ in range(10):
        observation, _, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape))
    assert not terminated and not truncated
    # The planning problem's start moves at its speed (22 m/s) along x.
    assert observation[0] > start[0] + 1.0
