"""Shared helpers of the mjsafe package's tests: the repository, the `mjsafe` binary (the
command line the package is compared with, as an independent reference) and its outputs."""

import json
import os
import subprocess
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]


def scenario(name: str) -> str:
    return str(ROOT / "scenarios" / name)


def cli_binary() -> str:
    """$MJSAFE (scripts/test.sh sets it), else the debug build of $CARGO_TARGET_DIR or target/."""
    path = os.environ.get("MJSAFE") or os.path.join(os.environ.get("CARGO_TARGET_DIR", str(ROOT / "target")), "debug", "mjsafe")
    path = os.path.abspath(path)
    if not os.access(path, os.X_OK):
        pytest.fail(f"no mjsafe binary at {path}: build it (cargo build) or set MJSAFE")
    return path


def cli(*args: str, ok: bool = True) -> subprocess.CompletedProcess:
    """`mjsafe ARGS…` run from the repository."""
    done = subprocess.run([cli_binary(), *args], cwd=ROOT, capture_output=True, text=True)
    if ok:
        assert done.returncode == 0, f"mjsafe {' '.join(args)}: {done.stderr}"
    return done


def cli_error(*args: str) -> str:
    """The error line (without `error: `) of a command that fails."""
    done = cli(*args, ok=False)
    assert done.returncode != 0, f"mjsafe {' '.join(args)} succeeded"
    lines = [l for l in done.stderr.splitlines() if l.startswith("error: ")]
    assert lines, done.stderr
    return lines[-1].removeprefix("error: ")


def analyze_json(log: str) -> dict:
    """`mjsafe analyze --json LOG`: the run's object."""
    [run] = json.loads(cli("analyze", "--json", log).stdout)
    return run


def read_export_csv(path: Path) -> pd.DataFrame:
    """An `mjsafe export` CSV as examples/python/load_log.py reads it (exact doubles, NaN as
    written, empty text kept), with `time` as a column."""
    exact = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}
    return pd.read_csv(path, keep_default_na=False, na_values=["NaN"], **exact)


def export_tables(log: str, out: Path) -> dict:
    """{topic: DataFrame} of `mjsafe export LOG --out OUT` (CSV)."""
    cli("export", log, "--out", str(out))
    stem = Path(log).stem
    # <stem>-<topic with its slashes as underscores>.csv
    return {"/" + path.stem.removeprefix(stem + "-").replace("_", "/"): read_export_csv(path)
            for path in sorted(out.glob(f"{stem}-*.csv"))}


@pytest.fixture
def root() -> Path:
    return ROOT
