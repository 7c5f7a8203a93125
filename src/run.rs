//! The one run path: a loaded scenario → its episode → its sinks → its metrics. `mjsafe run`,
//! the embedding API (`embed`), sweeps, `falsify` and `bench` all run a scenario
//! through [`Prepared`], so they check the same outputs, refuse the same budgets and treat a
//! failing sink the same way:
//!
//! - the log of record (an MCAP file, or the in-memory analysis) receives every record first;
//! - a further sink (rerun, a user's) that fails stops the run: the log of record gets an
//!   `/event` error naming the failure and is finished as incomplete, and the run returns
//!   [`RunError::Sink`] (the log stays, marked incomplete);
//! - an error inside the episode (a non-finite state, a filter error, Ctrl-C) is not an error
//!   of the run: the log holds the run up to that point and [`Outcome::summary`] says why it
//!   stopped.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::analyze::{self, AnalysisSink, AnalyzeError, RunMetrics};
use crate::episode::{Episode, EpisodeError, EpisodeSummary};
use crate::log::mcap::{self, McapSink};
use crate::log::{LogError, Record, RunInfo, Sink, Tee};
use crate::scenario::LoadedScenario;

/// Where a run's records go, besides its further sinks.
#[derive(Debug, Clone, Copy)]
pub enum Keep<'a> {
    /// Into this MCAP log (written as `.partial`, renamed when complete; never over the
    /// scenario, its model or a foreign file), analysed once written.
    Log(&'a Path),
    /// Into the in-memory analysis ([`AnalysisSink`]): the metrics the log would give, without
    /// writing one. The name stands for the log in the metrics and in errors.
    Metrics(&'a str),
    /// Nowhere (a timing run).
    Nothing,
}

/// Anything that stops a run before it has an outcome.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Episode(#[from] EpisodeError),
    #[error(transparent)]
    Log(#[from] LogError),
    #[error(transparent)]
    Output(#[from] crate::files::FileError),
    #[error(transparent)]
    Analyze(#[from] AnalyzeError),
    /// A further sink failed: the run stopped there.
    #[error("{error}; the run stopped{}", log.as_ref().map_or(String::new(), |l| format!(" and its log {} is marked incomplete", l.display())))]
    Sink { error: LogError, log: Option<PathBuf> },
}

/// Wall-clock seconds of the parts of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RunTiming {
    /// Assembling the episode (MJCF compile, filter and predictors) and opening the log.
    pub assemble_seconds: f64,
    /// The episode's step loop, its sinks included (the log writer's own thread excluded).
    pub run_seconds: f64,
    /// Analysing the run: reading its log back, or concluding the in-memory analysis.
    pub analysis_seconds: f64,
    /// Time the log's writer thread spent compressing and writing (0 without a log).
    pub writer_busy_seconds: f64,
}

/// A finished (or stopped) run.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// How the episode ended ([`EpisodeSummary::error`]: why it stopped early).
    pub summary: EpisodeSummary,
    /// The log written ([`Keep::Log`]).
    pub log: Option<PathBuf>,
    /// The run's metrics (none for [`Keep::Nothing`]).
    pub metrics: Option<RunMetrics>,
    pub timing: RunTiming,
}

/// The log of record of a run.
enum LogOfRecord {
    Log { sink: Box<McapSink>, path: PathBuf },
    Metrics(Box<AnalysisSink>),
    Nothing(Discard),
}

/// A sink that keeps nothing (the log of record of a timing run).
struct Discard;

impl Sink for Discard {
    fn record(&mut self, _: &Record) -> Result<(), LogError> {
        Ok(())
    }
    fn finish(&mut self, _: bool) -> Result<(), LogError> {
        Ok(())
    }
}

/// A run assembled and its log opened, not yet started: further sinks that need the run's
/// description ([`Prepared::info`]) are made now, then [`Prepared::run`].
pub struct Prepared {
    episode: Episode,
    record: LogOfRecord,
    assemble_seconds: f64,
}

impl Prepared {
    /// Assembles `loaded` and opens where `keep` says its records go. With a log: the target
    /// is checked before the model is loaded, and a run whose log would exceed the log budget
    /// (`--max-log-size`) is refused before it starts.
    pub fn new(loaded: &LoadedScenario, keep: Keep<'_>) -> Result<Prepared, RunError> {
        let started = Instant::now();
        let inputs = loaded.inputs();
        let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
        // The log's target is checked before the model is loaded.
        if let Keep::Log(path) = keep {
            mcap::check_target(path, &inputs)?;
        }
        let mut episode = Episode::new(loaded)?;
        let record = match keep {
            Keep::Log(path) => {
                episode.check_log_budget()?;
                LogOfRecord::Log {
                    sink: Box::new(McapSink::create(path, episode.info(), &inputs)?),
                    path: path.to_path_buf(),
                }
            }
            Keep::Metrics(name) => LogOfRecord::Metrics(Box::new(AnalysisSink::new(episode.info(), name))),
            Keep::Nothing => LogOfRecord::Nothing(Discard),
        };
        Ok(Prepared {
            episode,
            record,
            assemble_seconds: started.elapsed().as_secs_f64(),
        })
    }

    /// What the run is (the log's run metadata).
    pub fn info(&self) -> &RunInfo {
        self.episode.info()
    }

    /// Steps the episode will take.
    pub fn steps(&self) -> u64 {
        self.episode.steps()
    }

    /// Gives up before running: a log opened is deleted, nothing is left under its name.
    pub fn abandon(self) {
        if let LogOfRecord::Log { sink, .. } = self.record {
            (*sink).abandon();
        }
    }

    /// Runs the episode into its log of record and `further` sinks, then analyses it.
    pub fn run(mut self, further: Vec<Box<dyn Sink + '_>>) -> Result<Outcome, RunError> {
        let (summary, failed) = {
            let log: &mut dyn Sink = match &mut self.record {
                LogOfRecord::Log { sink, .. } => sink.as_mut(),
                LogOfRecord::Metrics(sink) => sink.as_mut(),
                LogOfRecord::Nothing(sink) => sink,
            };
            let mut outputs = Tee::new(log, further);
            let result = self.episode.run(&mut [&mut outputs]);
            (result, outputs.other_failed())
        };
        let log = match &self.record {
            LogOfRecord::Log { path, .. } => Some(path.clone()),
            _ => None,
        };
        let summary = match summary {
            Err(EpisodeError::Log(error)) if failed => return Err(RunError::Sink { error, log }),
            result => result?,
        };
        let mut timing = RunTiming {
            assemble_seconds: self.assemble_seconds,
            run_seconds: summary.wall_seconds,
            ..RunTiming::default()
        };
        let started = Instant::now();
        let metrics = match self.record {
            LogOfRecord::Log { sink, path } => {
                timing.writer_busy_seconds = sink.writer_busy().as_secs_f64();
                drop(sink);
                Some(analyze::analyze_file(&path)?)
            }
            LogOfRecord::Metrics(sink) => Some(sink.metrics()?),
            LogOfRecord::Nothing(_) => None,
        };
        timing.analysis_seconds = started.elapsed().as_secs_f64();
        Ok(Outcome {
            summary,
            log,
            metrics,
            timing,
        })
    }
}

/// Runs `loaded` into `keep` and `further` sinks: [`Prepared::new`] then [`Prepared::run`].
pub fn run(loaded: &LoadedScenario, keep: Keep<'_>, further: Vec<Box<dyn Sink + '_>>) -> Result<Outcome, RunError> {
    Prepared::new(loaded, keep)?.run(further)
}
