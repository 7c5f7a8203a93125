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
use crate::episode::{Ended, Episode, EpisodeError, EpisodeSummary};
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

    /// Assembles `loaded` as a run would and drops it: every check that needs the model and
    /// the kinds (falsification's pre-flight of a box's centre).
    pub fn check(loaded: &LoadedScenario) -> Result<(), RunError> {
        Prepared::new(loaded, Keep::Nothing).map(drop)
    }

    /// Refuses, before anything runs, a run whose log would exceed the log budget
    /// (`--max-log-size`): what a later logged run of the same scenario would be refused for.
    pub fn check_log_budget(&mut self) -> Result<(), RunError> {
        Ok(self.episode.check_log_budget()?)
    }

    /// The assembled episode, for a caller that drives it itself: the benchmarks' probe (an
    /// audited run recording its actuation) and bare physics loop (that actuation replayed).
    pub fn into_episode(self) -> Episode {
        self.episode
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
    pub fn run(self, further: Vec<Box<dyn Sink + '_>>) -> Result<Outcome, RunError> {
        let _graceful = crate::episode::GracefulStop::begin();
        self.start(further).finish(Rest::Run)
    }

    /// Starts the run without taking a step: its caller steps it ([`Running::advance`]).
    pub fn start<'a>(self, further: Vec<Box<dyn Sink + 'a>>) -> Running<'a> {
        Running {
            prepared: self,
            further,
            failed: false,
            last_time: 0.0,
            run_seconds: 0.0,
        }
    }
}

/// What [`Running::finish`] does with the steps not taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rest {
    /// Takes them: the episode runs to its end.
    Run,
    /// Ends the episode where it is ([`Episode::end_here`]): its log says where it stopped.
    EndHere,
}

/// A run started ([`Prepared::start`]) and stepped by its caller, one plant step at a time,
/// through the loop of [`Prepared::run`] (which is [`Running::finish`] with [`Rest::Run`]).
pub struct Running<'a> {
    prepared: Prepared,
    further: Vec<Box<dyn Sink + 'a>>,
    /// Whether a further sink failed (the run then stopped).
    failed: bool,
    /// Time of the last record (of an error event a later step logs).
    last_time: f64,
    run_seconds: f64,
}

impl<'a> Running<'a> {
    /// The episode (its state, queues and step between steps).
    pub fn episode(&self) -> &Episode {
        &self.prepared.episode
    }

    /// Sets the input of an `external` nominal ([`Episode::set_external_input`]).
    pub fn set_external_input(&mut self, input: &[f64]) -> Result<(), String> {
        self.prepared.episode.set_external_input(input)
    }

    /// Takes the episode's next step into the log of record and the further sinks
    /// ([`Episode::advance`]); returns how the episode ended once it has. After an error the
    /// run can only be finished.
    pub fn advance(&mut self) -> Result<Option<Ended>, RunError> {
        self.with_outputs(|episode, outputs| episode.advance(outputs))
    }

    /// Calls `step` with the episode and the outputs (the log of record, then the further
    /// sinks), timing it; a failed further sink's error becomes [`RunError::Sink`].
    fn with_outputs<T>(
        &mut self,
        step: impl FnOnce(&mut Episode, &mut [&mut dyn Sink]) -> Result<T, EpisodeError>,
    ) -> Result<T, RunError> {
        let started = Instant::now();
        let further = (std::mem::take(&mut self.further), self.last_time);
        let Prepared { episode, record, .. } = &mut self.prepared;
        let mut outputs = Tee::resume(record.sink(), further);
        let result = step(episode, &mut [&mut outputs]);
        self.failed |= outputs.other_failed();
        (self.further, self.last_time) = outputs.into_parts();
        self.run_seconds += started.elapsed().as_secs_f64();
        match result {
            Err(EpisodeError::Log(error)) if self.failed => Err(RunError::Sink {
                error,
                log: self.prepared.record.path(),
            }),
            result => Ok(result?),
        }
    }

    /// Ends the run ([`Rest`] says how), finishes every sink and analyses the log of record.
    /// An error of a step or of a sink finishes the sinks as incomplete and is returned.
    pub fn finish(mut self, rest: Rest) -> Result<Outcome, RunError> {
        let ended = self.with_outputs(|episode, outputs| match rest {
            Rest::Run => loop {
                if let Some(end) = episode.advance(outputs)? {
                    break Ok(end);
                }
            },
            Rest::EndHere => episode.end_here(outputs),
        });
        let (steps, error) = match ended {
            Ok(end) => end,
            Err(e) => {
                let _ = self.prepared.record.sink().finish(false);
                for sink in &mut self.further {
                    let _ = sink.finish(false);
                }
                return Err(e);
            }
        };
        let complete = error.is_none();
        let finished = self.with_outputs(|_, outputs| outputs[0].finish(complete).map_err(EpisodeError::from));
        finished?;
        let summary = EpisodeSummary {
            steps,
            simulated_time: steps as f64 * self.prepared.episode.timestep(),
            wall_seconds: self.run_seconds,
            error,
            barrier_rows: self.prepared.episode.barrier_rows(),
        };
        let mut timing = RunTiming {
            assemble_seconds: self.prepared.assemble_seconds,
            run_seconds: summary.wall_seconds,
            ..RunTiming::default()
        };
        let log = self.prepared.record.path();
        let started = Instant::now();
        let metrics = match self.prepared.record {
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

impl LogOfRecord {
    fn sink(&mut self) -> &mut dyn Sink {
        match self {
            LogOfRecord::Log { sink, .. } => sink.as_mut(),
            LogOfRecord::Metrics(sink) => sink.as_mut(),
            LogOfRecord::Nothing(sink) => sink,
        }
    }

    fn path(&self) -> Option<PathBuf> {
        match self {
            LogOfRecord::Log { path, .. } => Some(path.clone()),
            _ => None,
        }
    }
}

/// Checks a scenario's requirements against the signals its runs have, before a run: one step
/// of it, analysed in memory; a requirement that names no signal of the run is an error naming
/// the requirement and the signal (with the closest signal there is).
pub fn check_requirement_signals(loaded: &LoadedScenario) -> Result<(), String> {
    if loaded.scenario.requirements.is_empty() {
        return Ok(());
    }
    let mut probe = loaded.clone();
    // A short run (every signal topic logs at t = 0): its first half second at most.
    probe.scenario.duration = loaded.scenario.duration.min(0.5);
    let outcome = run(&probe, Keep::Metrics("(requirement check)"), Vec::new()).map_err(|e| e.to_string())?;
    let Some(metrics) = outcome.metrics else { return Ok(()) };
    for requirement in &loaded.scenario.requirements {
        let column = format!("req.{}", requirement.name);
        let reason = (metrics.missing.iter())
            .find(|(k, _)| **k == column || **k == "req")
            .map(|(_, r)| r.clone());
        if let Some(reason) = reason.filter(|r| r.contains("signal `")) {
            return Err(format!("requirement `{}`: {reason}", requirement.name));
        }
    }
    Ok(())
}

/// Runs `loaded` into `keep` and `further` sinks: [`Prepared::new`] then [`Prepared::run`].
pub fn run(loaded: &LoadedScenario, keep: Keep<'_>, further: Vec<Box<dyn Sink + '_>>) -> Result<Outcome, RunError> {
    Prepared::new(loaded, keep)?.run(further)
}
