#!/usr/bin/env python3
"""Load an mjsafe run into pandas DataFrames, one per topic, indexed by time (s).

    import load_log
    tables = load_log.load("logs/run.mcap")          # runs `mjsafe export --format parquet`
    tables = load_log.load("exports/", stem="run")   # or reads an export already written
    tables["/state"][["x1", "x2"]].plot()
    tables["/barrier"]["obstacle_0.h"].min()

From the command line, `python3 load_log.py LOG.mcap|DIR [--stem STEM] [--json]` prints each
table's shape and columns (or, with --json, every table as {column: [values]} for checks).
Needs pandas and pyarrow (CSV exports need pandas only). The `mjsafe` binary is taken from
$MJSAFE, else from PATH.
"""
import glob
import json
import math
import os
import subprocess
import sys
import tempfile

import pandas as pd

# File suffix of each topic's table (`mjsafe export`: <stem>-<suffix>.parquet|csv).
TOPICS = ["/state", "/command/issued", "/command/applied", "/barrier", "/filter", "/event",
          "/prediction", "/state/measured", "/command/actuated"]


def suffix(topic):
    return topic.lstrip("/").replace("/", "_")


def read_table(path):
    if path.endswith(".parquet"):
        frame = pd.read_parquet(path)
    else:
        # The exact doubles the log holds (the export writes them round-trippable): pandas 3
        # parses them exactly by default and deprecates `float_precision`; older pandas needs
        # "round_trip".
        exact = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}
        frame = pd.read_csv(path, keep_default_na=False, na_values=["NaN"], **exact)
    return frame.set_index("time")


def load_export(directory, stem):
    """{topic: DataFrame} of the tables `mjsafe export` wrote for the log `stem`."""
    tables = {}
    for topic in TOPICS:
        for ext in ("parquet", "csv"):
            path = os.path.join(directory, f"{stem}-{suffix(topic)}.{ext}")
            if os.path.exists(path):
                tables[topic] = read_table(path)
                break
    return tables


def load(path, stem=None):
    """{topic: DataFrame} of a log (.mcap, exported to a temporary directory) or an export
    directory (with the log's file stem, or the only stem in it)."""
    if path.endswith(".mcap"):
        mjsafe = os.environ.get("MJSAFE", "mjsafe")
        with tempfile.TemporaryDirectory() as out:
            subprocess.run([mjsafe, "export", path, "--format", "parquet", "--out", out],
                           check=True, stdout=subprocess.DEVNULL)
            return load_export(out, os.path.splitext(os.path.basename(path))[0])
    if stem is None:
        stems = {os.path.basename(p).rsplit("-state.", 1)[0]
                 for p in glob.glob(os.path.join(path, "*-state.*"))}
        if len(stems) != 1:
            raise SystemExit(f"{path}: give --stem (logs exported here: {sorted(stems)})")
        stem = stems.pop()
    return load_export(path, stem)


def as_json(tables):
    def value(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None if math.isnan(v) else ("inf" if v > 0 else "-inf")
        return v.item() if hasattr(v, "item") else v
    return {topic: {"time": [value(v) for v in frame.index],
                    **{c: [value(v) for v in frame[c]] for c in frame.columns}}
            for topic, frame in tables.items()}


if __name__ == "__main__":
    args = sys.argv[1:]
    stem = None
    if "--stem" in args:
        i = args.index("--stem")
        stem = args[i + 1]
        del args[i:i + 2]
    tables = load(args[0], stem)
    if "--json" in args:
        json.dump(as_json(tables), sys.stdout)
    else:
        for topic, frame in tables.items():
            print(f"{topic}: {frame.shape[0]} rows, columns {list(frame.columns)}")
