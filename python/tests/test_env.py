"""mjsafe.Env, an episode stepped tick by tick: the same loop as mjsafe.run (the same log bytes,
the same metrics), the action as the nominal input through the filter and the delays, the
queues and barriers it shows against the log, Gymnasium's own environment checker, and its
errors."""

import math
import os
import warnings

import numpy as np
import pytest

import mjsafe
from conftest import scenario

BICYCLE = scenario("bicycle_obstacle.toml")


def drive(env, action=None):
    """Steps `env` to the end of its episode; returns the list of (obs, reward, terminated,
    truncated, info) of every step."""
    steps = []
    while True:
        step = env.step(action)
        steps.append(step)
        if step[2] or step[3]:
            return steps


def test_observed_episode_writes_the_log_mjsafe_run_writes(tmp_path):
    # drive=False: the scenario's own nominal, the episode only observed between ticks. Its log
    # is byte for byte the log of the same run made in one go.
    short = {"duration": 4.0, "delays.steering": 0.3}
    env = mjsafe.Env(BICYCLE, set=short, out=tmp_path, drive=False, terminate_on_collision=False)
    obs, info = env.reset()
    assert obs.tolist() == [-20.0, 0.0, 0.0, 3.0] and info["time"] == 0.0
    steps = drive(env)
    assert steps[-1][3] and not steps[-1][2], "ends truncated at the scenario's duration"
    assert steps[-1][4]["time"] == pytest.approx(4.0)
    assert len(steps) == 400  # a 0.01 s control period over 4 s
    stepped = tmp_path / "episode-0.mcap"
    whole = mjsafe.run(BICYCLE, set=short, out=str(tmp_path / "whole.mcap"))
    assert stepped.read_bytes() == (tmp_path / "whole.mcap").read_bytes()
    assert env.result.metrics == {**whole.metrics, "file": str(stepped)}
    # The observation is the plant's state: the last is the log's final state.
    final = whole.tables()["/state"].iloc[-1]
    assert steps[-1][0].tolist() == [final[n] for n in env.state_names]


def test_action_is_the_nominal_through_filter_and_delays():
    # A constant action is the `constant` nominal: the same run, the same metrics.
    u0 = [0.05, 0.2]
    short = {"duration": 5.0}
    env = mjsafe.Env(BICYCLE, set=short, terminate_on_collision=False)
    env.reset()
    steps = drive(env, np.array(u0))
    reference = mjsafe.run(BICYCLE, set={**short, "nominal": {"kind": "constant", "input": u0}}, tables=True)
    for key in ["min_h", "min_clearance", "collision", "filter_active_fraction", "max_correction"]:
        assert env.result.metrics.get(key) == reference.metrics.get(key), key
    # What the tick issued: u0 as the nominal, the filter's command as filtered.
    issued = reference.tables()["/command/issued"]
    for obs, _, _, _, info in steps[:-1]:
        row = issued[np.isclose(issued["time"], info["time"] - 0.01)]
        assert info["issued"]["nominal"] == u0
        assert info["issued"]["filtered"] == [row["steering.filtered"].item(), row["acceleration.filtered"].item()]


def test_queues_and_barriers_are_what_the_log_holds(tmp_path):
    delays = {"delays.steering": 0.3, "delays.acceleration": 0.5, "duration": 3.0}
    env = mjsafe.Env(BICYCLE, set=delays, out=tmp_path, terminate_on_collision=False)
    env.reset()
    seen, observed = [], []
    for _ in range(250):
        obs, _, terminated, truncated, info = env.step([0.0, 0.1])
        observed.append(obs)
        queues = env.queues()
        assert [q["channel"] for q in queues] == env.channels
        assert [q["delay"] for q in queues] == [pytest.approx(0.3, abs=1e-12), pytest.approx(0.5, abs=1e-12)]
        # The last command issued is the tick's filtered command, at the tick's time.
        for q, filtered in zip(queues, info["issued"]["filtered"]):
            assert q["issued"][-1] == (pytest.approx(info["issued"]["time"]), filtered)
        seen.append((info["time"], {name: b["h"] for name, b in info["barriers"].items()}))
        assert env.barriers() == seen[-1][1]
    env.close()
    barrier = env.result.tables()["/barrier"]
    assert len(seen) > 200
    for time, h in seen[:-1]:
        # The log's /barrier of step k is evaluated at x(t_k): the state observed at t_k (the
        # last state, where the episode was ended, starts no step).
        row = barrier[np.isclose(barrier["time"], time, atol=1e-9)]
        assert len(row) == 1, time
        assert h["obstacle_0"] == row["obstacle_0.h"].item()
    # The obstacle's h, independently: |p - c|^2 - r^2 of (4.81), with r = 3 (hull) + 3
    # (obstacle) and c = (-3, 0.5) as scenarios/bicycle_obstacle.toml has them.
    for obs, h in zip(observed, (h for _, h in seen)):
        assert h["obstacle_0"] == pytest.approx((obs[0] + 3.0) ** 2 + (obs[1] - 0.5) ** 2 - 36.0, abs=1e-9)


def test_collision_terminates_with_a_cost():
    # Straight on at 3 m/s under the delay-compensation-free filter with 0.4 s of steering delay.
    env = mjsafe.Env(BICYCLE, set={"delays.steering": 0.4})
    env.reset()
    steps = drive(env, [0.0, 0.0])
    obs, reward, terminated, truncated, info = steps[-1]
    assert terminated and not truncated
    assert info["cost"] == 1.0 and sum(s[4]["cost"] for s in steps) == 1.0
    assert [e["kind"] for e in info["events"]] == ["collision_start"]
    collision = env.result.collision
    assert collision is not None and collision["with"] == "obstacle_0"
    assert info["time"] - 0.01 <= collision["time"] <= info["time"]
    # The log ends where the episode did, and says so.
    assert env.result.metrics["complete"] is True
    assert env.result.simulated_time == pytest.approx(info["time"])
    # The default reward is the progress toward the goal (m) in the step.
    distances = [s[4]["distance_to_goal"] for s in steps]
    assert [s[1] for s in steps[1:]] == pytest.approx(-np.diff(distances))
    with pytest.raises(RuntimeError, match="reset"):
        env.step([0.0, 0.0])


def test_goal_reached_terminates():
    # gamma_m (Table 4.1) passes the obstacle; the scenario's path-tracking nominal drives.
    env = mjsafe.Env(scenario("bicycle_obstacle_gamma_m.toml"), drive=False)
    env.reset()
    steps = drive(env)
    info = steps[-1][4]
    assert steps[-1][2] and info["distance_to_goal"] <= env.goal_radius
    assert sum(s[4]["cost"] for s in steps) == 0.0
    time_to_goal = mjsafe.run(scenario("bicycle_obstacle_gamma_m.toml")).metrics["time_to_goal"]
    assert info["time"] == pytest.approx(time_to_goal, abs=0.01 + 1e-9)


def test_seed_reproduces_and_changes_the_episode():
    # The noise reaches the plant once the filter acts on the obstacle (known from 2.75 s).
    noisy = {"sensing": {"noise_std": [0.2, 0.2, 0.02, 0.1]}, "duration": 4.0}
    env = mjsafe.Env(BICYCLE, set=noisy)

    def states(seed):
        env.reset(seed=seed)
        return np.array([s[0] for s in drive(env, [0.0, 0.0])[:300]])

    a, b, c = states(1), states(1), states(2)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_gymnasium_env_checker_passes():
    gymnasium = pytest.importorskip("gymnasium")
    from gymnasium.utils.env_checker import check_env

    env = mjsafe.Env(BICYCLE)
    assert isinstance(env, gymnasium.Env)
    assert env.observation_space.shape == (4,) and env.action_space.shape == (2,)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded spaces: the model's inputs have no limits
        check_env(env, skip_render_check=True)


def test_reward_callable_and_errors():
    seen = []
    env = mjsafe.Env(scenario("unicycle_tv_delay.toml"), reward=lambda obs, info: seen.append(info["time"]) or -obs[0] ** 2)
    obs, _ = env.reset()
    obs, reward, *_ = env.step([0.0, 0.0])
    assert reward == -obs[0] ** 2 and len(seen) == 1 and seen[0] > 0
    with pytest.raises(ValueError, match="expected 2 values"):
        env.step([1.0])
    with pytest.raises(ValueError, match="finite"):
        env.step([math.nan, 0.0])
    with pytest.raises(ValueError, match="no \\[goal\\]"):
        mjsafe.Env(scenario("unicycle_tv_delay.toml"))
    with pytest.raises(TypeError, match="reward"):
        mjsafe.Env(BICYCLE, reward=3)
    with pytest.raises(ValueError, match="unknown"):
        mjsafe.Env(BICYCLE, set={"delays.stearing": 0.1})
    with pytest.raises(ValueError, match="not a directory"):
        mjsafe.Env(BICYCLE, out=os.path.join(BICYCLE, "nope"))
    with pytest.raises(RuntimeError, match="reset"):
        mjsafe.Env(BICYCLE).step([0.0, 0.0])


def test_python_filter_in_the_loop():
    # A Python filter and the Env together: the filter sees the agent's action as u0.
    class Clip:
        barrier_form = {"alpha": 1.0}
        uses_prediction = False

        def __init__(self, params):
            pass

        def filter_channel(self, t, channel, state, nominal, constraints):
            return float(np.clip(nominal[channel], -0.1, 0.1))

    mjsafe.register_filter("clip_env_test", Clip)
    env = mjsafe.Env(BICYCLE, set={"filter": {"kind": "clip_env_test"}, "duration": 1.0})
    env.reset()
    steps = drive(env, [0.5, -0.5])
    assert all(s[4]["issued"]["filtered"] == [0.1, -0.1] for s in steps)


def test_the_action_space_follows_the_vehicle_s_input_limits():
    """The car's steering input u1 = tan δ is bounded by its steering hinges (models/car.xml's
    range, read here with an XML parser); its acceleration and both bicycle inputs have no
    limit (±∞)."""
    import xml.etree.ElementTree as ET

    root = ET.parse(scenario("../models/car.xml")).getroot()
    ranges = {j.get("name"): [float(v) for v in j.get("range").split()] for j in root.iter("joint")
              if j.get("name", "").startswith("steer_")}
    steer = min(min(abs(lo), abs(hi)) for lo, hi in ranges.values())
    car = mjsafe.Env(scenario("car_obstacle_gamma_m.toml"), reward=lambda obs, info: 0.0)
    space = car.action_space
    assert space.low[0] == pytest.approx(-math.tan(steer), abs=1e-12) and space.high[0] == pytest.approx(math.tan(steer), abs=1e-12)
    assert space.low[1] == -np.inf and space.high[1] == np.inf
    bicycle = mjsafe.Env(scenario("bicycle_obstacle.toml"))
    assert np.isinf(bicycle.action_space.low).all() and np.isinf(bicycle.action_space.high).all()
    car.close(); bicycle.close()
