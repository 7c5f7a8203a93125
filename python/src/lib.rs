//! `mjsafe._core`: the Rust side of the `mjsafe` Python package (python/mjsafe/__init__.py
//! wraps it into `run`, `sweep`, `falsify` and `read_log`).
//!
//! Every function goes through the library's own paths, as the command line does: the run path
//! (`mjsafe::run`), the sweep and falsification functions, the one log reader (`analyze`,
//! `export`). What is Python's stays here: the arguments converted to the `--set`/`--grid`/
//! `--range` texts the command line takes (so a bad argument is the command line's error, as a
//! `ValueError`), and the results handed back as plain Python values.
//!
//! The GIL: every function converts its arguments while holding it, then releases it for the
//! whole of the Rust work (`Python::detach`, formerly `allow_threads`): a run, a sweep or a
//! search holds no Python lock while it steps, so Python-written filters (which take the GIL
//! in the control callback) and other Python threads can run meanwhile. A run, sweep or search
//! works on a thread of its own while the calling thread watches for Ctrl-C
//! ([`interruptible`]); `mjsafe.Env` steps on the calling thread, with the GIL (a tick is short).

#![deny(unsafe_code)]

mod kinds;
mod stepper;

use std::error::Error;
use std::path::{Path, PathBuf};

use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyBytes, PyDict, PyFloat, PyList, PyMapping, PyString, PyTuple};

use mjsafe::export::{MemoryTables, TableSink, Values};
use mjsafe::run::{Keep, Prepared};

/// How deep lists and dicts in a value may nest (a cycle is refused, not followed).
const MAX_DEPTH: usize = 32;

/// An error as the command line prints it (without its `error: `): the error and each of its
/// sources joined by `: `, numbers shortened (`mjsafe::message::shorten_numbers`).
fn line(e: &(dyn Error + 'static)) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        text.push_str(": ");
        text.push_str(&s.to_string());
        source = s.source();
    }
    mjsafe::message::shorten_numbers(&text)
}

/// A bad argument: the command line's error line as a `ValueError`.
fn bad(e: impl Error + 'static) -> PyErr {
    PyValueError::new_err(line(&e))
}

/// A failure while running: a `RuntimeError`.
fn failed(e: impl Error + 'static) -> PyErr {
    PyRuntimeError::new_err(line(&e))
}

/// The type name of `value`, for errors.
fn type_name(value: &Bound<'_, PyAny>) -> String {
    value
        .get_type()
        .name()
        .map_or_else(|_| "object".to_string(), |n| n.to_string())
}

/// A TOML basic string on one line: `"…"` with `\`, `"` and control characters escaped.
fn toml_string(text: &str) -> String {
    let mut out = String::with_capacity(text.len() + 2);
    out.push('"');
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            '\r' => out.push_str("\\r"),
            c if c.is_control() => out.push_str(&format!("\\u{:04X}", u32::from(c))),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// A float as TOML text, as a person writes it: `0.4`, `4.0`, `1e300`, `nan`, `inf`.
fn toml_float(x: f64) -> String {
    if x.is_nan() {
        "nan".to_string()
    } else {
        // Rust's shortest round-trip form (`inf`, `-inf`, `1e300`, `1e-7` included) is TOML.
        format!("{x:?}")
    }
}

/// A TOML key as written in an inline table: bare when it may be, else quoted.
fn toml_key(key: &str) -> String {
    if !key.is_empty() && key.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
        key.to_string()
    } else {
        toml_string(key)
    }
}

/// `value` as TOML value text, as `--set KEY=VALUE` takes it: bool, int (any size: the
/// scenario's parser says when it is beyond TOML's 64 bits), float, str, a list or tuple of
/// values, a dict of values (an inline table). `what` names the value in errors.
fn toml_text(value: &Bound<'_, PyAny>, what: &str, depth: usize) -> PyResult<String> {
    if depth > MAX_DEPTH {
        return Err(PyValueError::new_err(format!(
            "{what}: nested more than {MAX_DEPTH} deep (a list or dict that contains itself?)"
        )));
    }
    // Python's bool, numpy's (`bool_`, named `bool` since numpy 2).
    if value.is_instance_of::<PyBool>() || matches!(type_name(value).as_str(), "bool" | "bool_") {
        return Ok(value.is_truthy()?.to_string());
    }
    if value.is_instance_of::<PyString>() {
        return Ok(toml_string(&value.extract::<String>()?));
    }
    if value.is_instance_of::<PyFloat>() {
        return Ok(toml_float(value.extract::<f64>()?));
    }
    // Integers, Python's or numpy's (anything with __index__): their decimal text.
    if let Ok(index) = value.call_method0("__index__") {
        return Ok(index.str()?.to_string());
    }
    if let Ok(x) = value.extract::<f64>() {
        // numpy floats and other numbers with __float__.
        return Ok(toml_float(x));
    }
    if value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>() {
        let items: Vec<String> = value
            .try_iter()?
            .enumerate()
            .map(|(i, item)| toml_text(&item?, &format!("{what}[{i}]"), depth + 1))
            .collect::<PyResult<_>>()?;
        return Ok(format!("[{}]", items.join(", ")));
    }
    if let Ok(mapping) = value.cast::<PyMapping>() {
        let mut entries = Vec::new();
        for item in mapping.items()?.try_iter()? {
            let (key, item): (Bound<'_, PyAny>, Bound<'_, PyAny>) = item?.extract()?;
            let Ok(key) = key.extract::<String>() else {
                return Err(PyTypeError::new_err(format!(
                    "{what}: a key of a table is a str, not a {}",
                    type_name(&key)
                )));
            };
            let text = toml_text(&item, &format!("{what}[{key:?}]"), depth + 1)?;
            entries.push(format!("{} = {text}", toml_key(&key)));
        }
        return Ok(format!("{{{}}}", entries.join(", ")));
    }
    Err(PyTypeError::new_err(format!(
        "{what}: a {} has no TOML value (expected a bool, int, float, str, list or dict)",
        type_name(value)
    )))
}

/// The `KEY=VALUE` overrides of a `set`-like dict (dotted keys, Python values), in its order.
fn overrides(set: Option<&Bound<'_, PyAny>>, name: &str) -> PyResult<Vec<String>> {
    let Some(set) = set.filter(|s| !s.is_none()) else {
        return Ok(Vec::new());
    };
    let mapping = set.cast::<PyMapping>().map_err(|_| {
        PyTypeError::new_err(format!(
            "{name}: expected a dict of dotted keys, not a {}",
            type_name(set)
        ))
    })?;
    let mut out = Vec::new();
    for item in mapping.items()?.try_iter()? {
        let (key, value): (Bound<'_, PyAny>, Bound<'_, PyAny>) = item?.extract()?;
        let Ok(key) = key.extract::<String>() else {
            return Err(PyTypeError::new_err(format!(
                "{name}: a key is a dotted str such as \"delays.steering\", not a {}",
                type_name(&key)
            )));
        };
        out.push(format!("{key}={}", toml_text(&value, &format!("{name}[{key:?}]"), 0)?));
    }
    Ok(out)
}

/// The overrides of `set`, then those of `require` (`{name: formula}`, as `--require
/// NAME=FORMULA` each: appended to the scenario's `[[requirements]]`).
fn overrides_and_requirements(
    set: Option<&Bound<'_, PyAny>>,
    require: Option<&Bound<'_, PyAny>>,
) -> PyResult<Vec<String>> {
    let mut out = overrides(set, "set")?;
    let Some(require) = require.filter(|r| !r.is_none()) else {
        return Ok(out);
    };
    let mapping = require.cast::<PyMapping>().map_err(|_| {
        PyTypeError::new_err(format!(
            "require: expected a dict of requirement names to STL formulas, not a {}",
            type_name(require)
        ))
    })?;
    for item in mapping.items()?.try_iter()? {
        let (name, formula): (Bound<'_, PyAny>, Bound<'_, PyAny>) = item?.extract()?;
        let (Ok(name), Ok(formula)) = (name.extract::<String>(), formula.extract::<String>()) else {
            return Err(PyTypeError::new_err(format!(
                "require: expected str names and str formulas, found a {} and a {}",
                type_name(&name),
                type_name(&formula)
            )));
        };
        out.push(mjsafe::scenario::require_override(&format!("{name}={formula}")).map_err(bad)?);
    }
    Ok(out)
}

/// The `KEY=LO..HI[:STEP]` texts of a dict of `(lo, hi)` or `(lo, hi, step)`.
fn ranges(dict: Option<&Bound<'_, PyAny>>, name: &str) -> PyResult<Vec<String>> {
    let Some(dict) = dict.filter(|s| !s.is_none()) else {
        return Ok(Vec::new());
    };
    let mapping = dict.cast::<PyMapping>().map_err(|_| {
        PyTypeError::new_err(format!(
            "{name}: expected a dict of dotted keys to (lo, hi) or (lo, hi, step), not a {}",
            type_name(dict)
        ))
    })?;
    let mut out = Vec::new();
    for item in mapping.items()?.try_iter()? {
        let (key, value): (String, Bound<'_, PyAny>) = item?
            .extract()
            .map_err(|_| PyTypeError::new_err(format!("{name}: a key is a dotted str such as \"delays.steering\"")))?;
        let found = || value.repr().map_or_else(|_| type_name(&value), |r| r.to_string());
        // A tuple or list of numbers (a str is not one), of the wrong length: a bad value.
        let numbers = (!value.is_instance_of::<PyString>())
            .then(|| value.extract::<Vec<f64>>().ok())
            .flatten();
        let Some(bounds) = numbers else {
            return Err(PyTypeError::new_err(format!(
                "{name}[{key:?}]: expected (lo, hi) or (lo, hi, step) of numbers, found {}",
                found()
            )));
        };
        if !(bounds.len() == 2 || bounds.len() == 3) {
            return Err(PyValueError::new_err(format!(
                "{name}[{key:?}]: expected (lo, hi) or (lo, hi, step) of numbers, found {}",
                found()
            )));
        }
        let mut text = format!("{key}={:?}..{:?}", bounds[0], bounds[1]);
        if let Some(step) = bounds.get(2) {
            text.push_str(&format!(":{step:?}"));
        }
        out.push(text);
    }
    Ok(out)
}

/// The `KEY=V1,V2,…` texts of a dict of key → list of values.
fn grids(dict: Option<&Bound<'_, PyAny>>) -> PyResult<Vec<String>> {
    let Some(dict) = dict.filter(|s| !s.is_none()) else {
        return Ok(Vec::new());
    };
    let mapping = dict.cast::<PyMapping>().map_err(|_| {
        PyTypeError::new_err(format!(
            "grid: expected a dict of dotted keys to lists of values, not a {}",
            type_name(dict)
        ))
    })?;
    let mut out = Vec::new();
    for item in mapping.items()?.try_iter()? {
        let (key, values): (String, Bound<'_, PyAny>) = item?
            .extract()
            .map_err(|_| PyTypeError::new_err("grid: a key is a dotted str such as \"delays.steering\""))?;
        if !(values.is_instance_of::<PyList>() || values.is_instance_of::<PyTuple>()) {
            return Err(PyTypeError::new_err(format!(
                "grid[{key:?}]: expected a list of values, not a {}",
                type_name(&values)
            )));
        }
        let texts: Vec<String> = values
            .try_iter()?
            .enumerate()
            .map(|(i, v)| toml_text(&v?, &format!("grid[{key:?}][{i}]"), 1))
            .collect::<PyResult<_>>()?;
        out.push(format!("{key}={}", texts.join(",")));
    }
    Ok(out)
}

/// A TOML value as a Python value (tables as dicts, arrays as lists).
fn toml_to_py<'py>(py: Python<'py>, value: &toml::Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match value {
        toml::Value::String(s) => s.into_pyobject(py)?.into_any(),
        toml::Value::Integer(i) => i.into_pyobject(py)?.into_any(),
        toml::Value::Float(f) => f.into_pyobject(py)?.into_any(),
        toml::Value::Boolean(b) => PyBool::new(py, *b).to_owned().into_any(),
        toml::Value::Datetime(d) => d.to_string().into_pyobject(py)?.into_any(),
        toml::Value::Array(items) => {
            let list = PyList::empty(py);
            for item in items {
                list.append(toml_to_py(py, item)?)?;
            }
            list.into_any()
        }
        toml::Value::Table(table) => {
            let dict = PyDict::new(py);
            for (k, v) in table {
                dict.set_item(k, toml_to_py(py, v)?)?;
            }
            dict.into_any()
        }
    })
}

/// Tables as `{topic: [(column, kind, values)]}`: kind `f64`/`u64`/`bool` with the values as
/// little-endian bytes (numpy reads them without a copy per value), `text` with a list of str.
fn tables_to_py<'py>(py: Python<'py>, tables: &MemoryTables) -> PyResult<Bound<'py, PyDict>> {
    let out = PyDict::new(py);
    for (topic, table) in &tables.tables {
        let columns = PyList::empty(py);
        for (name, values) in &table.columns {
            let (kind, payload): (&str, Bound<'py, PyAny>) = match values {
                Values::F64(v) => (
                    "f64",
                    PyBytes::new(py, &v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>()).into_any(),
                ),
                Values::U64(v) => (
                    "u64",
                    PyBytes::new(py, &v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>()).into_any(),
                ),
                Values::Bool(v) => (
                    "bool",
                    PyBytes::new(py, &v.iter().map(|&b| u8::from(b)).collect::<Vec<u8>>()).into_any(),
                ),
                Values::Text(v) => ("text", PyList::new(py, v)?.into_any()),
            };
            columns.append((name, kind, payload))?;
        }
        out.set_item(topic.name(), columns)?;
    }
    Ok(out)
}

/// A metrics object as `analyze --json` prints it (one run's), as JSON text.
fn metrics_json(metrics: &mjsafe::analyze::RunMetrics) -> String {
    serde_json::to_string(metrics).expect("metrics serialise")
}

/// Runs `work` (a run, a sweep, a search) on a thread of its own while this thread, without the
/// GIL, waits for it and checks Python's signals every 50 ms: Ctrl-C (KeyboardInterrupt) asks
/// the work to stop as `mjsafe run` does on SIGINT (every episode logs `interrupted` and
/// finishes its log as incomplete), waits for it to return, and is raised.
fn interruptible<T: Send>(py: Python<'_>, work: impl FnOnce() -> PyResult<T> + Send) -> PyResult<T> {
    std::thread::scope(|scope| {
        let worker = scope.spawn(work);
        loop {
            py.detach(|| {
                let started = std::time::Instant::now();
                while !worker.is_finished() && started.elapsed() < std::time::Duration::from_millis(50) {
                    std::thread::sleep(std::time::Duration::from_millis(1));
                }
            });
            if worker.is_finished() {
                return worker
                    .join()
                    .unwrap_or_else(|_| Err(PyRuntimeError::new_err("the run panicked (a bug of mjsafe)")));
            }
            if let Err(signal) = py.check_signals() {
                mjsafe::episode::request_stop();
                let _ = py.detach(|| worker.join());
                mjsafe::episode::clear_stop_request();
                return Err(signal);
            }
        }
    })
}

/// What stands for the log of a run without one (`out=None`), in its metrics and errors.
const IN_MEMORY: &str = "(in memory)";

/// One run of a scenario: `mjsafe run` (or, without `out`, analysed in memory).
#[pyfunction]
#[pyo3(signature = (path, set=None, out=None, tables=false, require=None))]
fn run<'py>(
    py: Python<'py>,
    path: PathBuf,
    set: Option<&Bound<'py, PyAny>>,
    out: Option<PathBuf>,
    tables: bool,
    require: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let overrides = overrides_and_requirements(set, require)?;
    let result = interruptible(py, move || -> Result<_, PyErr> {
        let loaded = mjsafe::scenario::load(&path, &overrides).map_err(bad)?;
        // A requirement naming no signal of the run: said before the run, not after it.
        mjsafe::run::check_requirement_signals(&loaded)
            .map_err(|e| PyValueError::new_err(format!("{}: {e}", path.display())))?;
        let keep = match &out {
            Some(log) => Keep::Log(log),
            None => Keep::Metrics(IN_MEMORY),
        };
        let prepared = Prepared::new(&loaded, keep).map_err(bad)?;
        let name = out.as_ref().map_or(IN_MEMORY.to_string(), |p| p.display().to_string());
        let mut sink = tables.then(|| TableSink::new(&name));
        let further: Vec<Box<dyn mjsafe::log::Sink + '_>> = match sink.as_mut() {
            Some(sink) => vec![Box::new(sink)],
            None => Vec::new(),
        };
        let outcome = prepared.run(further).map_err(failed)?;
        Ok((outcome, sink.map(TableSink::tables)))
    })?;
    let (outcome, kept) = result;
    outcome_dict(py, &outcome, kept.as_ref())
}

/// A run's outcome as the dict `mjsafe.RunResult` is made of.
fn outcome_dict<'py>(
    py: Python<'py>,
    outcome: &mjsafe::run::Outcome,
    tables: Option<&MemoryTables>,
) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    let metrics = outcome.metrics.as_ref().expect("a logged or analysed run has metrics");
    dict.set_item("metrics", metrics_json(metrics))?;
    dict.set_item("error", outcome.summary.error.as_ref().map(ToString::to_string))?;
    dict.set_item("log", outcome.log.as_ref().map(|p| p.display().to_string()))?;
    dict.set_item("steps", outcome.summary.steps)?;
    dict.set_item("simulated_time", outcome.summary.simulated_time)?;
    let rtf = outcome.summary.real_time_factor();
    dict.set_item("real_time_factor", rtf.is_finite().then_some(rtf))?;
    match tables {
        Some(t) => dict.set_item("tables", tables_to_py(py, t)?)?,
        None => dict.set_item("tables", py.None())?,
    }
    Ok(dict)
}

/// The metrics of a log, as `mjsafe analyze --json` gives them (JSON text).
#[pyfunction]
fn log_metrics(py: Python<'_>, path: PathBuf) -> PyResult<String> {
    py.detach(move || {
        mjsafe::analyze::analyze_file(&path)
            .map(|m| metrics_json(&m))
            .map_err(bad)
    })
}

/// The tables of a log, as `mjsafe export` writes them (every table topic).
#[pyfunction]
fn log_tables<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let tables = py.detach(move || mjsafe::export::read_tables(&path, &mjsafe::export::table_topics()).map_err(bad))?;
    tables_to_py(py, &tables)
}

/// A sweep: `mjsafe sweep` (with `out`: its logs and summary files there; without: every run
/// analysed in memory, `--no-logs`, nothing written); the summary as CSV text.
#[pyfunction]
#[pyo3(signature = (path, grid=None, random=None, draws=0, seed=0, set=None, threads=None, out=None, require=None, scenarios=None, sweep_file=None))]
#[allow(clippy::too_many_arguments)]
fn sweep<'py>(
    py: Python<'py>,
    path: Option<PathBuf>,
    grid: Option<&Bound<'py, PyAny>>,
    random: Option<&Bound<'py, PyAny>>,
    draws: usize,
    seed: u64,
    set: Option<&Bound<'py, PyAny>>,
    threads: Option<usize>,
    out: Option<PathBuf>,
    require: Option<&Bound<'py, PyAny>>,
    scenarios: Option<Vec<String>>,
    sweep_file: Option<PathBuf>,
) -> PyResult<String> {
    use mjsafe::sweep::{self, Summary, SweepArgs, SweepSpec};
    let from_file = sweep_file.is_some();
    let scenarios = sweep::expand_scenarios(&scenarios.unwrap_or_default())
        .map_err(|e| PyValueError::new_err(format!("mjsafe.sweep: scenarios: {e}")))?;
    let args = SweepArgs {
        scenario: path,
        scenarios,
        sweep_file,
        set: overrides_and_requirements(set, require)?,
        grids: grids(grid)?,
        // A sweep file's own `[random]` stands unless draws are given here.
        random: (draws > 0).then_some(draws),
        seed: (!from_file || draws > 0).then_some(seed),
        ranges: ranges(random, "random")?,
    };
    interruptible(py, move || {
        let spec = SweepSpec::build(&args).map_err(bad)?;
        let threads = sweep::threads(threads).map_err(bad)?;
        if let Some(dir) = &out {
            sweep::check_out_dir(dir).map_err(bad)?;
            Summary::check_outputs(dir, None).map_err(bad)?;
        }
        let indices = spec.indices(None);
        let rows = sweep::execute(&spec, &indices, out.as_deref(), threads, |_| {}).map_err(failed)?;
        let summary = Summary::new(&spec, None, rows);
        if let Some(dir) = &out {
            summary.write(dir, &[]).map_err(failed)?;
        }
        Ok(summary.to_csv())
    })
}

/// A falsification search: `mjsafe falsify` with its outputs in `out`.
#[pyfunction]
#[pyo3(signature = (
    path, ranges_, baseline, budget, seed, objective, threshold, worst, set,
    baseline_threshold, baseline_no_stall, baseline_reaches_goal, compare_random, threads, out,
    search_line, require=None, method="guided", counterexamples=1, tolerance=mjsafe::falsify::DEFAULT_TOLERANCE
))]
#[allow(clippy::too_many_arguments)]
fn falsify<'py>(
    py: Python<'py>,
    path: PathBuf,
    ranges_: Option<&Bound<'py, PyAny>>,
    baseline: Option<&Bound<'py, PyAny>>,
    budget: usize,
    seed: u64,
    objective: String,
    threshold: f64,
    worst: bool,
    set: Option<&Bound<'py, PyAny>>,
    baseline_threshold: f64,
    baseline_no_stall: bool,
    baseline_reaches_goal: bool,
    compare_random: bool,
    threads: Option<usize>,
    out: PathBuf,
    search_line: String,
    require: Option<&Bound<'py, PyAny>>,
    method: &str,
    counterexamples: usize,
    tolerance: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let method = mjsafe::falsify::Method::from_flag(method).ok_or_else(|| {
        PyValueError::new_err(format!(
            "falsify: method: expected one of guided, cmaes, random, found {method:?}"
        ))
    })?;
    let request = mjsafe::falsify::Request {
        scenario: path,
        ranges: ranges(ranges_, "ranges")?,
        set: overrides_and_requirements(set, require)?,
        objective,
        threshold,
        tolerance,
        budget,
        seed,
        threads,
        worst,
        baseline_threshold,
        baseline: overrides(baseline, "baseline")?,
        baseline_no_stall,
        baseline_reaches_goal,
        method,
        counterexamples,
    };
    let (report, scenario_toml, evaluations) = interruptible(py, move || -> PyResult<_> {
        let (problem, _) = request.problem().map_err(bad)?;
        let report = mjsafe::falsify::falsify(&problem, &out, &search_line, compare_random, |_| {}).map_err(|e| {
            use mjsafe::falsify::FalsifyError as E;
            // With the context the command line gives it; what the search refuses before its
            // first run (a key of the baseline the scenario rejects) is a bad argument.
            let message = format!("falsify: {}", line(&e));
            match e {
                E::Spec(_) | E::Objective { .. } | E::Sweep(_) | E::Scenario(_) => PyValueError::new_err(message),
                _ => PyRuntimeError::new_err(message),
            }
        })?;
        let read = |p: &Path| std::fs::read_to_string(p).map_err(failed);
        let scenario_toml = report
            .counterexamples
            .iter()
            .map(|c| read(&c.scenario))
            .collect::<PyResult<Vec<_>>>()?;
        let evaluations = read(&report.evaluations_csv)?;
        Ok((report, scenario_toml, evaluations))
    })?;
    let dict = PyDict::new(py);
    let counterexamples = PyList::empty(py);
    let (reproduced, logs) = (PyList::empty(py), PyList::empty(py));
    for c in &report.counterexamples {
        let found = PyDict::new(py);
        for (key, text) in &c.evaluation.parameters {
            let value = mjsafe::scenario::override_value(text).map_err(PyRuntimeError::new_err)?;
            found.set_item(key, toml_to_py(py, &value)?)?;
        }
        counterexamples.append(found)?;
        reproduced.append(c.reproduced)?;
        logs.append(c.log.display().to_string())?;
    }
    dict.set_item("counterexamples", counterexamples)?;
    dict.set_item("scenario_tomls", scenario_toml)?;
    dict.set_item("evaluations_csv", evaluations)?;
    dict.set_item("reproduced", reproduced)?;
    dict.set_item("logs", logs)?;
    dict.set_item(
        "interrupted",
        report.searches.iter().any(|s| s.interrupted) || report.rerun_interrupted,
    )?;
    let cost = report.searches.first().map(|s| s.cost).unwrap_or_default();
    dict.set_item("wall_seconds", cost.wall_seconds)?;
    dict.set_item("run_seconds", cost.run_seconds)?;
    dict.set_item("threads", cost.threads)?;
    Ok(dict)
}

/// A scorecard: `mjsafe scorecard` (with `out`: scorecard.json, report.html and the kept logs
/// there; without: nothing written); scorecard.json's text.
#[pyfunction]
#[pyo3(signature = (filters, suite, threads=None, out=None, keep_logs="failing"))]
fn scorecard(
    py: Python<'_>,
    filters: Vec<String>,
    suite: String,
    threads: Option<usize>,
    out: Option<PathBuf>,
    keep_logs: &str,
) -> PyResult<String> {
    use mjsafe::scorecard::{self, KeepLogs, Request};
    let keep_logs = match keep_logs {
        "none" => KeepLogs::None,
        "failing" => KeepLogs::Failing,
        "all" => KeepLogs::All,
        other => {
            return Err(PyValueError::new_err(format!(
                "mjsafe.scorecard(): keep_logs: expected 'none', 'failing' or 'all', found '{other}'"
            )))
        }
    };
    interruptible(py, move || {
        let request = Request {
            suite: &suite,
            filters: &filters,
            threads,
            keep_logs,
            out: out.as_deref(),
        };
        let card = scorecard::score(&request, |_| {}).map_err(bad)?;
        Ok(card.to_json())
    })
}

/// The mjsafe command line in this process (`python -m mjsafe`): `args` with the program's name
/// first; its exit status. The kinds registered from Python in this process are known to it.
#[pyfunction]
fn cli(py: Python<'_>, args: Vec<String>) -> u8 {
    let code = py.detach(move || mjsafe::cli::run_with_args(args));
    (0..=u8::MAX)
        .find(|k| std::process::ExitCode::from(*k) == code)
        .unwrap_or(1)
}

/// The TOML value text `set` makes of a Python value (what `--set KEY=` would be given).
#[pyfunction]
fn toml_value(value: &Bound<'_, PyAny>) -> PyResult<String> {
    toml_text(value, "value", 0)
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(log_metrics, m)?)?;
    m.add_function(wrap_pyfunction!(log_tables, m)?)?;
    m.add_function(wrap_pyfunction!(sweep, m)?)?;
    m.add_function(wrap_pyfunction!(falsify, m)?)?;
    m.add_function(wrap_pyfunction!(scorecard, m)?)?;
    m.add_function(wrap_pyfunction!(cli, m)?)?;
    m.add_function(wrap_pyfunction!(toml_value, m)?)?;
    m.add_class::<stepper::Stepper>()?;
    m.add_function(wrap_pyfunction!(kinds::register_filter, m)?)?;
    m.add_function(wrap_pyfunction!(kinds::register_nominal, m)?)?;
    Ok(())
}
