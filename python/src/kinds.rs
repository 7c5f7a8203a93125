//! Filters and nominal controllers written in Python (`mjsafe.register_filter`,
//! `mjsafe.register_nominal`): registry kinds whose instances call a Python object from the
//! control tick, with the GIL taken for the call (the run itself releases it: Python kinds
//! run one call at a time, whichever run thread calls them).

use nalgebra::DVector;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};

use mjsafe::barrier::{BarrierForm, Constraint, Shape};
use mjsafe::filter::{
    delay_free_qp, ChannelInput, ChannelOutcome, FilterContext, FilterError, LawInput, ParamError, SafetyFilter,
    SeenBarriers,
};
use mjsafe::nominal::{NominalContext, NominalController, SeenActor};

/// A Python kind's parameters: its scenario table as it is (the class checks them).
#[derive(serde::Serialize, serde::Deserialize)]
#[serde(transparent)]
pub struct AnyParams(toml::Table);

impl mjsafe::registry::Params for AnyParams {}

/// "TypeName: message" of a Python exception, on one line.
fn exception_line(py: Python<'_>, e: &PyErr) -> String {
    let kind = e
        .get_type(py)
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "Exception".into());
    let message = e.value(py).str().map(|s| s.to_string()).unwrap_or_default();
    format!("{kind}: {}", message.replace('\n', " "))
}

/// The class instance built with the scenario's parameters (without `kind`), as a dict.
fn instantiate(cls: &Py<PyAny>, params: &toml::Table, section: &str) -> Result<Py<PyAny>, ParamError> {
    Python::attach(|py| {
        let dict = PyDict::new(py);
        for (key, value) in params.iter().filter(|(k, _)| k.as_str() != "kind") {
            let value = crate::toml_to_py(py, value).map_err(|e| ParamError::new(section, exception_line(py, &e)))?;
            dict.set_item(key, value)
                .map_err(|e| ParamError::new(section, exception_line(py, &e)))?;
        }
        cls.bind(py)
            .call1((dict,))
            .map(Bound::unbind)
            .map_err(|e| ParamError::new(section, format!("the Python class raised {}", exception_line(py, &e))))
    })
}

/// The file that defines `class` (where its `method` was compiled), absolute: what a
/// counterexample or a summary of a run with the kind says to load.
fn class_file(class: &Bound<'_, PyAny>, method: &str) -> Option<String> {
    let file: String = class
        .getattr(method)
        .ok()?
        .getattr("__code__")
        .ok()?
        .getattr("co_filename")
        .ok()?
        .extract()
        .ok()?;
    let path = std::path::Path::new(&file);
    path.is_file()
        .then(|| std::fs::canonicalize(path).map_or(file.clone(), |p| p.display().to_string()))
}

/// The filter's `barrier_form` attribute: None, {"alpha": a} or {"l0": …, "l1": …}. A class
/// without the attribute is refused: it would receive no constraints and pass the nominal
/// through without a word. Errors name the class's attribute.
fn read_form(object: &Bound<'_, PyAny>) -> Result<Option<BarrierForm>, ParamError> {
    let class = object
        .get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "the filter class".into());
    let expected = format!(
        "`{class}.barrier_form`: expected None, {{\"alpha\": a}} (relative degree 1) or {{\"l0\": l0, \"l1\": l1}} (relative degree 2)"
    );
    let Ok(value) = object.getattr("barrier_form") else {
        return Err(ParamError::new(
            "filter",
            format!("`{class}` has no `barrier_form`: it would receive no constraints and pass the nominal through; declare barrier_form = {{\"l0\": …, \"l1\": …}} or {{\"alpha\": …}}, or barrier_form = None to receive none"),
        ));
    };
    if value.is_none() {
        return Ok(None);
    }
    let dict = value
        .cast::<PyDict>()
        .map_err(|_| ParamError::new("filter", expected.clone()))?;
    let get = |key: &str| -> Result<Option<f64>, ParamError> {
        match dict
            .get_item(key)
            .map_err(|_| ParamError::new("filter", expected.clone()))?
        {
            Some(v) => v
                .extract::<f64>()
                .map(Some)
                .map_err(|_| ParamError::new("filter", expected.clone())),
            None => Ok(None),
        }
    };
    let known = ["alpha", "l0", "l1"];
    if let Some(unknown) = dict.keys().iter().find_map(|k| {
        let k = k.extract::<String>().unwrap_or_default();
        (!known.contains(&k.as_str())).then_some(k)
    }) {
        return Err(ParamError::new(
            "filter",
            format!("{expected}, found the key `{unknown}`"),
        ));
    }
    mjsafe::filter::barrier_form(get("alpha")?, get("l0")?, get("l1")?)
        .map(Some)
        .map_err(|e| ParamError::new("filter", format!("`{class}.barrier_form`: {}", e.message)))
}

/// The optional keyword arguments of `filter_channel` and `issued_law`.
const KEYWORDS: [&str; 4] = ["queues", "timestep", "barriers", "vehicle"];

/// A filter written in Python: `filter_channel(t, channel, state, nominal, constraints)` of an
/// instance of the registered class (docs/python.md, "Filters in Python").
pub struct PythonFilter {
    kind: String,
    object: Py<PyAny>,
    form: Option<BarrierForm>,
    uses_prediction: bool,
    asarray: Py<PyAny>,
    /// Which of [`KEYWORDS`] `filter_channel` and `issued_law` take (named, or through
    /// `**kwargs`).
    channel_takes: [bool; 4],
    law_takes: [bool; 4],
    /// The `vehicle` keyword argument: the same dict at every call of the run.
    vehicle: Py<PyDict>,
    /// Whether the instance has an `issued_law` (else the predictors assume the trait's
    /// default, the delay-free CBF-QP).
    has_law: bool,
    /// The error of the first `issued_law` call that failed: the run stops at this tick, and
    /// the predictors' further calls in it return the same error without calling Python.
    law_failed: Option<String>,
}

/// The constraints as a list of `(a, b)` tuples, b a numpy array.
fn constraint_list<'py>(
    py: Python<'py>,
    asarray: &Bound<'py, PyAny>,
    constraints: &[Constraint],
) -> PyResult<Bound<'py, PyList>> {
    let list = PyList::empty(py);
    for c in constraints {
        let b = asarray.call1((PyList::new(py, c.b.as_slice())?,))?;
        list.append(PyTuple::new(py, [c.a.into_pyobject(py)?.into_any(), b])?)?;
    }
    Ok(list)
}

/// What `issued_law` returned, into `u[j]` for j in `free`: None (the nominal, as a filter
/// without a known barrier issues), or one number per channel of `free`, in its order.
fn law_values(
    result: &Bound<'_, PyAny>,
    free: &[usize],
    nominal: &DVector<f64>,
    u: &mut DVector<f64>,
) -> Result<(), String> {
    let n = free.len();
    if result.is_none() {
        for &j in free {
            u[j] = nominal[j];
        }
        return Ok(());
    }
    let values: Vec<f64> = result.extract().map_err(|_| {
        format!(
            "{}: expected None or a sequence of {n} numbers (one per channel of `free`)",
            result.get_type().name().map(|n| n.to_string()).unwrap_or_default()
        )
    })?;
    if values.len() != n {
        return Err(format!(
            "{} values: expected {n} (one per channel of `free`, in its order)",
            values.len()
        ));
    }
    if let Some(x) = values.iter().find(|x| !x.is_finite()) {
        return Err(format!("{x}: expected finite commands"));
    }
    for (&j, value) in free.iter().zip(values) {
        u[j] = value;
    }
    Ok(())
}

/// Which of `names` the method accepts as keyword arguments (by name, or through `**kwargs`).
fn accepts<const N: usize>(method: &Bound<'_, PyAny>, names: [&str; N]) -> PyResult<[bool; N]> {
    let py = method.py();
    let inspect = py.import("inspect")?;
    let parameters = inspect.call_method1("signature", (method,))?.getattr("parameters")?;
    let var_keyword = inspect.getattr("Parameter")?.getattr("VAR_KEYWORD")?;
    let mut any = false;
    for p in parameters.call_method0("values")?.try_iter()? {
        any |= p?.getattr("kind")?.eq(&var_keyword)?;
    }
    Ok(names.map(|n| any || parameters.contains(n).unwrap_or(false)))
}

/// What `filter_channel` returned: None (no decision: the nominal passes), a number (the
/// command), or a dict with `input` and optionally `active`, `infeasible`, `mu`.
fn outcome(result: &Bound<'_, PyAny>, nominal: f64) -> Result<Option<ChannelOutcome>, String> {
    let expected = "expected a number, a dict with `input` (and `active`, `infeasible`, `mu`), or None";
    if result.is_none() {
        return Ok(None);
    }
    if let Ok(dict) = result.cast::<PyDict>() {
        let number = |key: &str| -> Result<Option<f64>, String> {
            match dict.get_item(key).map_err(|e| e.to_string())? {
                Some(v) => v
                    .extract::<f64>()
                    .map(Some)
                    .map_err(|_| format!("`{key}`: expected a number")),
                None => Ok(None),
            }
        };
        let flag = |key: &str| -> Result<Option<bool>, String> {
            match dict.get_item(key).map_err(|e| e.to_string())? {
                Some(v) => v
                    .extract::<bool>()
                    .map(Some)
                    .map_err(|_| format!("`{key}`: expected a bool")),
                None => Ok(None),
            }
        };
        let input = number("input")?.ok_or_else(|| format!("a dict without `input`: {expected}"))?;
        let active = flag("active")?.unwrap_or(input != nominal);
        let infeasible = flag("infeasible")?.unwrap_or(false);
        let mu = number("mu")?.unwrap_or(f64::NAN);
        return Ok(Some(ChannelOutcome::new(input, active, infeasible, mu)));
    }
    match result.extract::<f64>() {
        Ok(input) => Ok(Some(ChannelOutcome::new(input, input != nominal, false, f64::NAN))),
        Err(_) => Err(format!(
            "{expected}; found {}",
            result.get_type().name().map(|n| n.to_string()).unwrap_or_default()
        )),
    }
}

impl SafetyFilter for PythonFilter {
    fn barrier_form(&self) -> Option<BarrierForm> {
        self.form
    }

    fn uses_prediction(&self) -> bool {
        self.uses_prediction
    }

    fn filter_channel(&mut self, input: &ChannelInput<'_>) -> Result<Option<ChannelOutcome>, FilterError> {
        let kind = &self.kind;
        Python::attach(|py| {
            let asarray = self.asarray.bind(py);
            let array = |values: &[f64]| -> PyResult<Bound<'_, PyAny>> { asarray.call1((PyList::new(py, values)?,)) };
            let call = || -> PyResult<Bound<'_, PyAny>> {
                let constraints = constraint_list(py, asarray, input.constraints)?;
                let args = (
                    input.time,
                    input.channel,
                    array(input.state)?,
                    array(input.nominal.as_slice())?,
                    constraints,
                );
                let kwargs = PyDict::new(py);
                let [queues, timestep, barriers, vehicle] = self.channel_takes;
                if queues {
                    kwargs.set_item("queues", queue_list(py, asarray, input.queues, input.time)?)?;
                }
                if timestep {
                    kwargs.set_item("timestep", input.timestep)?;
                }
                if barriers {
                    kwargs.set_item("barriers", barrier_list(py, &input.barriers)?)?;
                }
                if vehicle {
                    kwargs.set_item("vehicle", self.vehicle.bind(py))?;
                }
                self.object.bind(py).call_method("filter_channel", args, Some(&kwargs))
            };
            match call() {
                Ok(result) => outcome(&result, input.nominal[input.channel])
                    .map_err(|message| FilterError::Other(format!("the Python filter `{kind}` returned {message}"))),
                Err(e) => Err(FilterError::Other(format!(
                    "the Python filter `{kind}` raised {}",
                    exception_line(py, &e)
                ))),
            }
        })
    }

    /// The instance's `issued_law(t, prediction_time, state, nominal, constraints, free, u)`,
    /// or without one the trait's default (the delay-free CBF-QP).
    fn issued_law(&mut self, input: &LawInput<'_>, u: &mut DVector<f64>) -> Result<(), FilterError> {
        if !self.has_law {
            delay_free_qp(input.constraints, input.nominal, None, None, u);
            return Ok(());
        }
        if let Some(message) = &self.law_failed {
            return Err(FilterError::Other(message.clone()));
        }
        let kind = &self.kind;
        let result = Python::attach(|py| {
            let asarray = self.asarray.bind(py);
            let array = |values: &[f64]| -> PyResult<Bound<'_, PyAny>> { asarray.call1((PyList::new(py, values)?,)) };
            let call = || -> PyResult<Bound<'_, PyAny>> {
                let args = (
                    input.time,
                    input.prediction_time,
                    array(input.state)?,
                    array(input.nominal.as_slice())?,
                    constraint_list(py, asarray, input.constraints)?,
                    PyList::new(py, input.free)?,
                    array(u.as_slice())?,
                );
                let kwargs = PyDict::new(py);
                let [_, _, barriers, vehicle] = self.law_takes;
                if barriers {
                    kwargs.set_item("barriers", barrier_list(py, &input.barriers)?)?;
                }
                if vehicle {
                    kwargs.set_item("vehicle", self.vehicle.bind(py))?;
                }
                self.object.bind(py).call_method("issued_law", args, Some(&kwargs))
            };
            match call() {
                Ok(result) => law_values(&result, input.free, input.nominal, u)
                    .map_err(|message| format!("the Python filter `{kind}`: issued_law returned {message}")),
                Err(e) => Err(format!(
                    "the Python filter `{kind}`: issued_law raised {}",
                    exception_line(py, &e)
                )),
            }
        });
        result.map_err(|message| {
            self.law_failed = Some(message.clone());
            FilterError::Other(message)
        })
    }
}

/// Per channel: its name, its delay at t, the input applied before the first command arrives,
/// and the commands issued that may still apply, as an array of (issue time, value) rows
/// (read-only copies).
fn queue_list<'py>(
    py: Python<'py>,
    asarray: &Bound<'py, PyAny>,
    queues: &[mjsafe::delay::DelayQueue],
    time: f64,
) -> PyResult<Bound<'py, PyList>> {
    let list = PyList::empty(py);
    for q in queues {
        let queue = PyDict::new(py);
        queue.set_item("channel", q.channel())?;
        let delay = q.constant_delay().unwrap_or_else(|| q.profile().delay(time));
        queue.set_item("delay", delay)?;
        queue.set_item("initial", q.initial_input())?;
        let rows = PyList::empty(py);
        for (time, value) in q.issued() {
            rows.append(PyList::new(py, [time, value])?)?;
        }
        let issued = asarray.call1((rows,))?.call_method1("reshape", (-1, 2))?;
        queue.set_item("issued", issued)?;
        list.append(queue)?;
    }
    Ok(list)
}

/// Every barrier the controller knows at this decision, as a dict (docs/python.md, "What a
/// filter sees"): its name, the obstacle it belongs to, its shape's geometry with a moving
/// actor's circle where the controller assumes it at the evaluation time, and the indices of
/// its constraint rows.
fn barrier_list<'py>(py: Python<'py>, seen: &SeenBarriers<'_>) -> PyResult<Bound<'py, PyList>> {
    let mut rows: Vec<Vec<usize>> = vec![Vec::new(); seen.known.len()];
    for (row, &k) in seen.rows.iter().enumerate() {
        if let Some(of) = rows.get_mut(k) {
            of.push(row);
        }
    }
    let list = PyList::empty(py);
    for (k, (barrier, rows)) in seen.known.iter().zip(rows).enumerate() {
        let d = PyDict::new(py);
        d.set_item("name", &barrier.name)?;
        let obstacle = barrier.name.split_once('/').map_or(barrier.name.as_str(), |(o, _)| o);
        d.set_item("obstacle", obstacle)?;
        let actor = seen.assumed_actor(k);
        d.set_item("moving", actor.is_some())?;
        let centre = |c: &[f64]| -> Vec<f64> { actor.map_or_else(|| c.to_vec(), |a| a.position.to_vec()) };
        match &barrier.shape {
            Shape::Ball {
                indices,
                centre: c,
                radius,
                inside,
            } => {
                d.set_item("shape", "ball")?;
                d.set_item("indices", indices.clone())?;
                d.set_item("centre", centre(c))?;
                d.set_item("radius", radius)?;
                d.set_item("inside", inside)?;
            }
            Shape::HalfSpace { coefficients, offset } => {
                d.set_item("shape", "half_space")?;
                d.set_item("coefficients", coefficients.clone())?;
                d.set_item("offset", offset)?;
            }
            Shape::Quadratic { q, c, d: constant } => {
                d.set_item("shape", "quadratic")?;
                d.set_item("q", q.clone())?;
                d.set_item("c", c.clone())?;
                d.set_item("d", constant)?;
            }
            Shape::BodyCircle {
                offset,
                centre: c,
                radius,
                inside,
                ..
            } => {
                d.set_item("shape", "body_circle")?;
                d.set_item("offset", offset.to_vec())?;
                d.set_item("centre", centre(c))?;
                d.set_item("radius", radius)?;
                d.set_item("inside", inside)?;
            }
            Shape::BodyHalfSpace {
                offset,
                normal,
                distance,
                ..
            } => {
                d.set_item("shape", "body_half_space")?;
                d.set_item("offset", offset.to_vec())?;
                d.set_item("normal", normal.to_vec())?;
                d.set_item("distance", distance)?;
            }
            Shape::BodyCurve {
                offset,
                curve,
                side,
                margin,
                ..
            } => {
                d.set_item("shape", "body_curve")?;
                d.set_item("offset", offset.to_vec())?;
                d.set_item("points", curve.samples().iter().map(|p| p.to_vec()).collect::<Vec<_>>())?;
                d.set_item("side", side)?;
                d.set_item("margin", margin)?;
            }
            Shape::Headway {
                lead,
                rear,
                standstill,
                time_headway,
                ..
            } => {
                d.set_item("shape", "headway")?;
                d.set_item("lead", actor.map_or(*lead, |a| a.position[0]))?;
                d.set_item("rear", rear)?;
                d.set_item("standstill", standstill)?;
                d.set_item("time_headway", time_headway)?;
            }
        }
        if let Some(a) = actor {
            d.set_item("velocity", a.velocity.to_vec())?;
            d.set_item("acceleration", a.acceleration.to_vec())?;
        }
        d.set_item("rows", rows)?;
        list.append(d)?;
    }
    Ok(list)
}

/// The `vehicle` keyword argument: what the filter is built knowing of the vehicle.
fn vehicle_dict<'py>(py: Python<'py>, ctx: &FilterContext<'_>) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("kind", ctx.vehicle_kind)?;
    d.set_item("states", ctx.model.state_names().to_vec())?;
    d.set_item("channels", ctx.model.channel_names().to_vec())?;
    let parameters = PyDict::new(py);
    for (name, value) in ctx.model.parameters() {
        parameters.set_item(name, value)?;
    }
    d.set_item("parameters", parameters)?;
    d.set_item("hull_radius", ctx.hull_radius)?;
    let footprint = match &ctx.footprint {
        None => None,
        Some(rectangle) => {
            let f = PyDict::new(py);
            f.set_item("length", rectangle.length)?;
            f.set_item("width", rectangle.width)?;
            f.set_item("offset", rectangle.offset)?;
            let circles = PyList::empty(py);
            for c in rectangle.circles() {
                let circle = PyDict::new(py);
                circle.set_item("offset", c.offset.to_vec())?;
                circle.set_item("radius", c.radius)?;
                circles.append(circle)?;
            }
            f.set_item("circles", circles)?;
            Some(f)
        }
    };
    d.set_item("footprint", footprint)?;
    d.set_item("initial_state", ctx.initial_state.as_slice().to_vec())?;
    d.set_item("timestep", ctx.timestep)?;
    Ok(d)
}

/// Builds the registered class with the scenario's parameters and reads its attributes.
fn build_filter(
    kind: &str,
    cls: &Py<PyAny>,
    asarray: &Py<PyAny>,
    params: &AnyParams,
    ctx: &FilterContext<'_>,
) -> Result<Box<dyn SafetyFilter>, ParamError> {
    let object = instantiate(cls, &params.0, "filter")?;
    Python::attach(|py| {
        let bound = object.bind(py);
        let form = read_form(bound)?;
        let uses_prediction = match bound.getattr("uses_prediction") {
            Ok(v) => v
                .extract::<bool>()
                .map_err(|_| ParamError::new("filter", "expected `uses_prediction` to be a bool"))?,
            Err(_) => false,
        };
        let method = bound
            .getattr("filter_channel")
            .map_err(|e| ParamError::new("filter", exception_line(py, &e)))?;
        let channel_takes =
            accepts(&method, KEYWORDS).map_err(|e| ParamError::new("filter", exception_line(py, &e)))?;
        let (has_law, law_takes) = match bound.getattr("issued_law") {
            Ok(law) if law.is_none() => (false, [false; 4]),
            Ok(law) if law.is_callable() => (
                true,
                accepts(&law, KEYWORDS).map_err(|e| ParamError::new("filter", exception_line(py, &e)))?,
            ),
            Ok(_) => {
                return Err(ParamError::new(
                    "filter",
                    "expected `issued_law` to be a method (or None)",
                ))
            }
            Err(_) => (false, [false; 4]),
        };
        let vehicle = vehicle_dict(py, ctx).map_err(|e| ParamError::new("filter", exception_line(py, &e)))?;
        Ok(Box::new(PythonFilter {
            kind: kind.to_string(),
            object: object.clone_ref(py),
            form,
            uses_prediction,
            asarray: asarray.clone_ref(py),
            channel_takes,
            law_takes,
            vehicle: vehicle.unbind(),
            has_law,
            law_failed: None,
        }) as Box<dyn SafetyFilter>)
    })
}

/// Per (section, kind), the Python class (`module.qualname`) registered under it from Python.
static PYTHON_KINDS: std::sync::Mutex<std::collections::BTreeMap<(&str, String), String>> =
    std::sync::Mutex::new(std::collections::BTreeMap::new());

/// `module.qualname` of a class: what tells a re-run of its definition (a notebook cell, a
/// module reloaded) from another class.
fn class_identity(class: &Bound<'_, PyAny>) -> String {
    let text = |name: &str| -> String {
        class
            .getattr(name)
            .and_then(|v| v.extract::<String>())
            .unwrap_or_default()
    };
    format!("{}.{}", text("__module__"), text("__qualname__"))
}

/// Whether registering `identity` as the `section` kind `kind` replaces what is there: asked
/// for, or the same class registered again from Python.
fn replaces(section: &'static str, kind: &str, identity: &str, replace: bool) -> bool {
    let kinds = PYTHON_KINDS.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    replace || kinds.get(&(section, kind.to_string())).is_some_and(|i| i == identity)
}

/// Notes a registration done, for [`replaces`].
fn registered(section: &'static str, kind: &str, identity: String) {
    let mut kinds = PYTHON_KINDS.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    kinds.insert((section, kind.to_string()), identity);
}

/// The label of a Python class without its own that replaces a built-in: the kind's name and
/// whose it is, so a log never passes it off as the built-in.
fn replacing_label(section: &str, kind: &str, identity: &str) -> Option<String> {
    let registry = mjsafe::registry::registry();
    let builtin = registry.has_kind(section, kind)
        && match section {
            "filter" => registry.filter_origin(kind).is_none(),
            _ => registry.nominal_origin(kind).is_none(),
        };
    builtin.then(|| format!("{kind} (Python {identity})"))
}

/// `mjsafe.register_filter(kind, cls, replace=False)`: the kind works in scenario files and
/// `set` dicts, in `run`, `sweep` and `falsify` (in this process). A kind already registered
/// (a built-in's, or another class's) is refused unless `replace`.
#[pyfunction]
#[pyo3(signature = (kind, cls, replace = false))]
pub fn register_filter(py: Python<'_>, kind: &str, cls: Py<PyAny>, replace: bool) -> PyResult<()> {
    if kind.is_empty() || !kind.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(PyValueError::new_err(format!(
            "register_filter: expected a kind of letters, digits and `_`, found {kind:?}"
        )));
    }
    let class = cls.bind(py);
    if !class.hasattr("filter_channel")? {
        return Err(PyTypeError::new_err(
            "register_filter: expected a class with a method filter_channel(self, t, channel, state, nominal, constraints)",
        ));
    }
    let identity = class_identity(class);
    let replace = replaces("filter", kind, &identity, replace);
    let label = match class.getattr("label") {
        Ok(l) if !l.is_none() => Some(
            l.extract::<String>()
                .map_err(|_| PyTypeError::new_err("register_filter: expected `label` to be a str"))?,
        ),
        _ => replacing_label("filter", kind, &identity),
    };
    if let Ok(law) = class.getattr("issued_law") {
        if !law.is_none() && !law.is_callable() {
            return Err(PyTypeError::new_err(format!(
                "register_filter: expected `issued_law` to be a method issued_law(self, t, prediction_time, state, nominal, constraints, free, u), not a {}",
                law.get_type().name().map(|n| n.to_string()).unwrap_or_default()
            )));
        }
    }
    let asarray = py.import("numpy")?.getattr("asarray")?.unbind();
    let name = kind.to_string();
    let origin = class_file(class, "filter_channel");
    mjsafe::registry::register(move |r| {
        if replace {
            r.replacing();
        }
        let described = r.add_filter(&name.clone(), move |p: &AnyParams, ctx: &FilterContext| {
            build_filter(&name, &cls, &asarray, p, ctx)
        });
        let mut described = described.description(&match &origin {
            Some(file) => format!("a filter written in Python (mjsafe.register_filter) in {file}"),
            None => "a filter written in Python (mjsafe.register_filter)".into(),
        });
        if let Some(file) = &origin {
            described = described.origin(file);
        }
        if let Some(label) = &label {
            described.label(label);
        }
    })
    .map_err(|e| PyValueError::new_err(format!("register_filter: {e}")))?;
    registered("filter", kind, identity);
    Ok(())
}

/// A nominal controller written in Python: `input(t, state)` of an instance of the registered
/// class, one command per channel.
pub struct PythonNominal {
    kind: String,
    object: Py<PyAny>,
    asarray: Py<PyAny>,
}

impl NominalController for PythonNominal {
    fn input_into(&self, time: f64, x: &[f64], u: &mut [f64]) {
        // Only the control loop calls a nominal, through `try_input_into`; an error here has
        // nowhere to go, so it leaves non-finite commands, which the loop refuses.
        if self.try_input_into(time, x, &[], u).is_err() {
            u.fill(f64::NAN);
        }
    }

    fn try_input_into(&self, time: f64, x: &[f64], _: &[SeenActor], u: &mut [f64]) -> Result<(), String> {
        let kind = &self.kind;
        Python::attach(|py| {
            let call = || -> PyResult<Bound<'_, PyAny>> {
                let state = self.asarray.bind(py).call1((PyList::new(py, x)?,))?;
                self.object.bind(py).call_method1("input", (time, state))
            };
            let result =
                call().map_err(|e| format!("the Python nominal `{kind}` raised {}", exception_line(py, &e)))?;
            let values: Vec<f64> = result.extract().map_err(|_| {
                format!(
                    "the Python nominal `{kind}` returned {}: expected a sequence of {} numbers (one per channel)",
                    result.get_type().name().map(|n| n.to_string()).unwrap_or_default(),
                    u.len()
                )
            })?;
            if values.len() != u.len() {
                return Err(format!(
                    "the Python nominal `{kind}` returned {} values: expected {} (one per channel)",
                    values.len(),
                    u.len()
                ));
            }
            u.copy_from_slice(&values);
            Ok(())
        })
    }
}

/// `mjsafe.register_nominal(kind, cls, replace=False)`: `cls(params)` with the scenario's
/// `[nominal]` table, whose `input(t, state)` gives u0 (one value per channel). A kind already
/// registered is refused unless `replace`, as for filters.
#[pyfunction]
#[pyo3(signature = (kind, cls, replace = false))]
pub fn register_nominal(py: Python<'_>, kind: &str, cls: Py<PyAny>, replace: bool) -> PyResult<()> {
    if kind.is_empty() || !kind.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(PyValueError::new_err(format!(
            "register_nominal: expected a kind of letters, digits and `_`, found {kind:?}"
        )));
    }
    let class = cls.bind(py);
    if !class.hasattr("input")? {
        return Err(PyTypeError::new_err(
            "register_nominal: expected a class with a method input(self, t, state)",
        ));
    }
    let identity = class_identity(class);
    let replace = replaces("nominal", kind, &identity, replace);
    let label = match class.getattr("label") {
        Ok(l) if !l.is_none() => Some(
            l.extract::<String>()
                .map_err(|_| PyTypeError::new_err("register_nominal: expected `label` to be a str"))?,
        ),
        _ => replacing_label("nominal", kind, &identity),
    };
    let asarray = py.import("numpy")?.getattr("asarray")?.unbind();
    let name = kind.to_string();
    let origin = class_file(class, "input");
    mjsafe::registry::register(move |r| {
        if replace {
            r.replacing();
        }
        let described = r.add_nominal(&name.clone(), move |p: &AnyParams, _: &NominalContext| {
            let object = instantiate(&cls, &p.0, "nominal")?;
            Ok(Box::new(PythonNominal {
                kind: name.clone(),
                object,
                asarray: Python::attach(|py| asarray.clone_ref(py)),
            }) as Box<dyn NominalController>)
        });
        let mut described = described.description(&match &origin {
            Some(file) => format!("a nominal controller written in Python (mjsafe.register_nominal) in {file}"),
            None => "a nominal controller written in Python (mjsafe.register_nominal)".into(),
        });
        if let Some(file) = &origin {
            described = described.origin(file);
        }
        if let Some(label) = &label {
            described.label(label);
        }
    })
    .map_err(|e| PyValueError::new_err(format!("register_nominal: {e}")))?;
    registered("nominal", kind, identity);
    Ok(())
}
