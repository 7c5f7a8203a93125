"""mjsafe from Python: run, sweep and falsify scenarios and read their logs, with the Rust core
doing the work (the same run path, search and log reader as the ``mjsafe`` command line).

    import mjsafe
    r = mjsafe.run("scenarios/bicycle_obstacle.toml", set={"delays.steering": 0.4})
    r.min_h, r.collision            # -18.6..., {'time': 3.68, 'with': 'obstacle_0', 'depth': 1.83}
    r.metrics["min_clearance"]      # every metric of `mjsafe analyze --json`

    summary = mjsafe.sweep("scenarios/bicycle_obstacle.toml",
                           grid={"delays.acceleration": [0.5, 1.0, 1.5]})
    found = mjsafe.falsify("scenarios/bicycle_obstacle_gamma_m.toml",
                           ranges={"delays.steering": (0.0, 0.5)}, budget=40)
    log = mjsafe.read_log("logs/run.mcap")
    log.tables()["/barrier"]        # pandas DataFrame, the columns of `mjsafe export`

Arguments take what the command line takes, in Python types: ``set={"delays.steering": 0.4,
"filter": {"kind": "gamma_m", "l0": 4.0, "l1": 4.0, "m": 50.0}}`` is ``--set
delays.steering=0.4 --set filter={kind="gamma_m", l0=4.0, l1=4.0, m=50.0}``. An argument of
the wrong Python type raises ``TypeError`` naming it; a bad value (an unknown key, a value the
scenario refuses, a missing file) raises ``ValueError`` with the command line's error line. See
docs/python.md.
"""

from __future__ import annotations

import io
import json
import numbers
import operator
import os
import tempfile
import warnings
from collections.abc import Mapping as _MappingABC
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from mjsafe import _core

__version__: str = _core.__version__

__all__ = [
    "run",
    "sweep",
    "falsify",
    "scorecard",
    "read_log",
    "RunResult",
    "FalsifyResult",
    "LogData",
    "toml_value",
    "register_filter",
    "register_nominal",
    "Env",
]


def toml_value(value: Any) -> str:
    """The TOML text ``set`` makes of a Python value: what ``--set KEY=`` would be given."""
    return _core.toml_value(value)


# Argument checks: a wrong Python type is a TypeError naming the argument and the type it
# must be (as Python's own functions word it); a right type with a bad value is a ValueError
# (the command line's error line when it is the command line's check).

_U64_MAX = 2**64 - 1


def _type_error(function: str, name: str, expected: str, value: Any) -> TypeError:
    return TypeError(f"{function}(): argument '{name}' must be {expected}, not {type(value).__name__}")


def _path(function: str, name: str, value: Any, optional: bool = False) -> str | None:
    if value is None and optional:
        return None
    if isinstance(value, (str, bytes, os.PathLike)):
        path = os.fspath(value)
        return os.fsdecode(path) if isinstance(path, bytes) else path
    raise _type_error(function, name, "a str or os.PathLike" + (" or None" if optional else ""), value)


def _int(function: str, name: str, value: Any, low: int, optional: bool = False) -> int | None:
    if value is None and optional:
        return None
    if isinstance(value, (bool, np.bool_)) or not hasattr(type(value), "__index__"):
        raise _type_error(function, name, "an int" + (" or None" if optional else ""), value)
    number = operator.index(value)
    if not low <= number <= _U64_MAX:
        raise ValueError(f"{function}(): argument '{name}' must be an integer in {low}..=2^64 - 1, found {number}")
    return number


def _float(function: str, name: str, value: Any) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise _type_error(function, name, "a real number (int or float)", value)
    return float(value)


def _bool(function: str, name: str, value: Any) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise _type_error(function, name, "a bool", value)
    return bool(value)


def _str(function: str, name: str, value: Any) -> str:
    if not isinstance(value, str):
        raise _type_error(function, name, "a str", value)
    return value


def _mapping(function: str, name: str, value: Any, what: str, optional: bool = True) -> Mapping[str, Any] | None:
    if value is None and optional:
        return None
    if not isinstance(value, _MappingABC):
        raise _type_error(function, name, what + (" or None" if optional else ""), value)
    return value


_SET = "a dict of dotted keys to values"
_RANGES = "a dict of dotted keys to (lo, hi) or (lo, hi, step)"
_REQUIRE = "a dict of requirement names to STL formulas (str)"


def _class(function: str, kind: Any, cls: Any) -> None:
    _str(function, "kind", kind)
    if not isinstance(cls, type):
        raise _type_error(function, "cls", "a class", cls)


def _read_csv(source: str | os.PathLike[str] | io.StringIO) -> pd.DataFrame:
    """A CSV mjsafe wrote, read as pandas reads it with the exact doubles it holds."""
    # pandas 3 parses floats exactly by default (and deprecates `float_precision`); older
    # pandas needs "round_trip".
    exact = {} if int(pd.__version__.split(".")[0]) >= 3 else {"float_precision": "round_trip"}
    return pd.read_csv(source, **exact)


def _frames(tables: Mapping[str, list[tuple[str, str, Any]]]) -> dict[str, pd.DataFrame]:
    """{topic: DataFrame} of the tables the Rust side hands over (column, kind, values)."""
    frames = {}
    for topic, columns in tables.items():
        data = {}
        for name, kind, values in columns:
            if kind == "f64":
                data[name] = np.frombuffer(values, dtype="<f8").copy()
            elif kind == "u64":
                # Step counts and relative degrees: int64 as pandas reads the export's CSV.
                data[name] = np.frombuffer(values, dtype="<u8").astype(np.int64)
            elif kind == "bool":
                data[name] = np.frombuffer(values, dtype=np.uint8).astype(bool)
            else:
                data[name] = pd.Series(values, dtype="str")
        frames[topic] = pd.DataFrame(data)
    return frames


class RunResult:
    """One run's outcome (what ``mjsafe run --json`` prints, and the run's metrics).

    Attributes:
        min_h: min h over every barrier and step (None when the barriers have different units;
            see ``metrics["min_h_by_barrier"]``).
        collision: None, or ``{"time": s, "with": obstacle, "depth": m}`` of the first one.
        metrics: the run's object of ``mjsafe analyze --json`` (every metric, ``units``,
            ``complete``, ``error``, …); ``metrics["file"]`` is the log, or ``"(in memory)"``.
        error: None, or why the run stopped early (the run's error line); the run is then
            ``metrics["complete"] == False``.
        log: the MCAP log written (``out=``), or None.
        steps, simulated_time, real_time_factor: as ``mjsafe run --json`` reports them.
    """

    def __init__(self, raw: dict[str, Any]) -> None:
        self.metrics: dict[str, Any] = json.loads(raw["metrics"])
        self.min_h: float | None = self.metrics.get("min_h")
        self.collision: dict[str, Any] | None = self.metrics.get("collision")
        self.error: str | None = raw["error"]
        self.log: str | None = raw["log"]
        self.steps: int = raw["steps"]
        self.simulated_time: float = raw["simulated_time"]
        self.real_time_factor: float | None = raw["real_time_factor"]
        self._tables = raw["tables"]

    def tables(self) -> dict[str, pd.DataFrame]:
        """``{topic: DataFrame}``, one per topic with messages, with the columns of
        ``mjsafe export`` (``time`` first). Kept in memory by ``run(..., tables=True)``, else
        read from the run's log; a run with neither has none (``ValueError``)."""
        if self._tables is not None:
            return _frames(self._tables)
        if self.log is not None:
            return _frames(_core.log_tables(self.log))
        raise ValueError(
            "this run kept no tables and wrote no log: run it with tables=True (tables kept in "
            "memory) or with out=PATH (tables read from the log)"
        )

    def __repr__(self) -> str:
        collision = "no collision" if self.collision is None else f"collision at t = {self.collision['time']:.3f} s"
        error = "" if self.error is None else f", error={self.error!r}"
        return f"RunResult({self.metrics.get('scenario')!r}, min_h={self.min_h}, {collision}, log={self.log!r}{error})"


class LogData:
    """A log read by mjsafe's log reader: its metrics (``mjsafe analyze --json``) and tables
    (``mjsafe export``)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path: str = os.fspath(path)
        self.metrics: dict[str, Any] = json.loads(_core.log_metrics(self.path))

    def tables(self) -> dict[str, pd.DataFrame]:
        """``{topic: DataFrame}`` with the columns of ``mjsafe export`` (``time`` first)."""
        return _frames(_core.log_tables(self.path))

    def __repr__(self) -> str:
        return f"LogData({self.path!r})"


class FalsifyResult:
    """What a falsification search found.

    Attributes:
        counterexamples: the values found (``{range key: value}``, ready for ``set=``), one per
            distinct failure mode (``counterexamples=K``): the first violation (with
            ``worst=True`` the most severe one) first; empty if none.
        scenario_tomls: each counterexample as a standalone scenario (TOML text);
            ``scenario_toml`` is the first, or None.
        evaluations: every evaluated candidate (the rows of evaluations.csv).
        reproduced_all: the objective of each counterexample's own run from its scenario
            file (None: not re-run, the search was interrupted); ``reproduced`` the first's.
        logs: each counterexample's log (with ``out=``); ``log`` the first's, or None.
        out: the directory of the search's outputs (with ``out=``), or None.
        interrupted: whether the search was stopped before its end.
        runs: how many candidates ran (``len(evaluations)``).
        qualified: how many of them qualified — the baseline safe (and progressing where
            asked), so a violation there is the filter's: what the search tested.
        proves_nothing: no counterexample and no candidate qualified: the search never
            tested the filter, and says nothing about the box (a ``UserWarning`` says so).
        wall_seconds: the search from its first candidate to its end (s).
        run_seconds: the candidates' runs and baselines, summed over the threads (s).
        threads: the threads that ran candidates.
        own_seconds: with one thread, the search's own work (``wall_seconds - run_seconds``:
            proposing candidates, its model, its bookkeeping); None with more.
    """

    def __init__(self, raw: dict[str, Any], out: str | None) -> None:
        self.counterexamples: list[dict[str, Any]] = raw["counterexamples"]
        self.scenario_tomls: list[str] = raw["scenario_tomls"]
        self.scenario_toml: str | None = self.scenario_tomls[0] if self.scenario_tomls else None
        self.evaluations: pd.DataFrame = _read_csv(io.StringIO(raw["evaluations_csv"]))
        self.reproduced_all: list[float | None] = raw["reproduced"]
        self.reproduced: float | None = self.reproduced_all[0] if self.reproduced_all else None
        self.out: str | None = out
        self.logs: list[str] = raw["logs"] if out is not None else []
        self.log: str | None = self.logs[0] if self.logs else None
        self.interrupted: bool = raw["interrupted"]
        self.runs: int = len(self.evaluations)
        qualified = self.evaluations.get("qualified", pd.Series(dtype=bool))
        self.qualified: int = int(qualified.astype(str).str.lower().eq("true").sum())
        self.proves_nothing: bool = not self.counterexamples and self.qualified == 0
        self.wall_seconds: float = raw["wall_seconds"]
        self.run_seconds: float = raw["run_seconds"]
        self.threads: int = raw["threads"]
        self.own_seconds: float | None = (
            max(self.wall_seconds - self.run_seconds, 0.0) if self.threads == 1 else None
        )
        if self.proves_nothing:
            warnings.warn(
                f"falsify: no counterexample, and none of the {self.runs} candidates qualified "
                "(no baseline run was safe, and progressing where asked): this proves nothing about the box",
                stacklevel=3,
            )

    def __repr__(self) -> str:
        return (
            f"FalsifyResult({self.runs} runs, {self.qualified} qualified, "
            f"counterexamples={self.counterexamples!r})"
        )


def run(
    path: str | os.PathLike[str],
    set: Mapping[str, Any] | None = None,
    out: str | os.PathLike[str] | None = None,
    tables: bool = False,
    require: Mapping[str, str] | None = None,
) -> RunResult:
    """Runs a scenario once, as ``mjsafe run PATH --set … --out OUT``.

    Args:
        path: the scenario file (TOML).
        set: overrides, ``{dotted key: value}`` (``--set``), applied in order; a dict value is a
            whole table, e.g. ``{"filter": {"kind": "gamma_m", "l0": 4.0, "l1": 4.0, "m": 50.0}}``.
        out: the MCAP log to write; None writes no log (the run is analysed in memory, as a
            falsification candidate is: the same metrics).
        tables: keep the run's tables in memory (``RunResult.tables()`` without a log).
        require: requirements ``{name: STL formula}`` (``--require NAME=FORMULA``; added to the
            scenario's ``[[requirements]]``): each one's robustness is ``metrics["req"][name]``
            (docs/requirements.md).

    Raises:
        TypeError: an argument of the wrong Python type (a path that is not a str or
            os.PathLike, ``set`` not a dict, a value without a TOML form such as None).
        ValueError: bad input (the command line's error line): an unknown key, a value the
            scenario refuses, a missing scenario or model, an output refused.
        RuntimeError: the run could not finish its log or analysis.
    """
    raw = _core.run(
        _path("run", "path", path),
        _mapping("run", "set", set, _SET),
        _path("run", "out", out, optional=True),
        _bool("run", "tables", tables),
        _mapping("run", "require", require, _REQUIRE),
    )
    return RunResult(raw)


def register_filter(kind: str, cls: type, replace: bool = False) -> None:
    """Registers a safety filter written in Python as the filter ``kind`` of this process.

    ``cls(params)`` is built for each run with the scenario's ``[filter]`` table (without
    ``kind``) as a dict. Its attributes: ``barrier_form`` (``{"alpha": a}``, ``{"l0": l0,
    "l1": l1}`` or None: the condition whose constraint data the filter receives),
    ``uses_prediction`` (bool, default False: evaluated at the channel's prediction rather
    than the measured state), and on the class an optional ``label`` (e.g. an equation
    number, shown in logs and legends). Its method ``filter_channel(self, t, channel, state,
    nominal, constraints)`` receives numpy arrays and ``constraints`` as a list of ``(a, b)``
    (the constraint a + b·u ≥ 0 of each known barrier at ``state``) and returns channel
    ``channel``'s command: a float, a dict with ``input`` (and ``active``, ``infeasible``,
    ``mu``: what ``/filter`` records), or None (no barrier known: the nominal passes).

    The kind then works in scenario files and ``set`` dicts, in ``run``, ``sweep`` and
    ``falsify``. It runs inside the control tick with the GIL held; an exception stops the
    run with an error event carrying its type and message (``RunResult.error``).

    A class may also define ``issued_law(self, t, prediction_time, state, nominal,
    constraints, free, u)``: the law the predictors assume for the commands not yet issued
    inside their window (default: the delay-free CBF-QP). It gets the tick ``t`` that issues
    them, the time ``prediction_time`` the predicted ``state`` is for, u0 there
    (``nominal``), the ``constraints`` there, ``free`` (the indices of the channels whose
    commands it gives, a list) and ``u`` (every channel's command; outside ``free`` the ones
    applied at ``prediction_time``), and returns one command per channel of ``free``, in its
    order (e.g. ``solution[free]``), or None (the nominal). An exception or another return
    stops the run with an error event, as in ``filter_channel``.

    A ``kind`` already registered — a built-in's (``"gamma_m"``) or another class's — is
    refused unless ``replace=True``; registering the same class again (a notebook cell run
    again, a module reloaded: the same ``__module__`` and ``__qualname__``) replaces it. A class
    without ``label`` that replaces a built-in is labelled ``"<kind> (Python module.Class)"``.

    Raises:
        TypeError: ``kind`` not a str, ``cls`` not a class, a class without
            ``filter_channel``, or an ``issued_law`` that is not a method.
        ValueError: a kind that is not letters, digits and ``_``, or one already registered
            (without ``replace=True``).
    """
    _class("register_filter", kind, cls)
    _bool("register_filter", "replace", replace)
    _core.register_filter(kind, cls, replace)


def register_nominal(kind: str, cls: type, replace: bool = False) -> None:
    """Registers a nominal controller written in Python as the nominal ``kind`` of this process.

    ``cls(params)`` is built for each run with the scenario's ``[nominal]`` table (without
    ``kind``) as a dict; its method ``input(self, t, state)`` receives the time and the state
    (a numpy array) the controller evaluates u0 at and returns one value per channel; ``label``
    on the class is optional. An exception, or a result that is not one number per channel,
    stops the run with an error event carrying the message (``RunResult.error``).

    A ``kind`` already registered is refused unless ``replace=True``, as in
    ``register_filter``.

    Raises:
        TypeError: ``kind`` not a str, ``cls`` not a class, or a class without ``input``.
        ValueError: a kind that is not letters, digits and ``_``, or one already registered
            (without ``replace=True``).
    """
    _class("register_nominal", kind, cls)
    _bool("register_nominal", "replace", replace)
    _core.register_nominal(kind, cls, replace)


def read_log(path: str | os.PathLike[str]) -> LogData:
    """Reads an MCAP log of a run: its metrics now, its tables on ``.tables()``.

    Raises:
        TypeError: ``path`` not a str or os.PathLike.
        ValueError: not a readable log of a run (the error ``mjsafe analyze`` gives).
    """
    return LogData(_path("read_log", "path", path))


def sweep(
    path: str | os.PathLike[str] | None = None,
    grid: Mapping[str, Sequence[Any]] | None = None,
    random: Mapping[str, tuple[float, float] | tuple[float, float, float]] | None = None,
    draws: int = 0,
    seed: int = 0,
    set: Mapping[str, Any] | None = None,
    threads: int | None = None,
    *,
    out: str | os.PathLike[str] | None = None,
    require: Mapping[str, str] | None = None,
    scenarios: Sequence[str | os.PathLike[str]] | None = None,
    sweep_file: str | os.PathLike[str] | None = None,
) -> pd.DataFrame:
    """A parameter sweep, as ``mjsafe sweep``: the grid's cartesian product, times ``draws``
    seeded random draws of the ``random`` ranges, run in parallel.

    Args:
        path: the scenario file (TOML); None with ``scenarios``.
        grid: ``{dotted key: [values]}`` (``--grid KEY=V1,V2,…``); the first key varies slowest.
        random: ``{dotted key: (lo, hi)}`` or ``(lo, hi, step)`` (``--range``), drawn ``draws``
            times (``--random N``) with ``seed`` (``--seed``).
        set: overrides applied to every run (``--set``).
        threads: runs at once (default: every core).
        out: a directory for the runs' logs and summary.csv/summary.json (``--out``); None
            keeps no logs and writes nothing (``--no-logs``: each run analysed in memory).
        require: requirements of every run ``{name: STL formula}`` (``--require``): the
            summary's ``req.<name>`` columns.
        scenarios: CommonRoad files or patterns (``--scenarios``, e.g.
            ``["data/commonroad/*.xml"]``), the swept key ``commonroad.file``
            (docs/commonroad.md); instead of ``path``.
        sweep_file: a sweep file (``--sweep``: its scenario, ``set``, grids with their ``with``
            companions, ranges and ``[random]``); ``path`` may then be None, and the other
            arguments add to it as the command line's flags do.

    Returns:
        The summary, one row per run: the columns of summary.csv (index, log, the swept keys,
        every metric column, error).

    Raises:
        TypeError: an argument of the wrong Python type (``draws="x"``, ``grid`` values not a
            list, a range not a tuple of numbers, …).
        ValueError: bad values (the command line's error line; a negative count).
    """
    if scenarios is not None and (isinstance(scenarios, (str, bytes)) or not isinstance(scenarios, Sequence)):
        raise _type_error("sweep", "scenarios", "a list of str or os.PathLike, or None", scenarios)
    files = None if scenarios is None else [_path("sweep", "scenarios", f) for f in scenarios]
    text = _core.sweep(
        _path("sweep", "path", path, optional=scenarios is not None or sweep_file is not None),
        _mapping("sweep", "grid", grid, "a dict of dotted keys to lists of values"),
        _mapping("sweep", "random", random, _RANGES),
        _int("sweep", "draws", draws, 0),
        _int("sweep", "seed", seed, 0),
        _mapping("sweep", "set", set, _SET),
        _int("sweep", "threads", threads, 0, optional=True),
        _path("sweep", "out", out, optional=True),
        _mapping("sweep", "require", require, _REQUIRE),
        files,
        _path("sweep", "sweep_file", sweep_file, optional=True),
    )
    return _read_csv(io.StringIO(text))


def falsify(
    path: str | os.PathLike[str],
    ranges: Mapping[str, tuple[float, float] | tuple[float, float, float]],
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
    out: str | os.PathLike[str] | None = None,
    require: Mapping[str, str] | None = None,
    method: str = "guided",
    counterexamples: int = 1,
    tolerance: float = 1e-4,
) -> FalsifyResult:
    """A falsification search, as ``mjsafe falsify``: CMA-ES over the ``ranges`` box for a run
    whose ``objective`` falls below ``threshold``.

    Args:
        path: the scenario file (TOML).
        ranges: ``{dotted key: (lo, hi)}`` or ``(lo, hi, step)`` (``--range``), at least one.
        baseline: the reference configuration as overrides (``--baseline``): a candidate counts
            only where its baseline is safe (objective ≥ ``baseline_threshold``).
        budget, seed, objective, threshold, worst: ``--budget``, ``--seed``, ``--objective``
            (``"-metric"`` searches for large values), ``--threshold``, ``--worst``.
        set: overrides of every candidate (``--set``).
        baseline_threshold, baseline_no_stall, baseline_reaches_goal, compare_random, threads:
            the flags of the same names.
        out: the directory of the search's outputs (evaluations.csv/.json, the counterexample
            scenario and log, the convergence plot); None: a temporary one, removed after.
        require: requirements of every candidate ``{name: STL formula}`` (``--require``);
            ``objective="req.<name>"`` minimises one's robustness.
        method: ``"guided"`` (default), ``"cmaes"`` or ``"random"`` (``--method``).
        counterexamples: up to this many distinct failure modes (``--counterexamples``).
        tolerance: how far below ``threshold`` counts as a violation (``--tolerance``, in the
            objective's unit; a round-off graze is not a failure; 0 counts every one).

    Raises:
        TypeError: an argument of the wrong Python type (``budget="many"``, ``ranges`` not a
            dict, ``objective`` not a str, …).
        ValueError: bad values (the command line's error line; a negative count).
    """
    f = "falsify"
    path = _path(f, "path", path)
    ranges = _mapping(f, "ranges", ranges, _RANGES, optional=False)
    baseline = _mapping(f, "baseline", baseline, _SET)
    budget = _int(f, "budget", budget, 0)
    seed = _int(f, "seed", seed, 0)
    objective = _str(f, "objective", objective)
    threshold = _float(f, "threshold", threshold)
    worst = _bool(f, "worst", worst)
    set = _mapping(f, "set", set, _SET)
    baseline_threshold = _float(f, "baseline_threshold", baseline_threshold)
    baseline_no_stall = _bool(f, "baseline_no_stall", baseline_no_stall)
    baseline_reaches_goal = _bool(f, "baseline_reaches_goal", baseline_reaches_goal)
    compare_random = _bool(f, "compare_random", compare_random)
    threads = _int(f, "threads", threads, 0, optional=True)
    out = _path(f, "out", out, optional=True)
    require = _mapping(f, "require", require, _REQUIRE)
    method = _str(f, "method", method)
    counterexamples = _int(f, "counterexamples", counterexamples, 0)
    tolerance = _float(f, "tolerance", tolerance)
    call = ", ".join(
        [repr(path), f"ranges={dict(ranges)!r}"]
        + [f"{k}={v!r}" for k, v in [("baseline", baseline), ("set", set), ("require", require)] if v is not None]
        + [f"budget={budget!r}", f"seed={seed!r}", f"objective={objective!r}", f"threshold={threshold!r}"]
        + (["worst=True"] if worst else [])
        + ([f"method={method!r}"] if method != "guided" else [])
        + ([f"counterexamples={counterexamples!r}"] if counterexamples != 1 else [])
        + ([f"tolerance={tolerance!r}"] if tolerance != 1e-4 else [])
    )
    search_line = f"mjsafe.falsify({call})"
    args = (
        path, ranges, baseline, budget, seed, objective, threshold, worst, set,
        baseline_threshold, baseline_no_stall, baseline_reaches_goal, compare_random, threads,
    )
    if out is not None:
        raw = _core.falsify(*args, out, search_line, require, method, counterexamples, tolerance)
        return FalsifyResult(raw, out)
    with tempfile.TemporaryDirectory(prefix="mjsafe-falsify-") as tmp:
        raw = _core.falsify(*args, tmp, search_line, require, method, counterexamples, tolerance)
        return FalsifyResult(raw, None)

_SCORECARD_COLUMNS = [
    "section", "item", "filter", "status", "score", "max", "unit", "figure", "figure_value",
    "figure_unit", "detail", "reason", "runs", "command", "log",
]


def scorecard(
    filters: Sequence[str | Mapping[str, Any]],
    suite: str | os.PathLike[str] = "standard",
    threads: int | None = None,
    *,
    out: str | os.PathLike[str] | None = None,
    keep_logs: str = "failing",
) -> pd.DataFrame:
    """Scores filters over a suite, as ``mjsafe scorecard`` (docs/scorecard.md): each filter
    replaces every item's own; a filter registered with :func:`register_filter` is scored like
    a built-in.

    Args:
        filters: one column each: a preset of the suite (``"gamma_m"``, ``"cbf_qp"``, …), a
            filter table as a dict (``{"kind": "my_filter", "l0": 4.0}``) or as TOML inline
            table text.
        suite: ``"standard"``, ``"quick"`` or a suite file.
        threads: runs at once (default: every core).
        out: a directory for scorecard.json, report.html and the kept logs; None writes
            nothing and keeps no log.
        keep_logs: ``"failing"`` (each cell's failing run), ``"all"`` or ``"none"``
            (``--keep-logs``; only with ``out``).

    Returns:
        One row per (item, filter), in the suite's order: section, item, filter, status
        (pass, fail, scored, not_applicable, error, not_run), score, max, unit, the figure
        behind the score (figure, figure_value, figure_unit), detail (the table's cell),
        reason, runs, command (reproduces the failing run), log. ``df.attrs["scorecard"]``
        holds all of scorecard.json (Euro NCAP points and totals, margins' bisections,
        searches); ``df.pivot(index="item", columns="filter", values="detail")`` is the
        command line's table.

    Raises:
        TypeError: an argument of the wrong Python type.
        ValueError: a bad suite, filter or output (the command line's error line).
    """
    if isinstance(filters, (str, bytes)) or not isinstance(filters, Sequence):
        raise _type_error("scorecard", "filters", "a list of preset names, dicts or inline tables", filters)
    specs = []
    for f in filters:
        if isinstance(f, str):
            specs.append(f)
        elif isinstance(f, _MappingABC):
            specs.append(_core.toml_value(dict(f)))
        else:
            raise _type_error("scorecard", "filters", "a list of str or dict", f)
    if not isinstance(suite, (str, os.PathLike)):
        raise _type_error("scorecard", "suite", "str or os.PathLike", suite)
    keep = _str("scorecard", "keep_logs", keep_logs)
    text = _core.scorecard(
        specs,
        os.fspath(suite),
        _int("scorecard", "threads", threads, 0, optional=True),
        _path("scorecard", "out", out, optional=True),
        keep,
    )
    card = json.loads(text)
    rows = []
    for item in card["items"]:
        for column, cell in enumerate(item["cells"]):
            figure = cell.get("figure") or {}
            rows.append({
                "section": item["section"], "item": item["name"], "filter": card["filters"][column]["name"],
                "status": cell["status"], "score": cell.get("score"), "max": cell.get("max"),
                "unit": cell.get("unit"), "figure": figure.get("name"), "figure_value": figure.get("value"),
                "figure_unit": figure.get("unit"), "detail": cell.get("detail"), "reason": cell.get("reason"),
                "runs": cell.get("runs"), "command": cell.get("command"), "log": cell.get("log"),
            })
    frame = pd.DataFrame(rows, columns=_SCORECARD_COLUMNS)
    for column in ("score", "max", "figure_value"):
        frame[column] = pd.to_numeric(frame[column])
    frame.attrs["scorecard"] = card
    return frame


from mjsafe.env import Env  # noqa: E402  (it reads RunResult from this module)
from mjsafe import filter  # noqa: E402,A004  (the TypedDicts of a Python filter's keyword arguments)
