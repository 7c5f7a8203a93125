//! `mjsafe._core.Stepper`: one episode stepped control tick by control tick from Python
//! (python/mjsafe/env.py builds the Gymnasium-style `mjsafe.Env` on it).
//!
//! It is the run path of `mjsafe.run` ([`mjsafe::run::Prepared::start`]): the same episode,
//! log of record and analysis, with the loop's steps taken when Python asks
//! ([`mjsafe::run::Running::advance`]). What Python observes between ticks is the plant's state
//! and the controller's queues, read from the episode, and the latest records of the step loop,
//! kept by a sink that only observes ([`Latest`]).

use std::cell::RefCell;
use std::path::PathBuf;
use std::rc::Rc;

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use mjsafe::log::{proto, LogError, Record, Sink};
use mjsafe::run::{Keep, Prepared, Rest, Running};

/// The latest records of the step loop, and the events since they were last taken.
#[derive(Default)]
struct Latest {
    issued: Option<proto::IssuedCommand>,
    filter: Option<proto::Filter>,
    events: Vec<proto::Event>,
}

/// A sink that keeps [`Latest`] (shared with the stepper that reads it).
struct LatestSink(Rc<RefCell<Latest>>);

/// At most this many events are kept between two reads (a run logs a handful per tick at most).
const MAX_EVENTS: usize = 10_000;

impl Sink for LatestSink {
    fn record(&mut self, record: &Record) -> Result<(), LogError> {
        let mut latest = self.0.borrow_mut();
        match record {
            Record::Issued(m) => latest.issued = Some(m.clone()),
            Record::Filter(m) => latest.filter = Some(m.clone()),
            Record::Event(m) if latest.events.len() < MAX_EVENTS => latest.events.push(m.clone()),
            _ => {}
        }
        Ok(())
    }
    fn finish(&mut self, _: bool) -> Result<(), LogError> {
        Ok(())
    }
}

/// One episode, stepped from Python. Not shared between threads (the MuJoCo episode and its
/// callback belong to the thread that steps them).
#[pyclass(unsendable, module = "mjsafe._core")]
pub struct Stepper {
    running: Option<Running<'static>>,
    latest: Rc<RefCell<Latest>>,
    /// The in-memory tables, when asked for.
    tables: Option<Rc<RefCell<Option<mjsafe::export::MemoryTables>>>>,
    /// How the episode ended, once it has (steps, error).
    ended: Option<(u64, Option<String>)>,
}

/// A sink that hands its tables over when finished.
struct SharedTables {
    sink: Option<mjsafe::export::TableSink>,
    out: Rc<RefCell<Option<mjsafe::export::MemoryTables>>>,
}

impl Sink for SharedTables {
    fn record(&mut self, record: &Record) -> Result<(), LogError> {
        match &mut self.sink {
            Some(sink) => sink.record(record),
            None => Ok(()),
        }
    }
    fn finish(&mut self, complete: bool) -> Result<(), LogError> {
        let Some(mut sink) = self.sink.take() else {
            return Ok(());
        };
        sink.finish(complete)?;
        *self.out.borrow_mut() = Some(sink.tables());
        Ok(())
    }
}

impl Stepper {
    fn running(&mut self) -> PyResult<&mut Running<'static>> {
        self.running
            .as_mut()
            .ok_or_else(|| PyRuntimeError::new_err("the episode is finished: reset() starts a new one"))
    }

    fn episode(&self) -> PyResult<&mjsafe::episode::Episode> {
        self.running
            .as_ref()
            .map(Running::episode)
            .ok_or_else(|| PyRuntimeError::new_err("the episode is finished: reset() starts a new one"))
    }
}

#[pymethods]
impl Stepper {
    /// Loads and assembles the scenario (with `set` overrides as `mjsafe.run` takes them) and
    /// opens its log (`out`) or its in-memory analysis; no step is taken.
    #[new]
    #[pyo3(signature = (path, set=None, out=None, tables=false))]
    fn new(path: PathBuf, set: Option<&Bound<'_, PyAny>>, out: Option<PathBuf>, tables: bool) -> PyResult<Stepper> {
        let overrides = crate::overrides(set, "set")?;
        let loaded = mjsafe::scenario::load(&path, &overrides).map_err(crate::bad)?;
        let keep = match &out {
            Some(log) => Keep::Log(log),
            None => Keep::Metrics(crate::IN_MEMORY),
        };
        let prepared = Prepared::new(&loaded, keep).map_err(crate::bad)?;
        let latest = Rc::new(RefCell::new(Latest::default()));
        let mut further: Vec<Box<dyn Sink>> = vec![Box::new(LatestSink(latest.clone()))];
        let tables = tables.then(|| {
            let name = out
                .as_ref()
                .map_or(crate::IN_MEMORY.to_string(), |p| p.display().to_string());
            let shared = Rc::new(RefCell::new(None));
            further.push(Box::new(SharedTables {
                sink: Some(mjsafe::export::TableSink::new(&name)),
                out: shared.clone(),
            }));
            shared
        });
        Ok(Stepper {
            running: Some(prepared.start(further)),
            latest,
            tables,
            ended: None,
        })
    }

    /// Takes `steps` steps of the loop (at most; fewer when the episode ends); returns whether
    /// it has ended. A failed sink is a RuntimeError.
    fn advance(&mut self, steps: u64) -> PyResult<bool> {
        if self.ended.is_some() {
            return Ok(true);
        }
        let running = self.running()?;
        for _ in 0..steps {
            if let Some((steps, error)) = running.advance().map_err(crate::failed)? {
                self.ended = Some((steps, error.map(|e| e.to_string())));
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Sets the action: the input of the `external` nominal from the next tick on.
    fn set_input(&mut self, values: Vec<f64>) -> PyResult<()> {
        self.running()?
            .set_external_input(&values)
            .map_err(|e| PyValueError::new_err(format!("action: {e}")))
    }

    /// The loop's next step k (t_k = k h), the steps of the episode, the steps per tick, h.
    fn clock(&self) -> PyResult<(u64, u64, u64, f64)> {
        let e = self.episode()?;
        Ok((e.step_index(), e.steps(), e.steps_per_tick(), e.timestep()))
    }

    /// The plant's state now, x(t_k).
    fn state(&self) -> PyResult<Vec<f64>> {
        Ok(self.episode()?.plant_state().as_slice().to_vec())
    }

    /// State names, channel names, and the run's metadata (as the log stores it).
    fn describe<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let e = self.episode()?;
        let dict = PyDict::new(py);
        dict.set_item("state_names", e.state_names().to_vec())?;
        dict.set_item("channels", e.channel_names().to_vec())?;
        let metadata = PyDict::new(py);
        for (k, v) in e.info().metadata() {
            metadata.set_item(k, v)?;
        }
        dict.set_item("metadata", metadata)?;
        dict.set_item("planar_position", e.info().planar_position.map(|p| p.to_vec()))?;
        dict.set_item(
            "input_limits",
            e.input_limits().iter().map(|l| l.to_vec()).collect::<Vec<_>>(),
        )?;
        Ok(dict)
    }

    /// The controller's delay queues: per channel its delay now and the commands issued and
    /// still held, (issue time, value), oldest first.
    fn queues<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let e = self.episode()?;
        let time = e.step_index() as f64 * e.timestep();
        let out = PyList::empty(py);
        for q in e.queues() {
            let d = PyDict::new(py);
            d.set_item("channel", q.channel())?;
            d.set_item("delay", q.profile().delay(time))?;
            d.set_item("issued", q.issued().collect::<Vec<_>>())?;
            out.append(d)?;
        }
        Ok(out)
    }

    /// Every barrier at the current state: name, h, clearance, known, obstacle.
    fn barriers<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let out = PyList::empty(py);
        for b in self.episode()?.barriers_now() {
            let d = PyDict::new(py);
            d.set_item("name", b.name)?;
            d.set_item("h", b.h)?;
            d.set_item("clearance", b.clearance)?;
            d.set_item("known", b.known)?;
            d.set_item("obstacle", b.obstacle)?;
            out.append(d)?;
        }
        Ok(out)
    }

    /// The latest `/command/issued` and `/filter` records as dicts (None before
    /// the first), and the `/event`s logged since the last call.
    fn latest<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let mut latest = self.latest.borrow_mut();
        let dict = PyDict::new(py);
        match &latest.issued {
            Some(m) => {
                let d = PyDict::new(py);
                d.set_item("time", m.time)?;
                d.set_item("nominal", m.nominal.clone())?;
                d.set_item("filtered", m.filtered.clone())?;
                dict.set_item("issued", d)?;
            }
            None => dict.set_item("issued", py.None())?,
        }
        match &latest.filter {
            Some(m) => {
                let d = PyDict::new(py);
                d.set_item("time", m.time)?;
                d.set_item("active", m.active)?;
                d.set_item("infeasible", m.infeasible)?;
                d.set_item("correction", m.correction.clone())?;
                d.set_item("unmet", m.unmet.clone())?;
                dict.set_item("filter", d)?;
            }
            None => dict.set_item("filter", py.None())?,
        }
        let events = PyList::empty(py);
        for e in latest.events.drain(..) {
            let d = PyDict::new(py);
            d.set_item("time", e.time)?;
            d.set_item("kind", e.kind)?;
            d.set_item("message", e.message)?;
            d.set_item("participants", e.participants)?;
            d.set_item("depth", e.depth)?;
            events.append(d)?;
        }
        dict.set_item("events", events)?;
        Ok(dict)
    }

    /// Finishes the episode — `rest`: "run" takes the remaining steps, "end_here" ends it where
    /// it is — and returns the run's result as `mjsafe.run` does.
    fn finish<'py>(&mut self, py: Python<'py>, rest: &str) -> PyResult<Bound<'py, PyDict>> {
        let rest = match rest {
            "run" => Rest::Run,
            "end_here" => Rest::EndHere,
            other => {
                return Err(PyValueError::new_err(format!(
                    "rest: expected \"run\" or \"end_here\", found {other:?}"
                )))
            }
        };
        let running = self
            .running
            .take()
            .ok_or_else(|| PyRuntimeError::new_err("the episode is already finished"))?;
        let outcome = running.finish(rest).map_err(crate::failed)?;
        let tables = self.tables.as_ref().and_then(|t| t.borrow_mut().take());
        crate::outcome_dict(py, &outcome, tables.as_ref())
    }

    /// Whether the episode is finished (its result taken).
    #[getter]
    fn finished(&self) -> bool {
        self.running.is_none()
    }
}
