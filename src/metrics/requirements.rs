//! Requirements: STL formulas ([`crate::stl`]) over the signals of a run, each reported as the
//! metric `req.<name>`, its robustness ρ(φ, 0) (docs/requirements.md).
//!
//! The signals are the columns of the tables of `mjsafe export` ([`crate::signals::table_row`],
//! the one definition of those columns), on the plant's step grid:
//!
//! - a sample per `/state` message, at its time t_k; every other table topic's latest message
//!   at or before t_k gives its columns' values (per-tick signals such as `/filter` and
//!   `/command/issued` are held between ticks, and the last state, which starts no step, holds
//!   the per-step topics' values of the step before);
//! - a name is a column of exactly one table (`speed`, `obstacle_0.h`, `steering.filtered`) or
//!   a qualified `<topic>.<column>` (`/state/measured.speed`); a name found in several tables
//!   (`time`, `step`, a state name with a sensor) is refused with its qualified spellings;
//!   `/prediction` and `/event` are not signals;
//! - booleans are 1 and 0, counts are numbers.
//!
//! A formula with bounded memory ([`crate::stl::Formula::online`]) is monitored as the records
//! arrive (a fixed number of samples, allocation-free per step); the others keep their signals
//! and are evaluated when the run ends. Both give the offline value of [`crate::stl::robustness`].

use std::collections::BTreeMap;

use crate::log::{Topic, REQUIREMENT_METADATA_PREFIX};
use crate::metrics::{Accumulate, Observed, RunFacts, Value};
use crate::signals::{is_signal_topic, resolve_name, table_row, Cell, Columns, Source};
use crate::stl::{self, Formula};

/// The requirements a run's metadata records (`requirement.<name>` = formula), by name.
pub fn from_metadata(metadata: &BTreeMap<String, String>) -> Vec<(String, String)> {
    metadata
        .iter()
        .filter_map(|(k, v)| Some((k.strip_prefix(REQUIREMENT_METADATA_PREFIX)?.to_string(), v.clone())))
        .collect()
}

/// One requirement being evaluated.
struct Tracked {
    name: String,
    formula: Formula,
    /// Per signal of the formula, its slot in [`RequirementsAccumulator::values`].
    slots: Vec<usize>,
    /// The sample handed to the monitor (one value per signal of the formula).
    sample: Vec<f64>,
    how: How,
    /// Why it has no value (set at the first problem).
    absent: Option<String>,
}

/// How a requirement is evaluated.
enum How {
    Online(stl::Monitor),
    /// Every sample of each signal, for the offline evaluation at the end.
    Offline(Vec<Vec<f64>>),
}

/// Most samples per signal kept for a requirement's violation time (8 MB a signal): longer
/// runs report the time absent with this reason.
pub const MAX_KEPT_SAMPLES: usize = 1 << 20;

/// The `req` metric's accumulator: the signals of every requirement of the run, sampled on the
/// step grid, into each requirement's monitor.
#[derive(Default)]
pub struct RequirementsAccumulator {
    /// Whether every requirement keeps its signals (evaluated offline, at most
    /// [`MAX_KEPT_SAMPLES`]) for [`ViolationTimes`].
    keep: bool,
    started: bool,
    tracked: Vec<Tracked>,
    /// Requirements whose formula does not parse (a log written by another version), with why.
    unparsed: Vec<(String, String)>,
    /// Distinct signal names of all requirements, and their current values.
    names: Vec<String>,
    values: Vec<f64>,
    /// Per signal, where it comes from once resolved.
    sources: Vec<Option<Source>>,
    /// Per signal topic, its columns (from its first message).
    columns: BTreeMap<Topic, Columns>,
    /// Per signal topic, its latest row until the names are resolved (the first sample).
    first_rows: BTreeMap<Topic, Vec<Cell>>,
    resolved: bool,
    /// The time of the sample being gathered, once a record was seen.
    open: Option<f64>,
    /// Whether the open sample has its `/state`.
    has_state: bool,
    samples: u64,
    step: f64,
    cells: Vec<Cell>,
}

impl RequirementsAccumulator {
    /// Builds the monitors from the run's requirements (first record).
    fn start(&mut self, run: &RunFacts) {
        self.started = true;
        self.step = run.timestep.unwrap_or(f64::NAN);
        for (name, text) in &run.requirements {
            let parsed = stl::parse(text).map_err(|e| format!("formula {text:?}: {e}"));
            let formula = match parsed {
                Ok(f) => f,
                Err(reason) => {
                    self.unparsed.push((name.clone(), reason));
                    continue;
                }
            };
            let mut slots = Vec::new();
            for signal in formula.signals() {
                let slot = match self.names.iter().position(|n| n == signal) {
                    Some(i) => i,
                    None => {
                        self.names.push(signal.clone());
                        self.values.push(f64::NAN);
                        self.sources.push(None);
                        self.names.len() - 1
                    }
                };
                slots.push(slot);
            }
            let how = if !self.step.is_finite() {
                Err("no `timestep` in the run metadata".to_string())
            } else if let Err(e) = formula.check_step(self.step) {
                Err(e.to_string())
            } else if formula.online() && !self.keep {
                stl::Monitor::new(&formula, self.step)
                    .map(How::Online)
                    .map_err(|e| e.to_string())
            } else {
                Ok(How::Offline(vec![Vec::new(); slots.len()]))
            };
            let (how, absent) = match how {
                Ok(how) => (how, None),
                Err(reason) => (How::Offline(Vec::new()), Some(reason)),
            };
            self.tracked.push(Tracked {
                name: name.clone(),
                sample: vec![f64::NAN; slots.len()],
                slots,
                formula,
                how,
                absent,
            });
        }
    }

    /// Resolves every signal name to its table cell, from the columns seen (at the first
    /// sample's end: every signal topic has logged at t = 0 by then).
    fn resolve(&mut self) {
        self.resolved = true;
        let rows = std::mem::take(&mut self.first_rows);
        for (i, name) in self.names.iter().enumerate() {
            match resolve_name(name, &self.columns) {
                Ok(source) => {
                    self.values[i] = rows
                        .get(&source.topic)
                        .map_or(f64::NAN, |row| number(row.get(source.cell)));
                    self.sources[i] = Some(source);
                }
                Err(reason) => {
                    for t in self.tracked.iter_mut().filter(|t| t.slots.contains(&i)) {
                        t.absent.get_or_insert_with(|| reason.clone());
                    }
                }
            }
        }
    }

    /// Hands the open sample (the values as of its time) to every requirement.
    fn push_sample(&mut self) {
        if !self.resolved {
            self.resolve();
        }
        let time = self.samples as f64 * self.step;
        for t in self.tracked.iter_mut().filter(|t| t.absent.is_none()) {
            for (value, &slot) in t.sample.iter_mut().zip(&t.slots) {
                *value = self.values[slot];
            }
            if let Some(k) = t.sample.iter().position(|v| v.is_nan()) {
                t.absent = Some(format!(
                    "signal `{}` has no value at t = {time} s",
                    t.formula.signals()[k]
                ));
                continue;
            }
            match &mut t.how {
                How::Online(monitor) => monitor.push(&t.sample),
                How::Offline(signals) => {
                    if self.keep && self.samples >= MAX_KEPT_SAMPLES as u64 {
                        t.absent = Some(format!(
                            "the run has more than {MAX_KEPT_SAMPLES} samples, the most kept to find when a requirement fails"
                        ));
                        *signals = Vec::new();
                        continue;
                    }
                    for (signal, v) in signals.iter_mut().zip(&t.sample) {
                        signal.push(*v);
                    }
                }
            }
        }
        self.samples += 1;
    }

    /// Updates the current values from a record of a signal topic.
    fn update(&mut self, record: Observed<'_>) {
        let topic = record.topic();
        if !self.columns.contains_key(&topic) {
            let mut columns = Vec::new();
            table_row(record, None, &mut self.cells, Some(&mut columns));
            self.columns.insert(topic, columns);
        } else {
            table_row(record, None, &mut self.cells, None);
        }
        if !self.resolved {
            self.first_rows.insert(topic, self.cells.clone());
            return;
        }
        for (value, source) in self.values.iter_mut().zip(&self.sources) {
            if let Some(source) = source.as_ref().filter(|s| s.topic == topic) {
                *value = number(self.cells.get(source.cell));
            }
        }
    }
}

/// A cell as a signal's value: booleans 1 and 0, counts as numbers (text: none).
fn number(cell: Option<&Cell>) -> f64 {
    match cell {
        Some(Cell::F(x)) => *x,
        Some(Cell::U(n)) => *n as f64,
        Some(Cell::B(b)) => f64::from(u8::from(*b)),
        Some(Cell::S(_)) | None => f64::NAN,
    }
}

impl Accumulate for RequirementsAccumulator {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        if !self.started {
            self.start(run);
        }
        if self.tracked.is_empty() || !is_signal_topic(record.topic()) {
            return;
        }
        let time = record.time();
        // Records come in log-time order: a later time closes the sample being gathered.
        if let Some(open) = self.open {
            if time > open + 1e-6 * self.step && self.has_state {
                self.push_sample();
                self.has_state = false;
            }
        }
        self.open = Some(time);
        self.has_state |= record.topic() == Topic::State;
        self.update(record);
    }

    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        self.finish(run);
        let mut values = BTreeMap::new();
        for t in &mut self.tracked {
            let value = match (&t.absent, &mut t.how) {
                (Some(_), _) => None,
                (None, How::Online(monitor)) => Some(monitor.finish()),
                (None, How::Offline(signals)) => {
                    let views: Vec<&[f64]> = signals.iter().map(Vec::as_slice).collect();
                    match stl::robustness(&t.formula, &views, self.step) {
                        Ok(v) => Some(v),
                        Err(e) => {
                            t.absent = Some(e.to_string());
                            None
                        }
                    }
                }
            };
            match value {
                Some(v) if !v.is_nan() => {
                    values.insert(t.name.clone(), v);
                }
                Some(_) => {
                    missing.insert(format!("req.{}", t.name), "a signal is NaN in the run".into());
                }
                None => {
                    let reason = t.absent.clone().unwrap_or_else(|| "no samples".into());
                    missing.insert(format!("req.{}", t.name), reason);
                }
            }
        }
        self.note_unevaluated("req", missing);
        Value::PerChannel((!values.is_empty()).then_some(values))
    }
}

impl RequirementsAccumulator {
    /// Closes the last sample (the run has ended).
    fn finish(&mut self, run: &RunFacts) {
        if !self.started {
            self.start(run);
        }
        if self.has_state {
            self.push_sample();
            self.has_state = false;
        }
    }

    /// `<column>.<name>` of the requirements not evaluated at all: a formula that does not
    /// parse, or a log without a state.
    fn note_unevaluated(&self, column: &str, missing: &mut BTreeMap<String, String>) {
        for (name, reason) in &self.unparsed {
            missing.insert(format!("{column}.{name}"), reason.clone());
        }
        if self.samples == 0 {
            for t in &self.tracked {
                missing
                    .entry(format!("{column}.{}", t.name))
                    .or_insert_with(|| "no /state message in the log".into());
            }
        }
    }
}

/// The `req_violated_at` metric's accumulator: per violated requirement, when it first
/// certainly failed ([`stl::violation_time`]): its signals kept (at most
/// [`MAX_KEPT_SAMPLES`] each) and evaluated when the run ends.
pub struct ViolationTimes(RequirementsAccumulator);

impl Default for ViolationTimes {
    fn default() -> ViolationTimes {
        ViolationTimes(RequirementsAccumulator {
            keep: true,
            ..RequirementsAccumulator::default()
        })
    }
}

impl Accumulate for ViolationTimes {
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts) {
        self.0.observe(record, run);
    }

    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value {
        let column = super::builtin::REQUIREMENT_VIOLATED_AT;
        let acc = &mut self.0;
        acc.finish(run);
        let mut values = BTreeMap::new();
        for t in &acc.tracked {
            let key = format!("{column}.{}", t.name);
            let time = match (&t.absent, &t.how) {
                (Some(reason), _) => Err(reason.clone()),
                (None, How::Offline(signals)) => {
                    let views: Vec<&[f64]> = signals.iter().map(Vec::as_slice).collect();
                    stl::violation_time(&t.formula, &views, acc.step).map_err(|e| e.to_string())
                }
                (None, How::Online(_)) => Err("its signals were not kept".into()),
            };
            match time {
                Ok(Some(time)) => {
                    values.insert(t.name.clone(), time);
                }
                Ok(None) => {
                    missing.insert(key, "not violated (ρ ≥ 0)".into());
                }
                Err(reason) => {
                    missing.insert(key, reason);
                }
            }
        }
        acc.note_unevaluated(column, missing);
        Value::PerChannel((!values.is_empty()).then_some(values))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::log::proto;
    use crate::mujoco::counting_alloc::{allocations, count_allocations};

    /// A run of `n` steps of h = 0.1 s: x1 = k h, a barrier h = 1 − x1, the filter active
    /// from x1 ≥ 0.5 (ticks every other step, held between them).
    fn feed(acc: &mut RequirementsAccumulator, facts: &RunFacts, n: u64, counted_from: u64) -> u64 {
        let mut state = proto::State {
            names: vec!["x1".into()],
            values: vec![0.0],
            ..Default::default()
        };
        let mut barrier = proto::Barrier {
            barriers: vec![proto::BarrierValue {
                name: "wall".into(),
                ..Default::default()
            }],
            ..Default::default()
        };
        let mut filter = proto::Filter {
            channels: vec!["u".into()],
            correction: vec![0.0],
            ..Default::default()
        };
        let mut counted = 0;
        for k in 0..n {
            if k == counted_from {
                allocations(true);
                count_allocations(true);
            }
            let t = k as f64 * 0.1;
            (state.time, state.step, state.values[0]) = (t, k, t);
            acc.observe(Observed::State(&state), facts);
            if k + 1 == n {
                break;
            }
            if k % 2 == 0 {
                (filter.time, filter.active) = (t, t >= 0.5);
                acc.observe(Observed::Filter(&filter), facts);
            }
            (barrier.time, barrier.barriers[0].h) = (t, 1.0 - t);
            acc.observe(Observed::Barrier(&barrier), facts);
        }
        if counted_from < n {
            count_allocations(false);
            counted = allocations(true);
        }
        counted
    }

    fn facts(requirements: &[(&str, &str)]) -> RunFacts {
        RunFacts {
            timestep: Some(0.1),
            requirements: requirements
                .iter()
                .map(|(n, f)| (n.to_string(), f.to_string()))
                .collect(),
            ..RunFacts::default()
        }
    }

    #[test]
    fn signals_are_sampled_on_the_state_grid_held_between_ticks() {
        // 11 samples, t = 0 … 1.0 s. always wall.h >= 0: min over samples of 1 − x1, where the
        // last state (t = 1) holds the barrier of t = 0.9: 0.1. eventually active: held from
        // the tick at 0.6 (the first at or after 0.5).
        let facts = facts(&[
            ("wall", "always wall.h >= 0"),
            ("active", "eventually[0, 0.5] active > 0.5"),
            ("late", "eventually active > 0.5"),
            ("x", "always x1 <= 1"),
        ]);
        let mut acc = RequirementsAccumulator::default();
        feed(&mut acc, &facts, 11, u64::MAX);
        let mut missing = BTreeMap::new();
        let Value::PerChannel(Some(values)) = acc.value(&facts, &mut missing) else {
            panic!("no values: {missing:?}")
        };
        assert!(missing.is_empty(), "{missing:?}");
        assert!((values["wall"] - 0.1).abs() < 1e-12, "{values:?}");
        assert_eq!(values["active"], -0.5, "inactive over [0, 0.5]");
        assert_eq!(values["late"], 0.5);
        assert!((values["x"] - 0.0).abs() < 1e-12);
    }

    #[test]
    fn a_violated_requirement_says_when_it_failed() {
        // x1 = k h, h = 0.1 s, 11 samples; wall.h = 1 − x1 (held: 0.1 at t = 1).
        let facts = facts(&[
            ("x", "always x1 < 0.45"),
            ("window", "eventually[0, 0.3] x1 > 5"),
            ("reaction", "always (x1 > 0.15 implies eventually[0, 0.2] active > 0.5)"),
            ("met", "always wall.h >= 0"),
        ]);
        let mut acc = ViolationTimes::default();
        feed(&mut acc.0, &facts, 11, u64::MAX);
        let mut missing = BTreeMap::new();
        let Value::PerChannel(Some(times)) = acc.value(&facts, &mut missing) else {
            panic!("no values: {missing:?}")
        };
        // x1 first ≥ 0.45 at t = 0.5; the window [0, 0.3] closes without x1 > 5 at 0.3;
        // x1 > 0.15 at t = 0.2 asks for `active` by 0.4, which comes at 0.6: known at 0.4.
        assert!((times["x"] - 0.5).abs() < 1e-12, "{times:?}");
        assert!((times["window"] - 0.3).abs() < 1e-12, "{times:?}");
        assert!((times["reaction"] - 0.4).abs() < 1e-12, "{times:?}");
        assert!(!times.contains_key("met"));
        assert_eq!(missing["req_violated_at.met"], "not violated (ρ ≥ 0)");
    }

    #[test]
    fn monitoring_a_step_does_not_allocate() {
        // After the first samples (names resolved, buffers grown), a step costs no allocation.
        let facts = facts(&[
            ("wall", "always (wall.h >= 0 or eventually[0, 2] active > 0.5)"),
            ("past", "always (x1 > 3 implies once[0, 1] active > 0.5)"),
        ]);
        let mut acc = RequirementsAccumulator::default();
        let counted = feed(&mut acc, &facts, 400, 50);
        assert_eq!(counted, 0, "allocations while monitoring");
        let mut missing = BTreeMap::new();
        assert!(
            matches!(acc.value(&facts, &mut missing), Value::PerChannel(Some(_))),
            "{missing:?}"
        );
    }
}
