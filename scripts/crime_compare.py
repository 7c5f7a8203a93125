"""CommonRoad-CriMe's own THW and BTN of a run of mjsafe's on a CommonRoad scenario.

Run with the CriMe venv's python (scripts/crime-compare.sh creates it: PyPI commonroad-crime
0.4.5 and mcap, nothing of mjsafe's):

    python scripts/crime_compare.py SCENARIO.xml LOG.mcap [--rotate RADIANS]

The scenario is read with commonroad-io (the version commonroad-crime pins). The car of the log
becomes one more dynamic obstacle of it: at every time step k (t = k dt within 1e-9 s of a
`/state` message) its centre (the planar position plus (front - rear) / 2 of the log's
`vehicle_extent` along the heading), heading and speed, and a rectangle of the footprint's length
and width. A dynamic obstacle listed under the planning problem's id (the ego's recorded twin in
two commonroad-crime files) is removed, as mjsafe leaves it out. The car is assigned to
lanelets (`Scenario.assign_obstacles_to_lanelets`, the car's) and CriMe's `THW` and `BTN`
(`commonroad_crime.measure`, default `CriMeConfiguration`) are computed for every other dynamic
obstacle at every time step where both exist. --rotate turns the whole scene, the car with it,
about the origin first (`Scenario.translate_rotate`): a measure of the scene's geometry does not
change. Prints one JSON object:

    {"thw": {"value": min THW (s) | null, "obstacle": id, "time": t},
     "btn": {"value": max BTN | null, "obstacle": id, "time": t},
     "evaluations": n, "errors": n, "first_error": text | null}

(null: no finite value; CriMe's THW is inf when the car never reaches the other's rear.)
"""
import json
import logging
import math
import os
import sys
import warnings

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
import commonroad_check as log_reader  # noqa: E402  (the hand decoder of /state: car_on_steps)


def ego_obstacle(scenario, log, obstacle_id):
    """The log's car as a CommonRoad dynamic obstacle, one state per time step."""
    import numpy as np
    from commonroad.geometry.shape import Rectangle
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
    from commonroad.scenario.state import CustomState, InitialState
    from commonroad.scenario.trajectory import Trajectory

    dt = scenario.dt
    (front, rear, half_width), poses = log_reader.car_on_steps(log, dt)
    states = []
    for k, _, x, y, heading, state in poses:
        shift = (front - rear) / 2.0
        centre = np.array([x + shift * math.cos(heading), y + shift * math.sin(heading)])
        speed = state["speed"]
        if not states:
            states.append(InitialState(time_step=k, position=centre, orientation=heading, velocity=speed,
                                       acceleration=0.0, yaw_rate=0.0, slip_angle=0.0))
        else:
            states.append(CustomState(time_step=k, position=centre, orientation=heading, velocity=speed))
    if len(states) < 2:
        raise SystemExit(f"crime_compare: {log} has fewer than two /state messages on time steps of {dt} s")
    shape = Rectangle(front + rear, 2.0 * half_width)
    prediction = TrajectoryPrediction(Trajectory(states[1].time_step, states[1:]), shape)
    return DynamicObstacle(obstacle_id, ObstacleType.CAR, shape, states[0], prediction), [s.time_step for s in states]


def main(argv):
    rotation = 0.0
    if len(argv) == 4 and argv[2] == "--rotate":
        rotation = float(argv[3])
    elif len(argv) != 2:
        raise SystemExit("usage: crime_compare.py SCENARIO.xml LOG.mcap [--rotate RADIANS]")
    scenario_path, log = argv[:2]
    import numpy as np
    logging.disable(logging.CRITICAL)
    warnings.simplefilter("ignore")
    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad_crime.data_structure.configuration import CriMeConfiguration
    from commonroad_crime.measure import BTN, THW

    scenario, problems = CommonRoadFileReader(scenario_path).open()
    for problem_id in problems.planning_problem_dict:
        twin = scenario.obstacle_by_id(problem_id)
        if twin is not None:
            scenario.remove_obstacle(twin)
    ego_id = scenario.generate_object_id()
    ego, steps = ego_obstacle(scenario, log, ego_id)
    scenario.add_objects(ego)
    if rotation:
        scenario.translate_rotate(np.zeros(2), rotation)
    # (The car alone: CriMe's reference path starts at its initial lanelet; commonroad-io cannot
    # assign set-valued positions, which A9-3's road users have.)
    scenario.assign_obstacles_to_lanelets(obstacle_ids={ego_id})
    config = CriMeConfiguration()
    config.update(ego_id=ego_id, sce=scenario)
    # The smallest THW, the largest BTN.
    measures = {"thw": (THW(config), lambda a, b: a < b), "btn": (BTN(config), lambda a, b: a > b)}
    best = {name: None for name in measures}
    evaluations, errors, first_error = 0, 0, None
    for other in scenario.dynamic_obstacles:
        if other.obstacle_id == ego_id:
            continue
        for k in steps:
            if other.state_at_time(k) is None:
                continue
            for name, (measure, improves) in measures.items():
                evaluations += 1
                try:
                    value = float(measure.compute(other.obstacle_id, k, verbose=False))
                except Exception as e:  # CriMe's own failure at this pair: counted, reported
                    errors += 1
                    first_error = first_error or f"{name} of {other.obstacle_id} at step {k}: {e}"
                    continue
                if math.isfinite(value) and (best[name] is None or improves(value, best[name][0])):
                    best[name] = (value, other.obstacle_id, k * scenario.dt)
    out = {name: ({"value": b[0], "obstacle": b[1], "time": round(b[2], 9)} if b else
                  {"value": None, "obstacle": None, "time": None}) for name, b in best.items()}
    out.update(evaluations=evaluations, errors=errors, first_error=first_error)
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1:])
