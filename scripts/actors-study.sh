#!/usr/bin/env bash
# What the delay does against moving road users (docs/actors.md): each Euro NCAP scenario under
# the nominal alone, the delay-free CBF-QP without delays, the same filter with the delays
# (uncompensated (2.16)), and the gamma-m filter (4.67) on predictions with what it assumes of the
# actor: static (a predictor that ignores the actor's motion), constant velocity, constant
# acceleration, the oracle. Prints a Markdown table.
#   scripts/actors-study.sh [MJSAFE_BINARY] [OUT_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
mjsafe="${1:-target/release/mjsafe}"
out="${2:-logs/actors-study}"
mkdir -p "$out"
configs=(
  "nominal alone|filter={kind=\"none\"}"
  "delay-free CBF-QP, no delays|filter={kind=\"cbf_qp\",l0=4.0,l1=4.0};delays.steering=0.0;delays.acceleration=0.0"
  "delay-free CBF-QP (2.16), delays|filter={kind=\"cbf_qp\",l0=4.0,l1=4.0}"
  "(4.67), actor static|actor_knowledge.kind=\"static\""
  "(4.67), constant velocity|actor_knowledge.kind=\"constant_velocity\""
  "(4.67), constant acceleration|actor_knowledge.kind=\"constant_acceleration\""
  "(4.67), oracle|actor_knowledge.kind=\"oracle\""
)
scenarios="ncap_ccrs ncap_ccrm ncap_ccrb ncap_cpna ncap_cpfa"
printf '| configuration |'; for s in $scenarios; do printf ' %s |' "$s"; done; echo
printf '|---|'; for s in $scenarios; do printf -- '---|'; done; echo
for c in "${configs[@]}"; do
  label="${c%%|*}"; sets="${c#*|}"
  printf '| %s |' "$label"
  for s in $scenarios; do
    args=()
    IFS=';' read -ra parts <<<"$sets"
    for p in "${parts[@]}"; do args+=(--set "$p"); done
    log="$out/$s-$(echo "$label" | tr -c 'a-zA-Z0-9' '_').mcap"
    "$mjsafe" run "scenarios/$s.toml" "${args[@]}" --out "$log" >/dev/null 2>&1 || true
    "$mjsafe" analyze --json "$log" 2>/dev/null | python3 -c '
import json, sys
m = json.load(sys.stdin)[0]
c = m.get("collision")
if c:
    print(" hit at {:.2f} s ({:.2f} m deep) |".format(c["time"], c["depth"]), end="")
else:
    stall = ", stalls" if m.get("stall_time") is not None else ""
    print(" clear ({:.2f} m{}) |".format(m["min_clearance"], stall), end="")
'
  done
  echo
done
