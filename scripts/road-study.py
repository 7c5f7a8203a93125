#!/usr/bin/env python3
"""The road study of docs/studies.md: per road width, assumed acceleration delay and jitter,
how many runs pass (reach the goal), stall, collide with the obstacle or leave the road.
Reads the sweep's summary.csv (scenarios/road_gamma_m.sweep.toml); prints a Markdown table.
    scripts/road-study.py logs/road/summary.csv
Outcome of a run: "hits" the obstacle (a MuJoCo contact: collision_time) and/or "leaves the
road" (min h of an edge < 0: edges are not MuJoCo geoms), "hits + leaves" both; otherwise
"stalls" (stall_time: below 0.05 m/s for 1 s while the filter overrides the nominal), "reaches
the goal" (time_to_goal: inside the goal disc at (10, 0) within the 12 s), "passes late" (beyond
the obstacle, x1 > 3 m, i.e. progress_along_path > 23 m, but not at the goal by 12 s), else
"neither"."""
import re
import sys

import pandas as pd

EDGE_SPARE = {-15.0: "4.5 m", -9.0: "0.5 m", -8.6: "0.1 m", -8.0: "none (−0.5 m)"}


# The obstacle's far side (x1 = -3 + 6) from the start x1 = -20, along the path y = 0.
PASSED_OBSTACLE = 23.0


def outcome(run: pd.Series) -> str:
    hits = pd.notna(run["collision_time"])
    edges = [c for c in run.index if c.startswith("min_h_by_barrier.") and "edge" in c]
    leaves = any(run[c] < 0 for c in edges)
    if hits or leaves:
        return "hits + leaves" if hits and leaves else "hits" if hits else "leaves the road"
    if pd.notna(run["stall_time"]):
        return "stalls"
    if pd.notna(run["time_to_goal"]):
        return "reaches the goal"
    if run["progress_along_path"] > PASSED_OBSTACLE:
        return "passes late"
    return "neither"


def jitter(actuation: str) -> str:
    return f"{float(re.findall(r'max = ([0-9.]+)', actuation)[0]) * 1000:.0f} ms"


def main() -> None:
    runs = pd.read_csv(sys.argv[1] if len(sys.argv) > 1 else "logs/road/summary.csv")
    runs["edge"] = runs["road.edges.1.point"].map(lambda p: float(p.strip("[]").split(",")[1]))
    runs["outcome"] = runs.apply(outcome, axis=1)
    runs["jitter"] = runs["actuation"].map(jitter)
    kinds = ["reaches the goal", "passes late", "stalls", "hits", "leaves the road", "hits + leaves", "neither"]
    jitters = list(dict.fromkeys(runs["jitter"]))
    print("| lower edge x2 (m) | spare below the obstacle | assumed D2 (s) | runs | "
          + " | ".join(kinds) + " | min clearance (m) | min h lower edge (m) |")
    print("|" + "---|" * (6 + len(kinds)))
    for (edge, d2), cell in runs.groupby(["edge", "assumed_delays.acceleration"], sort=False):
        def count(kind: str) -> str:
            n = (cell["outcome"] == kind).sum()
            if n == 0 or n == len(cell):
                return str(n)
            per = [str(((cell["outcome"] == kind) & (cell["jitter"] == j)).sum()) for j in jitters]
            return f"{n} ({'/'.join(per)})"
        print(f"| {edge:g} | {EDGE_SPARE.get(edge, '?')} | {d2:g} | {len(cell)} | "
              + " | ".join(count(k) for k in kinds)
              + f" | {cell['min_clearance'].min():.3f} | {cell['min_h_by_barrier.right_edge'].min():.3f} |")
    print()
    print(f"Counts split by extra latency ({' / '.join(jitters)}) where a cell is mixed.")
    total = runs["outcome"].value_counts()
    print()
    print(f"{len(runs)} runs: " + ", ".join(f"{total.get(k, 0)} {k}" for k in kinds))
    for edge, cell in runs.groupby("edge", sort=False):
        c = cell["outcome"].value_counts()
        print(f"- lower edge at {edge:g} m: " + ", ".join(f"{c.get(k, 0)} {k}" for k in kinds if c.get(k, 0)))


if __name__ == "__main__":
    main()
