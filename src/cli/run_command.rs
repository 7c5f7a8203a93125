//! `mjsafe run` and `mjsafe replay`: one scenario into its log (and rerun), a log back into rerun.

use super::*;
use crate::metrics::builtin::{REQUIREMENTS, REQUIREMENT_VIOLATED_AT};
use crate::metrics::Value;

/// Rerun outputs of `mjsafe run` (with the `rerun` feature); none given: nothing is built or sent.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct RerunArgs {
    /// Spawn a rerun viewer (a `rerun` binary on PATH) and stream the run to it.
    #[cfg(feature = "rerun")]
    #[arg(long)]
    pub rerun: bool,
    /// Stream the run to a running rerun viewer or server (e.g. rerun+http://127.0.0.1:9876/proxy).
    #[cfg(feature = "rerun")]
    #[arg(long, value_name = "URL")]
    pub rerun_connect: Option<String>,
    /// Save the run as a rerun recording (.rrd) next to the MCAP log.
    #[cfg(feature = "rerun")]
    #[arg(long, value_name = "FILE")]
    pub rrd: Option<PathBuf>,
}

impl RerunArgs {
    /// Checks the output files asked for before anything is created or simulated: an `.rrd`
    /// is not the MCAP log, not an input of the run, and replaceable (see [`crate::files`]).
    #[cfg(feature = "rerun")]
    fn check(&self, log_path: &Path, inputs: &[&Path]) -> Result<()> {
        if let Some(file) = &self.rrd {
            if crate::files::same_path(file, log_path) {
                bail!(
                    "--rrd {}: it is also the MCAP log's path (--out); choose another file",
                    file.display()
                );
            }
            crate::log::rerun::check_save_target(file, inputs)?;
        }
        Ok(())
    }

    #[cfg(not(feature = "rerun"))]
    fn check(&self, _log_path: &Path, _inputs: &[&Path]) -> Result<()> {
        Ok(())
    }

    /// The rerun sinks asked for (none without the `rerun` feature).
    #[cfg(feature = "rerun")]
    fn sinks(&self, log_path: &Path, info: &crate::log::RunInfo, inputs: &[&Path]) -> Result<Vec<Box<dyn Sink>>> {
        use crate::log::rerun::{recording_id, RerunSink, RerunTarget};
        let mut targets = Vec::new();
        if self.rerun {
            targets.push(RerunTarget::Spawn);
        }
        if let Some(url) = &self.rerun_connect {
            targets.push(RerunTarget::Connect(url.clone()));
        }
        if let Some(file) = &self.rrd {
            targets.push(RerunTarget::Save(file.clone()));
        }
        let id = recording_id(log_path);
        targets
            .into_iter()
            .map(|t| {
                // A file's errors name the file already.
                let what = (!matches!(t, RerunTarget::Save(_))).then(|| t.to_string());
                let sink = RerunSink::create_with_inputs(t, &id, info.timestep, inputs).map_err(anyhow::Error::from);
                let mut sink = match what {
                    Some(what) => sink.with_context(|| format!("opening the recording for {what}"))?,
                    None => sink?,
                };
                sink.declare_planar_position(info.planar_position);
                Ok(Box::new(sink) as Box<dyn Sink>)
            })
            .collect()
    }

    #[cfg(not(feature = "rerun"))]
    fn sinks(&self, _log_path: &Path, _info: &crate::log::RunInfo, _inputs: &[&Path]) -> Result<Vec<Box<dyn Sink>>> {
        Ok(Vec::new())
    }
}

/// How `mjsafe run` reports: the text line or JSON, and whether a collision fails the process.
#[derive(Debug, Clone, Copy)]
pub(super) struct RunOutput {
    json: bool,
    fail_on_collision: bool,
    fail_on_violation: bool,
}

/// A progress line on a terminal (stderr) for a run that takes more than two seconds: the
/// simulated time reached, the fraction done and the speed, once a second; cleared when the
/// value is dropped. Nothing when stderr is not a terminal.
pub(super) struct RunProgress {
    done: Option<(
        std::sync::Arc<std::sync::atomic::AtomicBool>,
        std::thread::JoinHandle<()>,
    )>,
}

impl RunProgress {
    fn start(steps: u64, timestep: f64) -> RunProgress {
        use std::io::IsTerminal;
        if !std::io::stderr().is_terminal() {
            return RunProgress { done: None };
        }
        let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = done.clone();
        let thread = std::thread::spawn(move || {
            let started = Instant::now();
            let mut shown = false;
            let mut next = std::time::Duration::from_secs(2);
            while !flag.load(std::sync::atomic::Ordering::Relaxed) {
                std::thread::sleep(std::time::Duration::from_millis(50));
                let elapsed = started.elapsed();
                if elapsed < next {
                    continue;
                }
                next = elapsed + std::time::Duration::from_secs(1);
                let step = episode::progress().min(steps);
                let simulated = step as f64 * timestep;
                eprint!(
                    "\r\x1b[Krun: t = {simulated:.2} s of {:.2} s ({:.0} %), {:.2}x real time",
                    steps as f64 * timestep,
                    100.0 * step as f64 / steps.max(1) as f64,
                    simulated / elapsed.as_secs_f64()
                );
                shown = true;
            }
            if shown {
                eprint!("\r\x1b[K");
            }
        });
        RunProgress {
            done: Some((done, thread)),
        }
    }
}

impl Drop for RunProgress {
    fn drop(&mut self) {
        if let Some((done, thread)) = self.done.take() {
            done.store(true, std::sync::atomic::Ordering::Relaxed);
            let _ = thread.join();
        }
    }
}

pub(super) fn run_scenario(
    path: &Path,
    overrides: &[String],
    out: Option<PathBuf>,
    rerun: &RerunArgs,
    report: RunOutput,
) -> Result<ExitCode> {
    let loaded = scenario::load(path, overrides)?;
    // A requirement naming no signal of the run: said before the run, not after it.
    crate::run::check_requirement_signals(&loaded).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    print_commonroad_notes(&loaded);
    let inputs = loaded.inputs();
    let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    let log_path = out.unwrap_or_else(|| episode::default_log_path(Path::new("logs"), &loaded.scenario.name));
    // Every output is checked before the model is loaded, and opened before the simulation.
    rerun.check(&log_path, &inputs)?;
    let prepared = crate::run::Prepared::new(&loaded, crate::run::Keep::Log(&log_path))?;
    let further = match rerun.sinks(&log_path, prepared.info(), &inputs) {
        Ok(sinks) => sinks,
        Err(e) => {
            prepared.abandon();
            return Err(e);
        }
    };
    let _progress = RunProgress::start(prepared.steps(), prepared.info().timestep);
    let outcome = prepared.run(further)?;
    drop(_progress);
    let summary = outcome.summary;
    let metrics = outcome.metrics.expect("a logged run is analysed");
    if report.json {
        let value = summary_json(&loaded.scenario.name, &summary, &metrics, &log_path);
        outln!("{value}");
    } else {
        outln!(
            "{}: {}{}{}{} | min h = {} | {} steps, {:.2} s simulated, {}x real time | log: {}",
            loaded.scenario.name,
            collision_text(&metrics),
            // Safe by not moving is said next to "no collision".
            metrics.number("stall_time").map_or(String::new(), |t| format!(
                ", but STALLED from t = {t:.2} s (held still by the filter)"
            )),
            match metrics.warnings.len() {
                0 => String::new(),
                n => format!(
                    " | {n} MUJOCO WARNING{}: physics not the model's",
                    if n > 1 { "S" } else { "" }
                ),
            },
            match goal_outcome(&metrics) {
                Some(Some(t)) => format!(" | goal reached at {t:.2} s"),
                Some(None) => " | goal NOT REACHED".to_string(),
                None => String::new(),
            },
            min_h_text(&metrics),
            summary.steps,
            summary.simulated_time,
            // Two significant digits below 10x (a slow run is not "0x").
            match summary.real_time_factor() {
                f if f < 10.0 => format!("{f:.2}"),
                f => format!("{f:.0}"),
            },
            log_path.display()
        );
    }
    if let Some(past) = metrics.past_vehicle_limits() {
        eprintln!("warning: {past}");
    }
    for warning in &metrics.warnings {
        eprintln!("warning: MuJoCo: {warning}; the run's metrics describe that physics, not the model's");
    }
    let requirements = requirement_values(&loaded, &metrics);
    if !report.json {
        for (name, value, at) in &requirements {
            match (value, at) {
                (Ok(r), Some(at)) if *r < 0.0 => {
                    outln!("requirement {name}: VIOLATED at t = {at:.3} s (robustness {r:.4})")
                }
                (Ok(r), _) => outln!(
                    "requirement {name}: {} (robustness {r:.4})",
                    if *r < 0.0 { "VIOLATED" } else { "satisfied" }
                ),
                (Err(reason), _) => outln!("requirement {name}: not evaluated ({reason})"),
            }
        }
    }
    if let Some(error) = summary.error {
        eprintln!("error: the episode stopped early: {error} (the log holds the run up to that point)");
        // 130: the shell's convention for a run ended by a signal.
        return Ok(if error == episode::StopReason::Interrupted {
            ExitCode::from(exit::INTERRUPTED)
        } else {
            ExitCode::from(exit::ERROR)
        });
    }
    if report.fail_on_collision {
        if let Some(c) = metrics.collision() {
            eprintln!(
                "error: --fail-on-collision: the run collided with {} at t = {:.3} s",
                c.with, c.time
            );
            return Ok(ExitCode::from(exit::COLLISION));
        }
    }
    if report.fail_on_violation {
        if let Some((name, Err(reason), _)) = requirements.iter().find(|(_, v, _)| v.is_err()) {
            eprintln!("error: --fail-on-violation: requirement {name} cannot be evaluated: {reason}");
            return Ok(ExitCode::from(exit::ERROR));
        }
        let violated: Vec<String> = (requirements.iter())
            .filter_map(|(name, v, at)| {
                let at = at.map(|t| format!(" at t = {t:.3} s")).unwrap_or_default();
                v.as_ref()
                    .ok()
                    .filter(|r| **r < 0.0)
                    .map(|r| format!("{name} ({r:.4}{at})"))
            })
            .collect();
        if !violated.is_empty() {
            eprintln!("error: --fail-on-violation: violated: {}", violated.join(", "));
            return Ok(ExitCode::from(exit::VIOLATION));
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// A requirement's name, its robustness (or why it has none) and, violated, when it failed.
type RequirementValue = (String, Result<f64, String>, Option<f64>);

/// Each requirement of the run, in the scenario's order: its robustness, or why it has none,
/// and the time it first failed.
fn requirement_values(loaded: &scenario::LoadedScenario, metrics: &RunMetrics) -> Vec<RequirementValue> {
    let per_name = |metric: &str| match metrics.value(metric) {
        Some(Value::PerChannel(Some(values))) => Some(values),
        _ => None,
    };
    let (values, times) = (per_name(REQUIREMENTS), per_name(REQUIREMENT_VIOLATED_AT));
    (loaded.scenario.requirements.iter())
        .map(|r| {
            let column = format!("{REQUIREMENTS}.{}", r.name);
            let value = values.and_then(|v| v.get(&r.name).copied()).ok_or_else(|| {
                metrics
                    .missing
                    .get(&column)
                    .cloned()
                    .unwrap_or_else(|| "no value".into())
            });
            let at = times.and_then(|t| t.get(&r.name).copied());
            (r.name.clone(), value, at)
        })
        .collect()
}

#[cfg(feature = "rerun")]
pub(super) fn replay(file: &Path, rrd: Option<PathBuf>, connect: Option<String>, recover: bool) -> Result<ExitCode> {
    use crate::log::rerun::RerunTarget;
    let target = match (rrd, connect) {
        (Some(out), _) => RerunTarget::Save(out),
        (None, Some(url)) => RerunTarget::Connect(url),
        (None, None) => RerunTarget::Spawn,
    };
    let what = target.to_string();
    let summary = crate::log::rerun::replay(file, target, recover)?;
    outln!(
        "replayed {} messages of {}{} into {what}",
        summary.messages,
        file.display(),
        match (&summary.damage, summary.complete) {
            (Some(_), _) => " (recovered before the damage)",
            (None, true) => "",
            (None, false) => " (an incomplete run)",
        }
    );
    if let Some(damage) = summary.damage {
        eprintln!("error: {damage}");
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

/// `mjsafe run`: Run one scenario headless; writes one MCAP log and prints a one-line summary.
#[derive(Debug, clap::Args)]
pub struct RunCommand {
    /// Scenario file (TOML).
    scenario: PathBuf,
    /// Override a field: KEY.PATH=VALUE in TOML value syntax, or a bare word as a string (`plant=ode`) (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Log file (default: logs/<name>-<UTC time>.mcap).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Print the summary as one JSON object on stdout instead of the text line.
    #[arg(long)]
    json: bool,
    /// Exit with 4 when the run collided (a CI gate); without it a collision exits 0.
    #[arg(long)]
    fail_on_collision: bool,
    /// A requirement: an STL formula over the run's signals, reported as `req.NAME` (its
    /// robustness; docs/requirements.md), added to the scenario's `[[requirements]]` (repeatable).
    #[arg(long = "require", value_name = "NAME=FORMULA")]
    require: Vec<String>,
    /// Exit with 5 when a requirement is violated (robustness < 0; a CI gate next to
    /// --fail-on-collision, which is checked first); 1 when one cannot be evaluated.
    #[arg(long)]
    fail_on_violation: bool,
    #[command(flatten)]
    rerun: RerunArgs,
}

impl RunCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let RunCommand {
            scenario,
            mut overrides,
            out,
            json,
            fail_on_collision,
            require,
            fail_on_violation,
            rerun,
        } = self;
        for flag in &require {
            overrides.push(scenario::require_override(flag)?);
        }
        run_scenario(
            &scenario,
            &overrides,
            out,
            &rerun,
            RunOutput {
                json,
                fail_on_collision,
                fail_on_violation,
            },
        )
    }
}

#[cfg(feature = "rerun")]
/// `mjsafe replay`: Rebuild the rerun recording of a run from its MCAP log alone (no re-simulation):
#[derive(Debug, clap::Args)]
pub struct ReplayCommand {
    /// The run's log (.mcap).
    file: PathBuf,
    /// Save the recording to this .rrd file.
    #[arg(long, value_name = "OUT", conflicts_with = "connect")]
    rrd: Option<PathBuf>,
    /// Stream to a running rerun viewer or server (e.g. rerun+http://127.0.0.1:9876/proxy).
    #[arg(long, value_name = "URL")]
    connect: Option<String>,
    /// On a damaged log, still replay (and keep the .rrd of) what was read before the
    /// damage; the exit status is still non-zero.
    #[arg(long)]
    recover: bool,
}

#[cfg(feature = "rerun")]
impl ReplayCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let ReplayCommand {
            file,
            rrd,
            connect,
            recover,
        } = self;
        replay(&file, rrd, connect, recover)
    }
}

/// What of a scenario's CommonRoad file mjsafe does not use, named on stderr (nothing of it is
/// dropped silently).
pub(super) fn print_commonroad_notes(loaded: &scenario::LoadedScenario) {
    if let (Some(cr), Some(file)) = (&loaded.commonroad, loaded.commonroad_path()) {
        for line in cr.remarks() {
            eprintln!("{}: {line}", file.display());
        }
    }
}

/// `run --json`'s object: the summary of the run, and the keys a run has only when they apply.
fn summary_json(
    name: &str,
    summary: &crate::episode::EpisodeSummary,
    metrics: &RunMetrics,
    log_path: &Path,
) -> serde_json::Value {
    let rtf = summary.real_time_factor();
    let mut value = serde_json::json!({
        "scenario": name,
        "collision": metrics.collision(),
        "min_h": metrics.min_h(),
        "min_h_by_barrier": metrics.min_h_by_barrier(),
        "steps": summary.steps,
        "simulated_time": summary.simulated_time,
        "real_time_factor": rtf.is_finite().then_some(rtf),
        "log": log_path.display().to_string(),
        "complete": summary.error.is_none(),
        "error": summary.error.as_ref().map(ToString::to_string),
    });
    // Only for a run that stalled, or with warnings, so the object of a clean run keeps
    // its keys.
    if let Some(t) = metrics.number("stall_time") {
        value["stall_time"] = serde_json::json!(t);
    }
    // Only for a run with a goal: when it reached it (null: not reached, `analyze` says
    // how close it came).
    if let Some(reached) = goal_outcome(metrics) {
        value["time_to_goal"] = serde_json::json!(reached);
    }
    // Only for a run whose filter received barrier rows: how many, and how many of road
    // users out of reach were left out.
    let rows = summary.barrier_rows;
    if rows.formed + rows.left_out > 0 {
        value["barrier_rows"] = serde_json::json!(rows);
    }
    // Only for a run with requirements: their robustness (null when absent: `missing`).
    if let Some(Value::PerChannel(values)) = metrics.value(REQUIREMENTS) {
        value["req"] = serde_json::json!(values);
    }
    if let Some(Value::PerChannel(Some(times))) = metrics.value(REQUIREMENT_VIOLATED_AT) {
        value[REQUIREMENT_VIOLATED_AT] = serde_json::json!(times);
    }
    if !metrics.warnings.is_empty() {
        value["warnings"] = serde_json::json!(metrics.warnings);
    }
    value
}

/// For a run with a goal, when it reached it (`time_to_goal`), or None inside when it did not;
/// None for a run without a goal.
fn goal_outcome(metrics: &RunMetrics) -> Option<Option<f64>> {
    match metrics.number("time_to_goal") {
        Some(t) => Some(Some(t)),
        None => metrics.missing.contains_key("time_to_goal").then_some(None),
    }
}

/// The summary line's collision: none, or the first one's time, road user and depth.
fn collision_text(metrics: &RunMetrics) -> String {
    metrics.collision().map_or("no collision".to_string(), |c| {
        format!(
            "COLLISION at t = {:.3} s with {} ({})",
            c.time,
            c.with,
            if c.depth.is_nan() {
                "depth not in the log".to_string()
            } else {
                format!("depth {:.3} m", c.depth)
            }
        )
    })
}

/// The summary line's min h: one number, or — the barriers' units differing — each barrier's,
/// or with many (a CommonRoad world's) the min clearance, one unit for all.
fn min_h_text(metrics: &RunMetrics) -> String {
    match (metrics.min_h(), metrics.min_h_by_barrier()) {
        (Some(h), _) => format!("{h:.3}"),
        (None, Some(by)) if by.len() > MAX_LISTED_BARRIERS => format!(
            "per barrier, {} of mixed units (`mjsafe analyze`); min clearance {}",
            by.len(),
            metrics
                .number("min_clearance")
                .map_or("-".into(), |c| format!("{c:.3} m"))
        ),
        (None, Some(by)) => by
            .iter()
            .map(|(name, h)| format!("{h:.3} ({name})"))
            .collect::<Vec<_>>()
            .join(", "),
        (None, None) => "-".into(),
    }
}

/// Most barriers the summary line lists one by one when their units differ.
const MAX_LISTED_BARRIERS: usize = 6;
