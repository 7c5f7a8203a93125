//! The metrics of a run, each one declaration ([`Metric`] in [`builtin::METRICS`]): its name,
//! unit, one-line meaning, the log topics and run metadata keys it needs, how it accumulates
//! (an [`Accumulate`]) and the shape of its value ([`Shape`]), from which its JSON, its flat
//! columns (CSV, `--compare`, sweep summaries, `falsify --objective`), its table cell and its
//! row of docs/metrics.md all follow. The accumulators consume the typed records
//! ([`Observed`]): decoded from a log by `analyze`, or handed over by a running episode
//! (`analyze::AnalysisSink`).

pub mod builtin;
pub mod report;
pub mod requirements;
mod value;

use std::collections::BTreeMap;

use serde::ser::SerializeMap;
use serde::Serialize;

use crate::log::{read, Topic};

pub use value::{Cell, Collision, FlatMetrics, PredictionStats, PrescribedTimeMetrics, Value};

pub use crate::signals::Observed;

/// What the run metadata says about the run, as the metrics need it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunFacts {
    /// Physics timestep Δt (metadata `timestep`).
    pub timestep: Option<f64>,
    /// Control period (metadata `control_period`).
    pub control_period: Option<f64>,
    /// The longest actuator latency (metadata `max_delay`).
    pub max_delay: Option<f64>,
    /// T of a prescribed-time run (metadata `prescribed_time`).
    pub prescribed_time: Option<f64>,
    /// Whether the controller predicted (metadata `predicts`).
    pub predicts: Option<bool>,
    /// The planar position the vehicle declared (None: not declared; Some(None): none).
    pub declared_planar: Option<Option<[usize; 2]>>,
    /// The scenario's goal (metadata `goal_position`, `goal_radius` or `goal_polygons`,
    /// `goal_after`, `goal_by`).
    pub goal: Option<Goal>,
    /// The nominal's straight reference path: a point and the heading ψ (metadata
    /// `reference_path`).
    pub reference_path: Option<([f64; 2], f64)>,
    /// The state index of the vehicle's heading (metadata `heading_index`).
    pub heading_index: Option<usize>,
    /// The vehicle's extent about its planar position, [front, rear, half width] (m; metadata
    /// `vehicle_extent`), and each road user's [length, width] (m; `actor_extents`).
    pub vehicle_extent: Option<[f64; 3]>,
    pub actor_extents: BTreeMap<String, [f64; 2]>,
    /// The requirements to evaluate, (name, formula): the run's (metadata
    /// `requirement.<name>`), then those an analysis adds (`analyze --require`).
    pub requirements: Vec<(String, String)>,
    /// The largest |u| per channel the vehicle takes, as the scenario declared them (metadata
    /// `vehicle_limits`; empty: none declared).
    pub vehicle_limits: BTreeMap<String, f64>,
}

/// A goal as the run metadata records it: a region — the disc of centre `position` and
/// `radius` (m), or the union of `polygons` — to be entered after `after` and by `by` (s), if
/// given; or no region (metadata `goal_region` = "none"): the window, speed and heading alone.
#[derive(Debug, Clone, PartialEq)]
pub struct Goal {
    pub disc: Option<([f64; 2], f64)>,
    pub polygons: Vec<Vec<[f64; 2]>>,
    pub after: Option<f64>,
    /// The point that must enter lies this far ahead of the planar position along the heading
    /// (metadata `goal_offset`, with `heading_index`: its state index).
    pub offset: Option<(f64, Option<usize>)>,
    /// Intervals the speed (the state named `speed`) and the heading (modulo 2π, the state at
    /// `heading_index`) must lie in when the goal is reached (metadata `goal_speed`,
    /// `goal_heading`); with the heading's state index.
    pub speed: Option<[f64; 2]>,
    pub heading: Option<([f64; 2], Option<usize>)>,
    pub by: Option<f64>,
    /// The goal states, any one of which, whole, reaches it (metadata `goal_states`; each with
    /// the goal's offset and heading index); empty: the goal is one state.
    pub states: Vec<Goal>,
}

impl Goal {
    /// One goal state of a `[goal]`'s `states`, with the goal's point (`offset`, `heading`).
    fn of_state(
        spec: &crate::scenario::GoalSpec,
        offset: Option<(f64, Option<usize>)>,
        heading: Option<usize>,
    ) -> Goal {
        Goal {
            disc: spec.position.zip(spec.radius),
            polygons: spec.polygons.clone(),
            after: spec.after,
            offset,
            speed: spec.speed,
            heading: spec.heading.map(|i| (i, heading)),
            by: spec.by,
            states: Vec::new(),
        }
    }

    /// Whether the goal has a region (a disc or polygons); without one it is its time window,
    /// speed and heading alone (a CommonRoad goal without a position).
    pub fn has_region(&self) -> bool {
        self.disc.is_some() || !self.polygons.is_empty()
    }

    /// The distance (m) from `p` to the region: 0 inside it (+inf without a region).
    pub fn distance(&self, p: [f64; 2]) -> f64 {
        let disc = self.disc.map(|(c, r)| ((p[0] - c[0]).hypot(p[1] - c[1]) - r).max(0.0));
        let polygons = self.polygons.iter().map(|polygon| polygon_distance(polygon, p));
        disc.into_iter().chain(polygons).fold(f64::INFINITY, f64::min)
    }

    /// Whether `theta` lies in the heading interval [lo, hi] modulo 2π.
    pub fn heading_within([lo, hi]: [f64; 2], theta: f64) -> bool {
        let tau = std::f64::consts::TAU;
        hi - lo >= tau || (theta - lo).rem_euclid(tau) <= hi - lo + 1e-12
    }

    /// The region in words, for a reason: the disc's centre and radius, or the polygons.
    pub fn describe(&self) -> String {
        let mut text = match self.disc {
            Some(([x, y], r)) => format!("within {r} m of ({x}, {y})"),
            None if self.polygons.is_empty() => "no region".to_string(),
            None => format!("inside its {} polygon(s)", self.polygons.len()),
        };
        if let Some([lo, hi]) = self.speed {
            text.push_str(&format!(", speed in [{lo}, {hi}] m/s"));
        }
        if let Some(([lo, hi], _)) = self.heading {
            text.push_str(&format!(", heading in [{lo}, {hi}] rad"));
        }
        if !self.states.is_empty() {
            text.push_str(&format!("; one of its {} goal states whole", self.states.len()));
        }
        text
    }
}

/// The distance from `p` to a polygon (0 inside: even-odd rule), m.
fn polygon_distance(polygon: &[[f64; 2]], p: [f64; 2]) -> f64 {
    match crate::planar::polygon_contains(polygon, p) {
        true => 0.0,
        false => crate::planar::polygon_boundary_distance(polygon, p),
    }
}

/// Whitespace-separated numbers, exactly `N` of them.
fn numbers<const N: usize>(text: &str) -> Option<[f64; N]> {
    let values: Vec<f64> = text.split_whitespace().map(|v| v.parse().ok()).collect::<Option<_>>()?;
    values.try_into().ok()
}

impl RunFacts {
    /// The facts of the run metadata record.
    pub fn from_metadata(metadata: &BTreeMap<String, String>) -> RunFacts {
        let number = |key: &str| metadata.get(key).and_then(|s| s.parse().ok());
        RunFacts {
            timestep: number("timestep"),
            control_period: number("control_period"),
            max_delay: number("max_delay"),
            prescribed_time: number("prescribed_time"),
            predicts: metadata.get("predicts").and_then(|s| s.parse().ok()),
            declared_planar: read::declared_planar_position(metadata),
            goal: {
                let disc = metadata
                    .get("goal_position")
                    .and_then(|p| numbers::<2>(p))
                    .zip(number("goal_radius"));
                let polygons: Vec<Vec<[f64; 2]>> = metadata
                    .get("goal_polygons")
                    .and_then(|p| serde_json::from_str(p).ok())
                    .unwrap_or_default();
                let heading = metadata.get("heading_index").and_then(|h| h.trim().parse().ok());
                let regionless = metadata.get("goal_region").is_some_and(|r| r == "none");
                let offset = number("goal_offset").map(|offset| (offset, heading));
                let states: Vec<crate::scenario::GoalSpec> = metadata
                    .get("goal_states")
                    .and_then(|p| serde_json::from_str(p).ok())
                    .unwrap_or_default();
                (disc.is_some() || !polygons.is_empty() || regionless).then(|| Goal {
                    disc,
                    polygons,
                    after: number("goal_after"),
                    offset,
                    speed: metadata.get("goal_speed").and_then(|p| numbers::<2>(p)),
                    heading: metadata
                        .get("goal_heading")
                        .and_then(|p| numbers::<2>(p))
                        .map(|i| (i, heading)),
                    by: number("goal_by"),
                    states: states.iter().map(|s| Goal::of_state(s, offset, heading)).collect(),
                })
            },
            reference_path: metadata
                .get("reference_path")
                .and_then(|p| numbers::<3>(p))
                .map(|[x, y, heading]| ([x, y], heading)),
            heading_index: metadata.get("heading_index").and_then(|h| h.trim().parse().ok()),
            vehicle_extent: metadata.get("vehicle_extent").and_then(|p| numbers::<3>(p)),
            actor_extents: metadata
                .get("actor_extents")
                .and_then(|p| serde_json::from_str(p).ok())
                .unwrap_or_default(),
            requirements: requirements::from_metadata(metadata),
            vehicle_limits: metadata
                .get("vehicle_limits")
                .and_then(|p| serde_json::from_str::<BTreeMap<String, f64>>(p).ok())
                .map(|limits| limits.into_iter().filter(|(_, l)| l.is_finite() && *l > 0.0).collect())
                .unwrap_or_default(),
        }
    }

    /// What the `stall_time` definition reads of them.
    pub fn stall_facts(&self) -> crate::stall::StallFacts {
        crate::stall::StallFacts {
            control_period: self.control_period,
            declared_planar: self.declared_planar,
        }
    }

    /// Whether the metadata key a metric needs is there.
    fn has(&self, key: &str) -> bool {
        match key {
            "timestep" => self.timestep.is_some(),
            "control_period" => self.control_period.is_some(),
            "max_delay" => self.max_delay.is_some(),
            "prescribed_time" => self.prescribed_time.is_some(),
            _ => false,
        }
    }

    /// Whether `time` is the prescribed time T (within half a timestep).
    pub fn is_prescribed_time(&self, time: f64) -> bool {
        match (self.prescribed_time, self.timestep) {
            (Some(t), Some(h)) => (time - t).abs() < 0.5 * h,
            _ => false,
        }
    }
}

/// How a metric accumulates over the records of a run.
pub trait Accumulate: Send {
    /// One record of a topic the metric reads ([`Metric::reads`]).
    fn observe(&mut self, record: Observed<'_>, run: &RunFacts);
    /// The value once every record is read. `missing` holds why parts of this and other
    /// metrics are absent (the log lacks a topic or a key they need); a part named there must
    /// be absent, and the metric may add reasons of its own (`<name>.<part>`).
    fn value(&mut self, run: &RunFacts, missing: &mut BTreeMap<String, String>) -> Value;
}

/// A part of a composite metric (e.g. `collision.depth`): its JSON key and flat column.
#[derive(Debug, Clone, Copy)]
pub struct Part {
    /// The key inside the metric's JSON object.
    pub key: &'static str,
    /// Its flat column (`<column>.<channel>` for a per-channel metric, `<column>.<i>` for a
    /// list).
    pub column: &'static str,
    pub unit: &'static str,
    pub meaning: &'static str,
    /// What its cells hold.
    pub cell: CellKind,
    /// Topics and run metadata keys this part needs beyond the metric's own.
    pub reads: &'static [Topic],
    pub metadata: &'static [&'static str],
}

/// What the cells of a metric column hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellKind {
    Num,
    Int,
    Text,
}

/// The shape of a metric's value, which fixes its JSON, columns and cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// A number: one column, the metric's name.
    Number,
    /// A count: one column.
    Count,
    /// A number per input channel: `<name>.<channel>` columns.
    PerChannel,
    /// A number per barrier (obstacle or constraint, by name): `<name>.<barrier>` columns.
    PerBarrier,
    /// The first collision: time, obstacle, depth.
    Collision,
    /// Prediction statistics per channel.
    Prediction,
    /// The values at the prescribed time.
    AtPrescribedTime,
}

/// One metric, declared once.
pub struct Metric {
    /// JSON key (and flat column of a number or count).
    pub name: &'static str,
    /// Unit of the value (of every part without one of its own).
    pub unit: &'static str,
    /// What it is, in one line (docs/metrics.md has the rest).
    pub meaning: &'static str,
    pub shape: Shape,
    /// Parts of a composite metric, in JSON order.
    pub parts: &'static [Part],
    /// Log topics it reads (a log without one of them cannot give the metric).
    pub reads: &'static [Topic],
    /// Run metadata keys it needs.
    pub metadata: &'static [&'static str],
    /// Whether the run has the metric at all (a prescribed-time metric in another run does
    /// not lack anything).
    pub applies: fn(&RunFacts) -> bool,
    /// A fresh accumulator.
    pub accumulator: fn() -> Box<dyn Accumulate>,
    /// Shown in the aligned table of `mjsafe analyze` under this header.
    pub table: Option<&'static str>,
}

/// Always applies.
pub fn always(_: &RunFacts) -> bool {
    true
}

impl Metric {
    /// The declared metric named `name`.
    pub fn named(name: &str) -> Option<&'static Metric> {
        builtin::METRICS.iter().find(|m| m.name == name)
    }

    /// The metric and part a flat column belongs to (`max_correction.steering` →
    /// `max_correction`; `collision_time` → `collision`, part `time`).
    pub fn of_column(column: &str) -> Option<(&'static Metric, Option<&'static Part>)> {
        let base = column.split_once('.').map_or(column, |(base, _)| base);
        builtin::METRICS.iter().find_map(|m| {
            if m.parts.is_empty() {
                (m.name == base).then_some((m, None))
            } else {
                m.parts.iter().find(|p| p.column == base).map(|p| (m, Some(p)))
            }
        })
    }

    /// The unit of a flat column (`None`: not a metric's column).
    pub fn unit_of_column(column: &str) -> Option<&'static str> {
        Metric::of_column(column).map(|(m, part)| part.map_or(m.unit, |p| p.unit))
    }
}

/// The metrics of one run while its records are read: one accumulator per declared metric,
/// each record handed only to those that read its topic.
pub struct Accumulators {
    accumulators: Vec<Box<dyn Accumulate>>,
    /// Per topic (`Topic as usize`), the accumulators that read it.
    readers: Vec<Vec<usize>>,
    facts: RunFacts,
}

impl Default for Accumulators {
    fn default() -> Self {
        let mut readers = vec![Vec::new(); Topic::ALL.len()];
        for (i, metric) in builtin::METRICS.iter().enumerate() {
            for topic in metric.reads.iter().chain(metric.parts.iter().flat_map(|p| p.reads)) {
                if !readers[*topic as usize].contains(&i) {
                    readers[*topic as usize].push(i);
                }
            }
        }
        Accumulators {
            accumulators: builtin::METRICS.iter().map(|m| (m.accumulator)()).collect(),
            readers,
            facts: RunFacts::default(),
        }
    }
}

impl Accumulators {
    /// Whether some metric reads `topic` (the others' messages need not be decoded).
    pub fn reads(&self, topic: Topic) -> bool {
        !self.readers[topic as usize].is_empty()
    }

    /// The facts of the run metadata, for the records that follow. With requirements, the
    /// `req` metric reads every signal topic.
    pub fn set_facts(&mut self, mut facts: RunFacts) {
        // Requirements added to the analysis (`analyze --require`) after the run's own.
        for (name, formula) in std::mem::take(&mut self.facts.requirements) {
            facts.requirements.retain(|(n, _)| *n != name);
            facts.requirements.push((name, formula));
        }
        let signal_readers = [builtin::REQUIREMENTS, builtin::REQUIREMENT_VIOLATED_AT];
        for (req, _) in (builtin::METRICS.iter().enumerate())
            .filter(|(_, m)| signal_readers.contains(&m.name) && !facts.requirements.is_empty())
        {
            for topic in crate::signals::SIGNAL_TOPICS {
                let readers = &mut self.readers[topic as usize];
                if !readers.contains(&req) {
                    readers.push(req);
                }
            }
        }
        self.facts = facts;
    }

    /// Adds requirements to evaluate besides the run's own (`analyze --require`): call it
    /// before the run metadata is read.
    pub fn add_requirements(&mut self, requirements: &[(String, String)]) {
        self.facts.requirements.extend(requirements.iter().cloned());
    }

    /// Hands `record` to the metrics that read its topic.
    pub fn observe(&mut self, record: Observed<'_>) {
        for &i in &self.readers[record.topic() as usize] {
            self.accumulators[i].observe(record, &self.facts);
        }
    }

    /// Every metric's value; a metric (or part) whose topic (`missing_topics`) or metadata
    /// key the log lacks is absent, with its reason in `missing`.
    pub fn finish(mut self, missing_topics: &[Topic], missing: &mut BTreeMap<String, String>) -> Vec<Value> {
        for metric in builtin::METRICS {
            if !(metric.applies)(&self.facts) {
                continue;
            }
            let lacks = |reads: &[Topic], keys: &[&str]| -> Vec<String> {
                let topics = reads
                    .iter()
                    .filter(|t| missing_topics.contains(t))
                    .map(|t| format!("no {t} topic in the log"));
                let keys = keys
                    .iter()
                    .filter(|k| !self.facts.has(k))
                    .map(|k| format!("no `{k}` in the run metadata"));
                topics.chain(keys).collect()
            };
            let reasons = lacks(metric.reads, metric.metadata);
            if !reasons.is_empty() {
                missing.insert(metric.name.to_string(), reasons.join("; "));
                continue;
            }
            for part in metric.parts {
                let reasons = lacks(part.reads, part.metadata);
                if !reasons.is_empty() {
                    missing.insert(format!("{}.{}", metric.name, part.key), reasons.join("; "));
                }
            }
        }
        let facts = &self.facts;
        builtin::METRICS
            .iter()
            .zip(&mut self.accumulators)
            .map(|(metric, accumulator)| {
                if missing.contains_key(metric.name) {
                    Value::absent(metric.shape)
                } else {
                    accumulator.value(facts, missing)
                }
            })
            .collect()
    }
}

/// Per-run metrics (docs/metrics.md; the topics they come from: docs/log-format.md): what the
/// run was, then the value of every declared metric.
#[derive(Debug, Clone, PartialEq)]
pub struct RunMetrics {
    pub file: String,
    pub scenario: String,
    /// The safety filter by its label (equation number, e.g. `γm filter (4.67), m = 50`), from
    /// the run metadata; absent in logs without it.
    pub filter_label: Option<String>,
    /// The value of each metric of [`builtin::METRICS`], in that order.
    pub values: Vec<Value>,
    /// Whether the run finished (false: stopped by an error or interrupted, or the log has no
    /// `mjsafe_status` record).
    pub complete: bool,
    pub error: Option<String>,
    /// The metrics the log cannot give, each with the reason (a log topic or a run metadata
    /// key it lacks, e.g. in a topic-filtered copy; a contact the log never closes): their
    /// values are absent (`null`), never computed from a default. Empty (and left out of the
    /// JSON) for a whole log of this version.
    pub missing: BTreeMap<String, String>,
    /// MuJoCo warnings after which the simulated physics was not the model's (`mujoco_warning`
    /// events): the metrics describe that other physics. Left out of the JSON when none.
    pub warnings: Vec<String>,
}

impl RunMetrics {
    /// The value of the metric `name`.
    pub fn value(&self, name: &str) -> Option<&Value> {
        builtin::METRICS
            .iter()
            .position(|m| m.name == name)
            .and_then(|i| self.values.get(i))
    }

    /// The number `name` (a number or count metric), if the run has it.
    pub fn number(&self, name: &str) -> Option<f64> {
        match self.value(name)? {
            Value::Number(v) => *v,
            Value::Count(v) => v.map(|v| v as f64),
            _ => None,
        }
    }

    /// The warning a run whose inputs went past the vehicle's declared limits gets
    /// (`vehicle_limit_ratio` above 1 on some channel), naming each such channel and its ratio;
    /// None when they stayed within them or none were declared.
    pub fn past_vehicle_limits(&self) -> Option<String> {
        let Some(Value::PerChannel(Some(ratios))) = self.value("vehicle_limit_ratio") else {
            return None;
        };
        let past: Vec<String> = ratios
            .iter()
            .filter(|(_, ratio)| **ratio > 1.0)
            .map(|(channel, ratio)| format!("{channel} {ratio:.2}×"))
            .collect();
        (!past.is_empty()).then(|| {
            format!(
                "the inputs that reached the vehicle went past its declared [vehicle_limits] ({}: the largest |u| over the limit); a real vehicle could not have followed them (vehicle_limit_ratio)",
                past.join(", ")
            )
        })
    }

    /// Time of the last `/state` record, s.
    pub fn simulated_time(&self) -> f64 {
        self.number("simulated_time").unwrap_or(0.0)
    }

    /// Physics steps taken.
    pub fn steps(&self) -> u64 {
        match self.value("steps") {
            Some(Value::Count(Some(n))) => *n,
            _ => 0,
        }
    }

    /// The first collision, if the run had one.
    pub fn collision(&self) -> Option<&Collision> {
        match self.value("collision")? {
            Value::Collision(c) => c.as_ref(),
            _ => None,
        }
    }

    /// min h over all barriers and steps.
    pub fn min_h(&self) -> Option<f64> {
        self.number("min_h")
    }

    /// min h per barrier, each in its own unit.
    pub fn min_h_by_barrier(&self) -> Option<&BTreeMap<String, f64>> {
        match self.value("min_h_by_barrier")? {
            Value::PerChannel(v) => v.as_ref(),
            _ => None,
        }
    }

    /// Smallest clearance to any obstacle, m.
    pub fn min_clearance(&self) -> Option<f64> {
        self.number("min_clearance")
    }

    /// Prediction consistency per channel.
    pub fn prediction(&self) -> Option<&BTreeMap<String, PredictionStats>> {
        match self.value("prediction")? {
            Value::Prediction(p) => p.as_ref(),
            _ => None,
        }
    }

    /// The values at the prescribed time.
    pub fn at_prescribed_time(&self) -> Option<&PrescribedTimeMetrics> {
        match self.value("at_prescribed_time")? {
            Value::AtPrescribedTime(p) => p.as_ref(),
            _ => None,
        }
    }

    /// Unit of every metric (and part) by its JSON path.
    pub fn units() -> BTreeMap<String, &'static str> {
        let mut units = BTreeMap::new();
        for m in builtin::METRICS {
            if m.parts.is_empty() {
                units.insert(m.name.to_string(), m.unit);
            }
            for p in m.parts {
                units.insert(format!("{}.{}", m.name, p.key), p.unit);
            }
        }
        units
    }
}

/// `analyze --json`: what the run was, every metric under its name (declaration order), the
/// units by JSON path, then `complete`, `error`, `missing` and `warnings` (the last two only
/// when not empty).
impl Serialize for RunMetrics {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(None)?;
        map.serialize_entry("file", &self.file)?;
        map.serialize_entry("scenario", &self.scenario)?;
        map.serialize_entry("filter_label", &self.filter_label)?;
        for (metric, value) in builtin::METRICS.iter().zip(&self.values) {
            map.serialize_entry(metric.name, &value.json())?;
        }
        map.serialize_entry("complete", &self.complete)?;
        map.serialize_entry("error", &self.error)?;
        if !self.missing.is_empty() {
            map.serialize_entry("missing", &self.missing)?;
        }
        if !self.warnings.is_empty() {
            map.serialize_entry("warnings", &self.warnings)?;
        }
        map.serialize_entry("units", &RunMetrics::units())?;
        map.end()
    }
}

/// The reference table of docs/metrics.md, generated from the declarations: one row per
/// metric (or part) with its JSON path, flat column, unit and meaning.
pub fn reference_table() -> String {
    let mut text = String::from("| JSON (`analyze --json`) | flat column | unit | meaning |\n|---|---|---|---|\n");
    let code = |s: String| {
        if s.is_empty() {
            "—".to_string()
        } else {
            format!("`{s}`")
        }
    };
    for m in builtin::METRICS {
        let keyed = |column: &str, key: &str| match m.shape {
            _ if column.is_empty() => String::new(),
            Shape::PerChannel | Shape::Prediction => format!("{column}.<channel>"),
            Shape::PerBarrier if m.name.starts_with(builtin::REQUIREMENTS) => format!("{column}.<name>"),
            Shape::PerBarrier => format!("{column}.<barrier>"),
            Shape::AtPrescribedTime if key == "state_residuals" => format!("{column}.<i>"),
            _ => column.to_string(),
        };
        let rows: Vec<(String, String, &str, &str)> = if m.parts.is_empty() {
            vec![(keyed(m.name, m.name), keyed(m.name, m.name), m.unit, m.meaning)]
        } else {
            m.parts
                .iter()
                .map(|p| {
                    let json = match m.shape {
                        Shape::Prediction => format!("{}.<channel>.{}", m.name, p.key),
                        _ => format!("{}.{}", m.name, p.key),
                    };
                    (json, keyed(p.column, p.key), p.unit, p.meaning)
                })
                .collect()
        };
        for (json, column, unit, meaning) in rows {
            let unit = if unit.is_empty() { "—" } else { unit };
            text += &format!(
                "| {} | {} | {unit} | {} |\n",
                code(json),
                code(column),
                meaning.replace('|', "\\|")
            );
        }
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The distance to a goal region, by hand: 0 inside a polygon (a square and an L shape,
    /// concave), the distance to the nearest edge or corner outside; a disc's max(0, d − r); the
    /// union's smallest.
    #[test]
    fn distance_to_a_goal_region() {
        let square = vec![[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]];
        let ell = vec![
            [10.0, 0.0],
            [14.0, 0.0],
            [14.0, 1.0],
            [11.0, 1.0],
            [11.0, 4.0],
            [10.0, 4.0],
        ];
        let goal = Goal {
            disc: None,
            polygons: vec![square, ell],
            after: None,
            offset: None,
            speed: None,
            heading: None,
            by: None,
            states: Vec::new(),
        };
        assert_eq!(goal.distance([1.0, 1.0]), 0.0);
        assert!((goal.distance([3.0, 1.0]) - 1.0).abs() < 1e-12);
        assert!((goal.distance([3.0, 3.0]) - 2f64.sqrt()).abs() < 1e-12);
        assert_eq!(goal.distance([10.5, 3.0]), 0.0);
        // The L's notch is outside it: 0.5 m from the inner edges.
        assert!((goal.distance([12.0, 2.0]) - 1.0).abs() < 1e-12);
        assert!((goal.distance([11.5, 1.5]) - 0.5).abs() < 1e-12);
        let disc = Goal {
            disc: Some(([0.0, 0.0], 1.0)),
            polygons: Vec::new(),
            after: None,
            offset: None,
            speed: None,
            heading: None,
            by: None,
            states: Vec::new(),
        };
        assert!((disc.distance([3.0, 4.0]) - 4.0).abs() < 1e-12);
        // Headings modulo 2π: [−0.8, −0.6] holds −0.7 and −0.7 + 2π, not 0.
        assert_eq!(disc.distance([0.5, 0.0]), 0.0);
        let tau = std::f64::consts::TAU;
        assert!(Goal::heading_within([-0.8, -0.6], -0.7) && Goal::heading_within([-0.8, -0.6], -0.7 + tau));
        assert!(!Goal::heading_within([-0.8, -0.6], 0.0) && !Goal::heading_within([-0.8, -0.6], -0.5));
        assert!(Goal::heading_within([3.0, 3.3], -3.1));
    }
}
