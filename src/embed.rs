//! Using mjsafe from your own program: register your own filter or nominal kinds, load (or
//! write) a scenario that names them, run an episode into an MCAP log with any extra sinks, and
//! read its metrics back from the log, exactly as `mjsafe run` does.
//!
//! ```no_run
//! use std::path::Path;
//!
//! // 1. Your kinds (see examples/robust_cbf.rs for a whole filter).
//! // mjsafe::registry::register(|r| {
//! //     r.add_filter("my_filter", my_filter::build).label("my filter (eq. 7)");
//! // });
//!
//! // 2. A scenario file, with `--set`-style overrides that may name your kinds.
//! let loaded = mjsafe::embed::load_scenario(
//!     Path::new("scenarios/bicycle_obstacle.toml"),
//!     &["filter={kind='cbf_qp', l0=4.0, l1=4.0}".to_string()],
//! )?;
//!
//! // 3. Run it into a log; the metrics are read back from the log (docs/metrics.md).
//! let outcome = mjsafe::embed::run_logged(&loaded, Path::new("out.mcap"), &mut [])?;
//! let metrics = outcome.metrics.expect("a logged run is analysed");
//! println!("min h = {:?}, collision: {}", metrics.min_h(), metrics.collision().is_some());
//! # Ok::<(), mjsafe::embed::EmbedError>(())
//! ```
//!
//! The control tick stays the library's: it runs inside MuJoCo's control callback (or the ODE
//! plant's stages), dispatches to the episode of the calling thread, and turns a panic into an
//! error event instead of unwinding into C. What a filter must not do there is in
//! docs/writing-a-filter.md.

use std::path::Path;

pub use crate::analyze::RunMetrics;
pub use crate::episode::{Episode, EpisodeSummary, StopReason};
pub use crate::log::Sink;
pub use crate::registry::{register, registry, AlreadyRegistered, Params, Registry};
pub use crate::scenario::{from_text as scenario_from_text, load as load_scenario, LoadedScenario};

pub use crate::run::{Keep, Outcome, Prepared, RunError, RunTiming};

/// Anything that stops a run before it has a log to read: the scenario ([`load_scenario`])
/// or the run ([`RunError`]).
#[derive(Debug, thiserror::Error)]
pub enum EmbedError {
    #[error(transparent)]
    Scenario(#[from] crate::scenario::ScenarioError),
    #[error(transparent)]
    Run(#[from] RunError),
}

/// Runs `loaded` into the MCAP log `log` (written as `log.partial`, renamed when complete;
/// never over the scenario, its model or a foreign file) and into `sinks`, then analyses the
/// log: the run path of `mjsafe run` ([`crate::run`]), with its policy for a failing sink. A
/// run stopped early (see [`Outcome::summary`]) still returns its metrics.
pub fn run_logged(loaded: &LoadedScenario, log: &Path, sinks: &mut [&mut dyn Sink]) -> Result<Outcome, EmbedError> {
    let further: Vec<Box<dyn Sink + '_>> = sinks.iter_mut().map(|s| Box::new(&mut **s) as Box<dyn Sink>).collect();
    Ok(crate::run::run(loaded, Keep::Log(log), further)?)
}
