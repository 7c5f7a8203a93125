//! `mjsafe falsify`: the search, its outputs and its progress line.

use super::*;

/// The arguments of `mjsafe falsify`.
#[derive(Debug, clap::Args)]
pub struct FalsifyArgs {
    /// Scenario file (TOML).
    pub scenario: PathBuf,
    /// A searched parameter: KEY=LO..HI, or KEY=LO..HI:STEP for multiples of STEP from LO
    /// (same keys as `sweep`; repeatable, at least one).
    #[arg(long = "range", value_name = "KEY=LO..HI[:STEP]", required = true)]
    pub ranges: Vec<String>,
    /// Override applied to every candidate: KEY.PATH=VALUE in TOML value syntax, or a bare word as a string (`plant=ode`) (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// A requirement of every candidate (an STL formula, docs/requirements.md): with
    /// `--objective req.NAME` the search minimises its robustness (repeatable).
    #[arg(long = "require", value_name = "NAME=FORMULA")]
    pub require: Vec<String>,
    /// The metric minimised (a numeric column of `analyze --csv`): min_h, min_clearance,
    /// min_time_to_collision, progress_along_path, …; `-<metric>` minimises its negation, a
    /// search for large values: `--objective=-distance_to_goal --threshold=-5` looks for runs
    /// that end more than 5 m from the goal.
    #[arg(long, default_value = "min_h", allow_hyphen_values = true)]
    pub objective: String,
    /// A candidate violates when the objective is below this, by more than --tolerance.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub threshold: f64,
    /// How far below the threshold counts as a violation, in the objective's unit: a round-off
    /// graze (min h = −2e−6) is not a failure; 0 counts every one.
    #[arg(long, value_name = "T", default_value_t = crate::falsify::DEFAULT_TOLERANCE)]
    pub tolerance: f64,
    /// Most runs (rounded up to whole CMA-ES generations).
    #[arg(long, value_name = "N", default_value_t = 200)]
    pub budget: usize,
    /// Seed of the search (the optimiser's sampling and restarts).
    #[arg(long, value_name = "S", default_value_t = 0)]
    pub seed: u64,
    /// Runs executed at once (default: all cores); the result does not depend on it.
    #[arg(long, value_name = "K")]
    pub threads: Option<usize>,
    /// Keep searching after the first violation (pushing its severity) and report the worst
    /// qualified one evaluated: the lowest objective among candidates whose baseline is safe.
    #[arg(long)]
    pub worst: bool,
    /// The baseline is safe when its objective is at least this (default 0: the boundary of
    /// min_h and min_clearance), whatever --threshold is.
    #[arg(long, value_name = "TB", default_value_t = 0.0, allow_negative_numbers = true)]
    pub baseline_threshold: f64,
    /// The reference configuration of each candidate, as overrides applied after the
    /// candidate's (repeatable), e.g. --baseline delays.steering=0 --baseline
    /// delays.acceleration=0: only a candidate whose baseline stays safe is a counterexample.
    #[arg(long = "baseline", value_name = "KEY=VALUE")]
    pub baseline: Vec<String>,
    /// A candidate counts only where the baseline also does not stall (no `stall_time`: it is
    /// not held still by its filter; safe by not moving is not safe enough).
    #[arg(long)]
    pub baseline_no_stall: bool,
    /// A candidate counts only where the baseline also reaches the scenario's `[goal]`
    /// (`distance_to_goal` = 0).
    #[arg(long)]
    pub baseline_reaches_goal: bool,
    /// How candidates are chosen: guided (a spread first generation, trisection of the boundary
    /// where the baseline starts to fail, a local model of the score (a Gaussian process in a
    /// trust region) alternating with uniform draws; once a
    /// trisection shows that noise decides, only uniform draws where the baseline held, with
    /// the smallest margin nearby), cmaes (CMA-ES from the box's centre) or random (uniform
    /// draws).
    #[arg(long, value_enum, default_value_t = falsify::Method::Guided)]
    pub method: falsify::Method,
    /// Find up to K distinct failure modes (violations that fail differently or lie a quarter
    /// of a range apart), each written as counterexample[-k].toml with its log.
    #[arg(long, value_name = "K", default_value_t = 1)]
    pub counterexamples: usize,
    /// Also run random search with the same budget and seed, and compare runs to the first
    /// violation.
    #[arg(long)]
    pub compare_random: bool,
    /// Output directory (default: logs/falsify-<scenario name>).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

/// `arg` as a shell reads it back, on one line: as is when it holds only safe characters, in
/// single quotes (a quote inside written `'\''`) when it holds no control character, else
/// ANSI-C quoted (`$'…\n…'`: bash, zsh).
pub(super) fn shell_quoted(arg: &str) -> String {
    let safe = |c: char| c.is_ascii_alphanumeric() || "_-./=:,+@%".contains(c);
    if !arg.is_empty() && arg.chars().all(safe) {
        arg.to_string()
    } else if !arg.chars().any(char::is_control) {
        format!("'{}'", arg.replace('\'', "'\\''"))
    } else {
        // On one line: ANSI-C quoting (bash, zsh) spells the control characters out.
        let escaped: String = arg
            .chars()
            .map(|c| match c {
                '\\' => "\\\\".to_string(),
                '\'' => "\\'".to_string(),
                '\n' => "\\n".to_string(),
                '\t' => "\\t".to_string(),
                c if c.is_control() => format!("\\x{:02x}", u32::from(c)),
                c => c.to_string(),
            })
            .collect();
        format!("$'{escaped}'")
    }
}

/// `mjsafe falsify`: its checks, the problem, the search and the report.
impl FalsifyArgs {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        falsify_command(self)
    }
}

fn falsify_command(args: FalsifyArgs) -> Result<ExitCode> {
    let FalsifyArgs {
        scenario,
        ranges,
        mut overrides,
        require,
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
        compare_random,
        out,
    } = args;
    for flag in &require {
        overrides.push(scenario::require_override(flag)?);
    }
    let (problem, name) = falsify::Request {
        scenario,
        ranges,
        set: overrides,
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
    }
    .problem()?;
    let out = out.unwrap_or_else(|| Path::new("logs").join(format!("falsify-{name}")));
    run_falsify(&problem, &out, compare_random)
}

pub(super) fn run_falsify(problem: &falsify::Problem, out: &Path, compare_random: bool) -> Result<ExitCode> {
    let _graceful = episode::GracefulStop::begin();
    // The command line as a shell takes it back (quoted where needed).
    let search_line = std::iter::once("mjsafe".to_string())
        .chain(std::env::args().skip(1).map(|a| shell_quoted(&a)))
        .collect::<Vec<_>>()
        .join(" ");
    let started = Instant::now();
    let report = falsify::falsify(problem, out, &search_line, compare_random, |s| {
        let best = s.best().map_or("none yet".to_string(), |e| format!("{:.4}", e.score));
        let found = s
            .runs_to_first_violation()
            .map_or(String::new(), |n| format!(" | first violation at run {n}"));
        eprintln!(
            "{}: {} runs | best score {best}{found} | {:.1} s",
            s.method.name(),
            s.evaluations.len(),
            started.elapsed().as_secs_f64()
        );
    })
    .context("falsify")?;
    for s in &report.searches {
        let best = s.best();
        let qualified = s.evaluations.iter().filter(|e| e.qualified).count();
        let cost = &s.cost;
        outln!(
            "{}: {:.2} s in the runs of {:.2} s on {} thread{}{}",
            s.method.name(),
            cost.run_seconds,
            cost.wall_seconds,
            cost.threads,
            if cost.threads == 1 { "" } else { "s" },
            cost.own_seconds().map_or(String::new(), |own| format!(
                "; the search's own work {:.1} ms ({:.2} % of the wall time)",
                own * 1e3,
                100.0 * own / cost.wall_seconds.max(f64::MIN_POSITIVE)
            ))
        );
        outln!(
            "{}: {} runs, {qualified} qualified{}, {}; best {} = {}{}",
            s.method.name(),
            s.evaluations.len(),
            if problem.baseline.is_empty() {
                " (no baseline: every candidate with a metric)"
            } else {
                " (baseline safe and making the progress asked)"
            },
            s.runs_to_first_violation()
                .map_or("no violation".to_string(), |n| format!("first violation at run {n}")),
            problem.objective,
            best.and_then(|e| e.objective)
                .map_or("absent".into(), |v| format!("{v:.4}")),
            best.and_then(|e| e.baseline)
                .map_or(String::new(), |b| format!(" (baseline {b:.4})")),
        );
    }
    let first = if problem.worst { "most severe" } else { "first" };
    for (k, c) in report.counterexamples.iter().enumerate() {
        let e = &c.evaluation;
        outln!(
            "{} violation: index {} in evaluations.csv, {} = {}{} | {}{}",
            if k == 0 {
                first.to_string()
            } else {
                format!("failure mode {}", k + 1)
            },
            e.index,
            problem.objective,
            e.objective.map_or("absent".into(), |v| format!("{v:.4}")),
            e.baseline.map_or(String::new(), |b| format!(" (baseline {b:.4})")),
            e.severity.describe(),
            e.failure_mode.as_ref().map_or(String::new(), |m| format!(", {m}"))
        );
        if let Some(t) = e.within_delay {
            outln!(
                "note: h < 0 for {t:.3} s within the delay after an obstacle appeared: no filter with this delay could avoid that part (it still counts; add a baseline to count only the filter's own failures)"
            );
        }
        outln!(
            "counterexample: {} ({})",
            c.scenario.display(),
            match c.reproduced {
                Some(v) => format!("its run: {}, {} = {v:.4}", c.log.display(), problem.objective),
                None if report.rerun_interrupted =>
                    format!("its run was interrupted: {} is incomplete", c.log.display()),
                None => "not re-run: the search was interrupted".into(),
            }
        );
    }
    if report.counterexamples.is_empty() {
        let runs = report.searches[0].evaluations.len();
        let qualified = report.searches[0].evaluations.iter().filter(|e| e.qualified).count();
        // A search in which nothing qualified never tested the filter: it proves nothing.
        let what = if qualified == 0 {
            format!("no counterexample, and none of the {runs} candidates qualified: this proves nothing about the box")
        } else {
            format!("no counterexample within {runs} runs ({qualified} qualified)")
        };
        outln!(
            "{what} | evaluations: {}, {}",
            report.evaluations_csv.display(),
            report.evaluations_json.display()
        );
    } else {
        if report.counterexamples.len() < problem.counterexamples {
            outln!(
                "{} distinct failure modes of the {} asked for within {} runs",
                report.counterexamples.len(),
                problem.counterexamples,
                report.searches[0].evaluations.len()
            );
        }
        outln!(
            "evaluations: {}, {}{}",
            report.evaluations_csv.display(),
            report.evaluations_json.display(),
            report
                .convergence_png
                .as_ref()
                .map_or(String::new(), |p| format!(" | plot: {}", p.display()))
        );
    }
    if report.searches.iter().any(|s| s.interrupted) {
        eprintln!("error: the search was interrupted; what it found so far is written");
        return Ok(ExitCode::from(130));
    }
    if report.rerun_interrupted {
        eprintln!("error: interrupted while re-running the counterexample; the search's outputs are written, its log is incomplete");
        return Ok(ExitCode::from(130));
    }
    // A search whose every candidate failed learned nothing about safety: not a result.
    let evaluations: Vec<_> = report.searches.iter().flat_map(|s| &s.evaluations).collect();
    let errors: Vec<&str> = evaluations.iter().filter_map(|e| e.error.as_deref()).collect();
    if let Some(first) = errors.first() {
        let (failed, total) = (errors.len(), evaluations.len());
        if failed == total {
            eprintln!("error: every candidate failed ({total} runs); the first: {first}");
            return Ok(ExitCode::from(3));
        }
        eprintln!("warning: {failed} of {total} candidates failed (their rows hold the error); the first: {first}");
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::shell_quoted;

    #[test]
    fn arguments_are_quoted_as_a_shell_reads_them_back() {
        assert_eq!(shell_quoted("--range"), "--range");
        assert_eq!(shell_quoted("obstacles.0.centre.1=-3..3"), "obstacles.0.centre.1=-3..3");
        assert_eq!(
            shell_quoted("filter={kind='gamma_m', m=40.0}"),
            "'filter={kind='\\''gamma_m'\\'', m=40.0}'"
        );
        assert_eq!(shell_quoted(""), "''");
        // A shell gives back the argument.
        let quoted = shell_quoted("filter={kind='gamma_m', m=40.0} $HOME");
        let o = std::process::Command::new("sh")
            .args(["-c", &format!("printf %s {quoted}")])
            .output()
            .unwrap();
        assert_eq!(
            String::from_utf8(o.stdout).unwrap(),
            "filter={kind='gamma_m', m=40.0} $HOME"
        );
        // A newline stays on the line (the counterexample's `# search:` comment).
        let multiline = "description=\"\"\"a\nb's\\\"\"\"";
        let quoted = shell_quoted(multiline);
        assert!(!quoted.contains('\n'), "{quoted}");
        let o = std::process::Command::new("bash")
            .args(["-c", &format!("printf %s {quoted}")])
            .output()
            .unwrap();
        assert_eq!(String::from_utf8(o.stdout).unwrap(), multiline);
    }
}
