//! Falsification: search a scenario's parameter box for a run that violates safety, instead of
//! sampling it. A search ([`Method`]: the guided search of [`guided`] by default, CMA-ES from
//! the `cmaes` crate, or uniform draws) minimises an analysis metric (the robustness: `min_h`
//! by default, or a requirement's `req.<name>`) over the `--range` keys; a candidate whose metric falls
//! below the threshold T is a violation. With a baseline (the same candidate under other
//! overrides, e.g. without delays), a candidate counts (is *qualified*) only where the baseline
//! is safe by its own threshold T_b (`--baseline-threshold`, default 0): m_baseline ≥ T_b,
//! independent of T. The optimiser minimises m − T for qualified candidates (so after the
//! first violation it keeps pushing severity), and max(m − T, 0) + (T_b − m_baseline) > 0 for
//! the others (never a violation, ordered toward qualification and toward m < T).
//! The baseline can also be required to make progress ([`BaselineProgress`]): a baseline that
//! stays safe by stalling (or never reaches the goal) disqualifies the candidate too.
//!
//! Determinism: a candidate's result depends only on its parameters (each run is seeded by the
//! scenario), every method samples from its own seeded generator, and a generation's
//! evaluations are numbered in an order of their parameters and the seed, not of their
//! completion: the same seed gives the same search on any number of threads.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use serde::Serialize;

use crate::analyze::{Cell, FlatMetrics};
use crate::random::SplitMix64;
use crate::sweep::{self, Range, Run};

pub mod guided;
pub mod surrogate;

#[derive(Debug, thiserror::Error)]
pub enum FalsifyError {
    #[error("--objective {name}: {message}")]
    Objective { name: String, message: String },
    #[error("{0}")]
    Spec(String),
    #[error(transparent)]
    Sweep(#[from] sweep::SweepError),
    #[error(transparent)]
    Scenario(#[from] crate::scenario::ScenarioError),
    #[error("{path}: {reason}")]
    Io { path: String, reason: std::io::Error },
    #[error("the optimiser: {0}")]
    Optimiser(String),
    #[error("{0}")]
    Output(String),
}

/// How candidates are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// A first generation spread over the box, trisection of the boundary between candidates
    /// that hold and candidates whose baseline fails too, a local model of the score in a trust
    /// region (a Gaussian process, Thompson-sampled) alternating with uniform draws, and once a
    /// trisection shows noise only uniform draws where the baseline held, with the smallest
    /// baseline margin nearby ([`guided`]).
    Guided,
    /// CMA-ES on the box mapped to [0, 1]^d (reflected at the bounds), restarted with a doubled
    /// population (IPOP) when it converges before the budget is spent.
    Cmaes,
    /// Uniform draws from the box (the baseline the optimiser must beat).
    Random,
}

impl Method {
    /// The method `--method` names (guided, cmaes, random).
    pub fn from_flag(flag: &str) -> Option<Method> {
        match flag {
            "guided" => Some(Method::Guided),
            "cmaes" => Some(Method::Cmaes),
            "random" => Some(Method::Random),
            _ => None,
        }
    }

    /// Its name for people.
    pub fn name(self) -> &'static str {
        match self {
            Method::Guided => "guided search",
            Method::Cmaes => "CMA-ES",
            Method::Random => "random search",
        }
    }
}

/// What to search and how.
#[derive(Debug, Clone)]
pub struct Problem {
    pub scenario: PathBuf,
    /// Overrides applied to every candidate before its own.
    pub set: Vec<String>,
    pub ranges: Vec<Range>,
    /// The metric minimised (a column of `analyze --csv`).
    pub objective: String,
    /// A candidate violates when its metric is below this, by more than `tolerance`.
    pub threshold: f64,
    /// How far below the threshold a metric must be to count as a violation (round-off
    /// grazes of 1e-6 do not; [`DEFAULT_TOLERANCE`]).
    pub tolerance: f64,
    /// The baseline is safe (the candidate qualified) when its metric is at least this.
    pub baseline_threshold: f64,
    /// Overrides of the reference configuration (applied after the candidate's); empty: none.
    pub baseline: Vec<String>,
    /// Most evaluations (rounded up to whole CMA-ES generations).
    pub budget: usize,
    pub seed: u64,
    pub threads: usize,
    /// Keep searching after the first violation for the worst one.
    pub worst: bool,
    /// What the baseline must do besides staying safe.
    pub baseline_progress: BaselineProgress,
    /// How candidates are chosen.
    pub method: Method,
    /// How many distinct failure modes to find (1: the first violation, or the worst).
    pub counterexamples: usize,
}

/// What `mjsafe falsify` is given (its flags, as the command line spells them), before the
/// checks that make it a [`Problem`]: the command line and the embeddings (the Python
/// package) check it alike.
#[derive(Debug, Clone)]
pub struct Request {
    pub scenario: PathBuf,
    /// `--range KEY=LO..HI[:STEP]`.
    pub ranges: Vec<String>,
    /// `--set KEY=VALUE`.
    pub set: Vec<String>,
    pub objective: String,
    pub threshold: f64,
    /// `--tolerance`.
    pub tolerance: f64,
    pub budget: usize,
    pub seed: u64,
    /// None: every core.
    pub threads: Option<usize>,
    pub worst: bool,
    pub baseline_threshold: f64,
    /// `--baseline KEY=VALUE`.
    pub baseline: Vec<String>,
    pub baseline_no_stall: bool,
    pub baseline_reaches_goal: bool,
    /// `--method`.
    pub method: Method,
    /// `--counterexamples K`.
    pub counterexamples: usize,
}

impl Request {
    /// The problem, every argument checked and the scenario loaded with the overrides; and the
    /// scenario's name (of the default output directory).
    pub fn problem(self) -> Result<(Problem, String), FalsifyError> {
        let Request {
            scenario,
            ranges,
            set,
            objective,
            threshold,
            tolerance,
            budget,
            seed,
            threads,
            worst,
            baseline_threshold,
            baseline,
            baseline_no_stall,
            baseline_reaches_goal,
            method,
            counterexamples,
        } = self;
        let spec = |message: String| FalsifyError::Spec(message);
        let ranges = ranges
            .iter()
            .map(|r| sweep::parse_range(r))
            .collect::<Result<Vec<_>, _>>()?;
        if let Some(twice) = sweep::swept_twice(ranges.iter().map(|r| r.key.as_str())) {
            return Err(spec(format!(
                "--range {twice}: the key is given twice (each key takes one --range)"
            )));
        }
        check_objective(&objective)?;
        if !threshold.is_finite() {
            return Err(spec(format!(
                "--threshold: expected a finite number, found {threshold}"
            )));
        }
        if !(tolerance.is_finite() && tolerance >= 0.0) {
            return Err(spec(format!(
                "--tolerance: expected a finite number >= 0 (in the objective's unit), found {tolerance}"
            )));
        }
        if !baseline_threshold.is_finite() {
            return Err(spec(format!(
                "--baseline-threshold: expected a finite number, found {baseline_threshold}"
            )));
        }
        let threads = sweep::threads(threads)?;
        if !(1..=MAX_COUNTEREXAMPLES).contains(&counterexamples) {
            return Err(spec(format!(
                "--counterexamples: expected 1 to {MAX_COUNTEREXAMPLES} failure modes, found {counterexamples}"
            )));
        }
        // The scenario and every override are checked once before the search starts.
        let base = crate::scenario::load(&scenario, &set)?;
        // `--objective req.NAME`: NAME is a requirement of the runs, and every requirement's
        // signals exist (one short run), before the budget is spent.
        if let Some(name) = metric_and_sign(&objective).0.strip_prefix("req.") {
            let names: Vec<&str> = base.scenario.requirements.iter().map(|r| r.name.as_str()).collect();
            if !names.contains(&name) {
                return Err(spec(format!(
                    "--objective {objective}: no requirement `{name}` (the runs' requirements: {}; add one with --require {name}=FORMULA)",
                    if names.is_empty() { "none".to_string() } else { names.join(", ") }
                )));
            }
        }
        crate::run::check_requirement_signals(&base).map_err(|e| spec(format!("{}: {e}", scenario.display())))?;
        for (given, flag) in [
            (baseline_no_stall, "--baseline-no-stall"),
            (baseline_reaches_goal, "--baseline-reaches-goal"),
        ] {
            if given && baseline.is_empty() {
                return Err(spec(format!(
                    "{flag}: a requirement of the baseline; give the baseline with --baseline KEY=VALUE"
                )));
            }
        }
        if baseline_reaches_goal && base.scenario.goal.is_none() {
            return Err(spec(format!(
                "--baseline-reaches-goal: {} has no [goal] (add one, or --set \"goal={{position=[x, y], radius=r}}\")",
                scenario.display()
            )));
        }
        if let Some((group, _)) = metric_and_sign(&objective).0.split_once('.') {
            // A per-channel metric names a channel of the vehicle: told by one run of the
            // scenario as given (when it runs), not by a whole budget of absent values.
            let run = Run {
                index: 0,
                overrides: set.clone(),
                parameters: Vec::new(),
            };
            let row = sweep::execute_analysed(&scenario, &run, "the scenario's run");
            if let Some(metrics) = &row.metrics {
                let columns = FlatMetrics::columns([metrics]);
                if !columns.iter().any(|c| c == metric_and_sign(&objective).0) {
                    let prefix = format!("{group}.");
                    let known: Vec<&str> = columns
                        .iter()
                        .map(String::as_str)
                        .filter(|c| c.starts_with(&prefix))
                        .collect();
                    return Err(spec(format!(
                        "--objective {objective}: not a metric of this scenario's runs; its per-channel {group} metrics: {}",
                        if known.is_empty() { "none".to_string() } else { known.join(", ") }
                    )));
                }
            }
        }
        let problem = Problem {
            scenario,
            set,
            ranges,
            objective,
            threshold,
            tolerance,
            baseline_threshold,
            baseline,
            budget,
            seed,
            threads,
            worst,
            baseline_progress: BaselineProgress {
                no_stall: baseline_no_stall,
                reach_goal: baseline_reaches_goal,
            },
            method,
            counterexamples,
        };
        Ok((problem, base.scenario.name))
    }
}

/// Progress the baseline must make for a candidate to count (a delay-free filter can stay
/// "safe" only by stalling in front of the obstacle).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct BaselineProgress {
    /// Its run has no `stall_time` (`--baseline-no-stall`).
    pub no_stall: bool,
    /// Its `distance_to_goal` is 0: it entered the goal disc, by the goal's `by`; for a goal
    /// without a region, it has a `time_to_goal` (`--baseline-reaches-goal`; the scenario
    /// needs a `[goal]`).
    pub reach_goal: bool,
}

impl BaselineProgress {
    /// Why the baseline's run (its flat metrics) fails the requirement, and the penalty it adds
    /// to the score (1 for a stall; the distance to the goal in m, at least 1e-3, for a missed
    /// goal); None when it meets it.
    pub fn failure(&self, baseline: &FlatMetrics) -> Option<(String, f64)> {
        let mut reasons = Vec::new();
        let mut penalty = 0.0;
        if self.no_stall {
            if let Some(t) = baseline.number("stall_time") {
                reasons.push(format!("the baseline stalled from t = {t} s"));
                penalty += 1.0;
            }
        }
        if self.reach_goal {
            match baseline.number("distance_to_goal") {
                Some(d) if d <= 0.0 => {}
                Some(d) => {
                    reasons.push(format!("the baseline stayed {d:.3} m from the goal"));
                    penalty += d.max(1e-3);
                }
                // A goal without a region has no distance: reaching it is its time.
                None if baseline.number("time_to_goal").is_some() => {}
                None => {
                    reasons.push("the baseline's run has no distance_to_goal and never reached the goal".into());
                    penalty += 1.0;
                }
            }
        }
        (!reasons.is_empty()).then(|| (reasons.join("; "), penalty))
    }
}

/// The metrics `--objective` accepts: the numeric columns of the flat metrics.
pub fn check_objective(objective: &str) -> Result<(), FalsifyError> {
    let (name, _) = metric_and_sign(objective);
    let probe = FlatMetrics::columns(std::iter::empty());
    let numeric = FlatMetrics::is_numeric_column;
    let known = probe.iter().any(|c| c == name) || name.contains('.');
    if !known || !numeric(name) {
        let names: Vec<&str> = probe.iter().map(String::as_str).filter(|c| numeric(c)).collect();
        return Err(FalsifyError::Objective {
            name: objective.into(),
            message: format!(
                "expected a numeric metric of `mjsafe analyze`, or -<metric> to search for large values: {} (or a per-channel one such as max_correction.<channel>)",
                names.join(", ")
            ),
        });
    }
    Ok(())
}

/// One evaluated candidate.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Evaluation {
    /// Position in the search (0-based).
    pub index: usize,
    /// CMA-ES generation (random search: batch) it belongs to.
    pub generation: usize,
    /// Range key → value (TOML text), in the order of the ranges.
    pub parameters: Vec<(String, String)>,
    /// The objective metric of the candidate, if its log has it.
    pub objective: Option<f64>,
    /// The same metric of the baseline configuration (with a baseline).
    pub baseline: Option<f64>,
    /// What the optimiser minimised: m − T for a qualified candidate (negative exactly for a
    /// counterexample), a positive penalty for one whose baseline is unsafe.
    pub score: f64,
    /// Whether the candidate counts: its baseline is safe and makes the progress required
    /// (always, without a baseline).
    pub qualified: bool,
    /// Why the baseline failed the progress required of it ([`BaselineProgress`]), if it did.
    pub baseline_progress: Option<String>,
    /// Qualified and objective below the threshold.
    pub violation: bool,
    /// How severe the candidate's run is, whatever the objective.
    pub severity: Severity,
    /// Why the objective is absent (run failed, metric not in the log, …).
    pub error: Option<String>,
    /// How the candidate's run fails: what it first collided with, else the barrier of its
    /// lowest h (`min_h_by_barrier`); absent without a barrier.
    pub failure_mode: Option<String>,
    /// Seconds of h < 0 within the delay after an obstacle appeared
    /// (`delay_attributed_violation_time` > 0): a violation no filter with that delay could
    /// avoid, flagged (it still counts).
    pub within_delay: Option<f64>,
    /// The candidate's point in the box, each range mapped to [0, 1].
    #[serde(skip)]
    pub point: Vec<f64>,
}

/// The default `--tolerance`: a candidate violates when its objective is this far below the
/// threshold (1e-4 of the objective's unit: 0.1 mm² of min h); `--tolerance 0` counts every
/// graze.
pub const DEFAULT_TOLERANCE: f64 = 1e-4;

/// Most failure modes `--counterexamples` may ask for.
pub const MAX_COUNTEREXAMPLES: usize = 100;

/// Two violations are distinct failure modes when they fail differently (their
/// [`Evaluation::failure_mode`]) or lie this far apart in some coordinate of the box (a
/// quarter of its range).
pub const MODE_SEPARATION: f64 = 0.25;

impl Evaluation {
    /// The largest difference of a coordinate between two candidates, in box units.
    pub fn box_distance(&self, other: &Evaluation) -> f64 {
        self.point
            .iter()
            .zip(&other.point)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
    }

    /// Whether two violations are distinct failure modes ([`MODE_SEPARATION`]).
    pub fn distinct_from(&self, other: &Evaluation) -> bool {
        self.failure_mode != other.failure_mode || self.box_distance(other) >= MODE_SEPARATION
    }
}

/// How a run fails: the object of its first collision, else the barrier of its lowest h.
fn failure_mode(metrics: &FlatMetrics) -> Option<String> {
    if let Cell::Text(Some(with)) = metrics.cell("collision_with") {
        return Some(format!("collision with {with}"));
    }
    FlatMetrics::columns([metrics])
        .iter()
        .filter_map(|c| c.strip_prefix("min_h_by_barrier.").map(|b| (b, metrics.number(c))))
        .filter_map(|(b, h)| h.map(|h| (b, h)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(barrier, _)| format!("lowest h: {barrier}"))
}

/// The severity of a run: its lowest barrier value and its first collision, if any.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Severity {
    /// min h over the run (the barrier's unit).
    pub min_h: Option<f64>,
    /// Time of the first collision (s), absent without one.
    pub collision_time: Option<f64>,
    /// Deepest penetration of the first collision (m), absent without one.
    pub collision_depth: Option<f64>,
}

impl Severity {
    fn of(metrics: &FlatMetrics) -> Severity {
        Severity {
            min_h: metrics.number("min_h"),
            collision_time: metrics.number("collision_time"),
            collision_depth: metrics.number("collision_depth"),
        }
    }

    /// "min h −0.54, collision at 5.12 s, 0.031 m deep" (or "no collision").
    pub fn describe(&self) -> String {
        let min_h = self
            .min_h
            .map_or("min h absent".to_string(), |v| format!("min h {v:.4}"));
        match (self.collision_time, self.collision_depth) {
            (Some(t), depth) => format!(
                "{min_h}, collision at {t:.3} s, {} deep",
                depth.map_or("depth absent".to_string(), |d| format!("{d:.4} m"))
            ),
            (None, _) => format!("{min_h}, no collision"),
        }
    }
}

/// A finished (or interrupted) search.
#[derive(Debug, Clone, Serialize)]
pub struct Search {
    pub method: Method,
    pub evaluations: Vec<Evaluation>,
    /// Whether Ctrl-C / SIGTERM stopped it.
    pub interrupted: bool,
    /// What the search cost in time (not in the evaluations' files: it differs run to run).
    #[serde(skip)]
    pub cost: SearchCost,
}

/// What a search cost in time: the candidates' runs against the whole search. With one thread
/// (`--threads 1`) the search's own work — proposing candidates, its model, its bookkeeping —
/// is `wall_seconds - run_seconds`; with more, the threads also wait for a generation's
/// slowest run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SearchCost {
    /// The search from its first candidate to its end (s; the pre-flight check left out).
    pub wall_seconds: f64,
    /// The candidates' evaluations (each run and its baseline), summed over the threads (s).
    pub run_seconds: f64,
    /// The threads that ran candidates.
    pub threads: usize,
}

impl SearchCost {
    /// The search's own work (s) when one thread ran every candidate; None with more.
    pub fn own_seconds(&self) -> Option<f64> {
        (self.threads == 1).then(|| (self.wall_seconds - self.run_seconds).max(0.0))
    }
}

impl Search {
    /// The first violation in search order.
    pub fn first_violation(&self) -> Option<&Evaluation> {
        self.evaluations.iter().find(|e| e.violation)
    }

    /// Evaluations up to and including the first violation.
    pub fn runs_to_first_violation(&self) -> Option<usize> {
        self.first_violation().map(|e| e.index + 1)
    }

    /// The most severe violation: the lowest objective among the qualified candidates below
    /// the threshold (the worst counterexample evaluated).
    pub fn worst_violation(&self) -> Option<&Evaluation> {
        self.evaluations.iter().filter(|e| e.violation).min_by(|a, b| {
            let objective = |e: &Evaluation| e.objective.unwrap_or(f64::INFINITY);
            objective(a).total_cmp(&objective(b))
        })
    }

    /// Up to `k` distinct failure modes ([`Evaluation::distinct_from`]): the violations taken
    /// in search order (with `worst`: most severe first), each kept when it is distinct from
    /// every one kept before it. The first is [`Search::first_violation`] (with `worst`:
    /// [`Search::worst_violation`]).
    pub fn failure_modes(&self, k: usize, worst: bool) -> Vec<&Evaluation> {
        let mut violations: Vec<&Evaluation> = self.evaluations.iter().filter(|e| e.violation).collect();
        if worst {
            // Stable: among equal objectives the earlier one first, as worst_violation does.
            violations.sort_by(|a, b| {
                let objective = |e: &Evaluation| e.objective.unwrap_or(f64::INFINITY);
                objective(a).total_cmp(&objective(b))
            });
        }
        let mut modes: Vec<&Evaluation> = Vec::new();
        for v in violations {
            if modes.len() == k {
                break;
            }
            if modes.iter().all(|m| v.distinct_from(m)) {
                modes.push(v);
            }
        }
        modes
    }

    /// The candidate with the lowest score among those with an objective.
    pub fn best(&self) -> Option<&Evaluation> {
        self.evaluations
            .iter()
            .filter(|e| e.objective.is_some())
            .min_by(|a, b| a.score.total_cmp(&b.score))
    }

    /// Best score after each evaluation (for the convergence plot).
    pub fn best_so_far(&self) -> Vec<f64> {
        let mut best = f64::INFINITY;
        self.evaluations
            .iter()
            .map(|e| {
                if e.objective.is_some() {
                    best = best.min(e.score);
                }
                best
            })
            .collect()
    }
}

/// Score of a candidate whose objective is absent: worse than any real one (a real score is
/// a difference of finite metrics and thresholds), never a violation. Written as an empty
/// CSV cell.
const ABSENT_SCORE: f64 = f64::MAX;

/// u ∈ R → [0, 1], reflected at the bounds (period 2).
fn reflect(z: f64) -> f64 {
    let r = z.rem_euclid(2.0);
    if r > 1.0 {
        2.0 - r
    } else {
        r
    }
}

/// The value of `range` at u ∈ [0, 1], as TOML text (quantised ranges: the nearest multiple
/// of STEP from LO not above HI).
pub fn range_value(range: &Range, u: f64) -> String {
    match range.step {
        None => format!("{:?}", range.lo + u * (range.hi - range.lo)),
        Some(step) => {
            let choices = ((range.hi - range.lo) / step + 1e-9).floor();
            sweep::step_value(range, (u * choices).round().clamp(0.0, choices) as u64)
        }
    }
}

/// The numeric value of metric `name` (a column of `analyze --csv`), if the run has one.
fn objective_value(metrics: &FlatMetrics, objective: &str) -> Option<f64> {
    let (name, sign) = metric_and_sign(objective);
    match metrics.cell(name) {
        Cell::Num(v) => v.map(|v| sign * v),
        Cell::Int(v) => v.map(|v| sign * v as f64),
        _ => None,
    }
}

/// An objective names a metric, minimised, or `-<metric>`: its negation, minimised (a search
/// for large values, e.g. `-distance_to_goal` or `-stall_time`).
pub fn metric_and_sign(objective: &str) -> (&str, f64) {
    match objective.strip_prefix('-') {
        Some(name) => (name, -1.0),
        None => (objective, 1.0),
    }
}

/// The search's evaluator: runs candidates (and their baselines) and scores them.
struct Evaluator<'a> {
    problem: &'a Problem,
    scenario: &'a Path,
    /// Numbers the candidates' runs (names in their errors).
    next_run: AtomicUsize,
    /// Wall time inside the candidates' evaluations (their runs and baselines), summed over
    /// the threads (ns).
    run_nanos: AtomicU64,
}

impl Evaluator<'_> {
    fn parameters(&self, unit: &[f64]) -> Vec<(String, String)> {
        self.problem
            .ranges
            .iter()
            .zip(unit)
            .map(|(r, &u)| (r.key.clone(), range_value(r, u)))
            .collect()
    }

    /// The metric of one run of the scenario with `overrides` and the run's severity, or why
    /// there is no metric.
    fn metric(&self, overrides: Vec<String>) -> Result<(f64, Severity, FlatMetrics), String> {
        let index = self.next_run.fetch_add(1, Ordering::Relaxed);
        let run = Run {
            index,
            overrides,
            parameters: Vec::new(),
        };
        // Analysed as it runs: the metrics its log would give, without writing one.
        let row = sweep::execute_analysed(self.scenario, &run, &format!("candidate {index}"));
        if let Some(e) = row.error {
            return Err(e);
        }
        let metrics = row.metrics.ok_or("the run gave no metrics")?;
        let value = objective_value(&metrics, &self.problem.objective).ok_or_else(|| {
            format!(
                "the run has no {} (a candidate is analysed without a log: `mjsafe run` the scenario with its overrides and `mjsafe analyze --json` that log to see its metrics)",
                self.problem.objective
            )
        })?;
        Ok((value, Severity::of(&metrics), metrics))
    }

    /// Runs the candidates at `units` in parallel on `pool`, in their order.
    fn evaluate_all(&self, pool: &rayon::ThreadPool, units: Vec<Vec<f64>>) -> Vec<Evaluation> {
        use rayon::prelude::*;
        pool.install(|| units.into_par_iter().map(|u| self.evaluate(&u)).collect())
    }

    /// What CMA-ES minimises: the score of the candidate at x reflected into the box; each
    /// evaluation is kept in `batch` (its generation's evaluations).
    fn cmaes_objective<'a>(
        &'a self,
        batch: &'a Mutex<Vec<Evaluation>>,
    ) -> impl Fn(&cmaes::DVector<f64>) -> f64 + Sync + 'a {
        move |x| {
            let unit: Vec<f64> = x.iter().map(|&z| reflect(z)).collect();
            let e = self.evaluate(&unit);
            let score = e.score;
            batch.lock().unwrap_or_else(|p| p.into_inner()).push(e);
            score
        }
    }

    /// Runs the candidate at `unit` (and its baseline) and scores it, adding its wall time to
    /// `run_nanos`.
    fn evaluate(&self, unit: &[f64]) -> Evaluation {
        let started = Instant::now();
        let evaluation = self.evaluate_untimed(unit);
        let nanos = u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.run_nanos.fetch_add(nanos, Ordering::Relaxed);
        evaluation
    }

    fn evaluate_untimed(&self, unit: &[f64]) -> Evaluation {
        let parameters = self.parameters(unit);
        let candidate: Vec<String> = self
            .problem
            .set
            .iter()
            .cloned()
            .chain(parameters.iter().map(|(k, v)| format!("{k}={v}")))
            .collect();
        let threshold = self.problem.threshold;
        let mut evaluation = Evaluation {
            index: 0,
            generation: 0,
            parameters,
            objective: None,
            baseline: None,
            score: ABSENT_SCORE,
            qualified: false,
            baseline_progress: None,
            violation: false,
            severity: Severity::default(),
            error: None,
            failure_mode: None,
            within_delay: None,
            point: unit.to_vec(),
        };
        let objective = match self.metric(candidate.clone()) {
            Ok((v, severity, metrics)) => {
                evaluation.severity = severity;
                evaluation.failure_mode = failure_mode(&metrics);
                evaluation.within_delay = metrics.number("delay_attributed_violation_time").filter(|t| *t > 0.0);
                v
            }
            Err(e) => {
                evaluation.error = Some(e);
                return evaluation;
            }
        };
        evaluation.objective = Some(objective);
        evaluation.score = objective - threshold;
        evaluation.qualified = true;
        if !self.problem.baseline.is_empty() {
            let overrides = candidate
                .into_iter()
                .chain(self.problem.baseline.iter().cloned())
                .collect();
            match self.metric(overrides) {
                Ok((b, _, metrics)) => {
                    evaluation.baseline = Some(b);
                    let unsafe_by = self.problem.baseline_threshold - b;
                    let stuck = self.problem.baseline_progress.failure(&metrics);
                    evaluation.qualified = unsafe_by <= 0.0 && stuck.is_none();
                    if !evaluation.qualified {
                        let penalty = stuck.as_ref().map_or(0.0, |(_, p)| *p);
                        evaluation.score = (objective - threshold).max(0.0) + unsafe_by.max(0.0) + penalty;
                    }
                    evaluation.baseline_progress = stuck.map(|(why, _)| why);
                }
                Err(e) => {
                    evaluation.error = Some(format!("baseline: {e}"));
                    evaluation.score = ABSENT_SCORE;
                    evaluation.qualified = false;
                    return evaluation;
                }
            }
        }
        // A violation lies beyond the tolerance: a round-off graze is not a failure.
        evaluation.violation = evaluation.qualified && objective < threshold - self.problem.tolerance;
        evaluation
    }
}

/// Order of a generation's evaluations: a parallel batch has none of its own, so they are
/// sorted by their unit coordinates (not by which thread finished first) and then put in a
/// random order seeded by the search's seed and the generation. Sorted alone, the count of
/// runs to the first violation favoured problems whose violations lie at low values of the
/// first range (gamma_m_underestimate: run 1 for every seed).
fn canonical_order(batch: &mut [Evaluation], seed: u64, generation: usize) {
    batch.sort_by(|a, b| {
        a.point
            .iter()
            .zip(&b.point)
            .map(|(x, y)| x.total_cmp(y))
            .find(|o| o.is_ne())
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let mut generator = SplitMix64(seed ^ 0x0D0E_5EED ^ (generation as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    for k in (1..batch.len()).rev() {
        batch.swap(k, generator.below(k + 1));
    }
}

/// Runs one search. `progress` is called after every generation with the search so far.
pub fn search(problem: &Problem, method: Method, mut progress: impl FnMut(&Search)) -> Result<Search, FalsifyError> {
    if problem.ranges.is_empty() {
        return Err(FalsifyError::Spec(
            "nothing to search: give at least one --range KEY=LO..HI".into(),
        ));
    }
    if problem.budget == 0 {
        return Err(FalsifyError::Spec("--budget: expected at least 1 evaluation".into()));
    }
    // Every candidate applies the same keys: one that the scenario rejects (an unknown key,
    // a value of the wrong type) is an error now, not a budget of failed runs.
    // The episode is assembled too: channel names and other model-dependent keys are checked.
    let centre: Vec<String> = problem
        .set
        .iter()
        .cloned()
        .chain(
            problem
                .ranges
                .iter()
                .map(|r| format!("{}={}", r.key, range_value(r, 0.5))),
        )
        .collect();
    let with_baseline: Vec<String> = centre.iter().chain(&problem.baseline).cloned().collect();
    for overrides in [&centre, &with_baseline] {
        let loaded =
            crate::scenario::load(&problem.scenario, overrides).map_err(|e| FalsifyError::Spec(e.to_string()))?;
        crate::run::Prepared::check(&loaded).map_err(|e| FalsifyError::Spec(e.to_string()))?;
    }
    let evaluator = Evaluator {
        problem,
        scenario: &problem.scenario,
        next_run: AtomicUsize::new(0),
        run_nanos: AtomicU64::new(0),
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(problem.threads.max(1))
        .thread_name(|i| format!("falsify-{i}"))
        .stack_size(16 << 20)
        .build()
        .map_err(|e| FalsifyError::Optimiser(e.to_string()))?;
    let mut found = Search {
        method,
        evaluations: Vec::new(),
        interrupted: false,
        cost: SearchCost::default(),
    };
    let started = Instant::now();
    let result = match method {
        Method::Guided => guided::run_guided(problem, &evaluator, &pool, &mut found, &mut progress),
        Method::Cmaes => run_cmaes(problem, &evaluator, &pool, &mut found, &mut progress),
        Method::Random => run_random(problem, &evaluator, &pool, &mut found, &mut progress),
    };
    result?;
    found.cost = SearchCost {
        wall_seconds: started.elapsed().as_secs_f64(),
        run_seconds: evaluator.run_nanos.load(Ordering::Relaxed) as f64 * 1e-9,
        threads: pool.current_num_threads(),
    };
    Ok(found)
}

/// Whether the search should stop after the evaluations so far.
fn done(problem: &Problem, found: &mut Search) -> bool {
    if crate::episode::stop_requested() {
        found.interrupted = true;
        return true;
    }
    found.evaluations.len() >= problem.budget
        || (!problem.worst && found.failure_modes(problem.counterexamples, false).len() >= problem.counterexamples)
}

/// Appends a generation's evaluations in canonical order.
fn append(found: &mut Search, seed: u64, generation: usize, mut batch: Vec<Evaluation>) {
    canonical_order(&mut batch, seed, generation);
    for mut e in batch {
        e.index = found.evaluations.len();
        e.generation = generation;
        found.evaluations.push(e);
    }
}

fn run_random(
    problem: &Problem,
    evaluator: &Evaluator<'_>,
    pool: &rayon::ThreadPool,
    found: &mut Search,
    progress: &mut impl FnMut(&Search),
) -> Result<(), FalsifyError> {
    let d = problem.ranges.len();
    let batch_size = population_size(d);
    let mut generator = SplitMix64(problem.seed ^ 0x005E_ED0F_F41F);
    let mut generation = 0;
    while !done(problem, found) {
        let count = batch_size.min(problem.budget - found.evaluations.len());
        let batch = evaluator.evaluate_all(pool, uniform_points(&mut generator, count, d));
        append(found, problem.seed, generation, batch);
        generation += 1;
        progress(found);
    }
    Ok(())
}

/// λ = 4 + ⌊3 ln d⌋ (Hansen's default), at least 8: enough candidates per generation to keep
/// the cores busy; it depends on d only, never on the thread count.
fn population_size(d: usize) -> usize {
    (4 + (3.0 * (d as f64).ln()).floor() as usize).max(8)
}

/// The population of a CMA-ES restart: doubled (IPOP), never beyond what is left of the
/// budget (a generation runs whole), never below λ.
fn doubled_population(population: usize, problem: &Problem, found: &Search) -> usize {
    let left = problem.budget.saturating_sub(found.evaluations.len());
    (population * 2).min(left.max(population_size(problem.ranges.len())))
}

/// `count` uniform points of the d-dimensional unit box.
fn uniform_points(generator: &mut SplitMix64, count: usize, d: usize) -> Vec<Vec<f64>> {
    (0..count)
        .map(|_| (0..d).map(|_| generator.next_f64()).collect())
        .collect()
}

/// CMA-ES from `mean` (box units, step size 0.3) over `objective`, seeded.
fn cmaes_from<F: cmaes::ObjectiveFunction>(
    mean: Vec<f64>,
    population: usize,
    seed: u64,
    objective: F,
) -> Result<cmaes::CMAES<F>, FalsifyError> {
    cmaes::CMAESOptions::new(mean, 0.3)
        .population_size(population)
        .seed(seed)
        .build(objective)
        .map_err(|e| FalsifyError::Optimiser(format!("{e:?}")))
}

fn run_cmaes(
    problem: &Problem,
    evaluator: &Evaluator<'_>,
    pool: &rayon::ThreadPool,
    found: &mut Search,
    progress: &mut impl FnMut(&Search),
) -> Result<(), FalsifyError> {
    let d = problem.ranges.len();
    let mut population = population_size(d);
    let mut restart_generator = SplitMix64(problem.seed ^ 0xC0DE_5EED);
    let mut generation = 0;
    for restart in 0u64.. {
        if done(problem, found) {
            break;
        }
        // The first run starts at the box's centre, restarts at a seeded random point.
        let mean: Vec<f64> = if restart == 0 {
            vec![0.5; d]
        } else {
            (0..d).map(|_| restart_generator.next_f64()).collect()
        };
        let batch: Mutex<Vec<Evaluation>> = Mutex::new(Vec::new());
        let objective = evaluator.cmaes_objective(&batch);
        let mut optimiser = cmaes_from(mean, population, problem.seed.wrapping_add(restart), &objective)?;
        loop {
            let terminated = pool.install(|| optimiser.next_parallel());
            let evaluated = std::mem::take(&mut *batch.lock().unwrap_or_else(|p| p.into_inner()));
            append(found, problem.seed, generation, evaluated);
            generation += 1;
            progress(found);
            if done(problem, found) || terminated.is_some() {
                break;
            }
        }
        population = doubled_population(population, problem, found);
    }
    Ok(())
}

/// The counterexample as a standalone scenario: the scenario with the base and candidate
/// overrides applied, the model path made absolute, and a comment naming the search.
pub fn counterexample_text(
    problem: &Problem,
    evaluation: &Evaluation,
    search_line: &str,
) -> Result<String, FalsifyError> {
    let overrides: Vec<String> = problem
        .set
        .iter()
        .cloned()
        .chain(evaluation.parameters.iter().map(|(k, v)| format!("{k}={v}")))
        .collect();
    let loaded =
        crate::scenario::load(&problem.scenario, &overrides).map_err(|e| FalsifyError::Output(e.to_string()))?;
    let mut scenario = loaded.scenario.clone();
    // Paths made absolute so that the counterexample runs from wherever it is written (a
    // built-in model is its name).
    if let Some(model) = loaded.model_path().filter(|m| !crate::models::is_builtin(m)) {
        let absolute = std::fs::canonicalize(&model).map_err(|reason| FalsifyError::Io {
            path: model.display().to_string(),
            reason,
        })?;
        scenario.vehicle.model = Some(absolute);
    }
    if let (Some(file), Some(spec)) = (loaded.commonroad_path(), scenario.commonroad.as_mut()) {
        spec.file = std::fs::canonicalize(&file).map_err(|reason| FalsifyError::Io {
            path: file.display().to_string(),
            reason,
        })?;
    }
    let body = toml::to_string(&scenario).map_err(|e| FalsifyError::Output(e.to_string()))?;
    let mut text = String::new();
    text.push_str(&format!(
        "# Counterexample found by `mjsafe falsify` ({}, index {} in evaluations.csv): {} = {}{}\n",
        "CMA-ES",
        evaluation.index,
        problem.objective,
        evaluation.objective.map_or("absent".into(), |v| format!("{v}")),
        evaluation
            .baseline
            .map_or(String::new(), |b| format!(" (baseline {b})")),
    ));
    text.push_str(&format!("# severity: {}\n", evaluation.severity.describe()));
    text.push_str(&format!("# search: {search_line}\n"));
    for (k, v) in &evaluation.parameters {
        text.push_str(&format!("# {k} = {v}\n"));
    }
    text.push_str(&format!(
        "# from {} with every override applied\n",
        problem.scenario.display()
    ));
    text.push_str(&crate::scenario::load_lines(&scenario));
    text.push_str(&body);
    Ok(text)
}

/// The evaluations as CSV: index, generation, method, each range key, objective, baseline,
/// score, violation, error.
pub fn evaluations_csv_text(searches: &[&Search], problem: &Problem) -> String {
    let mut rows = vec![["method", "index", "generation"]
        .iter()
        .map(|s| s.to_string())
        .chain(problem.ranges.iter().map(|r| r.key.clone()))
        .chain(
            [
                problem.objective.as_str(),
                "baseline",
                "score",
                "qualified",
                "violation",
                "baseline_progress",
                "candidate_min_h",
                "candidate_collision_time",
                "candidate_collision_depth",
                "failure_mode",
                "error",
            ]
            .iter()
            .map(|s| s.to_string()),
        )
        .collect::<Vec<_>>()];
    for search in searches {
        for e in &search.evaluations {
            let number = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v}"));
            rows.push(
                [
                    search.method.name().to_string(),
                    e.index.to_string(),
                    e.generation.to_string(),
                ]
                .into_iter()
                .chain(e.parameters.iter().map(|(_, v)| v.clone()))
                .chain([
                    number(e.objective),
                    number(e.baseline),
                    if e.score == ABSENT_SCORE {
                        String::new()
                    } else {
                        format!("{}", e.score)
                    },
                    e.qualified.to_string(),
                    e.violation.to_string(),
                    e.baseline_progress.clone().unwrap_or_default(),
                    number(e.severity.min_h),
                    number(e.severity.collision_time),
                    number(e.severity.collision_depth),
                    e.failure_mode.clone().unwrap_or_default(),
                    e.error.clone().unwrap_or_default(),
                ])
                .collect(),
            );
        }
    }
    crate::table::csv_lines(&rows)
}

/// Best score so far against evaluations, one line per search, with the zero line below which
/// a candidate violates: a PNG or an SVG, as `path`'s extension says.
pub fn convergence_figure(path: &Path, searches: &[&Search], objective: &str, score: &str) -> Result<(), FalsifyError> {
    let curves: Vec<(String, Vec<(f64, f64)>)> = searches
        .iter()
        .map(|s| {
            let points = s
                .best_so_far()
                .into_iter()
                .enumerate()
                .filter(|(_, v)| v.is_finite() && *v < ABSENT_SCORE)
                .map(|(i, v)| ((i + 1) as f64, v))
                .collect();
            (s.method.name().to_string(), points)
        })
        .collect();
    crate::plot::line_chart_figure(
        path,
        &format!("Falsification: best {objective} so far (violation below 0)"),
        ("evaluations (runs)", &format!("best score so far: {score}")),
        &curves,
    )
    .map_err(|e| FalsifyError::Output(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn violation(index: usize, point: [f64; 2], objective: f64, mode: &str) -> Evaluation {
        Evaluation {
            index,
            generation: 0,
            parameters: Vec::new(),
            objective: Some(objective),
            baseline: None,
            score: objective,
            qualified: true,
            baseline_progress: None,
            violation: objective < 0.0,
            severity: Severity::default(),
            error: None,
            failure_mode: Some(mode.into()),
            within_delay: None,
            point: point.to_vec(),
        }
    }

    #[test]
    fn failure_modes_are_violations_a_quarter_of_a_range_apart_or_failing_differently() {
        let evaluations = vec![
            violation(0, [0.50, 0.50], -0.1, "collision with a"),
            violation(1, [0.60, 0.40], -0.9, "collision with a"), // within 0.25 of #0
            violation(2, [0.50, 0.80], -0.2, "collision with a"), // 0.30 from #0 in y
            violation(3, [0.55, 0.55], 0.4, "collision with a"),  // not a violation
            violation(4, [0.52, 0.48], -0.3, "collision with b"), // fails differently
        ];
        let search = Search {
            method: Method::Guided,
            evaluations,
            interrupted: false,
            cost: SearchCost::default(),
        };
        let indices = |modes: Vec<&Evaluation>| modes.iter().map(|e| e.index).collect::<Vec<_>>();
        assert_eq!(indices(search.failure_modes(10, false)), [0, 2, 4]);
        assert_eq!(indices(search.failure_modes(2, false)), [0, 2]);
        // Most severe first: #1 (−0.9), then #4 (another object), then #2 (0.4 from #1 in y).
        assert_eq!(indices(search.failure_modes(10, true)), [1, 4, 2]);
        assert_eq!(
            search.failure_modes(1, true)[0].index,
            search.worst_violation().unwrap().index
        );
    }

    #[test]
    fn a_generations_order_depends_on_its_points_and_seed_not_on_completion() {
        let batch = |order: &[usize]| -> Vec<Evaluation> {
            order
                .iter()
                .map(|&i| violation(i, [i as f64 / 10.0, 0.0], 1.0, ""))
                .collect()
        };
        let ordered = |mut b: Vec<Evaluation>, seed| {
            canonical_order(&mut b, seed, 3);
            b.iter().map(|e| e.index).collect::<Vec<_>>()
        };
        let a = ordered(batch(&[0, 1, 2, 3, 4, 5, 6, 7]), 1);
        assert_eq!(a, ordered(batch(&[7, 3, 5, 1, 0, 2, 6, 4]), 1));
        let mut sorted = a.clone();
        sorted.sort();
        assert_eq!(sorted, (0..8).collect::<Vec<_>>());
        assert_ne!(a, sorted, "a random order, not the coordinates' (seed 1)");
        assert_ne!(a, ordered(batch(&[0, 1, 2, 3, 4, 5, 6, 7]), 2));
    }

    #[test]
    fn reflection_keeps_candidates_in_the_box() {
        for (z, u) in [(0.25, 0.25), (1.25, 0.75), (-0.25, 0.25), (2.5, 0.5), (-1.75, 0.25)] {
            assert!((reflect(z) - u).abs() < 1e-12, "{z}");
        }
    }

    #[test]
    fn quantised_ranges_give_multiples_of_the_step() {
        let r = Range {
            key: "delays.acceleration".into(),
            lo: 0.0,
            hi: 1.5,
            step: Some(0.1),
        };
        assert_eq!(range_value(&r, 0.0), "0.0");
        assert_eq!(range_value(&r, 1.0), "1.5");
        assert_eq!(range_value(&r, 0.2), "0.3");
        let c = Range {
            step: None,
            ..r.clone()
        };
        assert_eq!(range_value(&c, 0.5), "0.75");
        let seeds = Range {
            key: "seed".into(),
            lo: 0.0,
            hi: 1000.0,
            step: Some(1.0),
        };
        assert_eq!(range_value(&seeds, 0.5), "500");
    }

    #[test]
    fn an_unknown_or_text_objective_is_refused_with_the_choices() {
        assert!(check_objective("min_h").is_ok());
        assert!(check_objective("max_correction.steering").is_ok());
        let e = check_objective("min_hh").unwrap_err().to_string();
        assert!(e.contains("min_clearance"), "{e}");
        assert!(check_objective("collision_with").is_err());
    }
}

/// What `mjsafe falsify` wrote and found.
#[derive(Debug)]
pub struct Report {
    pub searches: Vec<Search>,
    /// The counterexamples written, one per failure mode (the first: the first violation, or
    /// with `worst` the most severe one).
    pub counterexamples: Vec<Counterexample>,
    /// Ctrl-C came during a counterexample's run: its log is incomplete.
    pub rerun_interrupted: bool,
    pub evaluations_csv: PathBuf,
    pub evaluations_json: PathBuf,
    pub convergence_png: Option<PathBuf>,
}

/// One failure mode written as a scenario and its log.
#[derive(Debug)]
pub struct Counterexample {
    /// The evaluation it is.
    pub evaluation: Evaluation,
    /// The scenario file (`counterexample.toml`, then `counterexample-2.toml`, …).
    pub scenario: PathBuf,
    /// Its log, re-run from the file.
    pub log: PathBuf,
    /// The objective of its own run from the file (None when not re-run: interrupted).
    pub reproduced: Option<f64>,
}

/// How the outputs start: existing files that start otherwise are never replaced.
const CSV_START: &[u8] = b"method,index,";
const JSON_START: &[u8] = b"{\n  \"mjsafe_version\"";
const SCENARIO_START: &[u8] = b"# Counterexample found by `mjsafe falsify`";

/// The files a search writes into its directory.
struct Outputs {
    /// Each failure mode's scenario and log.
    counterexamples: Vec<(PathBuf, PathBuf)>,
    csv: PathBuf,
    json: PathBuf,
    png: PathBuf,
    /// The same figure as SVG.
    svg: PathBuf,
}

impl Outputs {
    fn in_dir(dir: &Path, modes: usize) -> Outputs {
        Outputs {
            counterexamples: (1..=modes)
                .map(|k| {
                    let name = if k == 1 {
                        "counterexample".to_string()
                    } else {
                        format!("counterexample-{k}")
                    };
                    (dir.join(format!("{name}.toml")), dir.join(format!("{name}.mcap")))
                })
                .collect(),
            csv: dir.join("evaluations.csv"),
            json: dir.join("evaluations.json"),
            png: dir.join("convergence.png"),
            svg: dir.join("convergence.svg"),
        }
    }

    /// Each output may be written: absent, or a file of the kind it replaces.
    fn check(&self, problem: &Problem) -> Result<(), FalsifyError> {
        use crate::files::{check_output, Replace};
        let inputs = [problem.scenario.as_path()];
        let checks = [
            (&self.csv, "falsification evaluations", CSV_START),
            (&self.json, "falsification evaluations", JSON_START),
            (&self.png, "PNG plot", crate::plot::PNG_MAGIC),
            (&self.svg, "SVG plot", crate::plot::SVG_MAGIC),
        ];
        let scenarios = self
            .counterexamples
            .iter()
            .map(|(scenario, _)| (scenario, "counterexample scenario", SCENARIO_START));
        for (path, what, start) in scenarios.chain(checks) {
            check_output(path, what, Replace::IfStartsWith(start), &inputs)
                .map_err(|e| FalsifyError::Output(e.to_string()))?;
        }
        for (_, log) in &self.counterexamples {
            crate::log::mcap::check_target(log, &inputs).map_err(|e| FalsifyError::Output(e.to_string()))?;
        }
        Ok(())
    }
}

#[derive(Serialize)]
struct EvaluationsFile<'a> {
    mjsafe_version: &'static str,
    scenario: String,
    set: &'a [String],
    ranges: &'a [Range],
    objective: &'a str,
    threshold: f64,
    baseline_threshold: f64,
    baseline: &'a [String],
    baseline_progress: BaselineProgress,
    budget: usize,
    seed: u64,
    searches: Vec<SearchSummary<'a>>,
}

#[derive(Serialize)]
struct SearchSummary<'a> {
    method: Method,
    evaluations_run: usize,
    runs_to_first_violation: Option<usize>,
    best_score: Option<f64>,
    interrupted: bool,
    evaluations: &'a [Evaluation],
}

/// Writes evaluations.csv and evaluations.json of the searches; returns their paths.
fn write_evaluations(
    problem: &Problem,
    searches: &[Search],
    outputs: &Outputs,
) -> Result<(PathBuf, PathBuf), FalsifyError> {
    let refs: Vec<&Search> = searches.iter().collect();
    let evaluations_csv = outputs.csv.clone();
    crate::files::write_atomically(
        &evaluations_csv,
        "falsification evaluations",
        crate::files::Replace::IfStartsWith(CSV_START),
        &[],
        evaluations_csv_text(&refs, problem).as_bytes(),
    )
    .map_err(|e| FalsifyError::Output(e.to_string()))?;
    let file = EvaluationsFile {
        mjsafe_version: env!("CARGO_PKG_VERSION"),
        scenario: problem.scenario.display().to_string(),
        set: &problem.set,
        ranges: &problem.ranges,
        objective: &problem.objective,
        threshold: problem.threshold,
        baseline_threshold: problem.baseline_threshold,
        baseline: &problem.baseline,
        baseline_progress: problem.baseline_progress,
        budget: problem.budget,
        seed: problem.seed,
        searches: searches
            .iter()
            .map(|s| SearchSummary {
                method: s.method,
                evaluations_run: s.evaluations.len(),
                runs_to_first_violation: s.runs_to_first_violation(),
                best_score: s.best().map(|e| e.score),
                interrupted: s.interrupted,
                evaluations: &s.evaluations,
            })
            .collect(),
    };
    let json = serde_json::to_string_pretty(&file).map_err(|e| FalsifyError::Output(e.to_string()))? + "\n";
    let evaluations_json = outputs.json.clone();
    crate::files::write_atomically(
        &evaluations_json,
        "falsification evaluations",
        crate::files::Replace::IfStartsWith(JSON_START),
        &[],
        json.as_bytes(),
    )
    .map_err(|e| FalsifyError::Output(e.to_string()))?;
    Ok((evaluations_csv, evaluations_json))
}

/// The search (and with `compare_random` random search with the same budget and seed), its
/// outputs in `dir`: the counterexample as a scenario file plus its log (re-run from the file),
/// every evaluation as CSV and JSON, and the convergence plot.
pub fn falsify(
    problem: &Problem,
    dir: &Path,
    search_line: &str,
    compare_random: bool,
    mut progress: impl FnMut(&Search),
) -> Result<Report, FalsifyError> {
    if dir.exists() && !dir.is_dir() {
        return Err(FalsifyError::Output(format!(
            "--out {}: expected a directory for the search's outputs, found a file",
            dir.display()
        )));
    }
    std::fs::create_dir_all(dir).map_err(|reason| FalsifyError::Io {
        path: dir.display().to_string(),
        reason,
    })?;
    crate::files::check_writable_dir(dir).map_err(|reason| {
        FalsifyError::Output(format!(
            "--out {}: cannot write the search's outputs there: {reason}",
            dir.display()
        ))
    })?;
    // Every output is checked before the first run: the search is never lost to a file in
    // the way.
    let outputs = Outputs::in_dir(dir, problem.counterexamples);
    outputs.check(problem)?;
    let mut searches = vec![search(problem, problem.method, &mut progress)?];
    if compare_random && problem.method != Method::Random && !searches[0].interrupted {
        searches.push(search(problem, Method::Random, &mut progress)?);
    }
    let refs: Vec<&Search> = searches.iter().collect();
    let (evaluations_csv, evaluations_json) = write_evaluations(problem, &searches, &outputs)?;
    let png = outputs.png.clone();
    let convergence_png = if searches.iter().any(|s| s.best().is_some()) {
        let score = if problem.baseline.is_empty() {
            format!("{} − threshold", problem.objective)
        } else {
            format!("m − T, baseline safe (m = {})", problem.objective)
        };
        convergence_figure(&png, &refs, &problem.objective, &score)?;
        convergence_figure(&outputs.svg, &refs, &problem.objective, &score)?;
        Some(png)
    } else {
        None
    };
    let modes: Vec<Evaluation> = searches[0]
        .failure_modes(problem.counterexamples, problem.worst)
        .into_iter()
        .cloned()
        .collect();
    let interrupted = searches.iter().any(|s| s.interrupted);
    let mut counterexamples = Vec::new();
    let mut rerun_interrupted = false;
    for (e, (scenario, log)) in modes.into_iter().zip(&outputs.counterexamples) {
        let text = counterexample_text(problem, &e, search_line)?;
        let inputs = [problem.scenario.as_path()];
        crate::files::write_atomically(
            scenario,
            "counterexample scenario",
            crate::files::Replace::IfStartsWith(SCENARIO_START),
            &inputs,
            text.as_bytes(),
        )
        .map_err(|e| FalsifyError::Output(e.to_string()))?;
        // The written file alone reproduces the run (no overrides); after Ctrl-C the file is
        // kept but not re-run (the stop request would end that run too).
        let mut reproduced = None;
        if !interrupted && !rerun_interrupted {
            let file_name = log
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            reproduced = rerun(problem, &e, scenario, dir, file_name)?;
            rerun_interrupted = reproduced.is_none();
        }
        counterexamples.push(Counterexample {
            evaluation: e,
            scenario: scenario.clone(),
            log: log.clone(),
            reproduced,
        });
    }
    Ok(Report {
        searches,
        counterexamples,
        rerun_interrupted,
        evaluations_csv,
        evaluations_json,
        convergence_png,
    })
}

/// Re-runs a written counterexample `scenario` into `dir/file_name` and checks that it
/// reproduces the search's metric (to 1e-9 relative): its objective, or None when Ctrl-C
/// ended the run (its log is then incomplete).
fn rerun(
    problem: &Problem,
    e: &Evaluation,
    scenario: &Path,
    dir: &Path,
    file_name: String,
) -> Result<Option<f64>, FalsifyError> {
    let run = Run {
        index: 0,
        overrides: Vec::new(),
        parameters: Vec::new(),
    };
    let row = sweep::execute_logged(scenario, &run, dir, file_name);
    if crate::episode::stop_requested() {
        return Ok(None);
    }
    let reproduced = row
        .metrics
        .as_ref()
        .and_then(|m| objective_value(m, &problem.objective));
    // The search's own value, bit for bit up to round-off, or the file is not the run.
    let expected = e.objective;
    let same = matches!((reproduced, expected), (Some(a), Some(b)) if (a - b).abs() <= 1e-9 * (1.0 + b.abs()));
    if let (false, Some(error)) = (same, &row.error) {
        return Err(FalsifyError::Output(format!(
            "{}: the counterexample's run failed: {error} (evaluations written)",
            scenario.display()
        )));
    }
    if !same {
        let shown = |v: Option<f64>| v.map_or("absent".to_string(), |v| format!("{v:e}"));
        return Err(FalsifyError::Output(format!(
            "{}: the written counterexample does not reproduce the search's run ({} = {} in the search, {} from the file; evaluations written)",
            scenario.display(),
            problem.objective,
            shown(expected),
            shown(reproduced)
        )));
    }
    Ok(reproduced)
}
