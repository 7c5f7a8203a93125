"""Independent check of mjsafe's CommonRoad support with CommonRoad's own reader.

Run with the CommonRoad venv's python (scripts/setup.sh --test creates it at
${MJSAFE_CR_VENV:-~/.cache/mjsafe/cr-venv}: PyPI commonroad-io and mcap, nothing of mjsafe's):

    python tests/commonroad_check.py SCENARIO.xml [LOG.mcap] [--time-step-size DT]
        [--planning-problem-json OUT] [--lanelets-json OUT] [--set-valued centre|contains|skip]
        [--time-to-goal T|none]

The scenario is read with commonroad-io (`CommonRoadFileReader(path).open()`); the log with the
`mcap` package's reader, its `/actors` messages (`mjsafe.Actors`, proto/mjsafe.proto) decoded
from the protobuf wire format by hand, so no generated classes (and no protobuf runtime, which
commonroad-io pins to 3.20.2) are involved.

For every `/actors` message whose time t is k * dt (within 1e-9 s; dt the scenario's
timeStepSize unless --time-step-size), every dynamic obstacle with a recorded trajectory is
compared with `obstacle.state_at_time(k)` (an index into the recorded states, no
interpolation). None there: the actor `cr_<id>` must be `absent` or not listed. Otherwise it
must be listed and not absent, |x - position[0]| and |y - position[1]| <= 1e-9 m, and its heading
equal to the state's orientation modulo 2 pi within 1e-9 rad. (A rectangle's position is its
centre, which commonroad-io's `compute_occupancy_for_state` moves from the state's position when
the shape has an `originXShift`.)

Set-valued states (2018b files such as DEU_A9-3_1_T-1 give positions as rectangles and
orientations as intervals): `--set-valued centre` (default) compares with the shape's centre
and the interval's midpoint, `contains` accepts a position inside the shape and a heading inside
the interval, `skip` leaves them out. Obstacles with a set-based prediction (an occupancySet,
no states after the initial one) are compared at their initial time step only.

Every `/prediction` entry of a road user is checked against its recorded life span (first and
last time step): `actor_realized` NaN exactly when it does not exist at the target time (and the
recorded position at a recorded step), `actor_predicted` NaN when it did not exist at the
controller's last observation at or before the prediction's tick (every tick, or every
`actor_knowledge.period` of the log's resolved scenario from t = 0; the oracle at every tick),
`actor_error` their distance (NaN when either is). The `road_user_entered`
and `road_user_left` events are checked against the same spans: one at the first logged step at
or after a first recorded time later than 0, one at the first step after a last recorded time
before the log's end, and no others.

With --time-to-goal (mjsafe's `time_to_goal` of the log, `none` when absent): at every `/state`
message, the car's centre (the planar position plus the log's `goal_offset` along the heading),
its heading, speed and time step t / dt go to the planning problem's `GoalRegion.is_reached`;
the first time it says yes must be T, and when it never does T must be none or later than the
goal's window.

Prints `commonroad_check: N states compared, M absent, K mismatches` and exits 1 with the
first 10 mismatches listed when K > 0, or when no `/actors` message fell on a time step.

--planning-problem-json OUT writes the planning problem set as commonroad-io reads it:
    {"time_step_size": dt, "planning_problems": [{"id", "initial_state": {"position": [x, y],
     "orientation", "velocity", "time_step"},
     "goal_states": [{"time_step": [start, end], "position": null | {"lanelets": [ids]} |
     {"shapes": [shape, ...]}, "orientation": [start, end] | null,
     "velocity": [start, end] | null}]}]}   (problems sorted by id)
  a shape: {"type": "rectangle", "center": [x, y], "length", "width", "orientation"},
  {"type": "circle", "center": [x, y], "radius"} or {"type": "polygon", "vertices": [[x, y],
  ...]} (the vertices as commonroad-io keeps them: clockwise, the first repeated at the end).
  A value given as an interval in the file is [start, end] in place of a number. The initial
  yaw rate and slip angle are left out: commonroad-io 2026.1 reads them as 0 whenever the initial
  state has no <acceleration> (its StateFactory stops filling InitialState at the first missing
  attribute, and acceleration comes before yaw_rate and slip_angle), so in USA_Lanker-1_1,
  USA_Peach-4_8, USA_US101-4_1 and USA_US101-5_1 they differ from the file.
--lanelets-json OUT writes every lanelet (sorted by id): {"lanelets": [{"id", "left": [[x, y],
  ...], "right": [...], "predecessor": [ids], "successor": [ids], "adjacent_left": id | null,
  "adjacent_left_same_direction": bool | null, "adjacent_right": ..., "adjacent_right_same_direction":
  ..., "lanelet_types": [names]}]}.
--obstacles-json OUT writes every road user (sorted by id, the planning problems' ids left out):
  {"obstacles": [{"id", "role", "occupancy": [shape, ...] | null}]}, where commonroad-io puts its
  shape at its initial state (see `obstacles_json`).
--write-turned OUT ANGLE X Y writes the scenario turned by ANGLE (rad) about the origin and then
  shifted by (X, Y) m, as commonroad-io turns it (`translate_rotate`), and exits.
--write-late-starts OUT STEP writes the scenario with every second road user (by id) appearing
  at STEP (its initial state there, its trajectory after it), and exits.
The XML alone is enough for these four (the log argument may be left out).
"""
import argparse
import copy
import json
import logging
import math
import os
import struct
import sys
import tomllib
import warnings

# A contact is decided within this much of touching (`check_contacts`), m.
CONTACT_MARGIN = 0.05
TOL = 1e-9
TWO_PI = 2.0 * math.pi


# ---------------------------------------------------------------- protobuf wire format


def _varint(buf, i):
    value = shift = 0
    while True:
        if i >= len(buf):
            raise ValueError("truncated varint")
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value, i
        shift += 7
        if shift > 63:
            raise ValueError("varint longer than 10 bytes")


def _fields(buf):
    """Yield (field number, wire type, value) of a protobuf message: an int for varints, 8 or 4
    raw bytes for fixed64 / fixed32, a bytes object for length-delimited fields."""
    i = 0
    n = len(buf)
    while i < n:
        key, i = _varint(buf, i)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(buf, i)
        elif wire == 1:
            value, i = buf[i:i + 8], i + 8
        elif wire == 2:
            length, i = _varint(buf, i)
            value, i = buf[i:i + length], i + length
        elif wire == 5:
            value, i = buf[i:i + 4], i + 4
        else:
            raise ValueError(f"unsupported wire type {wire} (field {field})")
        if i > n:
            raise ValueError(f"field {field} runs past the end of the message")
        yield field, wire, value


def _double(wire, value, what):
    if wire != 1:
        raise ValueError(f"{what}: wire type {wire}, expected 1 (double)")
    return struct.unpack("<d", value)[0]


ACTOR_DOUBLES = {2: "x", 3: "y", 4: "vx", 5: "vy", 6: "ax", 7: "ay", 8: "heading"}


def decode_actor(buf):
    """mjsafe.ActorValue; proto3 leaves out zero / false / empty fields, so they default here."""
    actor = {"name": "", "x": 0.0, "y": 0.0, "vx": 0.0, "vy": 0.0, "ax": 0.0, "ay": 0.0,
             "heading": 0.0, "absent": False}
    for field, wire, value in _fields(buf):
        if field == 1:
            if wire != 2:
                raise ValueError(f"ActorValue.name: wire type {wire}")
            actor["name"] = bytes(value).decode("utf-8")
        elif field in ACTOR_DOUBLES:
            actor[ACTOR_DOUBLES[field]] = _double(wire, value, "ActorValue." + ACTOR_DOUBLES[field])
        elif field == 9:
            if wire != 0:
                raise ValueError(f"ActorValue.absent: wire type {wire}")
            actor["absent"] = value != 0
        # Unknown fields: skipped, as a protobuf reader would.
    return actor


def decode_actors(buf):
    """mjsafe.Actors { double time = 1; repeated ActorValue actors = 2; }"""
    time, actors = 0.0, []
    for field, wire, value in _fields(buf):
        if field == 1:
            time = _double(wire, value, "Actors.time")
        elif field == 2:
            if wire != 2:
                raise ValueError(f"Actors.actors: wire type {wire}")
            actors.append(decode_actor(value))
    return time, actors


def decode_doubles(wire, value, what):
    """A repeated double: packed (wire type 2) or one element (wire type 1)."""
    if wire == 2:
        if len(value) % 8:
            raise ValueError(f"{what}: {len(value)} bytes is no whole number of doubles")
        return list(struct.unpack(f"<{len(value) // 8}d", value))
    return [_double(wire, value, what)]


def decode_prediction(buf):
    """The fields of mjsafe.Prediction checked here: time = 1, issued_at = 3, actors = 11,
    actor_predicted = 12, actor_realized = 13, actor_error = 14."""
    m = {"time": 0.0, "issued_at": 0.0, "actors": [], "actor_predicted": [], "actor_realized": [],
         "actor_error": []}
    names = {12: "actor_predicted", 13: "actor_realized", 14: "actor_error"}
    for field, wire, value in _fields(buf):
        if field == 1:
            m["time"] = _double(wire, value, "Prediction.time")
        elif field == 3:
            m["issued_at"] = _double(wire, value, "Prediction.issued_at")
        elif field == 11:
            m["actors"].append(bytes(value).decode("utf-8"))
        elif field in names:
            m[names[field]] += decode_doubles(wire, value, "Prediction." + names[field])
    return m


def decode_state(buf):
    """mjsafe.State { double time = 1; repeated string names = 3; repeated double values = 4; }"""
    m = {"time": 0.0, "names": [], "values": []}
    for field, wire, value in _fields(buf):
        if field == 1:
            m["time"] = _double(wire, value, "State.time")
        elif field == 3:
            m["names"].append(bytes(value).decode("utf-8"))
        elif field == 4:
            m["values"] += decode_doubles(wire, value, "State.values")
    return m


def decode_event(buf):
    """mjsafe.Event { double time = 1; string kind = 2; repeated string participants = 4; }"""
    m = {"time": 0.0, "kind": "", "participants": []}
    for field, wire, value in _fields(buf):
        if field == 1:
            m["time"] = _double(wire, value, "Event.time")
        elif field == 2:
            m["kind"] = bytes(value).decode("utf-8")
        elif field == 4:
            m["participants"].append(bytes(value).decode("utf-8"))
    return m


def read_messages(path, topic="/actors", decode=None):
    """The log's `topic` messages (CRCs checked): (log_time, time, actors) of each `/actors`
    message, or what `decode` makes of each message of another topic."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        for schema, channel, message in reader.iter_messages(topics=[topic]):
            expected = {"/actors": "mjsafe.Actors", "/prediction": "mjsafe.Prediction",
                        "/event": "mjsafe.Event", "/state": "mjsafe.State"}[topic]
            if channel.message_encoding != "protobuf":
                raise SystemExit(f"commonroad_check: {topic} message encoding is "
                                 f"{channel.message_encoding!r}, expected 'protobuf'")
            if schema is not None and schema.name != expected:
                raise SystemExit(f"commonroad_check: {topic} schema is {schema.name!r}, "
                                 f"expected {expected!r}")
            if decode is not None:
                yield decode(message.data)
                continue
            time, actors = decode_actors(message.data)
            yield message.log_time, time, actors


# ---------------------------------------------------------------- CommonRoad side


def open_scenario(path):
    # commonroad-io logs a warning per deprecated intersection element (2020a files written
    # before 2022) and warns about non-standard benchmark ids: not our business here.
    logging.getLogger("commonroad").setLevel(logging.ERROR)
    from commonroad.common.file_reader import CommonRoadFileReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return CommonRoadFileReader(path).open()


def is_interval(v):
    from commonroad.common.util import Interval

    return isinstance(v, Interval)


def num(v):
    """A number, or [start, end] for an interval; None stays None."""
    if v is None:
        return None
    if is_interval(v):
        return [float(v.start), float(v.end)]
    return float(v)


def point(p):
    return [float(p[0]), float(p[1])]


def shape_json(occ):
    """Flatten a commonroad-io occupancy into a list of shape dicts."""
    from commonroad.geometry.occupancy.circle_occupancy import CircleOccupancy
    from commonroad.geometry.occupancy.occupancy_group import OccupancyGroup
    from commonroad.geometry.occupancy.polygon_occupancy import PolygonOccupancy
    from commonroad.geometry.occupancy.rect_occupancy import RectOccupancy

    if isinstance(occ, OccupancyGroup):
        return [s for o in occ.occupancies for s in shape_json(o)]
    if isinstance(occ, RectOccupancy):
        return [{"type": "rectangle", "center": [float(occ.rect_center.x), float(occ.rect_center.y)],
                 "length": float(occ.length), "width": float(occ.width),
                 "orientation": float(occ.orientation)}]
    if isinstance(occ, CircleOccupancy):
        return [{"type": "circle", "center": [float(occ.circle_center.x), float(occ.circle_center.y)],
                 "radius": float(occ.radius)}]
    if isinstance(occ, PolygonOccupancy):
        return [{"type": "polygon", "vertices": [point(v) for v in occ.vertices]}]
    raise SystemExit(f"commonroad_check: unknown shape {type(occ).__name__}")


def planning_problems_json(pps, dt):
    out = []
    for pid in sorted(pps.planning_problem_dict):
        pp = pps.planning_problem_dict[pid]
        s = pp.initial_state
        initial = {
            "position": point(s.position),
            "orientation": num(getattr(s, "orientation", None)),
            "velocity": num(getattr(s, "velocity", None)),
            "time_step": int(s.time_step),
        }
        lanelets = pp.goal.lanelets_of_goal_position or {}
        goals = []
        for i, g in enumerate(pp.goal.state_list):
            if i in lanelets:
                position = {"lanelets": [int(x) for x in lanelets[i]]}
            elif getattr(g, "position", None) is not None:
                position = {"shapes": shape_json(g.position)}
            else:
                position = None
            ts = g.time_step
            goals.append({
                "time_step": [int(ts.start), int(ts.end)] if is_interval(ts) else [int(ts), int(ts)],
                "position": position,
                "orientation": num(getattr(g, "orientation", None)),
                "velocity": num(getattr(g, "velocity", None)),
            })
        out.append({"id": int(pid), "initial_state": initial, "goal_states": goals})
    return {"time_step_size": dt, "planning_problems": out}


def lanelets_json(scenario):
    out = []
    for l in sorted(scenario.lanelet_network.lanelets, key=lambda l: l.lanelet_id):
        out.append({
            "id": int(l.lanelet_id),
            "left": [point(p) for p in l.left_vertices],
            "right": [point(p) for p in l.right_vertices],
            "predecessor": [int(x) for x in l.predecessor],
            "successor": [int(x) for x in l.successor],
            "adjacent_left": None if l.adj_left is None else int(l.adj_left),
            "adjacent_left_same_direction": l.adj_left_same_direction if l.adj_left is not None else None,
            "adjacent_right": None if l.adj_right is None else int(l.adj_right),
            "adjacent_right_same_direction": l.adj_right_same_direction if l.adj_right is not None else None,
            "lanelet_types": sorted(t.value for t in (l.lanelet_type or [])),
        })
    return {"lanelets": out}


def obstacles_json(scenario, ego_ids):
    """Every road user as commonroad-io places it at its initial state (sorted by id; the planning
    problems' own ids left out): {"id", "role": "static" | "dynamic", "occupancy": [shape]}, the
    shapes of `obstacle_shape.compute_occupancy_for_state(initial_state)` as `shape_json` gives
    them (world frame); "occupancy": null for a set-valued initial state (2018b files)."""
    out = []
    for o in sorted(scenario.obstacles, key=lambda o: o.obstacle_id):
        if o.obstacle_id in ego_ids:
            continue
        state = o.initial_state
        exact = not hasattr(state.position, "center") and not is_interval(state.orientation)
        occupancy = shape_json(o.obstacle_shape.compute_occupancy_for_state(state)) if exact else None
        out.append({"id": int(o.obstacle_id), "role": o.obstacle_role.value, "occupancy": occupancy})
    return {"obstacles": out}


def angle_diff(a, b):
    """|a - b| modulo 2 pi, in [0, pi]."""
    d = math.fmod(a - b, TWO_PI)
    if d < 0:
        d += TWO_PI
    return min(d, TWO_PI - d)


def angle_in_interval(a, start, end):
    d = math.fmod(a - start, TWO_PI)
    if d < 0:
        d += TWO_PI
    return d <= (end - start) + TOL or TWO_PI - d <= TOL


def describe_position(pos):
    if hasattr(pos, "__len__"):
        return f"({float(pos[0])!r}, {float(pos[1])!r})"
    c = pos.center
    return f"a {type(pos).__name__} centred at ({c.x!r}, {c.y!r})"


def rectangle_centre(obstacle, state):
    """Where commonroad-io puts the centre of a road user's rectangle at an exact state
    (`compute_occupancy_for_state`): the state's position, unless the shape moves its origin
    (`originXShift`); the state's position for other shapes and set-valued states."""
    shape = obstacle.obstacle_shape
    if type(shape).__name__ != "RectObstacleShape" or not hasattr(state.position, "__len__"):
        return state.position
    centre = shape.compute_occupancy_for_state(state).center
    return [centre.x, centre.y]


def compare_state(actor, state, mode, position=None):
    """Returns (problem or None, set_valued); `position` in place of the state's when given."""
    import shapely

    pos, ori = (state.position if position is None else position), state.orientation
    set_valued = not hasattr(pos, "__len__") or is_interval(ori)
    if set_valued and mode == "skip":
        return None, True
    problems = []
    x, y, h = actor["x"], actor["y"], actor["heading"]
    if hasattr(pos, "__len__"):
        px, py = float(pos[0]), float(pos[1])
        if abs(x - px) > TOL or abs(y - py) > TOL:
            problems.append(f"position ({x!r}, {y!r}) != ({px!r}, {py!r})")
    elif mode == "contains":
        if not pos.contains_point(shapely.Point(x, y)):
            problems.append(f"position ({x!r}, {y!r}) outside the state's {type(pos).__name__}")
    else:
        c = pos.center
        if abs(x - c.x) > TOL or abs(y - c.y) > TOL:
            problems.append(f"position ({x!r}, {y!r}) != centre ({c.x!r}, {c.y!r}) of the state's "
                            f"{type(pos).__name__}")
    if is_interval(ori):
        if mode == "contains":
            if not angle_in_interval(h, ori.start, ori.end):
                problems.append(f"heading {h!r} outside [{ori.start!r}, {ori.end!r}]")
        else:
            mid = 0.5 * (ori.start + ori.end)
            if angle_diff(h, mid) > TOL:
                problems.append(f"heading {h!r} != midpoint {mid!r} of [{ori.start!r}, {ori.end!r}]")
    elif ori is None:
        problems.append("the recorded state has no orientation")
    elif angle_diff(h, float(ori)) > TOL:
        problems.append(f"heading {h!r} != orientation {float(ori)!r} (mod 2 pi)")
    return ("; ".join(problems) if problems else None), set_valued


def check_log(scenario, log_path, dt, mode, ego_ids=(), times=None):
    from commonroad.prediction.prediction import SetBasedPrediction

    # A road user listed under a planning problem's id is the ego itself (two commonroad-crime
    # files do this): mjsafe drives it, it is no road user of the run.
    obstacles = sorted(
        (o for o in scenario.dynamic_obstacles if o.obstacle_id not in ego_ids),
        key=lambda o: o.obstacle_id,
    )
    known = {f"cr_{o.obstacle_id}" for o in obstacles}
    compared = absent = set_valued_count = skipped = messages = on_step = 0
    mismatches = []
    for log_time, t, actors in read_messages(log_path):
        messages += 1
        if times is not None:
            times.append(t)
        if log_time != round(t * 1e9):
            mismatches.append(f"/actors at t={t!r}: log_time {log_time} ns is not its time")
        k = round(t / dt)
        if k < 0 or abs(t - k * dt) > TOL:
            continue
        on_step += 1
        by_name = {}
        for a in actors:
            if a["name"] in by_name:
                mismatches.append(f"t={t!r} (step {k}): actor {a['name']} listed twice")
            by_name[a["name"]] = a
        for unknown in sorted(set(by_name) - known):
            if unknown.startswith("cr_"):
                mismatches.append(f"t={t!r} (step {k}): actor {unknown} is no dynamic obstacle of "
                                  "the scenario")
        for o in obstacles:
            name = f"cr_{o.obstacle_id}"
            actor = by_name.get(name)
            if isinstance(o.prediction, SetBasedPrediction) and k != o.initial_state.time_step:
                skipped += 1  # an occupancy set: no state to compare with
                continue
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                state = o.state_at_time(k)
            if state is None:
                if actor is not None and not actor["absent"]:
                    mismatches.append(f"t={t!r} (step {k}) {name}: listed and not absent, but the "
                                      "scenario has no state at this step")
                else:
                    absent += 1
                continue
            if actor is None:
                mismatches.append(f"t={t!r} (step {k}) {name}: not in /actors, the scenario has a "
                                  f"state at {describe_position(state.position)}")
                continue
            if actor["absent"]:
                mismatches.append(f"t={t!r} (step {k}) {name}: absent, but the scenario has a state")
                continue
            problem, sv = compare_state(actor, state, mode, rectangle_centre(o, state))
            if sv:
                set_valued_count += 1
                if mode == "skip":
                    skipped += 1
                    continue
            compared += 1
            if problem:
                mismatches.append(f"t={t!r} (step {k}) {name}: {problem}")
    return messages, on_step, compared, absent, set_valued_count, skipped, mismatches


def check_predictions(scenario, log_path, dt, ego_ids=()):
    """Every `/prediction` entry of a road user against its recorded life span [first, last]
    time step (× dt): its true position (`actor_realized`) is NaN exactly when it does not
    exist at the target time, and its recorded position at a recorded step otherwise; the
    controller's assumption (`actor_predicted`) is NaN when it did not exist at the controller's
    last observation at or before the prediction's tick; `actor_error` is the distance between the two, NaN when either is. Road users with a
    set-based prediction are left out. Returns (entries checked, NaN errors, mismatches)."""
    span = life_spans(scenario, dt, ego_ids)
    knowledge = tomllib.loads(run_metadata(log_path)["scenario_resolved"]).get("actor_knowledge", {})
    period = 0.0 if knowledge.get("kind") == "oracle" else float(knowledge.get("period", 0.0))

    def observed_at(tick):
        """The time of the controller's last observation at or before `tick`."""
        return tick if period <= 0.0 else math.floor(tick / period + 1e-6) * period
    checked = without = 0
    mismatches = []
    for m in read_messages(log_path, "/prediction", decode_prediction):
        n = len(m["actors"])
        if len(m["actor_predicted"]) != 2 * n or len(m["actor_realized"]) != 2 * n \
                or len(m["actor_error"]) != n:
            mismatches.append(f"/prediction at t={m['time']!r}: {n} actors but "
                              f"{len(m['actor_predicted'])}, {len(m['actor_realized'])} and "
                              f"{len(m['actor_error'])} values")
            continue
        for i, name in enumerate(m["actors"]):
            if name not in span:
                continue
            o, first, last = span[name]
            def exists(t):
                return first - TOL <= t <= last + TOL
            t, tick = m["time"], m["issued_at"]
            predicted = m["actor_predicted"][2 * i:2 * i + 2]
            realized = m["actor_realized"][2 * i:2 * i + 2]
            error = m["actor_error"][i]
            where = f"/prediction issued at {tick!r} for {t!r}, {name}"
            checked += 1
            if exists(t) == any(math.isnan(v) for v in realized):
                mismatches.append(f"{where}: true position {realized} while it "
                                  f"{'exists' if exists(t) else 'does not exist'}")
            if not exists(observed_at(tick)) and not all(math.isnan(v) for v in predicted):
                mismatches.append(f"{where}: assumed at {predicted} although it did not exist at "
                                  f"the last observation ({observed_at(tick)!r})")
            expected = math.hypot(predicted[0] - realized[0], predicted[1] - realized[1])
            if math.isnan(expected) != math.isnan(error) or \
                    (not math.isnan(error) and abs(error - expected) > TOL * max(1.0, expected)):
                mismatches.append(f"{where}: error {error!r}, the distance is {expected!r}")
            without += math.isnan(error)
            k = round(t / dt)
            if exists(t) and abs(t - k * dt) <= TOL:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    state = o.state_at_time(k)
                pos = rectangle_centre(o, state) if state is not None else None
                if hasattr(pos, "__len__") and (abs(realized[0] - float(pos[0])) > TOL or
                                                abs(realized[1] - float(pos[1])) > TOL):
                    mismatches.append(f"{where}: true position {realized} != recorded "
                                      f"({float(pos[0])!r}, {float(pos[1])!r})")
    return checked, without, mismatches


def life_spans(scenario, dt, ego_ids):
    """cr_<id> -> (obstacle, first recorded time, last recorded time) of every road user with
    recorded states (set-based predictions left out)."""
    from commonroad.prediction.prediction import SetBasedPrediction

    span = {}
    for o in scenario.dynamic_obstacles:
        if o.obstacle_id in ego_ids or isinstance(o.prediction, SetBasedPrediction):
            continue
        first = o.initial_state.time_step
        last = o.prediction.final_time_step if o.prediction is not None else first
        span[f"cr_{o.obstacle_id}"] = (o, first * dt, last * dt)
    return span


def check_entries(scenario, log_path, dt, times, ego_ids=()):
    """The `road_user_entered` / `road_user_left` events against the recorded life spans: within
    the logged steps (t_0 = 0 < t_1 < … < t_end), a road user whose first recorded time lies in
    (0, t_end] enters once, at the first step at or after it; one whose last recorded time lies
    before t_end leaves once, at the first step after it; no other such events. Returns
    (events checked, mismatches). `times`: the times of the log's `/actors` messages."""
    if len(times) < 2:
        return 0, []
    end = times[-1]
    events = {"road_user_entered": {}, "road_user_left": {}}
    mismatches = []
    for e in read_messages(log_path, "/event", decode_event):
        if e["kind"] in events:
            for name in e["participants"]:
                events[e["kind"]].setdefault(name, []).append(e["time"])
    def first_step(after, strictly):
        return next((t for t in times if (t > after + TOL if strictly else t >= after - TOL)), None)
    for name, (_, first, last) in life_spans(scenario, dt, ego_ids).items():
        expected = {
            "road_user_entered": [first_step(first, False)] if TOL < first <= end + TOL else [],
            "road_user_left": [first_step(last, True)] if last < end - TOL else [],
        }
        for kind, want in expected.items():
            got = events[kind].pop(name, [])
            if len(got) != len(want) or any(abs(g - w) > TOL for g, w in zip(got, want)):
                mismatches.append(f"{name}: {kind} at {got}, expected at {want} (recorded from "
                                  f"{first!r} to {last!r} s)")
    for kind, rest in events.items():
        for name, got in rest.items():
            mismatches.append(f"{name}: {kind} at {got}, but it is no recorded road user")
    return sum(len(v) for v in events.values()), mismatches


def contact_intervals(log_path):
    """Per road user name, mjsafe's contact intervals [start, end) from the log's
    `collision_start` / `collision_end` events: MuJoCo finds a step's contacts at the state it
    starts from, so a `collision_end` at t says the state at t has none. A contact the episode's
    end (`episode_end`, `interrupted`, `error`) closed, or one left open, runs to +inf: no step
    followed the last state to say."""
    events = list(read_messages(log_path, "/event", decode_event))
    ended = {e["time"] for e in events if e["kind"] in ("episode_end", "interrupted", "error")}
    intervals, open_at = {}, {}
    for e in events:
        for name in e["participants"]:
            if name == "vehicle":
                continue
            if e["kind"] == "collision_start":
                open_at[name] = e["time"]
            elif e["kind"] == "collision_end" and name in open_at:
                end = math.inf if e["time"] in ended else e["time"]
                intervals.setdefault(name, []).append((open_at.pop(name), end))
    for name, start in open_at.items():
        intervals.setdefault(name, []).append((start, math.inf))
    return intervals


def car_on_steps(log_path, dt):
    """The car of a log at the time steps: its extent (front, rear, half width) from the log's
    `vehicle_extent`, and (k, t, x, y, heading, state by name) of every `/state` whose time is
    k * dt within TOL, (x, y) the planar position."""
    meta = run_metadata(log_path)
    extent = tuple(map(float, meta["vehicle_extent"].split()))
    i, j = map(int, meta["planar_position"].split())
    heading_index = int(meta["heading_index"])
    poses = []
    for state in read_messages(log_path, "/state", decode_state):
        t, values = state["time"], state["values"]
        k = round(t / dt)
        if k >= 0 and abs(t - k * dt) <= TOL:
            poses.append((k, t, values[i], values[j], values[heading_index], dict(zip(state["names"], values))))
    return extent, poses


def shapely_shape(shape):
    """commonroad-io's shape as a shapely polygon. A circle is built from its centre and radius:
    commonroad-io 2026.1's `CircleOccupancy.shapely_object` is `circle_center.buffer(radius / 2)`,
    a circle of half the radius (its own `contains_point` takes the whole radius, as the schema's
    `<circle><radius>` means)."""
    from shapely.geometry import Point

    if hasattr(shape, "radius"):
        centre = shape.center
        x, y = (centre.x, centre.y) if hasattr(centre, "x") else (centre[0], centre[1])
        return Point(x, y).buffer(shape.radius, quad_segs=64)
    return shape.shapely_object


def check_contacts(scenario, log_path, dt, ego_ids=(), margin=CONTACT_MARGIN):
    """mjsafe's contacts against the shapes CommonRoad gives: at every `/state` on a time step k,
    the car's footprint (a rectangle from the log's pose and its `vehicle_extent`) against every
    road user's `occupancy_at_time(k).shape` (commonroad-io's shapely polygon). Overlapping by more
    than `margin` (the footprint shrunk by `margin` still meets the shape) must be a contact in
    the log, and a gap of more than `margin` must not be (MuJoCo finds contacts at the state before
    each step: within a step's motion of touching, either is right). Returns (pairs compared,
    pairs overlapping, mismatches)."""
    from shapely.geometry import Polygon as ShapelyPolygon

    from commonroad.prediction.prediction import TrajectoryPrediction

    # (A road user with an occupancy set only is ignored by mjsafe, and named: not compared.)
    obstacles = [o for o in scenario.dynamic_obstacles + scenario.static_obstacles
                 if o.obstacle_id not in ego_ids
                 and (o in scenario.static_obstacles or isinstance(o.prediction, TrajectoryPrediction))]
    if not obstacles:
        return 0, 0, []
    (front, rear, half_width), poses = car_on_steps(log_path, dt)
    intervals = contact_intervals(log_path)
    compared = overlapping = 0
    mismatches = []
    for k, t, x, y, heading, _ in poses:
        c, s = math.cos(heading), math.sin(heading)
        corners = [(x + a * c - b * s, y + a * s + b * c)
                   for a, b in ((front, half_width), (-rear, half_width), (-rear, -half_width), (front, -half_width))]
        car = ShapelyPolygon(corners)
        shrunk = car.buffer(-margin)
        for o in obstacles:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                recorded = o.state_at_time(k) if hasattr(o, "state_at_time") else o.initial_state
                occupancy = o.occupancy_at_time(k)
            # (A set-valued state, as A9-3's, is no pose: left out.)
            if occupancy is None or recorded is None or hasattr(recorded.position, "center"):
                continue
            # (commonroad-io 2026.1's occupancy is the shape; older ones wrap it in `.shape`.)
            shape = shapely_shape(getattr(occupancy, "shape", occupancy))
            name = f"cr_{o.obstacle_id}"
            touching = any(start <= t < end for start, end in intervals.get(name, []))
            compared += 1
            if shrunk.intersects(shape):
                overlapping += 1
                if not touching:
                    mismatches.append(f"t={t!r} (step {k}) {name}: the car overlaps its shape by more "
                                      f"than {margin} m, and the log has no contact")
            elif car.distance(shape) > margin and touching:
                mismatches.append(f"t={t!r} (step {k}) {name}: the log has a contact, and the car is "
                                  f"{car.distance(shape):.3f} m from its shape")
    return compared, overlapping, mismatches


def own_recordings(scenario, pps):
    """The ids that are the ego, not a road user: the planning problems', and a road user whose
    initial state has exactly a planning problem's initial position, orientation and time step
    (CommonRoad-CriMe's files list the ego so, and name it by `ego_id`)."""
    import numpy as np

    ids = {pp.planning_problem_id for pp in pps.planning_problem_dict.values()}
    for pp in pps.planning_problem_dict.values():
        start = pp.initial_state
        for o in scenario.dynamic_obstacles:
            s = o.initial_state
            if (s.time_step == start.time_step and np.array_equal(s.position, start.position)
                    and s.orientation == start.orientation):
                ids.add(o.obstacle_id)
    return ids


def run_metadata(path):
    """The log's `mjsafe` metadata record."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        for m in make_reader(f, validate_crcs=True).iter_metadata():
            if m.name == "mjsafe":
                return dict(m.metadata)
    raise SystemExit(f"commonroad_check: {path} has no mjsafe metadata record")


def check_goal(pps, log_path, dt, expected):
    """When the car first reached its (the file's first) planning problem's goal, as commonroad-io's
    `GoalRegion.is_reached` decides it, against mjsafe's `time_to_goal` (`expected`, None when
    absent). At every `/state` message: the car's centre (the planar position plus the log's
    `goal_offset` along the heading), orientation, velocity and time step t / dt (rounded to the
    step within 1e-9 s of one). Returns
    (commonroad-io's first time or None, mismatches)."""
    from commonroad.scenario.state import CustomState
    import numpy as np

    # (mjsafe runs the file's first planning problem unless told otherwise; commonroad-io's
    # dict keeps the file's order.)
    problems = list(pps.planning_problem_dict.values())
    if not problems:
        return None, ["goal: the file has no planning problem"]
    goal = problems[0].goal
    offset = float(run_metadata(log_path).get("goal_offset", "0"))
    first = None
    for m in read_messages(log_path, "/state", decode_state):
        v = dict(zip(m["names"], m["values"]))
        x, y, heading, speed = v["x1"], v["x2"], v["heading"], v["speed"]
        centre = np.array([x + offset * math.cos(heading), y + offset * math.sin(heading)])
        # (A state on the grid is at its integer step: 8.2 s / 0.1 s is 81.99999999999999.)
        step = m["time"] / dt
        if abs(step - round(step)) * dt <= TOL:
            step = round(step)
        state = CustomState(position=centre, orientation=heading, velocity=speed, time_step=step)
        if goal.is_reached(state):
            first = m["time"]
            break
    mismatches = []
    if first is None and expected is not None:
        # mjsafe's time_to_goal counts an entry after the window's end too.
        end = max(float(g.time_step.end) for g in goal.state_list) * dt
        if expected <= end + TOL:
            mismatches.append(f"goal: mjsafe reached it at {expected} s, within the window "
                              f"(ends {end} s); commonroad-io never")
    elif first is not None and (expected is None or abs(first - expected) > TOL):
        mismatches.append(f"goal: commonroad-io reached it at {first} s, mjsafe at {expected}")
    return first, mismatches


def write_turned(xml, out, angle, x, y):
    """The scenario and its planning problems turned by `angle` about the origin, then shifted by
    (x, y) (`translate_rotate` of commonroad-io's Scenario and PlanningProblemSet: positions,
    orientations, shapes, lanelets, goal regions and their orientation intervals), written as
    2020a XML with 12 decimals (commonroad-io's default of 4 would round the recording)."""
    import numpy as np

    scenario, pps = open_scenario(xml)
    scenario.translate_rotate(np.zeros(2), angle)
    pps.translate_rotate(np.zeros(2), angle)
    scenario.translate_rotate(np.array([x, y]), 0.0)
    pps.translate_rotate(np.array([x, y]), 0.0)
    write_scenario(scenario, pps, out, "turned")


def write_origin_shifted(xml, out, fraction):
    """The scenario with every road user's rectangle given `originXShift` = fraction × its length
    and every state of it moved by that much along its orientation, so that each rectangle stays
    where it was (commonroad-io's `compute_occupancy_for_state` puts its centre at the position
    minus the shift). Written as `write_turned` writes."""
    import numpy as np
    from commonroad.geometry.obstacle_shapes.rect_obstacle_shape import RectObstacleShape

    scenario, pps = open_scenario(xml)
    for o in scenario.dynamic_obstacles:
        shape = o.obstacle_shape
        if not isinstance(shape, RectObstacleShape):
            continue
        trajectory = getattr(o.prediction, "trajectory", None)
        states = [o.initial_state] + (list(trajectory.state_list) if trajectory else [])
        # (commonroad-io places no shifted origin in a set-valued state, as A9-3's: left as is.)
        if any(not hasattr(st.position, "__len__") or is_interval(st.orientation) for st in states):
            continue
        shift = fraction * shape.length
        # (The shape has no setter: commonroad-io keeps obstacle shapes immutable.)
        o._obstacle_shape = RectObstacleShape(width=shape.width, length=shape.length, origin_x_shift=shift)
        for state in states:
            c, s = math.cos(state.orientation), math.sin(state.orientation)
            state.position = np.array([state.position[0] + shift * c, state.position[1] + shift * s])
    write_scenario(scenario, pps, out, "origin-shifted")


def write_late_starts(xml, out, step):
    """The scenario with every second road user (by id) appearing at `step`: its initial state
    is its recorded state there and its trajectory starts after it, as files converted from
    datasets (inD, highD) have them. commonroad-io writes the initial state's time as it is (the
    2020a schema says 0). Written as `write_turned` writes."""
    from commonroad.scenario.trajectory import Trajectory

    scenario, pps = open_scenario(xml)
    for o in sorted(scenario.dynamic_obstacles, key=lambda o: o.obstacle_id)[::2]:
        trajectory = getattr(o.prediction, "trajectory", None)
        if trajectory is None or o.initial_state.time_step != 0:
            continue
        later = [st for st in trajectory.state_list if st.time_step > step]
        first = o.state_at_time(step)
        if first is None or not later:
            continue
        # (An InitialState of the same attributes, with the recorded state's values.)
        initial = copy.deepcopy(o.initial_state)
        for name in ("time_step", "position", "orientation", "velocity", "acceleration"):
            if getattr(first, name, None) is not None:
                setattr(initial, name, getattr(first, name))
        o.initial_state = initial
        o.prediction.trajectory = Trajectory(later[0].time_step, later)
    write_scenario(scenario, pps, out, "late-starts")


def write_scenario(scenario, pps, out, source):
    """`scenario` and `pps` as 2020a XML at `out`, with 12 decimals (commonroad-io's default of 4
    would round the recording)."""
    from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile
    from commonroad.common.util import FileFormat

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        CommonRoadFileWriter(scenario, pps, "tests/commonroad_check.py", "mjsafe", source,
                             scenario.tags, decimal_precision=12,
                             file_format=FileFormat.XML).write_to_file(out, OverwriteExistingFile.ALWAYS)
    if not os.path.exists(out):
        raise SystemExit(f"commonroad_check: commonroad-io wrote no {out}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("xml")
    ap.add_argument("log", nargs="?")
    ap.add_argument("--time-step-size", type=float, default=None,
                    help="dt in seconds (default: the scenario's timeStepSize)")
    ap.add_argument("--planning-problem-json", metavar="OUT")
    ap.add_argument("--lanelets-json", metavar="OUT")
    ap.add_argument("--obstacles-json", metavar="OUT")
    ap.add_argument("--set-valued", choices=["centre", "contains", "skip"], default="centre",
                    help="how to compare states given as shapes / intervals (default: centre)")
    ap.add_argument("--write-turned", nargs=4, metavar=("OUT", "ANGLE", "X", "Y"),
                    help="write the scenario and its planning problems turned by ANGLE (rad) about "
                         "the origin, then shifted by (X, Y) m (commonroad-io's translate_rotate), "
                         "as a 2020a XML file, and exit")
    ap.add_argument("--contacts", action="store_true",
                    help="check the log's contacts against the car's footprint and CommonRoad's "
                         "shapes at every time step (check_contacts)")
    ap.add_argument("--write-late-starts", nargs=2, metavar=("OUT", "STEP"),
                    help="write the scenario with every second road user appearing at STEP and exit")
    ap.add_argument("--write-origin-shifted", nargs=2, metavar=("OUT", "FRACTION"),
                    help="write the scenario with every road user's rectangle given an originXShift "
                         "of FRACTION times its length and its states moved to keep the rectangle "
                         "in place, and exit")
    ap.add_argument("--time-to-goal", metavar="T|none",
                    help="mjsafe's time_to_goal of the log: checked against commonroad-io's "
                         "GoalRegion.is_reached at every /state")
    args = ap.parse_args(argv)
    if args.write_late_starts:
        out, step = args.write_late_starts
        write_late_starts(args.xml, out, int(step))
        return 0
    if args.write_origin_shifted:
        out, fraction = args.write_origin_shifted
        write_origin_shifted(args.xml, out, float(fraction))
        return 0
    if args.write_turned:
        out, angle, x, y = args.write_turned
        write_turned(args.xml, out, float(angle), float(x), float(y))
        return 0
    if args.log is None and not (args.planning_problem_json or args.lanelets_json or args.obstacles_json):
        ap.error("nothing to do: give a log, --planning-problem-json, --lanelets-json or --obstacles-json")

    scenario, pps = open_scenario(args.xml)
    dt = args.time_step_size if args.time_step_size is not None else float(scenario.dt)
    if not dt > 0:
        ap.error(f"time step size {dt} is not positive")

    if args.planning_problem_json:
        with open(args.planning_problem_json, "w") as f:
            json.dump(planning_problems_json(pps, dt), f, indent=1)
    if args.lanelets_json:
        with open(args.lanelets_json, "w") as f:
            json.dump(lanelets_json(scenario), f)
    if args.obstacles_json:
        egos = own_recordings(scenario, pps)
        with open(args.obstacles_json, "w") as f:
            json.dump(obstacles_json(scenario, egos), f)
    if args.log is None:
        return 0

    ego_ids = own_recordings(scenario, pps)
    times = []
    messages, on_step, compared, absent, set_valued, skipped, mismatches = check_log(
        scenario, args.log, dt, args.set_valued, ego_ids, times)
    checked, without, prediction_mismatches = check_predictions(scenario, args.log, dt, ego_ids)
    mismatches += prediction_mismatches
    _, entry_mismatches = check_entries(scenario, args.log, dt, times, ego_ids)
    mismatches += entry_mismatches
    if args.contacts:
        pairs, overlapping, contact_mismatches = check_contacts(scenario, args.log, dt, ego_ids)
        mismatches += contact_mismatches
        print(f"commonroad_check: contacts: {pairs} car and road user pairs compared at time "
              f"steps, {overlapping} overlapping, {len(contact_mismatches)} mismatches")
    if args.time_to_goal is not None:
        expected = None if args.time_to_goal == "none" else float(args.time_to_goal)
        first, goal_mismatches = check_goal(pps, args.log, dt, expected)
        mismatches += goal_mismatches
        print(f"commonroad_check: goal reached at {first} s by commonroad-io, "
              f"{expected} s by mjsafe")
    print(f"commonroad_check: {checked} road-user predictions checked, {without} without an "
          "error (the road user not there at the tick or at the target time)")
    if set_valued or skipped:
        print(f"commonroad_check: {set_valued} set-valued states ({args.set_valued}), "
              f"{skipped} left out (set-valued skipped or set-based predictions)")
    print(f"commonroad_check: {compared} states compared, {absent} absent, "
          f"{len(mismatches)} mismatches")
    from commonroad.prediction.prediction import TrajectoryPrediction

    # (No /actors at all is right for a scenario without a recorded road user mjsafe reads.)
    recorded = [o for o in scenario.dynamic_obstacles
                if o.obstacle_id not in ego_ids and isinstance(o.prediction, TrajectoryPrediction)]
    if on_step == 0 and (messages > 0 or recorded):
        print(f"commonroad_check: none of the {messages} /actors messages is at a multiple of "
              f"dt = {dt}", file=sys.stderr)
        return 1
    if mismatches:
        for m in mismatches[:10]:
            print("  " + m, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
