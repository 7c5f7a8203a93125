#!/usr/bin/env bash
# mjsafe's min_time_headway and max_brake_threat_number next to CommonRoad-CriMe's own THW and
# BTN (PyPI commonroad-crime 0.4.5) of the same runs: every committed CommonRoad scenario with its
# defaults and the nominal alone, one log each; CriMe computes on the logged car
# (scripts/crime_compare.py). Prints Markdown table rows (docs/studies.md, "Against CriMe itself").
# Makes a venv at $HOME/.cache/mjsafe/crime-venv (commonroad-crime pins commonroad-io 2024.3,
# which differs from the CommonRoad reader's venv; its polygon3 dependency is built from source).
#   scripts/crime-compare.sh [MJSAFE_BINARY] [OUT_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
mjsafe="${1:-target/release/mjsafe}"
out="${2:-logs/crime-compare}"
crime_version=0.4.5
mcap_pin=$(grep -m 1 '^mcap==' scripts/requirements-test.txt)
venv="$HOME/.cache/mjsafe/crime-venv"
if ! "$venv/bin/python" -c "import importlib.metadata as m, sys; sys.exit(m.version('commonroad-crime') != '$crime_version')" 2>/dev/null; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --disable-pip-version-check --prefer-binary "commonroad-crime==$crime_version" "$mcap_pin"
fi
mkdir -p "$out"
echo "| file | mjsafe THW | CriMe THW (road user, t) | mjsafe BTN | CriMe BTN (road user, t) | CriMe failed on |"
echo "|---|---|---|---|---|---|"
for scenario in data/commonroad/*.xml; do
  name=$(basename "$scenario" .xml)
  log="$out/$name.mcap"
  rm -f "$log"
  "$mjsafe" run "$scenario" --set 'filter={kind="none"}' --out "$log" >/dev/null 2>&1
  ours=$("$mjsafe" analyze "$log" --json)
  theirs=$("$venv/bin/python" scripts/crime_compare.py "$scenario" "$log")
  python3 - "$name" "$ours" "$theirs" <<'PY'
import json, sys
name, ours, theirs = sys.argv[1], json.loads(sys.argv[2]), json.loads(sys.argv[3])
ours = ours[0] if isinstance(ours, list) else ours
def mine(key, unit):
    v = ours.get(key)
    return "—" if v is None else f"{v:.2f}{unit}"
def crime(key, unit):
    m = theirs[key]
    return "—" if m["value"] is None else f"{m['value']:.2f}{unit} (cr_{m['obstacle']}, {m['time']:.1f} s)"
failed = f"{theirs['errors']} of {theirs['evaluations']}" if theirs["errors"] else "—"
print(f"| {name} | {mine('min_time_headway', ' s')} | {crime('thw', ' s')} | "
      f"{mine('max_brake_threat_number', '')} | {crime('btn', '')} | {failed} |")
PY
done
# The same run of US101-3 with the whole scene turned about the origin (a measure of the scene's
# geometry does not change; mjsafe's are computed in the car's own frame).
echo
echo "| US101-3 turned by (rad) | CriMe THW | CriMe BTN |"
echo "|---|---|---|"
for angle in 0 0.3 1.0 1.5707963267948966 3.141592653589793; do
  "$venv/bin/python" scripts/crime_compare.py data/commonroad/USA_US101-3_3_T-1.xml "$out/USA_US101-3_3_T-1.mcap" \
    --rotate "$angle" | python3 -c "
import json, sys
m = json.load(sys.stdin)
show = lambda v, unit: '—' if v is None else f'{v:.2f}{unit}'
print(f\"| {float(sys.argv[1]):.2f} | {show(m['thw']['value'], ' s')} | {show(m['btn']['value'], '')} |\")" "$angle"
done
