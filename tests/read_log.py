"""Independent reader for mjsafe logs: the Python `mcap` library with CRC validation and
`mcap-protobuf-support` decoding every message from the schema embedded in the file (no
mjsafe code involved). Prints a JSON digest that tests/log_format.rs checks."""
import json
import sys

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def main(path):
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        counts, schemas, encodings = {}, {}, {}
        first, last, events, applied, issued, barrier = {}, {}, [], [], [], []
        scene_ids, logs, scene_lines = set(), [], {}
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            schemas[topic] = schema.name
            encodings[topic] = [schema.encoding, channel.message_encoding]
            if schema.name.startswith("foxglove."):
                stamps = [e.timestamp for e in decoded.entities] if topic == "/scene" else [decoded.timestamp]
                for stamp in stamps:
                    if message.log_time != stamp.seconds * 1_000_000_000 + stamp.nanos:
                        raise SystemExit(f"{topic}: log_time {message.log_time} != timestamp {stamp}")
                if topic == "/scene":
                    scene_ids.update(e.id for e in decoded.entities)
                    for e in decoded.entities:
                        if e.id.startswith(("road/", "barrier/", "goal")):
                            scene_lines[e.id] = [{"type": l.type, "points": [[p.x, p.y] for p in l.points]} for l in e.lines]
                if topic == "/log":
                    logs.append({"time": message.log_time / 1e9, "level": decoded.level, "message": decoded.message, "name": decoded.name})
                continue
            if message.log_time != round(decoded.time * 1e9):
                raise SystemExit(f"{topic}: log_time {message.log_time} != time {decoded.time}")
            if topic == "/state":
                row = {"time": decoded.time, "step": decoded.step, "names": list(decoded.names), "values": list(decoded.values)}
                first.setdefault("state", row)
                last["state"] = row
            elif topic == "/event":
                events.append({"time": decoded.time, "kind": decoded.kind, "participants": list(decoded.participants), "depth": decoded.depth})
            elif topic == "/command/applied" and len(applied) < 100000:
                applied.append({"time": decoded.time, "values": list(decoded.values), "issued_at": list(decoded.issued_at)})
            elif topic == "/command/issued":
                issued.append({"time": decoded.time, "nominal": list(decoded.nominal), "filtered": list(decoded.filtered), "channels": list(decoded.channels)})
            elif topic == "/barrier":
                barrier.append({"time": decoded.time, "h": [b.h for b in decoded.barriers], "known": [b.known for b in decoded.barriers]})
    print(json.dumps({
        "message_count": summary.statistics.message_count,
        "counts": counts,
        "schemas": schemas,
        "encodings": encodings,
        "metadata": metadata,
        "first_state": first.get("state"),
        "last_state": last.get("state"),
        "events": events,
        "applied": applied,
        "issued": issued,
        "barrier": barrier,
        "scene_ids": sorted(scene_ids),
        "scene_lines": scene_lines,
        "logs": logs,
    }))


if __name__ == "__main__":
    main(sys.argv[1])
