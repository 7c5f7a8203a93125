#!/usr/bin/env bash
# What the road users out of reach of a CommonRoad world cost (docs/performance.md, "Stop 82"):
# the file as imported, and the same scenario with only the road users whose least h over the
# run is below H (m², default 100), run with `mjsafe bench` (median of five) and counted by
# scripts/instructions.sh. The two runs' issued commands must be the same (the far road users
# change nothing: tests/commonroad.rs, road_users_out_of_reach_on_lankershim_change_nothing).
#
#   scripts/reach-cost.sh [--mjsafe BINARY] FILE.xml [H]
set -euo pipefail
cd "$(dirname "$0")/.."
mjsafe="${CARGO_TARGET_DIR:-target}/debug/mjsafe"
if [[ ${1:-} == --mjsafe ]]; then
  mjsafe=$2
  shift 2
fi
[[ $# -ge 1 ]] || { echo "usage: scripts/reach-cost.sh [--mjsafe BINARY] FILE.xml [H]" >&2; exit 2; }
xml=$1
limit=${2:-100}
[[ -x $mjsafe ]] || { echo "reach-cost: no mjsafe binary at $mjsafe (cargo build --bin mjsafe)" >&2; exit 2; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$mjsafe" import commonroad "$xml" --out "$work/whole.toml" > "$work/import.txt" 2>&1 || { cat "$work/import.txt" >&2; exit 1; }
"$mjsafe" run "$work/whole.toml" --out "$work/whole.mcap" --json 2> /dev/null > "$work/whole.json"
python3 - "$work" "$limit" <<'EOF'
import json, sys, tomllib
work, limit = sys.argv[1], float(sys.argv[2])
summary = json.load(open(f"{work}/whole.json"))
near = {name for name, h in summary["min_h_by_barrier"].items() if h is not None and h < limit}
text = open(f"{work}/whole.toml").read()
# The import writes each road user as one [[obstacles]] block (its table and two subtables);
# keep the blocks of the near ones, and what follows the last block.
head, *blocks = text.split("\n[[obstacles]]\n")
kept, tail = [], ""
for i, block in enumerate(blocks):
    if i == len(blocks) - 1:
        end = block.find("\n[", block.find("[obstacles.motion]") + 1)
        block, tail = (block, "") if end < 0 else (block[:end], block[end:])
    name = tomllib.loads("[[obstacles]]\n" + block)["obstacles"][0]["name"]
    if name in near:
        kept.append(block)
open(f"{work}/near.toml", "w").write(head + "".join("\n[[obstacles]]\n" + b for b in kept) + tail)
print(f"{len(blocks)} road users; {len(kept)} with least h below {limit:g} m² kept: {' '.join(sorted(n for n in near if n.startswith('cr_')))}")
EOF
"$mjsafe" run "$work/near.toml" --out "$work/near.mcap" --json 2> /dev/null > "$work/near.json"
python3 - "$work" <<'EOF'
import json, sys
work = sys.argv[1]
rows = [json.load(open(f"{work}/{n}.json"))["barrier_rows"] for n in ("whole", "near")]
print(f"rows formed {rows[0]['formed']} and {rows[1]['formed']}, left out {rows[0]['left_out']} and {rows[1]['left_out']}")
EOF
# The issued commands, as exported tables (CSV: shortest round-trip decimals of each value).
"$mjsafe" export "$work/whole.mcap" "$work/near.mcap" --topics /command/issued --out "$work" > /dev/null
if ! cmp -s "$work/whole-command_issued.csv" "$work/near-command_issued.csv"; then
  echo "reach-cost: the issued commands differ without the road users out of reach" >&2
  exit 1
fi
echo "issued commands: the same"
for case in whole near; do
  echo "== $case"
  "$mjsafe" bench "$work/$case.toml" --repeat 5 | tail -1 | awk '{print "bench: bare " $4 ", pipeline " $5 ", with the log " $6}'
  scripts/instructions.sh "$mjsafe" "$work/$case.toml" | tail -n +2
done
