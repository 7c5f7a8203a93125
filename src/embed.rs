//! Using mjsafe from your own program: register your own filter or nominal kinds, load (or
//! write) a scenario that names them, run an episode into an MCAP log with any extra sinks, and
//! read its metrics back from the log, exactly as `mjsafe run` does.
//!
//! ```no_run
//! use std::path::Path;
//!
//! // 1. Your kinds (see examples/robust_cbf.rs for a whole filter).
//! // mjsafe::registry::register(|r| r.add_filter("my_filter", my_filter::build));
//!
//! // 2. A scenario file, with `--set`-style overrides that may name your kinds.
//! let loaded = mjsafe::embed::load_scenario(
//!     Path::new("scenarios/bicycle_obstacle.toml"),
//!     &["filter={kind='cbf_qp', l0=4.0, l1=4.0}".to_string()],
//! )?;
//!
//! // 3. Run it into a log; the metrics are read back from the log (docs/metrics.md).
//! let outcome = mjsafe::embed::run_logged(&loaded, Path::new("out.mcap"), &mut [])?;
//! println!("min h = {:?}, collision: {}", outcome.metrics.min_h, outcome.metrics.collision.is_some());
//! # Ok::<(), mjsafe::embed::EmbedError>(())
//! ```
//!
//! The control tick stays the library's: it runs inside MuJoCo's control callback (or the ODE
//! plant's stages), dispatches to the episode of the calling thread, and turns a panic into an
//! error event instead of unwinding into C. What a filter must not do there is in
//! docs/writing-a-filter.md.

use std::path::{Path, PathBuf};

pub use crate::analyze::RunMetrics;
pub use crate::episode::{Episode, EpisodeSummary, StopReason};
pub use crate::log::Sink;
pub use crate::registry::{register, registry, Params, Registry};
pub use crate::scenario::{from_text as scenario_from_text, load as load_scenario, LoadedScenario};

/// Anything that stops a run before it has a log to read.
#[derive(Debug, thiserror::Error)]
pub enum EmbedError {
    #[error(transparent)]
    Scenario(#[from] crate::scenario::ScenarioError),
    #[error(transparent)]
    Episode(#[from] crate::episode::EpisodeError),
    #[error(transparent)]
    Log(#[from] crate::log::LogError),
    #[error(transparent)]
    Output(#[from] crate::files::FileError),
    #[error(transparent)]
    Analyze(#[from] crate::analyze::AnalyzeError),
}

/// A finished run: how it ended, its log, and the metrics read from that log.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub summary: EpisodeSummary,
    pub log: PathBuf,
    pub metrics: RunMetrics,
}

/// Runs `loaded` into the MCAP log `log` (written as `log.partial`, renamed when complete;
/// never over the scenario, its model or a foreign file) and into `sinks`, then analyses the
/// log. A run stopped early (see [`Outcome::summary`]) still returns its metrics.
pub fn run_logged(loaded: &LoadedScenario, log: &Path, sinks: &mut [&mut dyn Sink]) -> Result<Outcome, EmbedError> {
    let inputs = loaded.inputs();
    let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    crate::log::mcap::check_target(log, &inputs)?;
    let mut episode = Episode::new(loaded)?;
    episode.check_log_budget()?;
    let mut mcap = crate::log::mcap::McapSink::create(log, episode.info(), &inputs)?;
    let summary = {
        let mut all: Vec<&mut dyn Sink> = Vec::with_capacity(1 + sinks.len());
        all.push(&mut mcap);
        for sink in sinks.iter_mut() {
            all.push(&mut **sink);
        }
        episode.run(&mut all)?
    };
    let metrics = crate::analyze::analyze_file(log)?;
    Ok(Outcome {
        summary,
        log: log.to_path_buf(),
        metrics,
    })
}
