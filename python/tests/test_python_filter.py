"""Safety filters written in Python (mjsafe.register_filter): the delay-free CBF-QP (4.9) in
numpy against the built-in `cbf_qp`, exceptions, bad classes, and a sweep of a Python kind."""

import subprocess
import sys

import numpy as np
import pytest

import mjsafe
from conftest import scenario


class DelayFreeCbfQp:
    """(4.9): min ‖u − u0‖² s.t. a_k + b_k·u ≥ 0, by an active-set search over the
    constraints (one or two here); component `channel` of the solution."""

    label = "numpy CBF-QP (4.9)"

    def __init__(self, params):
        self.barrier_form = {"l0": params["l0"], "l1": params["l1"]}
        self.uses_prediction = False

    def filter_channel(self, t, channel, state, nominal, constraints):
        if not constraints:
            return None
        u = nominal.copy()
        for a, b in constraints:
            mu = a + b @ u
            if mu < 0 and b @ b > 0:
                u = u - mu / (b @ b) * b
        return {"input": float(u[channel]), "active": bool(np.any(u != nominal)), "mu": float(constraints[0][0] + constraints[0][1] @ nominal)}


def test_a_numpy_cbf_qp_reproduces_the_built_in_min_h():
    mjsafe.register_filter("tested_numpy_cbf_qp", DelayFreeCbfQp)
    built_in = mjsafe.run(scenario("bicycle_obstacle.toml"))
    ours = mjsafe.run(scenario("bicycle_obstacle.toml"), set={"filter": {"kind": "tested_numpy_cbf_qp", "l0": 4.0, "l1": 4.0}})
    assert built_in.metrics["filter_label"] != ours.metrics["filter_label"]
    assert ours.metrics["filter_label"] == "numpy CBF-QP (4.9)"
    assert ours.error is None
    assert abs(ours.min_h - built_in.min_h) < 1e-9, (ours.min_h, built_in.min_h)
    assert ours.collision["time"] == built_in.collision["time"]


class Raises:
    barrier_form = {"alpha": 1.0}

    def __init__(self, params):
        self.after = params.get("after", 0.0)

    def filter_channel(self, t, channel, state, nominal, constraints):
        if t >= self.after:
            raise ZeroDivisionError("the filter divided by zero")
        return float(nominal[channel])


def test_an_exception_stops_the_run_with_its_type_and_message():
    mjsafe.register_filter("raises", Raises)
    r = mjsafe.run(scenario("bicycle_obstacle.toml"), set={"filter": {"kind": "raises", "after": 1.0}})
    assert r.error is not None and "ZeroDivisionError: the filter divided by zero" in r.error, r.error
    assert "raises" in r.error
    assert r.metrics["complete"] is False
    assert 0.99 <= r.simulated_time <= 1.02


def test_a_class_without_filter_channel_or_a_bad_kind_is_refused():
    class Nothing:
        pass

    # Not the protocol's type: TypeError; a kind of the right type but a bad value: ValueError.
    with pytest.raises(TypeError, match="filter_channel"):
        mjsafe.register_filter("nothing", Nothing)
    with pytest.raises(ValueError, match="letters, digits"):
        mjsafe.register_filter("bad kind", DelayFreeCbfQp)


def test_a_bad_barrier_form_or_return_value_is_one_clear_error():
    class BadForm(DelayFreeCbfQp):
        def __init__(self, params):
            self.barrier_form = {"l0": 5.0, "l1": 4.0}

    mjsafe.register_filter("bad_form", BadForm)
    with pytest.raises((ValueError, RuntimeError), match="l1"):
        mjsafe.run(scenario("bicycle_obstacle.toml"), set={"filter": {"kind": "bad_form"}})

    class Text(Raises):
        def filter_channel(self, t, channel, state, nominal, constraints):
            return "fast"

    mjsafe.register_filter("text", Text)
    r = mjsafe.run(scenario("bicycle_obstacle.toml"), set={"filter": {"kind": "text"}})
    assert r.error is not None and "expected a number" in r.error, r.error


def test_a_python_kind_sweeps_on_several_threads():
    mjsafe.register_filter("tested_numpy_cbf_qp", DelayFreeCbfQp)
    rows = mjsafe.sweep(
        scenario("bicycle_obstacle.toml"),
        grid={"delays.steering": [0.0, 0.1, 0.2]},
        set={"filter": {"kind": "tested_numpy_cbf_qp", "l0": 4.0, "l1": 4.0}},
        threads=2,
    )
    built = mjsafe.sweep(
        scenario("bicycle_obstacle.toml"),
        grid={"delays.steering": [0.0, 0.1, 0.2]},
        set={"filter": {"kind": "cbf_qp", "l0": 4.0, "l1": 4.0}},
        threads=2,
    )
    assert len(rows) == 3
    assert np.allclose(rows["min_h"].to_numpy(), built["min_h"].to_numpy(), rtol=0, atol=1e-9)


class Hold:
    """u0 = the scenario's `input`, one value per channel (the built-in `constant`)."""

    label = "held input"

    def __init__(self, params):
        self.u = [float(v) for v in params["input"]]

    def input(self, t, state):
        assert isinstance(state, np.ndarray) and state.shape == (4,)
        return self.u


def test_a_python_nominal_reproduces_the_built_in_constant_input():
    mjsafe.register_nominal("tested_hold", Hold)
    s = {"filter": {"kind": "gamma_m", "l0": 4.0, "l1": 4.0, "m": 50.0}}
    ours = mjsafe.run(scenario("bicycle_obstacle.toml"), set={**s, "nominal": {"kind": "tested_hold", "input": [0.05, 0.3]}})
    built_in = mjsafe.run(scenario("bicycle_obstacle.toml"), set={**s, "nominal": {"kind": "constant", "input": [0.05, 0.3]}})
    assert ours.error is None
    assert ours.min_h == built_in.min_h
    assert ours.collision == built_in.collision


class Broken(Hold):
    def input(self, t, state):
        if t > 0.5:
            raise KeyError("no such gain")
        return self.u[:1]


def test_a_python_nominal_s_exception_or_wrong_length_stops_the_run():
    mjsafe.register_nominal("broken", Broken)
    r = mjsafe.run(scenario("bicycle_obstacle.toml"), set={"nominal": {"kind": "broken", "input": [0.0, 0.0]}})
    assert r.error is not None and "returned 1 values: expected 2" in r.error, r.error
    assert r.simulated_time < 0.02

    class Late(Hold):
        def input(self, t, state):
            if t > 0.5:
                raise KeyError("no such gain")
            return self.u

    mjsafe.register_nominal("late", Late)
    r = mjsafe.run(scenario("bicycle_obstacle.toml"), set={"nominal": {"kind": "late", "input": [0.0, 0.0]}})
    assert r.error is not None and "KeyError: 'no such gain'" in r.error and "late" in r.error, r.error
    assert r.metrics["complete"] is False
    with pytest.raises(TypeError, match="input"):
        mjsafe.register_nominal("nothing", object)


class SeesQueues:
    """Passes the nominal, recording what the queues and the timestep said at each call."""

    barrier_form = {"alpha": 1.0}
    seen = []

    def __init__(self, params):
        pass

    def filter_channel(self, t, channel, state, nominal, constraints, *, queues, timestep):
        SeesQueues.seen.append((t, channel, [q["channel"] for q in queues], [q["delay"] for q in queues],
                                [q["issued"].copy() for q in queues], timestep))
        return float(nominal[channel])


def test_the_queues_and_the_timestep_reach_a_filter_that_takes_them():
    mjsafe.register_filter("sees_queues", SeesQueues)
    SeesQueues.seen.clear()
    r = mjsafe.run(scenario("bicycle_obstacle.toml"),
                   set={"filter": {"kind": "sees_queues"}, "duration": 1.0, "obstacles.0.appear_at": 0.0})
    assert r.error is None, r.error
    assert len(SeesQueues.seen) == 2 * 100    # two channels, 100 ticks of 10 ms
    t, channel, names, delays, issued, timestep = SeesQueues.seen[-1]
    assert names == ["steering", "acceleration"] and delays == [0.2, 1.5]
    # The commands issued before this tick that may still apply: every tick of the last
    # delay (the queue keeps back to t − D), as (issue time, value) rows.
    assert timestep == 0.002
    for queue, delay in zip(issued, delays):
        assert queue.ndim == 2 and queue.shape[1] == 2
        assert queue[-1, 0] < t and queue[0, 0] <= max(t - delay, 0.0) + 1e-9


class MarginQp:
    """Issues, at each channel's prediction, the CBF-QP with a margin: min ‖u − u0‖² s.t.
    a − margin + b·u ≥ 0 (a law other than the delay-free CBF-QP the predictors assume by
    default). No `issued_law`: the predictors assume the default law."""

    label = "numpy margin CBF-QP"

    def __init__(self, params):
        self.barrier_form = {"l0": 4.0, "l1": 4.0}
        self.uses_prediction = True
        self.margin = params["margin"]

    def law(self, nominal, constraints):
        u = nominal.copy()
        for a, b in constraints:
            mu = a - self.margin + b @ u
            if mu < 0 and b @ b > 0:
                u = u - mu / (b @ b) * b
        return u

    def filter_channel(self, t, channel, state, nominal, constraints):
        if not constraints:
            return None
        return float(self.law(nominal, constraints)[channel])


class MarginQpWithLaw(MarginQp):
    """The same filter, telling the predictors the law it issues."""

    calls = 0

    def issued_law(self, t, prediction_time, state, nominal, constraints, free, u):
        MarginQpWithLaw.calls += 1
        assert isinstance(u, np.ndarray) and u.shape == nominal.shape == (2,) and state.shape == (4,)
        assert prediction_time > t and list(free) == [0]     # steering, issued inside acceleration's window
        if not constraints:
            return None
        return self.law(nominal, constraints)[free]


def prediction_errors(r, since):
    """Per channel, the largest ‖predicted − realised‖ of the predictions issued from `since`."""
    p = r.tables()["/prediction"]
    p = p[p["issued_at"] >= since - 1e-9]
    names = [c.removeprefix("predicted.") for c in p.columns if c.startswith("predicted.")]
    error = np.sqrt(sum((p[f"predicted.{n}"] - p[f"realized.{n}"]) ** 2 for n in names))
    return {channel: float(e.max()) for channel, e in error.groupby(p["channel"])}


def test_the_predictors_assume_the_python_filter_s_issued_law():
    # (4.25): on the exact (ODE) plant a prediction is the state that follows only if the
    # predictors assume, for the commands not yet issued in their window, the law the filter
    # really issues. From the obstacle's appearance (2.75 s) the margin QP differs from the
    # delay-free CBF-QP (the default law), so only the filter that says so predicts exactly.
    mjsafe.register_filter("tested_margin_qp", MarginQp)
    mjsafe.register_filter("margin_qp_law", MarginQpWithLaw)
    s = {"plant": "ode", "duration": 6.0}
    MarginQpWithLaw.calls = 0
    exact = mjsafe.run(scenario("bicycle_obstacle_gamma_m.toml"),
                       set={**s, "filter": {"kind": "margin_qp_law", "margin": 2.0}}, tables=True)
    default = mjsafe.run(scenario("bicycle_obstacle_gamma_m.toml"),
                         set={**s, "filter": {"kind": "tested_margin_qp", "margin": 2.0}}, tables=True)
    assert exact.error is None and default.error is None, (exact.error, default.error)
    assert MarginQpWithLaw.calls > 100
    # The commands issued are the same law's, so the two runs differ only in their predictions.
    ours, theirs = prediction_errors(exact, 2.75), prediction_errors(default, 2.75)
    print("max prediction error with issued_law", ours, "with the default law", theirs)
    assert set(ours) == {"steering", "acceleration"}
    # Measured: 8e-14 m with issued_law, 3.9e-2 m (acceleration) with the default law.
    assert max(ours.values()) <= 1e-9, ours
    assert theirs["acceleration"] > 1e-3, theirs


class PredictedCbfQp(DelayFreeCbfQp):
    """The delay-free CBF-QP at each channel's prediction, without `issued_law`: the built-in
    `cbf_qp` with `compensation = "predictor"` (4.34), whose law is the default one."""

    def __init__(self, params):
        super().__init__(params)
        self.uses_prediction = True


def test_without_issued_law_the_predictors_assume_the_delay_free_cbf_qp():
    mjsafe.register_filter("predicted_cbf_qp", PredictedCbfQp)
    s = {"plant": "ode", "duration": 6.0}
    ours = mjsafe.run(scenario("bicycle_obstacle_gamma_m.toml"),
                      set={**s, "filter": {"kind": "predicted_cbf_qp", "l0": 4.0, "l1": 4.0}}, tables=True)
    built_in = mjsafe.run(scenario("bicycle_obstacle_gamma_m.toml"), tables=True, set={
        **s, "filter": {"kind": "cbf_qp", "l0": 4.0, "l1": 4.0, "compensation": "predictor"}})
    assert ours.error is None and built_in.error is None
    assert abs(ours.min_h - built_in.min_h) < 1e-9, (ours.min_h, built_in.min_h)
    assert max(prediction_errors(ours, 2.75).values()) <= 1e-9


class LawRaises(MarginQp):
    def issued_law(self, t, prediction_time, state, nominal, constraints, free, u):
        if constraints:
            raise ArithmeticError("no law at this state")
        return nominal[free]


class LawTooShort(MarginQp):
    def issued_law(self, t, prediction_time, state, nominal, constraints, free, u):
        return [] if constraints else None


def test_an_exception_or_a_bad_return_in_issued_law_stops_the_run():
    mjsafe.register_filter("law_raises", LawRaises)
    r = mjsafe.run(scenario("bicycle_obstacle_gamma_m.toml"), set={"filter": {"kind": "law_raises", "margin": 1.0}})
    assert r.error is not None and "ArithmeticError: no law at this state" in r.error, r.error
    assert "law_raises" in r.error and "issued_law" in r.error
    assert r.metrics["complete"] is False
    # Stopped at the first tick a barrier is known (2.75 s).
    assert 2.74 <= r.simulated_time <= 2.77, r.simulated_time

    mjsafe.register_filter("law_too_short", LawTooShort)
    r = mjsafe.run(scenario("bicycle_obstacle_gamma_m.toml"), set={"filter": {"kind": "law_too_short", "margin": 1.0}})
    assert r.error is not None and "issued_law returned 0 values: expected 1" in r.error, r.error
    assert r.metrics["complete"] is False

    class NotALaw(MarginQp):
        issued_law = 3

    with pytest.raises(TypeError, match="issued_law"):
        mjsafe.register_filter("not_a_law", NotALaw)


def test_a_filter_without_barrier_form_is_refused_and_a_typo_names_the_attribute():
    class NoForm:
        def __init__(self, params):
            pass

        def filter_channel(self, t, channel, state, nominal, constraints):
            return float(nominal[channel])

    mjsafe.register_filter("no_form", NoForm)
    # Before: it ran without a word, received no constraint and collided (min h −35.6).
    with pytest.raises(ValueError, match=r"`NoForm` has no `barrier_form`: it would receive no constraints"):
        mjsafe.run(scenario("bicycle_obstacle.toml"), set={"filter": {"kind": "no_form"}})

    class Typo(DelayFreeCbfQp):
        def __init__(self, params):
            self.barrier_form = {"lo": 4.0, "l1": 4.0}

    mjsafe.register_filter("typo_form", Typo)
    with pytest.raises(ValueError, match=r"`Typo.barrier_form`: .*found the key `lo`"):
        mjsafe.run(scenario("bicycle_obstacle.toml"), set={"filter": {"kind": "typo_form"}})


def test_a_requirement_on_an_unknown_signal_is_refused_before_the_run():
    with pytest.raises(ValueError, match=r"did you mean `obstacle_0.clearance`"):
        mjsafe.run(scenario("bicycle_obstacle.toml"), require={"brakes": "always (obstacle_0.clearence < 3)"})


def bicycle_rows(state, barriers, wheelbase, l0, l1):
    """(a, b) of ḧ + l1 ḣ + l0 h ≥ 0 (4.85)/(4.86) for h = ‖p − c‖² − r² (4.81) of each planar
    ball, on the bicycle (4.78), written out here: an independent computation of the rows."""
    x1, x2, th, v = state
    ahead, left = np.array([np.cos(th), np.sin(th)]), np.array([-np.sin(th), np.cos(th)])
    rows = []
    for b in barriers:
        d = np.array([x1, x2]) - np.array(b["centre"])
        h, hdot = d @ d - b["radius"] ** 2, 2 * v * (d @ ahead)
        rows.append((2 * v * v + l1 * hdot + l0 * h, np.array([2 * v * v / wheelbase * (d @ left), 2 * (d @ ahead)])))
    return rows


class SeesGeometry:
    """Passes the nominal, recording the constraints, barriers and vehicle of each call."""

    barrier_form = {"l0": 4.0, "l1": 4.0}
    uses_prediction = True
    seen = []

    def __init__(self, params):
        pass

    def filter_channel(self, t, channel, state, nominal, constraints, barriers, vehicle, **rest):
        SeesGeometry.seen.append((t, channel, state.copy(), [(a, b.copy()) for a, b in constraints],
                                  barriers, vehicle, rest))
        return None


def test_a_filter_gets_the_geometry_its_constraints_come_from():
    """The rows handed to the filter are (4.85)/(4.86) of the circle the `barriers` dict describes,
    recomputed here from that geometry and the `vehicle`'s wheelbase; moving the obstacle moves
    both."""
    mjsafe.register_filter("sees_geometry", SeesGeometry)
    for centre in ([-3.0, 0.5], [2.0, -1.0]):
        SeesGeometry.seen.clear()
        r = mjsafe.run(scenario("bicycle_obstacle.toml"), set={
            "filter": {"kind": "sees_geometry"}, "duration": 3.5, "obstacles.0.centre": centre})
        assert r.error is None, r.error
        before = [s for s in SeesGeometry.seen if s[0] < 2.75 - 1e-9]
        assert before and all(s[3] == [] and s[4] == [] for s in before)   # not yet known
        after = [s for s in SeesGeometry.seen if s[0] >= 2.75 - 1e-9]
        assert len(after) == 2 * 75
        for t, channel, state, constraints, barriers, vehicle, rest in after:
            assert rest == {"queues": rest["queues"], "timestep": 0.002}
            [b] = barriers
            assert b["name"] == b["obstacle"] == "obstacle_0" and b["shape"] == "ball" and not b["moving"]
            assert b["centre"] == centre and b["radius"] == 6.0 and b["rows"] == [0] and b["indices"] == [0, 1]
            [(a, bb)] = bicycle_rows(state, barriers, vehicle["parameters"]["wheelbase"], 4.0, 4.0)
            [(a_given, b_given)] = constraints
            assert abs(a - a_given) < 1e-9 * max(1.0, abs(a)) and np.allclose(bb, b_given, rtol=1e-12, atol=1e-12)
    assert vehicle == {"kind": "bicycle", "states": ["x1", "x2", "heading", "speed"],
                       "channels": ["steering", "acceleration"], "parameters": {"wheelbase": 6.0},
                       "hull_radius": 3.0, "footprint": None, "initial_state": [-20.0, 0.0, 0.0, 3.0],
                       "timestep": 0.002}


def test_a_moving_road_user_is_where_the_controller_assumes_it_at_each_prediction():
    """CCRm: the target drives at 5.556 m/s. Channel i is evaluated at its prediction t + D_i, so
    its covering circles are 5.556 (D_acceleration − D_steering) m further on for the
    acceleration channel; the vehicle's footprint and the circles' rows come along."""
    mjsafe.register_filter("sees_geometry", SeesGeometry)
    SeesGeometry.seen.clear()
    r = mjsafe.run(scenario("ncap_ccrm.toml"), set={"filter": {"kind": "sees_geometry"}, "duration": 0.5})
    assert r.error is None, r.error
    by_tick = {}
    for t, channel, state, constraints, barriers, vehicle, _ in SeesGeometry.seen:
        by_tick.setdefault(t, {})[channel] = (constraints, barriers)
    footprint = vehicle["footprint"]
    assert (footprint["length"], footprint["width"]) == (4.6, 1.8) and len(footprint["circles"]) == 3
    assert vehicle["parameters"] == {"wheelbase": 6.0}
    checked = 0
    for t, channels in by_tick.items():
        (_, steering), (constraints, acceleration) = channels[0], channels[1]
        assert len(acceleration) == 9    # 3 vehicle circles × 3 target circles
        for s, a in zip(steering, acceleration):
            assert s["moving"] and a["obstacle"] == "target" and a["name"].startswith("target/")
            assert a["velocity"] == pytest.approx([5.556, 0.0])
            assert a["centre"][0] - s["centre"][0] == pytest.approx(5.556 * (0.5 - 0.2), abs=1e-9)
            assert a["offset"] in [c["offset"] for c in footprint["circles"]]
        rows = sorted(r for b in acceleration for r in b["rows"])
        assert rows == list(range(len(constraints)))
        checked += 1
    assert checked == 50


class InitialInput:
    barrier_form = None
    seen = []

    def __init__(self, params):
        pass

    def filter_channel(self, t, channel, state, nominal, constraints, queues):
        InitialInput.seen.append([q["initial"] for q in queues])
        return None


def test_the_queues_say_the_input_applied_before_the_first_command():
    mjsafe.register_filter("initial_input", InitialInput)
    InitialInput.seen.clear()
    r = mjsafe.run(scenario("bicycle_obstacle.toml"), set={
        "filter": {"kind": "initial_input"}, "duration": 0.1, "initial_input.acceleration": 0.25})
    assert r.error is None, r.error
    assert InitialInput.seen and all(s == [0.0, 0.25] for s in InitialInput.seen)


class Imposter:
    """Passes the nominal through: not (4.67)."""

    barrier_form = None

    def __init__(self, params):
        pass

    def filter_channel(self, t, channel, state, nominal, constraints):
        return None


def test_a_kind_that_names_a_built_in_is_refused_unless_it_says_it_replaces():
    """Registering "gamma_m" once silently replaced (4.67) for the rest of the process: a run of
    the γm scenario then collided (min h −35.6) under the label "gamma_m". Now it is refused
    and the built-in runs as before; another class under a taken Python kind too; the same
    class again (a notebook cell re-run) replaces it."""
    before = mjsafe.run(scenario("bicycle_obstacle_gamma_m.toml"), set={"duration": 5.0})
    with pytest.raises(ValueError, match=r"filter kind `gamma_m` is already registered \(built in: γm filter \(4\.67\)\).*replace=True"):
        mjsafe.register_filter("gamma_m", Imposter)
    after = mjsafe.run(scenario("bicycle_obstacle_gamma_m.toml"), set={"duration": 5.0})
    assert after.min_h == before.min_h > 0 and after.metrics["filter_label"].startswith("γm filter (4.67)")
    with pytest.raises(ValueError, match="nominal kind `path_lqr` is already registered"):
        mjsafe.register_nominal("path_lqr", Hold)
    mjsafe.register_filter("imposter_once", Imposter)
    mjsafe.register_filter("imposter_once", Imposter)          # the same class again: fine
    with pytest.raises(ValueError, match=r"`imposter_once` is already registered \(imposter_once, from .*test_python_filter\.py\)"):
        mjsafe.register_filter("imposter_once", SeesQueues)
    mjsafe.register_filter("imposter_once", SeesQueues, replace=True)
    with pytest.raises(TypeError, match="replace"):
        mjsafe.register_filter("imposter_once", SeesQueues, replace="yes")


def test_a_built_in_replaced_on_purpose_says_whose_filter_ran():
    """With replace=True the kind runs the class, and the run's label says it is not the
    built-in (in a process of its own: the built-in cannot come back in this one)."""
    code = (
        "import mjsafe\n"
        "class Imposter:\n"
        "    barrier_form = None\n"
        "    def __init__(self, params): pass\n"
        "    def filter_channel(self, t, channel, state, nominal, constraints): return None\n"
        "mjsafe.register_filter('gamma_m', Imposter, replace=True)\n"
        f"r = mjsafe.run({str(scenario('bicycle_obstacle_gamma_m.toml'))!r}, set={{'duration': 5.0}})\n"
        "print(r.metrics['filter_label'], '|', r.min_h < 0)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    label, collided = (part.strip() for part in done.stdout.split("|"))
    assert label == "gamma_m (Python __main__.Imposter)"
    assert collided == "True"
