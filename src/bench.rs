//! End-to-end speed of one scenario (issue 9), measured in one process on one thread:
//!
//! - `bare`: `mj_step` (or the ODE plant's RK4) over the episode's own model for the same number
//!   of steps, with no controller and no logging, replaying the actuation (`ctrl`) an untimed
//!   run of the episode recorded, so it follows the same trajectory and meets the same contacts;
//! - `pipeline`: the full episode (delay queues, predictors, filters, nominal, events) with
//!   no sink;
//! - `pipeline_mcap`: the same with the MCAP sink writing the complete log (its chunks are
//!   compressed and written on a writer thread; that thread's busy time is reported too).
//!
//! Each is repeated and the median wall time reported, with the real-time factor (simulated
//! time / wall time) and the ratio to `bare`. Several predictor steps and chain-reuse
//! tolerances can be compared in one call: each row then also reports the prediction error the
//! log measures (Definition 4.3) and, from an audited untimed run, the largest difference chain
//! reuse made to a prediction.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use crate::analyze;
use crate::episode::EpisodeError;
use crate::log::LogError;
use crate::run::{Keep, Outcome, Prepared, RunError};
use crate::scenario::{self, LoadedScenario, ScenarioError};

#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error(transparent)]
    Episode(#[from] EpisodeError),
    #[error(transparent)]
    Log(#[from] LogError),
    #[error(transparent)]
    Analyze(#[from] analyze::AnalyzeError),
    #[error(transparent)]
    Run(#[from] RunError),
    #[error("the episode stopped early: {0}")]
    Stopped(String),
}

/// Median wall time of one configuration and what follows from it.
#[derive(Debug, Clone, Serialize)]
pub struct Timing {
    pub wall_seconds: f64,
    pub real_time_factor: f64,
    pub microseconds_per_step: f64,
    /// Median over the repeats of wall time / the same repeat's bare-loop wall time (each
    /// repeat times the bare loop and the runs back to back, so a machine that slows down
    /// between repeats moves both).
    pub ratio_to_bare: f64,
    /// First and third quartiles of those per-repeat ratios: the spread on this machine.
    pub ratio_quartiles: [f64; 2],
}

/// One benchmarked configuration (scenario with one predictor step).
#[derive(Debug, Clone, Serialize)]
pub struct BenchRow {
    pub scenario: String,
    /// RK4 step of the predictors, seconds.
    pub predictor_step: f64,
    /// control.chain_tolerance of the recursive predictors.
    pub chain_tolerance: f64,
    /// Predictions made from a reused chain in the audited run.
    pub reused_predictions: u64,
    /// Largest max-norm difference between a reused prediction and the whole-window
    /// recomputation at the same tick (audited run; 0 when nothing was reused).
    pub chain_reuse_error: f64,
    pub steps: u64,
    pub simulated_time: f64,
    pub repeats: usize,
    pub bare: Timing,
    /// |x_bare(T) − x(T)|: how closely the bare loop's replayed actuation followed the run.
    pub bare_final_state_deviation: f64,
    pub pipeline: Timing,
    pub pipeline_mcap: Timing,
    /// The run analysed in memory instead of logged (`analyze::AnalysisSink`, its metrics
    /// included): what a falsification candidate costs.
    pub pipeline_analysed: Timing,
    /// Median time the MCAP writer thread spent compressing, writing and syncing chunks (the
    /// syncs wait for the disk) while the episode ran (the work `pipeline_mcap` did not wait for).
    pub writer_thread_seconds: f64,
    /// Median over the repeats of (`pipeline_mcap` wall time + writer thread time) / bare: the
    /// whole cost of a logged run, what a core busy with another run (a sweep on every core) pays.
    pub pipeline_mcap_cpu_ratio: f64,
    /// What a sweep or falsification run pays before its first step (median): scenario parse,
    /// episode assembly with the MJCF compile, log open.
    pub startup_seconds: f64,
    /// Start-up as a share of the logged run's wall time.
    pub startup_share: f64,
    /// What it pays after the last step (median): analysing the log.
    pub analysis_seconds: f64,
    pub log_bytes: u64,
    /// Largest |p_i(t) − x(t + D_i)| over the run, per channel (from the log).
    pub max_prediction_error: std::collections::BTreeMap<String, f64>,
    pub min_h: Option<f64>,
    pub collision: bool,
}

/// The q-quantile of `samples` (linear between order statistics; q = 0.5 is the median).
fn quantile(samples: &[f64], q: f64) -> f64 {
    let mut sorted = samples.to_vec();
    sorted.sort_by(f64::total_cmp);
    let at = q * (sorted.len() - 1) as f64;
    let (below, above) = (at.floor() as usize, at.ceil() as usize);
    sorted[below] + (at - below as f64) * (sorted[above] - sorted[below])
}

fn median(samples: &[f64]) -> f64 {
    quantile(samples, 0.5)
}

/// Per-repeat `walls` against the same repeats' `bare` walls.
fn timing(walls: &[f64], simulated_time: f64, steps: u64, bare: &[f64]) -> Timing {
    let wall_seconds = median(walls);
    let ratios: Vec<f64> = walls.iter().zip(bare).map(|(w, b)| w / b).collect();
    Timing {
        wall_seconds,
        real_time_factor: simulated_time / wall_seconds,
        microseconds_per_step: wall_seconds / steps as f64 * 1e6,
        ratio_to_bare: median(&ratios),
        ratio_quartiles: [quantile(&ratios, 0.25), quantile(&ratios, 0.75)],
    }
}

/// Runs `loaded` into `keep` (the run path of every command, [`crate::run`]); an episode
/// that stops early is an error of the benchmark.
fn timed_run(loaded: &LoadedScenario, keep: Keep<'_>) -> Result<Outcome, BenchError> {
    let outcome = crate::run::run(loaded, keep, Vec::new())?;
    match &outcome.summary.error {
        Some(e) => Err(BenchError::Stopped(e.to_string())),
        None => Ok(outcome),
    }
}

/// Benchmarks `scenario` (with `overrides`) `repeats` times per configuration; the MCAP logs
/// go to `log_dir` (the last one of each configuration is kept and analysed).
pub fn run(
    scenario_path: &Path,
    overrides: &[String],
    predictor_steps: &[Option<f64>],
    chain_tolerances: &[Option<f64>],
    repeats: usize,
    log_dir: &Path,
) -> Result<Vec<BenchRow>, BenchError> {
    let repeats = repeats.max(1);
    let mut rows = Vec::new();
    let configurations = predictor_steps
        .iter()
        .flat_map(|step| chain_tolerances.iter().map(move |tolerance| (step, tolerance)));
    for (step, tolerance) in configurations {
        let mut overrides = overrides.to_vec();
        if let Some(step) = step {
            overrides.push(format!("control.predictor_step={step}"));
        }
        if let Some(tolerance) = tolerance {
            overrides.push(format!("control.chain_tolerance={tolerance:e}"));
        }
        let loaded = scenario::load(scenario_path, &overrides)?;
        // An untimed, audited run records the actuation the bare loop replays.
        let mut prepared = Prepared::new(&loaded, Keep::Nothing)?;
        // The logged repeats write a log each: over the log budget, refused before any run.
        prepared.check_log_budget()?;
        let mut probe = prepared.into_episode();
        let (steps, predictor_step) = (probe.steps(), probe.predictor_step());
        let chain_tolerance = loaded.scenario.control.chain_tolerance;
        let log_path = log_dir.join(format!(
            "bench-{}-{}-{:e}.mcap",
            loaded.scenario.name, predictor_step, chain_tolerance
        ));
        let input_files = loaded.inputs();
        let inputs: Vec<&Path> = input_files.iter().map(PathBuf::as_path).collect();
        // Checked before any run (the logged runs check again and open it exclusively).
        crate::log::mcap::check_target(&log_path, &inputs).map_err(LogError::from)?;
        let simulated_time = steps as f64 * probe.info().timestep;
        probe.record_actuation();
        probe.audit_chain_reuse();
        if let Some(e) = probe.run(&mut [])?.error {
            return Err(BenchError::Stopped(e.to_string()));
        }
        let (chain_reuse_error, reused_predictions) = probe.chain_audit().unwrap_or((0.0, 0));
        let actuation = probe.take_actuation();
        let recorded_final_state = probe.plant_state();
        drop(probe);
        let mut replay_deviation = 0.0;

        let mut bare = Vec::new();
        let mut pipeline = Vec::new();
        let mut pipeline_mcap = Vec::new();
        let (mut startup, mut analysis, mut writer_thread) = (Vec::new(), Vec::new(), Vec::new());
        let mut metrics = None;
        let mut analysed = Vec::new();
        for _ in 0..repeats {
            let mut episode = Prepared::new(&loaded, Keep::Nothing)?.into_episode();
            let started = Instant::now();
            episode.replay_actuation(&actuation)?;
            bare.push(started.elapsed().as_secs_f64());
            replay_deviation = (episode.plant_state() - &recorded_final_state).norm();

            pipeline.push(timed_run(&loaded, Keep::Nothing)?.timing.run_seconds);

            // As a falsification candidate: analysed as it runs, no log. Right after the
            // pipeline run it is compared with (after the logged run, the writer thread's
            // teardown and the page cache slowed the next run by 4–20 %, with no analysis at all).
            let in_memory = timed_run(&loaded, Keep::Metrics("the in-memory analysis"))?.timing;
            analysed.push(in_memory.run_seconds + in_memory.analysis_seconds);

            // As a sweep run: parse, assemble (MJCF compile), open the log; run; analyse.
            let started = Instant::now();
            let fresh = scenario::load(scenario_path, &overrides)?;
            let parse_seconds = started.elapsed().as_secs_f64();
            let logged = timed_run(&fresh, Keep::Log(&log_path))?;
            startup.push(parse_seconds + logged.timing.assemble_seconds);
            pipeline_mcap.push(logged.timing.run_seconds);
            writer_thread.push(logged.timing.writer_busy_seconds);
            analysis.push(logged.timing.analysis_seconds);
            metrics = logged.metrics;
        }
        let whole: Vec<f64> = (pipeline_mcap.iter().zip(&writer_thread).zip(&bare))
            .map(|((logged, writer), bare)| (logged + writer) / bare)
            .collect();
        let (startup, analysis, logged) = (median(&startup), median(&analysis), median(&pipeline_mcap));
        let writer_thread = median(&writer_thread);
        let metrics = metrics.expect("at least one logged repeat");
        rows.push(BenchRow {
            scenario: loaded.scenario.name.clone(),
            predictor_step,
            chain_tolerance,
            reused_predictions,
            chain_reuse_error,
            steps,
            simulated_time,
            repeats,
            bare: timing(&bare, simulated_time, steps, &bare),
            bare_final_state_deviation: replay_deviation,
            pipeline: timing(&pipeline, simulated_time, steps, &bare),
            pipeline_mcap: timing(&pipeline_mcap, simulated_time, steps, &bare),
            pipeline_analysed: timing(&analysed, simulated_time, steps, &bare),
            writer_thread_seconds: writer_thread,
            pipeline_mcap_cpu_ratio: median(&whole),
            startup_seconds: startup,
            startup_share: startup / logged,
            analysis_seconds: analysis,
            log_bytes: std::fs::metadata(&log_path).map(|m| m.len()).unwrap_or(0),
            max_prediction_error: metrics
                .prediction()
                .into_iter()
                .flatten()
                .map(|(channel, stats)| (channel.clone(), stats.max_error))
                .collect(),
            min_h: metrics.min_h(),
            collision: metrics.collision().is_some(),
        });
    }
    Ok(rows)
}

/// The rows as an aligned text table.
pub fn table(rows: &[BenchRow]) -> String {
    let mut lines = vec![[
        "scenario",
        "predictor step",
        "chain tol",
        "bare RTF",
        "pipeline RTF",
        "+MCAP RTF",
        "+MCAP / bare (quartiles)",
        "with writer thread",
        "analysed in memory / bare",
        "us/step",
        "start-up ms (% of run)",
        "analysis ms",
        "log MB",
        "max prediction error",
        "reused (max diff)",
        "min h",
    ]
    .map(String::from)
    .to_vec()];
    for r in rows {
        let errors: Vec<String> = r
            .max_prediction_error
            .iter()
            .map(|(channel, e)| format!("{channel} {e:.1e}"))
            .collect();
        lines.push(vec![
            r.scenario.clone(),
            format!("{}", r.predictor_step),
            format!("{:.0e}", r.chain_tolerance),
            format!("{:.0}x", r.bare.real_time_factor),
            format!("{:.0}x", r.pipeline.real_time_factor),
            format!("{:.0}x", r.pipeline_mcap.real_time_factor),
            format!(
                "{:.2} ({:.2}-{:.2})",
                r.pipeline_mcap.ratio_to_bare, r.pipeline_mcap.ratio_quartiles[0], r.pipeline_mcap.ratio_quartiles[1]
            ),
            format!("{:.2}", r.pipeline_mcap_cpu_ratio),
            format!("{:.2}", r.pipeline_analysed.ratio_to_bare),
            format!("{:.2}", r.pipeline_mcap.microseconds_per_step),
            format!("{:.1} ({:.0} %)", r.startup_seconds * 1e3, r.startup_share * 100.0),
            format!("{:.1}", r.analysis_seconds * 1e3),
            format!("{:.2}", r.log_bytes as f64 / 1e6),
            if errors.is_empty() {
                "-".into()
            } else {
                errors.join(", ")
            },
            format!("{} ({:.1e})", r.reused_predictions, r.chain_reuse_error),
            r.min_h.map_or("-".into(), |h| format!("{h:.4}")),
        ]);
    }
    crate::table::align_columns(&lines)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_interpolate_between_order_statistics() {
        let samples = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(median(&samples), 2.5);
        assert_eq!(quantile(&samples, 0.25), 1.75);
        assert_eq!(quantile(&samples, 0.75), 3.25);
        assert_eq!((quantile(&samples, 0.0), quantile(&samples, 1.0)), (1.0, 4.0));
        assert_eq!(median(&[7.0]), 7.0);
    }

    #[test]
    fn ratios_pair_each_run_with_its_own_bare_loop() {
        // The machine halves its speed during the second repeat, after its bare loop: the
        // paired ratios are 1.5, 3 and 1.5, median 1.5 (the medians' ratio would be 3 / 1).
        let bare = [1.0, 1.0, 2.0];
        let walls = [1.5, 3.0, 3.0];
        let t = timing(&walls, 10.0, 100, &bare);
        assert_eq!(t.wall_seconds, 3.0);
        assert_eq!(t.ratio_to_bare, 1.5);
        assert_eq!(t.ratio_quartiles, [1.5, 2.25]);
        let skewed = timing(&[1.0, 3.0, 2.0], 10.0, 100, &[1.0, 1.0, 1.0]);
        assert_eq!((skewed.ratio_to_bare, skewed.ratio_quartiles), (2.0, [1.5, 2.5]));
        assert_eq!(skewed.real_time_factor, 5.0);
    }
}
