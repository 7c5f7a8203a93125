//! Metrics of a run, computed from its MCAP log alone.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use mcap::read::{ChunkFlattener, Options};
use mcap::records::Record as McapRecord;
use prost::Message;
use serde::Serialize;

use crate::log::{proto, TOPICS};

#[derive(Debug, thiserror::Error)]
pub enum AnalyzeError {
    #[error("{file}: cannot read: {source}")]
    Io { file: String, source: std::io::Error },
    #[error("{file}: not a readable MCAP file ({message})")]
    NotMcap { file: String, message: String },
    #[error("{file}: truncated or corrupt MCAP after {messages} messages ({message})")]
    Corrupt {
        file: String,
        messages: u64,
        message: String,
    },
    #[error("{file}: an MCAP file, but not an mjsafe log ({message})")]
    Foreign { file: String, message: String },
    #[error("{file}: message on {topic} does not decode as {schema}: {message}")]
    Decode {
        file: String,
        topic: String,
        schema: String,
        message: String,
    },
}

/// First collision of a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Collision {
    /// Time of the first contact.
    pub time: f64,
    /// The obstacle first touched.
    pub with: String,
    /// Deepest penetration over all contacts of the run (MuJoCo contact distance), metres.
    pub depth: f64,
}

/// Prediction consistency of one channel: |p_i(t) − x(φ_i⁻¹(t))| over the run.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct PredictionStats {
    pub count: u64,
    pub max_error: f64,
    pub rms_error: f64,
    pub max_relative_error: f64,
    #[serde(skip)]
    sum_squares: f64,
}

/// Per-run metrics (see docs/log-format.md for the topics they come from).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunMetrics {
    pub file: String,
    pub scenario: String,
    /// Time of the last /state record.
    pub simulated_time: f64,
    /// Physics steps taken (step index of the last /state record).
    pub steps: u64,
    pub collision: Option<Collision>,
    /// Minimum of h over all barriers and steps (None without barriers).
    pub min_h: Option<f64>,
    /// Time spent with some barrier h < 0, seconds.
    pub time_h_negative: f64,
    /// Fraction of control ticks at which the filter changed the nominal input.
    pub filter_active_fraction: f64,
    pub filter_infeasible_ticks: u64,
    /// max |u − u_nom| per channel over the run.
    pub max_correction: BTreeMap<String, f64>,
    /// Prediction consistency (Definition 4.3) per channel, from /prediction.
    pub prediction: BTreeMap<String, PredictionStats>,
    /// Whether the run finished (false: stopped by an error or interrupted).
    pub complete: bool,
    pub error: Option<String>,
}

/// Reads and analyses one log file.
pub fn analyze_file(path: &Path) -> Result<RunMetrics, AnalyzeError> {
    let file = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| AnalyzeError::Io {
        file: file.clone(),
        source,
    })?;
    analyze_bytes(&bytes, &file)
}

#[derive(Default)]
struct Accumulator {
    scenario: String,
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
    complete: Option<bool>,
    error: Option<String>,
}

/// Analyses log bytes; `file` names them in errors.
pub fn analyze_bytes(bytes: &[u8], file: &str) -> Result<RunMetrics, AnalyzeError> {
    let reader = ChunkFlattener::new_with_options(bytes, Options::ValidateChunkCrcs.into()).map_err(|e| {
        AnalyzeError::NotMcap {
            file: file.into(),
            message: e.to_string(),
        }
    })?;
    let mut schemas: HashMap<u16, String> = HashMap::new();
    let mut channels: HashMap<u16, (String, String)> = HashMap::new();
    let mut acc = Accumulator::default();
    let mut messages = 0u64;
    let mut saw_mjsafe_metadata = false;
    for record in reader {
        let record = record.map_err(|e| {
            if messages == 0 && acc.states == 0 && channels.is_empty() {
                AnalyzeError::NotMcap {
                    file: file.into(),
                    message: e.to_string(),
                }
            } else {
                AnalyzeError::Corrupt {
                    file: file.into(),
                    messages,
                    message: e.to_string(),
                }
            }
        })?;
        match record {
            McapRecord::Schema { header, .. } => {
                schemas.insert(header.id, header.name);
            }
            McapRecord::Channel(c) => {
                let schema = schemas.get(&c.schema_id).cloned().unwrap_or_default();
                channels.insert(c.id, (c.topic, schema));
            }
            McapRecord::Metadata(m) if m.name == "mjsafe" => {
                saw_mjsafe_metadata = true;
                acc.scenario = m.metadata.get("scenario_name").cloned().unwrap_or_default();
                acc.timestep = m.metadata.get("timestep").and_then(|s| s.parse().ok());
            }
            McapRecord::Metadata(m) if m.name == "mjsafe_status" => {
                acc.complete = Some(m.metadata.get("complete").is_some_and(|v| v == "true"));
            }
            McapRecord::Message { header, data } => {
                messages += 1;
                let Some((topic, schema)) = channels.get(&header.channel_id) else {
                    continue;
                };
                let expected = TOPICS.iter().find(|(t, _)| t == topic).map(|(_, s)| *s);
                match expected {
                    Some(s) if s == schema => acc.add(topic, schema, &data, file)?,
                    Some(s) => {
                        return Err(AnalyzeError::Foreign {
                            file: file.into(),
                            message: format!("topic {topic} has schema {schema}, expected {s}"),
                        })
                    }
                    None => {}
                }
            }
            _ => {}
        }
    }
    if !saw_mjsafe_metadata || acc.states == 0 {
        return Err(AnalyzeError::Foreign {
            file: file.into(),
            message: "no mjsafe metadata record or no /state messages".into(),
        });
    }
    Ok(acc.finish(file))
}

impl Accumulator {
    fn add(&mut self, topic: &str, schema: &str, data: &[u8], file: &str) -> Result<(), AnalyzeError> {
        let decode_error = |e: prost::DecodeError| AnalyzeError::Decode {
            file: file.into(),
            topic: topic.into(),
            schema: schema.into(),
            message: e.to_string(),
        };
        match topic {
            "/state" => {
                let m = proto::State::decode(data).map_err(decode_error)?;
                self.states += 1;
                self.last_time = self.last_time.max(m.time);
                self.last_step = self.last_step.max(m.step);
            }
            "/barrier" => {
                let m = proto::Barrier::decode(data).map_err(decode_error)?;
                let step_min = m.barriers.iter().map(|b| b.h).fold(f64::INFINITY, f64::min);
                if step_min.is_finite() {
                    self.min_h = Some(self.min_h.map_or(step_min, |h| h.min(step_min)));
                    if step_min < 0.0 {
                        self.negative_steps += 1;
                    }
                }
            }
            "/filter" => {
                let m = proto::Filter::decode(data).map_err(decode_error)?;
                self.ticks += 1;
                self.active_ticks += u64::from(m.active);
                self.infeasible_ticks += u64::from(m.infeasible);
                for (channel, c) in m.channels.iter().zip(&m.correction) {
                    let entry = self.max_correction.entry(channel.clone()).or_insert(0.0);
                    *entry = entry.max(c.abs());
                }
            }
            "/prediction" => {
                let m = proto::Prediction::decode(data).map_err(decode_error)?;
                let stats = self.prediction.entry(m.channel).or_default();
                stats.count += 1;
                stats.max_error = stats.max_error.max(m.error);
                stats.max_relative_error = stats.max_relative_error.max(m.relative_error);
                stats.sum_squares += m.error * m.error;
            }
            "/event" => {
                let m = proto::Event::decode(data).map_err(decode_error)?;
                match m.kind.as_str() {
                    "collision_start" | "collision_end" => {
                        let with = m
                            .participants
                            .iter()
                            .find(|p| *p != "vehicle")
                            .cloned()
                            .unwrap_or_default();
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
                    "error" if self.error.is_none() => self.error = Some(m.message),
                    _ => {}
                }
            }
            _ => {}
        }
        Ok(())
    }

    fn finish(self, file: &str) -> RunMetrics {
        RunMetrics {
            file: file.into(),
            scenario: self.scenario,
            simulated_time: self.last_time,
            steps: self.last_step,
            collision: self.collision,
            min_h: self.min_h,
            time_h_negative: self.negative_steps as f64 * self.timestep.unwrap_or(0.0),
            filter_active_fraction: if self.ticks > 0 {
                self.active_ticks as f64 / self.ticks as f64
            } else {
                0.0
            },
            filter_infeasible_ticks: self.infeasible_ticks,
            max_correction: self.max_correction,
            prediction: self
                .prediction
                .into_iter()
                .map(|(channel, mut stats)| {
                    stats.rms_error = (stats.sum_squares / stats.count.max(1) as f64).sqrt();
                    (channel, stats)
                })
                .collect(),
            complete: self.complete.unwrap_or(false) && self.error.is_none(),
            error: self.error,
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
            r.collision
                .as_ref()
                .map_or("none".into(), |c| format!("t={:.3} {}", c.time, c.with)),
            r.min_h.map_or("-".into(), |h| format!("{h:.3}")),
            format!("{:.3}", r.time_h_negative),
            format!("{:.1}%", 100.0 * r.filter_active_fraction),
            r.filter_infeasible_ticks.to_string(),
            r.max_correction
                .iter()
                .map(|(c, v)| format!("{c}={v:.3}"))
                .collect::<Vec<_>>()
                .join(" "),
            if r.prediction.is_empty() {
                "-".to_string()
            } else {
                r.prediction
                    .iter()
                    .map(|(c, p)| format!("{c}={:.1e}/{:.1e}", p.max_error, p.rms_error))
                    .collect::<Vec<_>>()
                    .join(" ")
            },
            match (&r.error, r.complete) {
                (Some(e), _) => format!("error: {e}"),
                (None, true) => "complete".into(),
                (None, false) => "incomplete".into(),
            },
        ]);
    }
    let widths: Vec<usize> = (0..header.len())
        .map(|c| rows.iter().map(|r| r[c].chars().count()).max().unwrap_or(0))
        .collect();
    rows.iter()
        .map(|r| {
            r.iter()
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
