//! Metrics of a run, computed from its MCAP log alone.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use serde::Deserialize;
use serde::Serialize;

use crate::log::read::{self, Decoder, Message, ReadError, RunRead, RunVisitor};
use crate::log::{proto, Topic};

/// Why a log could not be analysed: the reader's error ([`ReadError`]), or damage with the
/// metrics of what was read before it.
#[derive(Debug, thiserror::Error)]
pub enum AnalyzeError {
    /// Every error of the reader except damage ([`ReadError::Corrupt`], which is
    /// [`AnalyzeError::Corrupt`]).
    #[error(transparent)]
    Read(#[from] ReadError),
    /// A CRC mismatch, a truncation or a framing error after some records were read
    /// (`damage`: a [`ReadError::Corrupt`]).
    #[error("{damage}")]
    Corrupt {
        damage: ReadError,
        /// The metrics of what was read from the chunks that passed their CRC before the damage
        /// (an mjsafe log only); not valid metrics of the run.
        partial: Option<Box<RunMetrics>>,
    },
}

impl From<crate::files::FileError> for AnalyzeError {
    fn from(e: crate::files::FileError) -> Self {
        AnalyzeError::Read(e.into())
    }
}

/// First collision of a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Collision {
    /// Time of the first contact.
    pub time: f64,
    /// The obstacle first touched.
    pub with: String,
    /// Deepest penetration over all contacts of the run (MuJoCo contact distance), metres; NaN
    /// (null in JSON, reason under `missing`) when a contact is still going on where the log
    /// ends without closing it.
    pub depth: f64,
}

/// Prediction consistency of one channel: |p_i(t) − x(φ_i⁻¹(t))| over the run.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct PredictionStats {
    pub count: u64,
    pub max_error: f64,
    pub rms_error: f64,
    pub max_relative_error: f64,
    /// Predictions that continued the previous tick's trajectory (control.chain_tolerance).
    pub reused_chain: u64,
    /// Largest |p_1 − previous chain| seen at a tick (0 when never measured).
    pub max_chain_mismatch: f64,
    #[serde(skip)]
    sum_squares: f64,
}

/// Values at the prescribed time T (Ch. 5): barrier value(s) and the "soft landing" residuals.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct PrescribedTimeMetrics {
    pub time: f64,
    /// min over barriers of h(x(T)).
    pub barrier: Option<f64>,
    /// |x_i(T)| per state component.
    pub state_residuals: Vec<f64>,
    /// |u(T)| (the command issued at T, max over channels).
    pub input_residual: Option<f64>,
}

/// Per-run metrics (see docs/log-format.md for the topics they come from).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunMetrics {
    pub file: String,
    pub scenario: String,
    /// The safety filter by its equation number (e.g. `γm filter (4.67), m = 50`), from the
    /// resolved scenario in the run metadata ([`filter_label`]); absent in logs without it.
    pub filter_label: Option<String>,
    /// Time of the last /state record.
    pub simulated_time: f64,
    /// Physics steps taken (step index of the last /state record).
    pub steps: u64,
    pub collision: Option<Collision>,
    /// Minimum of h over all barriers and steps (None without barriers).
    pub min_h: Option<f64>,
    /// Time spent with some barrier h < 0, seconds.
    pub time_h_negative: Option<f64>,
    /// Fraction of control ticks at which the filter changed the nominal input.
    pub filter_active_fraction: Option<f64>,
    pub filter_infeasible_ticks: Option<u64>,
    /// max |u − u_nom| per channel over the run.
    pub max_correction: Option<BTreeMap<String, f64>>,
    /// Prediction consistency (Definition 4.3) per channel, from /prediction.
    pub prediction: Option<BTreeMap<String, PredictionStats>>,
    /// Intervention and comfort: first control tick at which the filter changed the nominal,
    /// total time it did so, max |du/dt| of the issued input (over channels) overall and
    /// across ticks where the filter was overriding.
    pub first_override_time: Option<f64>,
    pub override_duration: Option<f64>,
    pub max_jerk: Option<f64>,
    pub max_jerk_overriding: Option<f64>,
    /// Safety: smallest clearance to any obstacle (metres; negative = overlap), smallest
    /// constant-velocity time to collision with a known obstacle, and time with h < 0 of an
    /// obstacle while the delays since it appeared were not yet compensated (within the
    /// longest delay after its appearance).
    pub min_clearance: Option<f64>,
    pub min_time_to_collision: Option<f64>,
    pub delay_attributed_violation_time: Option<f64>,
    /// Intervention: ∫‖u − u_nom‖ dt over the control ticks.
    pub intervention_integral: Option<f64>,
    /// Comfort: max |jerk| of the planar motion along and across the velocity (third
    /// differences of the positions at the control ticks; planar vehicles only).
    pub max_longitudinal_jerk: Option<f64>,
    pub max_lateral_jerk: Option<f64>,
    /// Prescribed-time runs (metadata `prescribed_time` = T): values at T.
    pub at_prescribed_time: Option<PrescribedTimeMetrics>,
    /// Whether the run finished (false: stopped by an error or interrupted, or the log has no
    /// `mjsafe_status` record).
    pub complete: bool,
    pub error: Option<String>,
    /// The metrics the log cannot give, each with the reason (a log topic or a run metadata
    /// key it lacks, e.g. in a topic-filtered copy; a contact the log never closes): their
    /// values above are absent (`null`), never computed from a default. Empty (and left out
    /// of the JSON) for a whole log of this version.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub missing: BTreeMap<String, String>,
    /// MuJoCo warnings after which the simulated physics was not the model's (`mujoco_warning`
    /// events): the metrics above describe that other physics. Left out of the JSON when none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// Reads and analyses one log file (through the run reader, [`read::read_run_file`]).
/// Streams through the file: memory stays bounded by the largest chunk (and the read size),
/// whatever the log's length. The result does not depend on where the run metadata sits in
/// the data section (the MCAP spec allows it anywhere).
pub fn analyze_file(path: &Path) -> Result<RunMetrics, AnalyzeError> {
    let file = path.display().to_string();
    let mut analysis = Analysis::new(&file);
    let result = read::read_run_file(path, &mut analysis);
    analysis.conclude(result)
}

/// Analyses log bytes; `file` names them in errors.
pub fn analyze_bytes(bytes: &[u8], file: &str) -> Result<RunMetrics, AnalyzeError> {
    analyze_reader(bytes, file)
}

/// Analyses an MCAP stream; `file` names it in errors. On damage the error is
/// [`AnalyzeError::Corrupt`], whose `partial` metrics cover the chunks that passed their CRC.
/// A stream is read once: run metadata after the first message is an error (the metrics that
/// need it would be computed without it); [`analyze_file`] reads such a file twice instead.
pub fn analyze_reader(input: impl Read, file: &str) -> Result<RunMetrics, AnalyzeError> {
    let mut analysis = Analysis::new(file);
    let result = read::read_run_stream(input, file, &mut analysis);
    analysis.conclude(result)
}

/// The analysis of a running episode, as a sink: each record a metric reads is encoded as
/// the log encodes it and handed to the same analysis [`analyze_file`] runs on the log, with
/// the same run metadata first and the same status last, so the metrics are those of the run's
/// log (`tests/analysis_sink.rs` compares them on every scenario) without writing, compressing
/// or reading one. What a falsification candidate runs with (`sweep::execute_analysed`).
pub struct AnalysisSink {
    analysis: Option<Analysis>,
    /// What stands for the log's path in errors.
    name: String,
    /// The record being handed on, encoded (reused).
    encoded: Vec<u8>,
    /// Records observed (the read's message count; the log also counts each event's `/log`
    /// line, and no metric reads the count).
    records: u64,
    metrics: Option<Result<RunMetrics, AnalyzeError>>,
}

impl AnalysisSink {
    /// An analysis of the run described by `info`; `name` stands for the log in the metrics'
    /// `file` and in errors.
    pub fn new(info: &crate::log::RunInfo, name: &str) -> AnalysisSink {
        let mut analysis = Analysis::new(name);
        // Infallible: the run metadata is read, never checked against anything.
        let _ = analysis.metadata(read::RUN_METADATA, &info.metadata());
        AnalysisSink {
            analysis: Some(analysis),
            name: name.to_string(),
            encoded: Vec::new(),
            records: 0,
            metrics: None,
        }
    }

    /// The run's metrics once the episode has finished the sink (an incomplete run's have
    /// `complete` false, as its log's would), or why there are none.
    pub fn metrics(self) -> Result<RunMetrics, AnalyzeError> {
        self.metrics.unwrap_or_else(|| {
            Err(AnalyzeError::Read(ReadError::Foreign {
                file: self.name,
                message: "the run did not finish its analysis".into(),
            }))
        })
    }
}

impl crate::log::Sink for AnalysisSink {
    fn record(&mut self, record: &crate::log::Record) -> Result<(), crate::log::LogError> {
        let Some(analysis) = self.analysis.as_mut() else {
            return Ok(());
        };
        self.records += 1;
        let topic = record.kind();
        if !reads(topic) {
            return Ok(());
        }
        self.encoded.clear();
        record.encode_append(&mut self.encoded);
        let time = crate::log::mcap::sim_time_ns(record.time());
        let message = Message::new(topic, time, &self.encoded, &self.name);
        if let Err(e) = analysis.message(&message) {
            // Our own encoding that the analysis cannot decode: the metrics say so.
            let analysis = self.analysis.take().expect("checked above");
            self.metrics = Some(analysis.conclude(Err(e)));
        }
        Ok(())
    }

    fn finish(&mut self, complete: bool) -> Result<(), crate::log::LogError> {
        if let Some(mut analysis) = self.analysis.take() {
            let _ = analysis.metadata(read::STATUS_METADATA, &crate::log::status_metadata(complete));
            // The topics the run's log would have channels for.
            let topics = Topic::always_logged().collect();
            let read = RunRead {
                messages: self.records,
                topics,
            };
            self.metrics = Some(analysis.conclude(Ok(read)));
        }
        Ok(())
    }
}

#[derive(Default)]
struct Accumulator {
    scenario: String,
    filter_label: Option<String>,
    /// The planar position the vehicle declared in the run metadata (None: not declared).
    declared_planar: Option<Option<[usize; 2]>>,
    timestep: Option<f64>,
    last_time: f64,
    last_step: u64,
    states: u64,
    collision: Option<Collision>,
    min_h: Option<f64>,
    negative_steps: u64,
    ticks: u64,
    active_ticks: u64,
    infeasible_ticks: u64,
    max_correction: BTreeMap<String, f64>,
    prediction: BTreeMap<String, PredictionStats>,
    prescribed_time: Option<f64>,
    control_period: Option<f64>,
    first_override_time: Option<f64>,
    active_ticks_time: f64,
    /// Previous issued command (time, values, overriding) for du/dt.
    previous_command: Option<(f64, Vec<f64>)>,
    /// |du/dt| between the last two issued commands, waiting for the /filter record of the
    /// later tick (written right after it) to know whether the filter was overriding.
    pending_jerk: Option<(f64, f64)>,
    /// The last /filter record (time, active), and whether the one before it was active: a
    /// tick's jerk counts as overriding when either tick's filter was. A /filter written
    /// before its tick's /command/issued (a log rewritten with the ties of one log time in
    /// another order) settles the jerk when the command comes.
    last_filter: Option<(f64, bool)>,
    previous_overriding: bool,
    /// None until a pair of commands (one with the filter active) defines it.
    max_jerk: Option<f64>,
    max_jerk_overriding: Option<f64>,
    terminal: PrescribedTimeMetrics,
    max_delay: Option<f64>,
    /// Whether the run's controller predicted (metadata `predicts`; absent in older logs).
    predicts: Option<bool>,
    min_clearance: Option<f64>,
    min_time_to_collision: Option<f64>,
    /// Appearance time per obstacle name.
    appeared: BTreeMap<String, f64>,
    /// Obstacles with a `collision_start` and no `collision_end` yet.
    open_contacts: std::collections::BTreeSet<String>,
    delay_attributed_steps: u64,
    intervention_integral: f64,
    /// Last four planar positions (time, x, y) for the jerk, and the position indices.
    planar: Option<[usize; 2]>,
    recent_positions: std::collections::VecDeque<(f64, f64, f64)>,
    max_longitudinal_jerk: Option<f64>,
    max_lateral_jerk: Option<f64>,
    complete: Option<bool>,
    error: Option<String>,
    warnings: Vec<String>,
}

/// The state of one analysis: the metrics so far.
struct Analysis {
    file: String,
    acc: Accumulator,
    decoder: Decoder,
    saw_mjsafe_metadata: bool,
}

/// The run's safety filter named by its equation number in the reference, from the resolved
/// scenario of the run metadata (`filter.kind` and its parameters; "no delays" when the run's
/// largest actuator latency, metadata `max_delay`, is zero, or without it every `[delays]`
/// entry is): the label of plot legends and `analyze --brief`.
pub fn filter_label(metadata: &BTreeMap<String, String>) -> Option<String> {
    let text = metadata.get("scenario_resolved").or_else(|| metadata.get("scenario"))?;
    let scenario: toml::Table = text.parse().ok()?;
    let filter = scenario.get("filter").and_then(|f| f.as_table());
    let kind = filter
        .and_then(|f| f.get("kind"))
        .and_then(|k| k.as_str())
        .unwrap_or("none");
    let param = |key: &str| {
        filter
            .and_then(|f| f.get(key))
            .map(|v| v.to_string().trim_matches('"').to_string())
    };
    let label = match kind {
        "none" => "no filter (nominal only)".to_string(),
        "cbf_qp" if param("compensation").as_deref() == Some("predictor") => "predictor CBF-QP (4.34)".into(),
        "cbf_qp" => "delay-free CBF-QP (4.9)–(4.11)".into(),
        "gamma_m" => match param("m") {
            Some(m) => format!("γm filter (4.67), m = {m}"),
            None => "γm filter (4.67)".into(),
        },
        "fixed_channel" => "fixed-channel filter (4.44)".into(),
        "clf_cbf_qp" => "γm CLF-CBF QP (3.27)–(3.33)".into(),
        "ptsf" => "PTSf (Ch. 5)".into(),
        "esf" => "ESf (Ch. 5)".into(),
        other => other.to_string(),
    };
    // The run's largest actuator latency when the log has it (jitter and extra latency
    // included); else the scenario's `[delays]`, all zero.
    let no_delays = match metadata.get("max_delay").and_then(|d| d.parse::<f64>().ok()) {
        Some(max_delay) => max_delay == 0.0,
        None => scenario.get("delays").and_then(|d| d.as_table()).is_some_and(|d| {
            d.values()
                .all(|v| v.as_float().or(v.as_integer().map(|i| i as f64)) == Some(0.0))
        }),
    };
    Some(if no_delays && kind != "none" {
        format!("{label}, no delays")
    } else {
        label
    })
}

/// A compact comparison of runs, one row per run: filter, collision, min h, min clearance
/// (`analyze --brief`, the table scripts/run.sh prints).
pub fn brief_table(runs: &[RunMetrics]) -> String {
    let mut rows = vec![["filter", "collision", "min_h", "min_clearance_m", "file"]
        .map(String::from)
        .to_vec()];
    for r in runs {
        rows.push(vec![
            r.filter_label.clone().unwrap_or_else(|| r.scenario.clone()),
            match &r.collision {
                Some(c) => format!("YES at t={:.2} s", c.time),
                None if r.missing.contains_key("collision") => "-".into(),
                None => "no".into(),
            },
            r.min_h.map_or("-".into(), |h| format!("{h:.3}")),
            r.min_clearance.map_or("-".into(), |c| format!("{c:.3}")),
            r.file.clone(),
        ]);
    }
    align_columns(&rows)
}

/// Applies the run metadata (`mjsafe` record) to the accumulator.
fn apply_run_metadata(acc: &mut Accumulator, metadata: &BTreeMap<String, String>) {
    acc.scenario = metadata.get("scenario_name").cloned().unwrap_or_default();
    acc.filter_label = filter_label(metadata);
    acc.timestep = metadata.get("timestep").and_then(|s| s.parse().ok());
    acc.control_period = metadata.get("control_period").and_then(|s| s.parse().ok());
    acc.prescribed_time = metadata.get("prescribed_time").and_then(|s| s.parse().ok());
    acc.max_delay = metadata.get("max_delay").and_then(|s| s.parse().ok());
    acc.predicts = metadata.get("predicts").and_then(|s| s.parse().ok());
}

impl RunVisitor for Analysis {
    fn metadata(&mut self, name: &str, entries: &BTreeMap<String, String>) -> Result<(), ReadError> {
        match name {
            read::RUN_METADATA => {
                self.saw_mjsafe_metadata = true;
                apply_run_metadata(&mut self.acc, entries);
                self.acc.declared_planar = read::declared_planar_position(entries);
            }
            read::STATUS_METADATA => {
                self.acc.complete = Some(entries.get("complete").is_some_and(|v| v == "true"));
            }
            _ => {}
        }
        Ok(())
    }

    fn message(&mut self, m: &Message<'_>) -> Result<(), ReadError> {
        if !reads(m.topic) {
            return Ok(());
        }
        let acc = &mut self.acc;
        match m.topic {
            Topic::State => acc.add_state(self.decoder.state(m)?),
            Topic::Barrier => acc.add_barrier(self.decoder.barrier(m)?),
            Topic::Filter => acc.add_filter(self.decoder.filter(m)?),
            Topic::Issued => acc.add_issued(self.decoder.issued(m)?),
            Topic::Prediction => acc.add_prediction(self.decoder.prediction(m)?),
            Topic::Event => acc.add_event(m.decode()?),
            _ => {}
        }
        Ok(())
    }
}

/// Whether some metric reads `topic` (the others' messages are not decoded).
fn reads(topic: Topic) -> bool {
    match topic {
        Topic::State | Topic::Barrier | Topic::Filter | Topic::Issued | Topic::Prediction | Topic::Event => true,
        Topic::Applied | Topic::Scene | Topic::Transform | Topic::Log | Topic::Measured | Topic::Actuated => false,
    }
}

impl Analysis {
    fn new(file: &str) -> Self {
        Analysis {
            file: file.to_string(),
            acc: Accumulator::default(),
            decoder: Decoder::default(),
            saw_mjsafe_metadata: false,
        }
    }

    /// The metrics, or the error, once the records have been read.
    fn conclude(self, result: Result<RunRead, ReadError>) -> Result<RunMetrics, AnalyzeError> {
        let Analysis {
            file,
            acc,
            saw_mjsafe_metadata,
            ..
        } = self;
        let read = match result {
            Ok(read) => read,
            Err(ReadError::Corrupt {
                file: f,
                messages,
                message,
            }) => {
                let partial = (saw_mjsafe_metadata && acc.states > 0).then(|| {
                    let mut m = acc.finish(&file, &[]);
                    m.complete = false;
                    m.error = Some(format!("truncated or corrupt after {messages} messages: {message}"));
                    Box::new(m)
                });
                let damage = ReadError::Corrupt {
                    file: f,
                    messages,
                    message,
                };
                return Err(AnalyzeError::Corrupt { damage, partial });
            }
            Err(e) => return Err(e.into()),
        };
        if acc.states == 0 {
            return Err(ReadError::Foreign {
                file,
                message: "no mjsafe metadata record or no /state messages".into(),
            }
            .into());
        }
        Ok(acc.finish(&file, &read.missing_topics()))
    }
}

impl Accumulator {
    fn add_state(&mut self, m: &proto::State) {
        if self.is_prescribed_time(m.time) {
            self.terminal.state_residuals = m.values.iter().map(|v| v.abs()).collect();
        }
        self.track_jerk(m);
        self.states += 1;
        self.last_time = self.last_time.max(m.time);
        self.last_step = self.last_step.max(m.step);
    }

    fn add_barrier(&mut self, m: &proto::Barrier) {
        let step_min = m.barriers.iter().map(|b| b.h).fold(f64::INFINITY, f64::min);
        if self.is_prescribed_time(m.time) && step_min.is_finite() {
            self.terminal.barrier = Some(step_min);
        }
        for b in m.barriers.iter().filter(|b| b.obstacle) {
            self.min_clearance = Some(self.min_clearance.map_or(b.clearance, |c| c.min(b.clearance)));
            if b.known && !b.time_to_collision.is_nan() {
                let ttc = b.time_to_collision;
                self.min_time_to_collision = Some(self.min_time_to_collision.map_or(ttc, |c| c.min(ttc)));
            }
        }
        let uncompensated_violation = m.barriers.iter().any(|b| {
            b.h < 0.0
                && self
                    .appeared
                    .get(&b.name)
                    .is_some_and(|t| m.time >= *t && m.time < t + self.max_delay.unwrap_or(0.0))
        });
        self.delay_attributed_steps += u64::from(uncompensated_violation);
        if step_min.is_finite() {
            self.min_h = Some(self.min_h.map_or(step_min, |h| h.min(step_min)));
            if step_min < 0.0 {
                self.negative_steps += 1;
            }
        }
    }

    fn add_filter(&mut self, m: &proto::Filter) {
        self.ticks += 1;
        self.active_ticks += u64::from(m.active);
        if m.active {
            self.first_override_time.get_or_insert(m.time);
            self.active_ticks_time += self.control_period.unwrap_or(0.0);
        }
        self.previous_overriding = self.last_filter.is_some_and(|(_, active)| active);
        self.last_filter = Some((m.time, m.active));
        if let Some((time, jerk)) = self.pending_jerk.take() {
            self.settle_jerk(time, jerk);
        }
        self.infeasible_ticks += u64::from(m.infeasible);
        let correction = m.correction.iter().map(|c| c * c).sum::<f64>().sqrt();
        self.intervention_integral += correction * self.control_period.unwrap_or(0.0);
        for (channel, c) in m.channels.iter().zip(&m.correction) {
            match self.max_correction.get_mut(channel) {
                Some(entry) => *entry = entry.max(c.abs()),
                None => {
                    self.max_correction.insert(channel.clone(), 0.0f64.max(c.abs()));
                }
            }
        }
    }

    /// The jerk of the tick at `time` counts as overriding when the filter of that tick (the
    /// last /filter, if it is that tick's) or of the tick before was active.
    fn settle_jerk(&mut self, time: f64, jerk: f64) {
        if let Some((filter_time, active)) = self.last_filter {
            if (filter_time - time).abs() < 1e-9 && (active || self.previous_overriding) {
                self.max_jerk_overriding = Some(self.max_jerk_overriding.map_or(jerk, |j| j.max(jerk)));
            }
        }
    }

    fn add_issued(&mut self, m: &proto::IssuedCommand) {
        if let Some((previous_time, previous)) = &self.previous_command {
            let dt = m.time - previous_time;
            if dt > 0.0 {
                let jerk = m
                    .filtered
                    .iter()
                    .zip(previous)
                    .map(|(u, p)| ((u - p) / dt).abs())
                    .fold(0.0, f64::max);
                self.max_jerk = Some(self.max_jerk.map_or(jerk, |j| j.max(jerk)));
                if self.last_filter.is_some_and(|(time, _)| (time - m.time).abs() < 1e-9) {
                    self.settle_jerk(m.time, jerk);
                } else {
                    self.pending_jerk = Some((m.time, jerk));
                }
            }
        }
        if self.is_prescribed_time(m.time) {
            self.terminal.input_residual = m.filtered.iter().map(|u| u.abs()).reduce(f64::max);
        }
        match &mut self.previous_command {
            Some((time, previous)) => {
                *time = m.time;
                previous.clear();
                previous.extend_from_slice(&m.filtered);
            }
            None => self.previous_command = Some((m.time, m.filtered.clone())),
        }
    }

    fn add_prediction(&mut self, m: &proto::Prediction) {
        let add = |stats: &mut PredictionStats| {
            stats.count += 1;
            stats.max_error = stats.max_error.max(m.error);
            stats.max_relative_error = stats.max_relative_error.max(m.relative_error);
            stats.sum_squares += m.error * m.error;
            stats.reused_chain += u64::from(m.reused_chain);
            if m.chain_mismatch.is_finite() {
                stats.max_chain_mismatch = stats.max_chain_mismatch.max(m.chain_mismatch);
            }
        };
        // The channel's key is allocated once, at its first prediction.
        match self.prediction.get_mut(&m.channel) {
            Some(stats) => add(stats),
            None => add(self.prediction.entry(m.channel.clone()).or_default()),
        }
    }

    fn add_event(&mut self, m: proto::Event) {
        match m.kind.as_str() {
            "obstacle_appeared" => {
                for name in &m.participants {
                    self.appeared.entry(name.clone()).or_insert(m.time);
                }
            }
            "collision_start" | "collision_end" => {
                let with = m
                    .participants
                    .iter()
                    .find(|p| *p != "vehicle")
                    .cloned()
                    .unwrap_or_default();
                if m.kind == "collision_start" {
                    self.open_contacts.insert(with.clone());
                } else {
                    self.open_contacts.remove(&with);
                }
                match self.collision.as_mut() {
                    Some(c) => c.depth = c.depth.max(m.depth),
                    None if m.kind == "collision_start" => {
                        self.collision = Some(Collision {
                            time: m.time,
                            with,
                            depth: m.depth,
                        })
                    }
                    None => {}
                }
            }
            "error" | "interrupted" if self.error.is_none() => self.error = Some(m.message),
            crate::log::MUJOCO_WARNING => self.warnings.push(m.message),
            _ => {}
        }
    }

    /// Longitudinal and lateral jerk from the last four planar positions (x1, x2 or x, y).
    fn track_jerk(&mut self, m: &proto::State) {
        if self.planar.is_none() {
            self.planar = read::planar_position_of(self.declared_planar, &m.names);
            if self.planar.is_none() {
                return;
            }
        }
        // Sample on the control-tick grid: the commanded acceleration is piecewise constant on
        // it, so the jerk is resolved at the control period (not at the physics step).
        if let Some(period) = self.control_period {
            let ticks = m.time / period;
            if (ticks - ticks.round()).abs() > 1e-6 {
                return;
            }
        }
        let [i, j] = self.planar.expect("set above");
        self.recent_positions.push_back((m.time, m.values[i], m.values[j]));
        if self.recent_positions.len() > 4 {
            self.recent_positions.pop_front();
        }
        if self.recent_positions.len() < 4 {
            return;
        }
        let q = &self.recent_positions;
        let p = [q[0], q[1], q[2], q[3]];
        let dt = (p[3].0 - p[0].0) / 3.0;
        if dt <= 0.0 {
            return;
        }
        // Third differences → jerk; the velocity direction (central difference) splits it.
        let third = |f: fn(&(f64, f64, f64)) -> f64| f(&p[3]) - 3.0 * f(&p[2]) + 3.0 * f(&p[1]) - f(&p[0]);
        let (jx, jy) = (third(|q| q.1) / dt.powi(3), third(|q| q.2) / dt.powi(3));
        let (vx, vy) = (p[2].1 - p[1].1, p[2].2 - p[1].2);
        let speed = vx.hypot(vy);
        if speed <= 1e-12 {
            return;
        }
        let (ux, uy) = (vx / speed, vy / speed);
        let longitudinal = (jx * ux + jy * uy).abs();
        let lateral = (-jx * uy + jy * ux).abs();
        self.max_longitudinal_jerk = Some(self.max_longitudinal_jerk.map_or(longitudinal, |v| v.max(longitudinal)));
        self.max_lateral_jerk = Some(self.max_lateral_jerk.map_or(lateral, |v| v.max(lateral)));
    }

    /// Whether `time` is the prescribed time T (within half a timestep).
    fn is_prescribed_time(&self, time: f64) -> bool {
        match (self.prescribed_time, self.timestep) {
            (Some(t), Some(h)) => (time - t).abs() < 0.5 * h,
            _ => false,
        }
    }

    /// Why each metric that the log cannot give is absent: a log topic it needs that the file
    /// has no channel for (`missing_topics`), or a run metadata key it needs.
    fn absent(&self, missing_topics: &[Topic]) -> BTreeMap<String, String> {
        use Topic::{Barrier, Event, Filter, Issued, Prediction};
        let metadata = [
            ("timestep", self.timestep.is_some()),
            ("control_period", self.control_period.is_some()),
            ("max_delay", self.max_delay.is_some()),
        ];
        let planar = self.planar.is_some();
        let prescribed = self.prescribed_time.is_some();
        // metric, whether it applies to this run, the topics and metadata keys it needs.
        let needs: [(&str, bool, &[Topic], &[&str]); 21] = [
            ("collision", true, &[Event], &[]),
            ("min_h", true, &[Barrier], &[]),
            ("time_h_negative", true, &[Barrier], &["timestep"]),
            ("filter_active_fraction", true, &[Filter], &[]),
            ("filter_infeasible_ticks", true, &[Filter], &[]),
            ("max_correction", true, &[Filter], &[]),
            // A run that made no predictions lacks nothing without its (empty) topic.
            ("prediction", self.predicts != Some(false), &[Prediction], &[]),
            ("first_override_time", true, &[Filter], &[]),
            ("override_duration", true, &[Filter], &["control_period"]),
            ("max_jerk", true, &[Issued], &[]),
            ("max_jerk_overriding", true, &[Issued, Filter], &[]),
            ("min_clearance", true, &[Barrier], &[]),
            ("min_time_to_collision", true, &[Barrier], &[]),
            (
                "delay_attributed_violation_time",
                true,
                &[Barrier, Event],
                &["timestep", "max_delay"],
            ),
            ("intervention_integral", true, &[Filter], &["control_period"]),
            ("max_longitudinal_jerk", planar, &[], &["control_period"]),
            ("max_lateral_jerk", planar, &[], &["control_period"]),
            ("at_prescribed_time.barrier", prescribed, &[Barrier], &["timestep"]),
            (
                "at_prescribed_time.input_residual",
                prescribed,
                &[Issued],
                &["timestep"],
            ),
            ("at_prescribed_time.state_residuals", prescribed, &[], &["timestep"]),
            ("error", true, &[Event], &[]),
        ];
        let mut absent = BTreeMap::new();
        for (metric, applies, topics, keys) in needs {
            let mut reasons: Vec<String> = topics
                .iter()
                .filter(|t| applies && missing_topics.contains(t))
                .map(|t| format!("no {t} topic in the log"))
                .collect();
            reasons.extend(
                keys.iter()
                    .filter(|k| applies && metadata.iter().any(|(name, present)| name == *k && !present))
                    .map(|k| format!("no `{k}` in the run metadata")),
            );
            if !reasons.is_empty() {
                absent.insert(metric.to_string(), reasons.join("; "));
            }
        }
        if self.complete.is_none() {
            absent.insert(
                "complete".into(),
                format!(
                    "no {} metadata record (false: not known to have finished)",
                    read::STATUS_METADATA
                ),
            );
        }
        absent
    }

    /// The metrics; those the log cannot give (see [`Accumulator::absent`]) are `None`.
    fn finish(mut self, file: &str, missing_topics: &[Topic]) -> RunMetrics {
        let mut missing = self.absent(missing_topics);
        // A contact the log never closes (a log cut short, or written before episodes closed
        // their contacts at the end): its deepest penetration is not in the log.
        if let (Some(c), Some(open)) = (self.collision.as_mut(), self.open_contacts.first()) {
            missing.insert(
                "collision.depth".into(),
                format!(
                    "the contact with {open} is still going on where the log ends: only its depth at first contact ({:.4} m) is in the log",
                    c.depth
                ),
            );
            c.depth = f64::NAN;
        }
        if let Some(t) = self.prescribed_time {
            // The values at T come from the messages logged at T: none when the run ended at
            // or before T (the barriers and commands of a step are logged at its start, so
            // the final state has none).
            let end = self.last_time;
            let half_step = 0.5 * self.timestep.unwrap_or(0.0);
            let reason = |topic: &str| {
                if end < t - half_step {
                    format!("no {topic} message at T = {t} s: the run ends before T, at t = {end} s")
                } else if end < t + half_step && topic != "/state" {
                    format!("no {topic} message at T = {t} s: the run ends at T, and {topic} is logged at the start of each step, not at the final state")
                } else {
                    format!("no {topic} message at T = {t} s")
                }
            };
            let absent_values = [
                (
                    "at_prescribed_time.barrier",
                    self.terminal.barrier.is_none(),
                    "/barrier",
                ),
                (
                    "at_prescribed_time.state_residuals",
                    self.terminal.state_residuals.is_empty(),
                    "/state",
                ),
                (
                    "at_prescribed_time.input_residual",
                    self.terminal.input_residual.is_none(),
                    "/command/issued",
                ),
            ];
            for (metric, absent, topic) in absent_values {
                if absent && !missing.contains_key(metric) {
                    missing.insert(metric.to_string(), reason(topic));
                }
            }
        }
        let given = |metric: &str| !missing.contains_key(metric);
        let known = |metric: &str, value| given(metric).then_some(value);
        let timestep = self.timestep.unwrap_or(0.0);
        let at_prescribed_time = self.prescribed_time.map(|time| PrescribedTimeMetrics {
            time,
            barrier: self.terminal.barrier.filter(|_| given("at_prescribed_time.barrier")),
            state_residuals: if given("at_prescribed_time.state_residuals") {
                self.terminal.state_residuals.clone()
            } else {
                Vec::new()
            },
            input_residual: self
                .terminal
                .input_residual
                .filter(|_| given("at_prescribed_time.input_residual")),
        });
        let prediction = self
            .prediction
            .into_iter()
            .map(|(channel, mut stats)| {
                stats.rms_error = (stats.sum_squares / stats.count.max(1) as f64).sqrt();
                (channel, stats)
            })
            .collect();
        RunMetrics {
            file: file.into(),
            scenario: self.scenario,
            filter_label: self.filter_label,
            simulated_time: self.last_time,
            steps: self.last_step,
            collision: self.collision.filter(|_| given("collision")),
            min_h: self.min_h.filter(|_| given("min_h")),
            // Only for a run with barriers (as min_h): 0 s would claim a safe set was kept.
            time_h_negative: self
                .min_h
                .and_then(|_| known("time_h_negative", self.negative_steps as f64 * timestep)),
            filter_active_fraction: known(
                "filter_active_fraction",
                if self.ticks > 0 {
                    self.active_ticks as f64 / self.ticks as f64
                } else {
                    0.0
                },
            ),
            filter_infeasible_ticks: given("filter_infeasible_ticks").then_some(self.infeasible_ticks),
            max_correction: given("max_correction").then_some(self.max_correction),
            first_override_time: self.first_override_time.filter(|_| given("first_override_time")),
            override_duration: known("override_duration", self.active_ticks_time),
            max_jerk: self.max_jerk.filter(|_| given("max_jerk")),
            max_jerk_overriding: self.max_jerk_overriding.filter(|_| given("max_jerk_overriding")),
            min_clearance: self.min_clearance.filter(|_| given("min_clearance")),
            min_time_to_collision: self.min_time_to_collision.filter(|_| given("min_time_to_collision")),
            // Only for a run with obstacles (whose appearance it measures from).
            delay_attributed_violation_time: self.min_clearance.and_then(|_| {
                known(
                    "delay_attributed_violation_time",
                    self.delay_attributed_steps as f64 * timestep,
                )
            }),
            intervention_integral: known("intervention_integral", self.intervention_integral),
            max_longitudinal_jerk: self.max_longitudinal_jerk.filter(|_| given("max_longitudinal_jerk")),
            max_lateral_jerk: self.max_lateral_jerk.filter(|_| given("max_lateral_jerk")),
            at_prescribed_time,
            prediction: given("prediction").then_some(prediction),
            complete: self.complete.unwrap_or(false) && self.error.is_none(),
            error: self.error.filter(|_| given("error")),
            missing,
            warnings: self.warnings,
        }
    }
}

/// Header and one row per run, as aligned text.
pub fn table(runs: &[RunMetrics]) -> String {
    let header = [
        "file",
        "scenario",
        "sim_time_s",
        "steps",
        "collision",
        "min_h",
        "t_h<0_s",
        "filter_active",
        "qp_infeasible",
        "max|u-u_nom|",
        "prediction_err_max/rms",
        "status",
    ];
    let mut rows: Vec<Vec<String>> = vec![header.iter().map(|s| s.to_string()).collect()];
    for r in runs {
        rows.push(vec![
            r.file.clone(),
            r.scenario.clone(),
            format!("{:.3}", r.simulated_time),
            r.steps.to_string(),
            match &r.collision {
                Some(c) => format!("t={:.3} {}", c.time, c.with),
                None if r.missing.contains_key("collision") => "-".into(),
                None => "none".into(),
            },
            r.min_h.map_or("-".into(), |h| format!("{h:.3}")),
            r.time_h_negative.map_or("-".into(), |t| format!("{t:.3}")),
            r.filter_active_fraction
                .map_or("-".into(), |f| format!("{:.1}%", 100.0 * f)),
            r.filter_infeasible_ticks.map_or("-".into(), |n| n.to_string()),
            match &r.max_correction {
                Some(m) => m
                    .iter()
                    .map(|(c, v)| format!("{c}={v:.3}"))
                    .collect::<Vec<_>>()
                    .join(" "),
                None => "-".into(),
            },
            match &r.prediction {
                Some(p) if !p.is_empty() => p
                    .iter()
                    .map(|(c, p)| format!("{c}={:.1e}/{:.1e}", p.max_error, p.rms_error))
                    .collect::<Vec<_>>()
                    .join(" "),
                _ => "-".to_string(),
            },
            match (&r.error, r.complete, r.warnings.len()) {
                (Some(e), _, _) => format!("error: {e}"),
                (None, true, 0) => "complete".into(),
                (None, true, n) => format!("complete, {n} MuJoCo warning(s)"),
                (None, false, _) => "incomplete".into(),
            },
        ]);
    }
    align_columns(&rows)
}

/// Rows of cells as text with every column left-aligned to its widest cell.
pub fn align_columns<Row: AsRef<[String]>>(rows: &[Row]) -> String {
    let columns = rows.iter().map(|r| r.as_ref().len()).max().unwrap_or(0);
    let widths: Vec<usize> = (0..columns)
        .map(|c| {
            rows.iter()
                .filter_map(|r| r.as_ref().get(c))
                .map(|cell| cell.chars().count())
                .max()
                .unwrap_or(0)
        })
        .collect();
    rows.iter()
        .map(|r| {
            r.as_ref()
                .iter()
                .enumerate()
                .map(|(c, cell)| format!("{cell:<width$}", width = widths[c]))
                .collect::<Vec<_>>()
                .join("  ")
                .trim_end()
                .to_string()
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// `Some(x)` for a finite x (JSON has no NaN or infinity: those are `null`, CSV leaves them empty).
fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// A run's metrics as one flat record (no nesting beyond per-channel maps): the rows of
/// `analyze --csv`, `analyze --compare` and the sweep summaries. Floats that are not finite
/// are `None`. Definitions: docs/metrics.md.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FlatMetrics {
    pub scenario: String,
    pub simulated_time: Option<f64>,
    pub steps: u64,
    pub collision_time: Option<f64>,
    pub collision_with: Option<String>,
    pub collision_depth: Option<f64>,
    pub min_h: Option<f64>,
    pub time_h_negative: Option<f64>,
    pub filter_active_fraction: Option<f64>,
    pub filter_infeasible_ticks: Option<u64>,
    pub max_correction: BTreeMap<String, Option<f64>>,
    pub prediction_count: BTreeMap<String, u64>,
    pub prediction_max_error: BTreeMap<String, Option<f64>>,
    pub prediction_rms_error: BTreeMap<String, Option<f64>>,
    pub prediction_max_relative_error: BTreeMap<String, Option<f64>>,
    pub first_override_time: Option<f64>,
    pub override_duration: Option<f64>,
    pub max_jerk: Option<f64>,
    pub max_jerk_overriding: Option<f64>,
    pub min_clearance: Option<f64>,
    pub min_time_to_collision: Option<f64>,
    pub delay_attributed_violation_time: Option<f64>,
    pub intervention_integral: Option<f64>,
    pub max_longitudinal_jerk: Option<f64>,
    pub max_lateral_jerk: Option<f64>,
    /// The prescribed time T (Ch. 5 runs only) and the values at T.
    pub prescribed_time: Option<f64>,
    pub prescribed_time_barrier: Option<f64>,
    pub prescribed_time_input_residual: Option<f64>,
    pub prescribed_time_state_residual: Vec<Option<f64>>,
    pub complete: bool,
    pub error: Option<String>,
}

/// One value of a [`FlatMetrics`] column.
#[derive(Debug, Clone, PartialEq)]
pub enum Cell {
    Num(Option<f64>),
    Int(Option<u64>),
    Text(Option<String>),
    Bool(Option<bool>),
}

/// The fixed scalar columns of [`FlatMetrics`] before the per-channel groups.
const SCALAR_COLUMNS: [&str; 23] = [
    "scenario",
    "simulated_time",
    "steps",
    "collision_time",
    "collision_with",
    "collision_depth",
    "min_h",
    "time_h_negative",
    "filter_active_fraction",
    "filter_infeasible_ticks",
    "first_override_time",
    "override_duration",
    "max_jerk",
    "max_jerk_overriding",
    "min_clearance",
    "min_time_to_collision",
    "delay_attributed_violation_time",
    "intervention_integral",
    "max_longitudinal_jerk",
    "max_lateral_jerk",
    "prescribed_time",
    "prescribed_time_barrier",
    "prescribed_time_input_residual",
];

/// Per-channel column groups: a column is `<group>.<channel>` (`<group>.<state index>` for
/// the state residuals at the prescribed time).
const CHANNEL_GROUPS: [&str; 6] = [
    "max_correction",
    "prediction_count",
    "prediction_max_error",
    "prediction_rms_error",
    "prediction_max_relative_error",
    "prescribed_time_state_residual",
];

impl From<&RunMetrics> for FlatMetrics {
    fn from(m: &RunMetrics) -> FlatMetrics {
        let prediction = m.prediction.clone().unwrap_or_default();
        let per_channel = |f: &dyn Fn(&PredictionStats) -> f64| {
            prediction
                .iter()
                .map(|(c, p)| (c.clone(), finite(f(p))))
                .collect::<BTreeMap<_, _>>()
        };
        FlatMetrics {
            scenario: m.scenario.clone(),
            simulated_time: finite(m.simulated_time),
            steps: m.steps,
            collision_time: m.collision.as_ref().and_then(|c| finite(c.time)),
            collision_with: m.collision.as_ref().map(|c| c.with.clone()),
            collision_depth: m.collision.as_ref().and_then(|c| finite(c.depth)),
            min_h: m.min_h.and_then(finite),
            time_h_negative: m.time_h_negative.and_then(finite),
            filter_active_fraction: m.filter_active_fraction.and_then(finite),
            filter_infeasible_ticks: m.filter_infeasible_ticks,
            max_correction: m
                .max_correction
                .iter()
                .flatten()
                .map(|(c, v)| (c.clone(), finite(*v)))
                .collect(),
            prediction_count: prediction.iter().map(|(c, p)| (c.clone(), p.count)).collect(),
            prediction_max_error: per_channel(&|p| p.max_error),
            prediction_rms_error: per_channel(&|p| p.rms_error),
            prediction_max_relative_error: per_channel(&|p| p.max_relative_error),
            first_override_time: m.first_override_time.and_then(finite),
            override_duration: m.override_duration.and_then(finite),
            max_jerk: m.max_jerk.and_then(finite),
            max_jerk_overriding: m.max_jerk_overriding.and_then(finite),
            min_clearance: m.min_clearance.and_then(finite),
            min_time_to_collision: m.min_time_to_collision.and_then(finite),
            delay_attributed_violation_time: m.delay_attributed_violation_time.and_then(finite),
            intervention_integral: m.intervention_integral.and_then(finite),
            max_longitudinal_jerk: m.max_longitudinal_jerk.and_then(finite),
            max_lateral_jerk: m.max_lateral_jerk.and_then(finite),
            prescribed_time: m.at_prescribed_time.as_ref().and_then(|p| finite(p.time)),
            prescribed_time_barrier: m.at_prescribed_time.as_ref().and_then(|p| p.barrier.and_then(finite)),
            prescribed_time_input_residual: m
                .at_prescribed_time
                .as_ref()
                .and_then(|p| p.input_residual.and_then(finite)),
            prescribed_time_state_residual: m
                .at_prescribed_time
                .as_ref()
                .map_or(Vec::new(), |p| p.state_residuals.iter().map(|v| finite(*v)).collect()),
            complete: m.complete,
            error: m.error.clone(),
        }
    }
}

impl FlatMetrics {
    /// Whether a column of [`FlatMetrics::columns`] holds numbers (what `falsify --objective`
    /// and `plot-sweep --y` accept).
    pub fn is_numeric_column(name: &str) -> bool {
        !matches!(name, "scenario" | "collision_with" | "complete" | "error")
    }

    /// Column names covering `rows`: the scalar columns, then per group the union of the
    /// channels (sorted), then `complete` and `error`.
    pub fn columns<'a>(rows: impl IntoIterator<Item = &'a FlatMetrics> + Clone) -> Vec<String> {
        let mut names: Vec<String> = SCALAR_COLUMNS.iter().map(|s| s.to_string()).collect();
        for group in CHANNEL_GROUPS {
            if group == "prescribed_time_state_residual" {
                let n = rows
                    .clone()
                    .into_iter()
                    .map(|r| r.prescribed_time_state_residual.len())
                    .max();
                names.extend((0..n.unwrap_or(0)).map(|i| format!("{group}.{i}")));
                continue;
            }
            let channels: std::collections::BTreeSet<&String> =
                rows.clone().into_iter().flat_map(|r| r.channels(group)).collect();
            names.extend(channels.into_iter().map(|c| format!("{group}.{c}")));
        }
        names.push("complete".into());
        names.push("error".into());
        names
    }

    fn channels(&self, group: &str) -> Vec<&String> {
        match group {
            "max_correction" => self.max_correction.keys().collect(),
            "prediction_count" => self.prediction_count.keys().collect(),
            "prediction_max_error" => self.prediction_max_error.keys().collect(),
            "prediction_rms_error" => self.prediction_rms_error.keys().collect(),
            "prediction_max_relative_error" => self.prediction_max_relative_error.keys().collect(),
            _ => Vec::new(),
        }
    }

    /// The value of one column (as named by [`FlatMetrics::columns`]); a channel this run
    /// does not have is an empty cell.
    pub fn cell(&self, column: &str) -> Cell {
        match column {
            "scenario" => Cell::Text(Some(self.scenario.clone())),
            "simulated_time" => Cell::Num(self.simulated_time),
            "steps" => Cell::Int(Some(self.steps)),
            "collision_time" => Cell::Num(self.collision_time),
            "collision_with" => Cell::Text(self.collision_with.clone()),
            "collision_depth" => Cell::Num(self.collision_depth),
            "min_h" => Cell::Num(self.min_h),
            "time_h_negative" => Cell::Num(self.time_h_negative),
            "filter_active_fraction" => Cell::Num(self.filter_active_fraction),
            "filter_infeasible_ticks" => Cell::Int(self.filter_infeasible_ticks),
            "first_override_time" => Cell::Num(self.first_override_time),
            "override_duration" => Cell::Num(self.override_duration),
            "max_jerk" => Cell::Num(self.max_jerk),
            "max_jerk_overriding" => Cell::Num(self.max_jerk_overriding),
            "min_clearance" => Cell::Num(self.min_clearance),
            "min_time_to_collision" => Cell::Num(self.min_time_to_collision),
            "delay_attributed_violation_time" => Cell::Num(self.delay_attributed_violation_time),
            "intervention_integral" => Cell::Num(self.intervention_integral),
            "max_longitudinal_jerk" => Cell::Num(self.max_longitudinal_jerk),
            "max_lateral_jerk" => Cell::Num(self.max_lateral_jerk),
            "prescribed_time" => Cell::Num(self.prescribed_time),
            "prescribed_time_barrier" => Cell::Num(self.prescribed_time_barrier),
            "prescribed_time_input_residual" => Cell::Num(self.prescribed_time_input_residual),
            "complete" => Cell::Bool(Some(self.complete)),
            "error" => Cell::Text(self.error.clone()),
            _ => {
                let Some((group, channel)) = column.split_once('.') else {
                    return Cell::Text(None);
                };
                let num = |m: &BTreeMap<String, Option<f64>>| Cell::Num(m.get(channel).copied().flatten());
                match group {
                    "max_correction" => num(&self.max_correction),
                    "prediction_count" => Cell::Int(self.prediction_count.get(channel).copied()),
                    "prediction_max_error" => num(&self.prediction_max_error),
                    "prediction_rms_error" => num(&self.prediction_rms_error),
                    "prediction_max_relative_error" => num(&self.prediction_max_relative_error),
                    "prescribed_time_state_residual" => Cell::Num(
                        channel
                            .parse::<usize>()
                            .ok()
                            .and_then(|i| self.prescribed_time_state_residual.get(i).copied().flatten()),
                    ),
                    _ => Cell::Text(None),
                }
            }
        }
    }
}

impl Cell {
    /// The CSV text: floats in Rust's shortest round-trip form (`0.1`, `1e-15`), empty for none.
    pub fn csv(&self) -> String {
        match self {
            Cell::Num(v) => v.map_or(String::new(), |x| format!("{x:?}")),
            Cell::Int(v) => v.map_or(String::new(), |x| x.to_string()),
            Cell::Text(v) => v.clone().unwrap_or_default(),
            Cell::Bool(v) => v.map_or(String::new(), |b| b.to_string()),
        }
    }

    /// Short human-readable text for aligned tables (`-` for none).
    pub fn display(&self) -> String {
        match self {
            Cell::Num(Some(x)) => short_number(*x),
            Cell::Num(None) | Cell::Int(None) | Cell::Text(None) | Cell::Bool(None) => "-".into(),
            _ => self.csv(),
        }
    }

    /// The value as JSON (`null` for none).
    pub fn json(&self) -> serde_json::Value {
        match self {
            Cell::Num(v) => v.map_or(serde_json::Value::Null, serde_json::Value::from),
            Cell::Int(v) => v.map_or(serde_json::Value::Null, serde_json::Value::from),
            Cell::Text(v) => v.clone().map_or(serde_json::Value::Null, serde_json::Value::from),
            Cell::Bool(v) => v.map_or(serde_json::Value::Null, serde_json::Value::from),
        }
    }

    /// `other − self` for numbers; for text and flags `same` or `differs`; `None` when
    /// either side is missing.
    pub fn difference(&self, other: &Cell) -> Option<Cell> {
        match (self, other) {
            (Cell::Num(Some(a)), Cell::Num(Some(b))) => Some(Cell::Num(finite(b - a))),
            (Cell::Int(Some(a)), Cell::Int(Some(b))) => Some(Cell::Num(Some(*b as f64 - *a as f64))),
            (Cell::Num(None), Cell::Num(None))
            | (Cell::Int(None), Cell::Int(None))
            | (Cell::Text(None), Cell::Text(None))
            | (Cell::Bool(None), Cell::Bool(None)) => Some(Cell::Text(Some("same".into()))),
            (Cell::Text(a), Cell::Text(b)) => Some(Cell::Text(Some(if a == b { "same" } else { "differs" }.into()))),
            (Cell::Bool(a), Cell::Bool(b)) => Some(Cell::Text(Some(if a == b { "same" } else { "differs" }.into()))),
            _ => None,
        }
    }
}

/// A number in at most 6 significant digits, without trailing zeros.
fn short_number(x: f64) -> String {
    if x == 0.0 {
        return "0".into();
    }
    let a = x.abs();
    if (1e-3..1e6).contains(&a) {
        let decimals = (5 - a.log10().floor() as i32).max(0) as usize;
        let s = format!("{x:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        format!("{x:.3e}")
    }
}

/// One CSV field, quoted when it holds a comma, quote or line break.
pub fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}

/// Lines of CSV fields joined, ending with a newline.
pub fn csv_lines(rows: &[Vec<String>]) -> String {
    rows.iter()
        .map(|r| r.iter().map(|f| csv_field(f)).collect::<Vec<_>>().join(",") + "\n")
        .collect()
}

/// `analyze --csv`: one row per run, `file` then every [`FlatMetrics`] column.
pub fn csv(runs: &[RunMetrics]) -> String {
    let flat: Vec<FlatMetrics> = runs.iter().map(FlatMetrics::from).collect();
    let columns = FlatMetrics::columns(&flat);
    let mut rows = vec![std::iter::once("file".to_string())
        .chain(columns.iter().cloned())
        .collect()];
    for (run, f) in runs.iter().zip(&flat) {
        rows.push(
            std::iter::once(run.file.clone())
                .chain(columns.iter().map(|c| f.cell(c).csv()))
                .collect(),
        );
    }
    csv_lines(&rows)
}

/// One line of a comparison: a metric and its values in runs A and B.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    pub metric: String,
    pub a: Cell,
    pub b: Cell,
    /// B − A for numbers, `same`/`differs` otherwise; `None` when one side lacks the metric.
    pub difference: Option<Cell>,
}

/// `analyze --compare A B`: every metric of either run, side by side.
pub fn compare(a: &RunMetrics, b: &RunMetrics) -> Vec<Comparison> {
    let (fa, fb) = (FlatMetrics::from(a), FlatMetrics::from(b));
    FlatMetrics::columns([&fa, &fb])
        .into_iter()
        .map(|metric| {
            let (ca, cb) = (fa.cell(&metric), fb.cell(&metric));
            let difference = ca.difference(&cb);
            Comparison {
                metric,
                a: ca,
                b: cb,
                difference,
            }
        })
        .collect()
}

/// A comparison as aligned text: header `metric  A  B  B-A`.
pub fn comparison_table(rows: &[Comparison]) -> String {
    let mut cells: Vec<[String; 4]> = vec![["metric".into(), "A".into(), "B".into(), "B-A".into()]];
    for r in rows {
        cells.push([
            r.metric.clone(),
            r.a.display(),
            r.b.display(),
            r.difference.as_ref().map_or("-".into(), Cell::display),
        ]);
    }
    align_columns(&cells)
}

/// A comparison as CSV: `metric,a,b,difference`.
pub fn comparison_csv(rows: &[Comparison]) -> String {
    let mut lines = vec![vec!["metric".to_string(), "a".into(), "b".into(), "difference".into()]];
    for r in rows {
        lines.push(vec![
            r.metric.clone(),
            r.a.csv(),
            r.b.csv(),
            r.difference.as_ref().map_or(String::new(), Cell::csv),
        ]);
    }
    csv_lines(&lines)
}

/// A comparison as JSON: `[{metric, a, b, difference}, …]`.
pub fn comparison_json(rows: &[Comparison]) -> serde_json::Value {
    serde_json::Value::Array(
        rows.iter()
            .map(|r| {
                serde_json::json!({
                    "metric": r.metric,
                    "a": r.a.json(),
                    "b": r.b.json(),
                    "difference": r.difference.as_ref().map_or(serde_json::Value::Null, Cell::json),
                })
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    #[test]
    fn no_delays_is_said_only_when_the_actuators_had_none() {
        let scenario = "[filter]\nkind = 'cbf_qp'\n[delays]\nsteering = 0.0\nacceleration = 0.0\n";
        let metadata = |max_delay: Option<&str>| {
            let mut m = BTreeMap::from([("scenario_resolved".to_string(), scenario.to_string())]);
            if let Some(d) = max_delay {
                m.insert("max_delay".to_string(), d.to_string());
            }
            m
        };
        let label = |max_delay| super::filter_label(&metadata(max_delay)).unwrap();
        // Zero [delays] but 0.3 s of extra actuator latency: delayed.
        assert_eq!(label(Some("0.3")), "delay-free CBF-QP (4.9)–(4.11)");
        assert_eq!(label(Some("0")), "delay-free CBF-QP (4.9)–(4.11), no delays");
        // A log without `max_delay`: the scenario's delays tell.
        assert_eq!(label(None), "delay-free CBF-QP (4.9)–(4.11), no delays");
    }
}
