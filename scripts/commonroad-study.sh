#!/usr/bin/env bash
# The CommonRoad study (docs/studies.md, "Real traffic"): every committed CommonRoad scenario
# (data/commonroad/) with its defaults (delays 0.2 s steering, 0.5 s acceleration; road edges;
# the goal region) under the nominal alone, the delay-free CBF-QP (2.16), the predictor CBF-QP
# (4.34) and the gamma-m filter (4.67), the road users assumed at constant velocity; then (4.67)
# with the road users assumed static, at constant acceleration and known exactly (oracle); then
# (4.67) at constant velocity with the road users observed at every 10 ms control tick and every
# 0.2 s (`actor_knowledge.period`; the default observes them when they were recorded, at each
# file's own time step, mostly 0.1 s); then (4.67) on a car with CommonRoad vehicle 2's limits
# as actuator dynamics it does not know of: the steering lock |delta| <= 1.066 rad (tan delta
# within +-1.8098), its 0.4 rad/s steering rate as 0.4 /s on tan delta (its rate at delta = 0;
# stricter than the car's at larger angles), |a| <= 11.5 m/s^2. A cell of a run without those
# limits whose commands went past them (`vehicle_limit_ratio` > 1: each world declares them as
# `[vehicle_limits]`) says how far (`max_applied_input`).
# Three sweeps with no logs (`sweep --scenarios`); prints a Markdown table. Then one figure per kind of
# scene with (4.67), each file's defaults: the scene at the car's closest approach to any road user
# (`analyze --plot`'s `-closest.png`) for the highway (US101-5, 25 cars), an urban intersection
# (Peach) and the crossing pedestrian, written to docs/figures/commonroad-{highway,intersection,pedestrian}.png.
#   scripts/commonroad-study.sh [MJSAFE_BINARY] [OUT_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
mjsafe="${1:-target/release/mjsafe}"
out="${2:-logs/commonroad-study}"
rm -rf "$out/filters" "$out/knowledge" "$out/observed" "$out/limits"
# A sweep with a failed run exits 3 (its row holds the error, shown in the table); anything else stops.
sweep() { "$mjsafe" sweep "$@" >/dev/null 2>&1 || [ $? -eq 3 ]; }
qp='kind="cbf_qp",l0=4.0,l1=4.0'
sweep --scenarios 'data/commonroad/*.xml' --no-logs --out "$out/filters" \
  --grid "filter={kind=\"none\"},{$qp},{$qp,compensation=\"predictor\"},{kind=\"gamma_m\",l0=4.0,l1=4.0,m=50.0}"
sweep --scenarios 'data/commonroad/*.xml' --no-logs --out "$out/knowledge" \
  --grid 'actor_knowledge.kind=static,constant_acceleration,oracle'
sweep --scenarios 'data/commonroad/*.xml' --no-logs --out "$out/observed" \
  --grid 'actor_knowledge.period=0.0,0.2'
limits='{steering={min=-1.8098,max=1.8098,rate_limit=0.4},acceleration={min=-11.5,max=11.5}}'
sweep --scenarios 'data/commonroad/*.xml' --no-logs --out "$out/limits" --grid "actuator_dynamics=$limits"
python3 - "$out" <<'PY'
import csv, math, sys
out = sys.argv[1]
label = {
    '{kind="none"}': "nominal alone",
    '{kind="cbf_qp",l0=4.0,l1=4.0}': "delay-free CBF-QP (2.16)",
    '{kind="cbf_qp",l0=4.0,l1=4.0,compensation="predictor"}': "(4.34)",
    '{kind="gamma_m",l0=4.0,l1=4.0,m=50.0}': "(4.67)",
    'static': "(4.67), static", '"static"': "(4.67), static",
    'constant_acceleration': "(4.67), const. accel.", '"constant_acceleration"': "(4.67), const. accel.",
    'oracle': "(4.67), oracle", '"oracle"': "(4.67), oracle",
    '0.0': "(4.67), observed every tick", '0.2': "(4.67), observed every 0.2 s",
}
columns, cells = [], {}
sweeps = (("filters", "filter"), ("knowledge", "actor_knowledge.kind"), ("observed", "actor_knowledge.period"),
          ("limits", "actuator_dynamics"))
for sweep, key in sweeps:
    for row in csv.DictReader(open(f"{out}/{sweep}/summary.csv")):
        column = "(4.67), vehicle 2's limits" if sweep == "limits" else label[row[key]]
        if column not in columns:
            columns.append(column)
        if row["collision_with"]:
            speed = row.get(f"impact_speed_by_actor.{row['collision_with']}", "")
            cell = f"**hit {row['collision_with']}** {float(row['collision_time']):.2f} s"
            if speed:
                cell += f", {float(speed):.1f} m/s"
        else:
            cell = "clear"
            ttc = row.get("min_time_to_collision", "")
            if ttc:
                cell += f", TTC {float(ttc):.1f} s"
        # CommonRoad-CriMe's time headway and brake threat number (docs/metrics.md).
        thw, btn = row.get("min_time_headway", ""), row.get("max_brake_threat_number", "")
        if thw:
            cell += f", THW {float(thw):.2f} s"
        if btn:
            cell += f", BTN {float(btn):.2f}"
        # Every planning problem has a goal (a goal of a time alone is reached by lasting into
        # its window).
        goal = row.get("time_to_goal", "")
        cell += f"; goal {float(goal):.1f} s" if goal else "; goal missed"
        if row.get("stall_time", ""):
            cell += f"; stall {float(row['stall_time']):.1f} s"
        # Inputs that reached the car past what vehicle 2 can do, as each world declares it
        # (`vehicle_limit_ratio` > 1; a run with the limits as actuator dynamics has them clipped).
        steer, accel = row.get("max_applied_input.steering", ""), row.get("max_applied_input.acceleration", "")
        past = lambda channel: float(row.get(f"vehicle_limit_ratio.{channel}", "") or 0.0) > 1.0
        beyond = []
        if past("steering"):
            beyond.append(f"δ {math.degrees(math.atan(float(steer))):.0f}°")
        if past("acceleration"):
            beyond.append(f"a {float(accel):.1f} m/s²")
        if beyond:
            cell += "; past vehicle 2: " + ", ".join(beyond)
        # A run that stopped with an error (its row has what happened before it).
        if row["error"]:
            cell += f"; **stopped at {float(row['simulated_time']):.2f} s: error**"
        # By file: two commonroad-crime files share a benchmark ID.
        cells[(row["commonroad.file"].strip('"').removesuffix(".xml"), column)] = cell
scenarios = sorted({s for s, _ in cells})
print("| file | " + " | ".join(columns) + " |")
print("|---|" + "---|" * len(columns))
for s in scenarios:
    print(f"| {s} | " + " | ".join(cells.get((s, c), "") for c in columns) + " |")
PY
for pair in highway:USA_US101-5_1_T-1 intersection:USA_Peach-4_8_T-1 pedestrian:OSC_PedestrianCollision-1_1_T-1; do
  kind="${pair%%:*}" file="${pair#*:}"
  "$mjsafe" run "data/commonroad/$file.xml" --out "$out/$kind.mcap" >/dev/null 2>&1
  "$mjsafe" analyze --plot "$out/plots" "$out/$kind.mcap" >/dev/null 2>&1
  mkdir -p docs/figures
  cp "$out/plots/$kind-closest.png" "docs/figures/commonroad-$kind.png"
done
