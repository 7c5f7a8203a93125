"""Independent check of mjsafe's route through a CommonRoad scenario with CommonRoad's own route
planner.

Run with the route planner's venv python (scripts/setup.sh --test creates it at
${MJSAFE_CR_ROUTE_VENV:-~/.cache/mjsafe/cr-route-venv}: PyPI commonroad-route-planner 2025.1.0
and the commonroad-io 2024.3 it needs, nothing of mjsafe's):

    python tests/route_check.py SCENARIO.xml ID,ID,...

The scenario is read with commonroad-io (`CommonRoadFileReader(path).open()`); its only planning
problem goes to `RoutePlanner(lanelet_network, planning_problem).plan_routes()`, which returns
lanelet sequences from the lanelets the start lies in to the goal's. mjsafe's route (the lanelet
ids given, from the start lanelet to the goal lanelet) must be one of them. Prints
`route_check: mjsafe's route [..] is route K of N of the route planner` and exits 0, or lists the
planner's routes and exits 1.
"""
import logging
import sys
import warnings


def main(argv):
    if len(argv) != 2:
        raise SystemExit("usage: route_check.py SCENARIO.xml ID,ID,...")
    path, ids = argv
    ours = [int(i) for i in ids.split(",") if i.strip()]
    logging.disable(logging.CRITICAL)
    warnings.simplefilter("ignore")
    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad_route_planner.route_planner import RoutePlanner

    scenario, problems = CommonRoadFileReader(path).open()
    if len(problems.planning_problem_dict) != 1:
        raise SystemExit(f"route_check: {path} has {len(problems.planning_problem_dict)} planning "
                         "problems; the check takes files with one")
    problem = next(iter(problems.planning_problem_dict.values()))
    routes = [list(map(int, r.lanelet_ids)) for r in RoutePlanner(scenario.lanelet_network, problem).plan_routes()]
    if ours in routes:
        print(f"route_check: mjsafe's route {ours} is route {routes.index(ours) + 1} of "
              f"{len(routes)} of the route planner")
        return 0
    print(f"route_check: mjsafe's route {ours} is none of the route planner's {routes}", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
