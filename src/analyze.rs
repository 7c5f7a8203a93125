//! Analysis: a run's metrics ([`crate::metrics`]) from its MCAP log alone, or from the
//! typed records of a running episode ([`AnalysisSink`]).

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use crate::log::read::{self, Decoder, Message, ReadError, RunRead, RunVisitor};
use crate::log::{proto, Topic};
use crate::metrics::{Accumulators, Observed, RunFacts};
pub use crate::metrics::{Cell, Collision, FlatMetrics, PredictionStats, PrescribedTimeMetrics, RunMetrics, Value};

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

/// Reads and analyses one log file (through the run reader, [`read::read_run_file`]).
/// Streams through the file: memory stays bounded by the largest chunk (and the read size),
/// whatever the log's length. The result does not depend on where the run metadata sits in
/// the data section (the MCAP spec allows it anywhere).
pub fn analyze_file(path: &Path) -> Result<RunMetrics, AnalyzeError> {
    analyze_file_with(path, &[])
}

/// [`analyze_file`] with requirements (name, STL formula) evaluated besides the run's own
/// (`analyze --require`; one of the run's with the same name is replaced): `req.<name>`.
pub fn analyze_file_with(path: &Path, requirements: &[(String, String)]) -> Result<RunMetrics, AnalyzeError> {
    let file = path.display().to_string();
    let mut analysis = Analysis::new(&file);
    analysis.metrics.add_requirements(requirements);
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

/// The analysis of a running episode, as a sink: each record a metric reads is handed, typed
/// as the episode made it, to the same accumulators [`analyze_file`] feeds from the log, with
/// the same run metadata first and the same status last, so the metrics are those of the run's
/// log (`tests/analysis_sink.rs` compares them on every scenario) without encoding, writing,
/// compressing or reading one. What a falsification candidate runs with (`run::Keep::Metrics`).
pub struct AnalysisSink {
    analysis: Option<Analysis>,
    /// What stands for the log's path in errors.
    name: String,
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
        let Some(observed) = Observed::of(record) else {
            return Ok(());
        };
        analysis.observe(observed);
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

/// The state of one analysis: what the run is, and the metrics so far.
struct Analysis {
    file: String,
    metrics: Accumulators,
    decoder: Decoder,
    saw_mjsafe_metadata: bool,
    scenario: String,
    filter_label: Option<String>,
    /// From the status record (None: the log has none).
    complete: Option<bool>,
    noted: Noted,
}

/// What the analysis itself reads of the records, besides the metrics.
#[derive(Default)]
struct Noted {
    /// `/state` messages read (a log without any is not a run's).
    states: u64,
    /// The first `error` or `interrupted` event.
    error: Option<String>,
    /// The MuJoCo warnings after which the physics was not the model's.
    warnings: Vec<String>,
}

impl Noted {
    fn note(&mut self, record: Observed<'_>) {
        match record {
            Observed::State(_) => self.states += 1,
            Observed::Event(m) => match m.kind.as_str() {
                "error" | "interrupted" if self.error.is_none() => self.error = Some(m.message.clone()),
                crate::log::MUJOCO_WARNING => self.warnings.push(m.message.clone()),
                _ => {}
            },
            _ => {}
        }
    }
}

/// The run's safety filter by the label its registration gives it (metadata `filter_label`:
/// the equation number it implements, completed by its parameters), with ", no delays" when
/// the run's largest actuator latency (metadata `max_delay`) is zero: the label of plot legends
/// and `analyze --brief`. Absent in logs without it.
pub fn filter_label(metadata: &BTreeMap<String, String>) -> Option<String> {
    let label = metadata.get("filter_label")?;
    let filtered = metadata.get("filter_kind").is_some_and(|k| k != "none");
    let no_delays = metadata
        .get("max_delay")
        .and_then(|d| d.parse::<f64>().ok())
        .is_some_and(|d| d == 0.0);
    Some(if filtered && no_delays {
        format!("{label}, no delays")
    } else {
        label.clone()
    })
}

impl RunVisitor for Analysis {
    fn metadata(&mut self, name: &str, entries: &BTreeMap<String, String>) -> Result<(), ReadError> {
        match name {
            read::RUN_METADATA => {
                self.saw_mjsafe_metadata = true;
                self.scenario = entries.get("scenario_name").cloned().unwrap_or_default();
                self.filter_label = filter_label(entries);
                self.metrics.set_facts(RunFacts::from_metadata(entries));
            }
            read::STATUS_METADATA => {
                self.complete = Some(entries.get("complete").is_some_and(|v| v == "true"));
            }
            _ => {}
        }
        Ok(())
    }

    fn message(&mut self, m: &Message<'_>) -> Result<(), ReadError> {
        if !self.metrics.reads(m.topic) {
            return Ok(());
        }
        let (event, actors, command, measured): (proto::Event, proto::Actors, proto::AppliedCommand, proto::State);
        let observed = match m.topic {
            Topic::State => Observed::State(self.decoder.state(m)?),
            Topic::Barrier => Observed::Barrier(self.decoder.barrier(m)?),
            Topic::Filter => Observed::Filter(self.decoder.filter(m)?),
            Topic::Issued => Observed::Issued(self.decoder.issued(m)?),
            Topic::Prediction => Observed::Prediction(self.decoder.prediction(m)?),
            Topic::Event => {
                event = m.decode()?;
                Observed::Event(&event)
            }
            Topic::Actors => {
                actors = m.decode()?;
                Observed::Actors(&actors)
            }
            // Only a requirement's signals read these.
            Topic::Applied | Topic::Actuated => {
                command = m.decode()?;
                match m.topic {
                    Topic::Applied => Observed::Applied(&command),
                    _ => Observed::Actuated(&command),
                }
            }
            Topic::Measured => {
                measured = m.decode()?;
                Observed::Measured(&measured)
            }
            _ => return Ok(()),
        };
        // `observed` borrows the decoder's buffers.
        self.noted.note(observed);
        self.metrics.observe(observed);
        Ok(())
    }
}

impl Analysis {
    fn new(file: &str) -> Self {
        Analysis {
            file: file.to_string(),
            metrics: Accumulators::default(),
            decoder: Decoder::default(),
            saw_mjsafe_metadata: false,
            scenario: String::new(),
            filter_label: None,
            complete: None,
            noted: Noted::default(),
        }
    }

    /// A typed record of a running episode.
    fn observe(&mut self, record: Observed<'_>) {
        self.noted.note(record);
        self.metrics.observe(record);
    }

    /// The metrics, or the error, once the records have been read.
    fn conclude(self, result: Result<RunRead, ReadError>) -> Result<RunMetrics, AnalyzeError> {
        let read = match result {
            Ok(read) => read,
            Err(ReadError::Corrupt {
                file: f,
                messages,
                message,
            }) => {
                let partial = (self.saw_mjsafe_metadata && self.noted.states > 0).then(|| {
                    let mut m = self.finish(&[]);
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
        if self.noted.states == 0 {
            return Err(ReadError::Foreign {
                file: self.file,
                message: "no mjsafe metadata record or no /state messages".into(),
            }
            .into());
        }
        Ok(self.finish(&read.missing_topics()))
    }

    /// The metrics; those the log cannot give are absent, with the reason in `missing`.
    fn finish(self, missing_topics: &[Topic]) -> RunMetrics {
        let mut missing = BTreeMap::new();
        if missing_topics.contains(&Topic::Event) {
            missing.insert("error".to_string(), format!("no {} topic in the log", Topic::Event));
        }
        if self.complete.is_none() {
            missing.insert(
                "complete".into(),
                format!(
                    "no {} metadata record (false: not known to have finished)",
                    read::STATUS_METADATA
                ),
            );
        }
        let values = self.metrics.finish(missing_topics, &mut missing);
        let complete = self.complete.unwrap_or(false) && self.noted.error.is_none();
        let error = self.noted.error.filter(|_| !missing.contains_key("error"));
        RunMetrics {
            file: self.file,
            scenario: self.scenario,
            filter_label: self.filter_label,
            values,
            complete,
            error,
            missing,
            warnings: self.noted.warnings,
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    #[test]
    fn no_delays_is_said_only_when_the_actuators_had_none() {
        let metadata = |kind: &str, max_delay: Option<&str>| {
            let mut m = BTreeMap::from([
                ("filter_kind".to_string(), kind.to_string()),
                ("filter_label".to_string(), "my label (1.1)".to_string()),
            ]);
            if let Some(d) = max_delay {
                m.insert("max_delay".to_string(), d.to_string());
            }
            m
        };
        let label = |kind, max_delay| super::filter_label(&metadata(kind, max_delay)).unwrap();
        // Zero [delays] but 0.3 s of extra actuator latency: delayed.
        assert_eq!(label("mine", Some("0.3")), "my label (1.1)");
        assert_eq!(label("mine", Some("0")), "my label (1.1), no delays");
        // Without a filter, no delays is not the filter's.
        assert_eq!(label("none", Some("0")), "my label (1.1)");
        // Without `max_delay` the delays are not known: not said.
        assert_eq!(label("mine", None), "my label (1.1)");
        assert_eq!(super::filter_label(&BTreeMap::new()), None);
    }
}
