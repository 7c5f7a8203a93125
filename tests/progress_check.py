"""Independent reading of a mjsafe log for tests/progress.rs: the Python `mcap` library decodes
every message from the schema in the file (no mjsafe code), and the progress metrics, the stall
and the `stall` events are computed here from their documented definitions (docs/metrics.md).
Prints one JSON object."""
import json
import math
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

STALL_SPEED, STALL_DURATION = 0.05, 1.0


def main(path):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}["mjsafe"]
        period = float(meta["control_period"])
        i, j = (int(k) for k in meta["planar_position"].split())
        goal = [float(v) for v in meta["goal_position"].split()] if "goal_position" in meta else None
        radius = float(meta["goal_radius"]) if "goal_radius" in meta else None
        by = float(meta["goal_by"]) if "goal_by" in meta else math.inf
        path_heading = float(meta["reference_path"].split()[2]) if "reference_path" in meta else None
        states, events = [], []
        overriding, last_tick, since, stall = False, None, None, None
        for _, channel, _, m in reader.iter_decoded_messages(log_time_order=False):
            if channel.topic == "/filter":
                overriding = m.active
            elif channel.topic == "/event":
                events.append({"time": m.time, "kind": m.kind, "message": m.message})
            elif channel.topic == "/state":
                p = (m.time, m.values[i], m.values[j])
                states.append(p)
                if abs(m.time / period - round(m.time / period)) > 1e-6:
                    continue
                if last_tick is not None:
                    speed = math.hypot(p[1] - last_tick[1], p[2] - last_tick[2]) / (p[0] - last_tick[0])
                    if speed < STALL_SPEED and overriding:
                        since = last_tick[0] if since is None else since
                        if stall is None and p[0] - since >= STALL_DURATION - 1e-9:
                            stall = since
                    else:
                        since = None
                last_tick = p
    out = {"stall_time": stall, "events": [e for e in events if e["kind"] == "stall"]}
    if goal is not None:
        d = [(math.hypot(x - goal[0], y - goal[1]), t) for t, x, y in states]
        out["distance_to_goal"] = max(0.0, min(dd for dd, t in d if t <= by + 1e-9) - radius)
        out["time_to_goal"] = next((t for dd, t in d if dd <= radius), None)
    if path_heading is not None:
        first, last = min(states), max(states)
        out["progress_along_path"] = (last[1] - first[1]) * math.cos(path_heading) + (last[2] - first[2]) * math.sin(path_heading)
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1])
