"""Type stubs of the mjsafe package (see __init__.py for the documentation)."""

import os
from typing import Any, Mapping, Sequence

import pandas as pd

__version__: str
__all__: list[str]

_Path = str | os.PathLike[str]
_Range = tuple[float, float] | tuple[float, float, float]

def toml_value(value: Any) -> str: ...

class RunResult:
    min_h: float | None
    collision: dict[str, Any] | None
    metrics: dict[str, Any]
    error: str | None
    log: str | None
    steps: int
    simulated_time: float
    real_time_factor: float | None
    def __init__(self, raw: dict[str, Any]) -> None: ...
    def tables(self) -> dict[str, pd.DataFrame]: ...

class LogData:
    path: str
    metrics: dict[str, Any]
    def __init__(self, path: _Path) -> None: ...
    def tables(self) -> dict[str, pd.DataFrame]: ...

class FalsifyResult:
    counterexamples: list[dict[str, Any]]
    scenario_tomls: list[str]
    scenario_toml: str | None
    evaluations: pd.DataFrame
    reproduced_all: list[float | None]
    reproduced: float | None
    logs: list[str]
    log: str | None
    out: str | None
    interrupted: bool
    runs: int
    qualified: int
    proves_nothing: bool
    wall_seconds: float
    run_seconds: float
    threads: int
    own_seconds: float | None

def run(
    path: _Path,
    set: Mapping[str, Any] | None = None,
    out: _Path | None = None,
    tables: bool = False,
    require: Mapping[str, str] | None = None,
) -> RunResult: ...
def read_log(path: _Path) -> LogData: ...
def sweep(
    path: _Path | None = None,
    grid: Mapping[str, Sequence[Any]] | None = None,
    random: Mapping[str, _Range] | None = None,
    draws: int = 0,
    seed: int = 0,
    set: Mapping[str, Any] | None = None,
    threads: int | None = None,
    *,
    out: _Path | None = None,
    require: Mapping[str, str] | None = None,
    scenarios: Sequence[_Path] | None = None,
    sweep_file: _Path | None = None,
) -> pd.DataFrame: ...
def falsify(
    path: _Path,
    ranges: Mapping[str, _Range],
    baseline: Mapping[str, Any] | None = None,
    budget: int = 200,
    seed: int = 0,
    objective: str = "min_h",
    threshold: float = 0.0,
    worst: bool = False,
    *,
    set: Mapping[str, Any] | None = None,
    baseline_threshold: float = 0.0,
    baseline_no_stall: bool = False,
    baseline_reaches_goal: bool = False,
    compare_random: bool = False,
    threads: int | None = None,
    out: _Path | None = None,
    require: Mapping[str, str] | None = None,
    method: str = "guided",
    counterexamples: int = 1,
    tolerance: float = 1e-4,
) -> FalsifyResult: ...
def scorecard(
    filters: Sequence[str | Mapping[str, Any]],
    suite: _Path = "standard",
    threads: int | None = None,
    *,
    out: _Path | None = None,
    keep_logs: str = "failing",
) -> pd.DataFrame: ...
def register_filter(kind: str, cls: type, replace: bool = False) -> None: ...
def register_nominal(kind: str, cls: type, replace: bool = False) -> None: ...

from mjsafe.env import Env as Env
from mjsafe import filter as filter
