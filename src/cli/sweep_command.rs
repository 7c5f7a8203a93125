//! `mjsafe sweep` and `mjsafe plot-sweep`.

use super::*;

pub(super) fn print_summary(summary: &Summary, format: Format) {
    match format {
        Format::Json => out!("{}", summary.to_json()),
        Format::Csv => out!("{}", summary.to_csv()),
        Format::Table | Format::Brief => outln!("{}", sweep_table(summary)),
    }
}

/// A short aligned table of a sweep: index, parameters, collision, min h, status.
pub(super) fn sweep_table(summary: &Summary) -> String {
    let mut header: Vec<String> = vec!["index".into()];
    header.extend(summary.parameters.iter().cloned());
    header.extend(["collision".into(), "min_h".into(), "status".into()]);
    let mut rows = vec![header];
    for r in &summary.runs {
        let mut line = vec![r.index.to_string()];
        line.extend(
            summary
                .parameters
                .iter()
                .map(|k| r.parameters.get(k).cloned().unwrap_or_default()),
        );
        let m = r.metrics.as_ref();
        line.push(m.map_or("-".into(), |m| {
            match (m.number("collision_time"), m.cell("collision_with")) {
                (Some(t), analyze::Cell::Text(Some(with))) => format!("t={t:.3} {with}"),
                _ => "none".into(),
            }
        }));
        line.push(
            m.and_then(|m| m.number("min_h"))
                .map_or("-".into(), |h| format!("{h:.3}")),
        );
        line.push(match &r.error {
            Some(e) => format!("error: {e}"),
            None => "complete".into(),
        });
        rows.push(line);
    }
    crate::table::align_columns(&rows)
}

pub(super) struct SweepOptions {
    threads: Option<usize>,
    shard: Option<String>,
    out: Option<PathBuf>,
    progress: bool,
    dry_run: bool,
    fail_on_collision: bool,
    /// Whether each run writes its log into the sweep directory (else only its metrics).
    logs: bool,
}

pub(super) fn run_sweep(args: &SweepArgs, options: &SweepOptions) -> Result<ExitCode> {
    let spec = SweepSpec::build(args)?;
    let shard = options.shard.as_deref().map(sweep::parse_shard).transpose()?;
    let threads = sweep::threads(options.threads)?;
    let dir = options
        .out
        .clone()
        .unwrap_or_else(|| Path::new("logs").join(format!("sweep-{}", spec.name)));
    let indices = spec.indices(shard);
    if options.dry_run {
        for &i in &indices {
            let run = spec.run(i);
            let log = match options.logs {
                true => dir.join(spec.log_name(i)).display().to_string(),
                false => "(no log)".into(),
            };
            outln!("{i}  {log}  {}", run.overrides.join(" "));
        }
        return Ok(ExitCode::SUCCESS);
    }
    sweep::check_out_dir(&dir)?;
    Summary::check_outputs(&dir, shard).with_context(|| format!("writing the summary into {}", dir.display()))?;
    print_commonroad_remarks(&spec, &indices);
    let _graceful = episode::GracefulStop::begin();
    let terminal = std::io::stderr().is_terminal();
    let mut progress = Progress {
        enabled: terminal || options.progress,
        terminal,
        total: indices.len(),
        done: 0,
        failed: 0,
        started: Instant::now(),
    };
    progress.show();
    let logs = options.logs.then_some(dir.as_path());
    let rows = sweep::execute(&spec, &indices, logs, threads, |row| progress.update(row))
        .with_context(|| format!("running the sweep into {}", dir.display()))?;
    progress.finish();
    let summary = Summary::new(&spec, shard, rows);
    let (json, csv) = summary
        .write(&dir, &[])
        .with_context(|| format!("writing the summary into {}", dir.display()))?;
    outln!("{}", sweep_table(&summary));
    let not_run = summary.runs.iter().filter(|r| r.not_run).count();
    let failures = summary.failures() - not_run;
    outln!(
        "{}: {} of {} runs{}{} in {:.1} s on {} threads, {} failed | {} | summary: {}, {}",
        spec.name,
        indices.len() - not_run,
        spec.runs,
        if not_run > 0 {
            format!(" ({not_run} not run)")
        } else {
            String::new()
        },
        shard.map_or(String::new(), |s| format!(" (shard {}/{})", s.index, s.count)),
        progress.started.elapsed().as_secs_f64(),
        threads.min(indices.len().max(1)),
        failures,
        match options.logs {
            true => format!("logs in {}", dir.display()),
            false => "no logs kept".into(),
        },
        csv.display(),
        json.display()
    );
    if episode::stop_requested() {
        eprintln!(
            "error: the sweep was interrupted after {} of {} runs; the summary holds them (the others are marked not run)",
            indices.len() - not_run,
            indices.len()
        );
        return Ok(ExitCode::from(exit::INTERRUPTED));
    }
    if failures > 0 {
        eprintln!(
            "error: {failures} of {} runs failed (their rows hold the error)",
            indices.len()
        );
        return Ok(ExitCode::from(exit::RUNS_FAILED));
    }
    let collided: Vec<usize> = summary
        .runs
        .iter()
        .filter(|r| r.metrics.as_ref().is_some_and(|m| m.number("collision_time").is_some()))
        .map(|r| r.index)
        .collect();
    if options.fail_on_collision && !collided.is_empty() {
        eprintln!(
            "error: --fail-on-collision: {} of {} runs collided: {}",
            collided.len(),
            indices.len(),
            abbreviate(&collided)
        );
        return Ok(ExitCode::from(exit::COLLISION));
    }
    Ok(ExitCode::SUCCESS)
}

/// What of the sweep's CommonRoad files mjsafe does not use, named on stderr once per file, as
/// `mjsafe run` names it (a file that does not load is left to its run's row).
fn print_commonroad_remarks(spec: &SweepSpec, indices: &[usize]) {
    let mut seen = std::collections::BTreeSet::new();
    for &i in indices {
        let run = spec.run(i);
        let file = run.parameters.iter().find(|(key, _)| key == "commonroad.file");
        if !seen.insert(file.map(|(_, value)| value.clone())) {
            continue;
        }
        if let Ok(loaded) = scenario::load(Path::new(&spec.scenario), &run.overrides) {
            super::run_command::print_commonroad_notes(&loaded);
        }
    }
}

/// `mjsafe plot-sweep`: a sweep's metric `y` against the swept key `x`, one PNG.
pub(super) fn plot_sweep_command(summary: PathBuf, x: &str, y: &str, out: Option<PathBuf>) -> Result<ExitCode> {
    let dir = if summary.is_dir() {
        summary.clone()
    } else {
        summary.parent().map_or_else(|| PathBuf::from("."), Path::to_path_buf)
    };
    let out = out.unwrap_or_else(|| dir.join(format!("{y}-vs-{x}.png")));
    let file = if summary.is_dir() {
        summary.join("summary.json")
    } else {
        summary.clone()
    };
    let read = Summary::read(&file)?;
    // A run that failed or stopped early has no metrics of a whole run: not a point.
    let (whole, left_out): (Vec<&Row>, Vec<&Row>) = read.runs.iter().partition(|r| r.error.is_none());
    if !left_out.is_empty() {
        let indices: Vec<usize> = left_out.iter().map(|r| r.index).collect();
        eprintln!(
            "warning: {} of {} runs left out (failed or incomplete: their rows hold the error): {}",
            left_out.len(),
            read.runs.len(),
            abbreviate(&indices)
        );
    }
    let points: Vec<crate::plot::SweepPoint<'_>> = whole
        .iter()
        .map(|r| crate::plot::SweepPoint {
            parameters: &r.parameters,
            metrics: r.metrics.as_ref(),
        })
        .collect();
    let written = crate::plot::plot_sweep(&file, &read.sweep.name, &read.parameters, &points, x, y, &out)?;
    eprintln!("plot: {}", written.display());
    Ok(ExitCode::SUCCESS)
}

/// `mjsafe sweep`: Run a scenario over a grid of overrides and/or seeded random draws, in parallel;
#[derive(Debug, clap::Args)]
pub struct SweepCommand {
    /// Scenario file (TOML); or name it in the sweep file.
    scenario: Option<PathBuf>,
    /// CommonRoad files to run, one run each per other grid point: files or patterns (quoted:
    /// `--scenarios 'data/commonroad/*.xml'`), the swept key `commonroad.file` (repeatable;
    /// docs/commonroad.md).
    #[arg(long = "scenarios", value_name = "FILES", conflicts_with = "scenario")]
    scenarios: Vec<String>,
    /// A grid axis: KEY=V1,V2,… (values in TOML syntax; commas inside [], {} and quotes
    /// are part of a value). Runs are the cartesian product of all grids (repeatable).
    #[arg(long = "grid", value_name = "KEY=V1,V2,…")]
    grids: Vec<String>,
    /// Sweep file (TOML): scenario, set, [[grid]], [[range]], [random] (see docs/sweeps.md).
    #[arg(long = "sweep", value_name = "FILE")]
    sweep_file: Option<PathBuf>,
    /// Override applied to every run: KEY.PATH=VALUE in TOML value syntax, or a bare word as a string (`plant=ode`) (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// A requirement of every run (an STL formula; its robustness is the summary column
    /// `req.NAME`; docs/requirements.md) (repeatable).
    #[arg(long = "require", value_name = "NAME=FORMULA")]
    require: Vec<String>,
    /// Number of random draws of the --range keys (per grid point).
    #[arg(long, value_name = "N")]
    random: Option<usize>,
    /// Seed of the random draws (default 0).
    #[arg(long, value_name = "S")]
    seed: Option<u64>,
    /// A range drawn uniformly: KEY=LO..HI, or KEY=LO..HI:STEP for multiples of STEP from LO (repeatable).
    #[arg(long = "range", value_name = "KEY=LO..HI[:STEP]")]
    ranges: Vec<String>,
    /// Runs executed at once (default: all cores).
    #[arg(long, value_name = "K")]
    threads: Option<usize>,
    /// Run only the indices with index % N == I (0 <= I < N); writes summary-shard-I-of-N.*.
    #[arg(long, value_name = "I/N")]
    shard: Option<String>,
    /// Directory of the logs and summaries (default: logs/sweep-<name>).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Print progress on stderr even when it is not a terminal (one line per finished run).
    #[arg(long)]
    progress: bool,
    /// List the runs (index, log, overrides) without running them.
    #[arg(long)]
    dry_run: bool,
    /// Exit with 4 when some run collided (and none failed); without it collisions exit 0.
    #[arg(long)]
    fail_on_collision: bool,
    /// Keep no logs, only the summary: each run is analysed while it runs (the metrics its
    /// log would give). A row's log is one `mjsafe run SCENARIO --set …` with its overrides.
    #[arg(long)]
    no_logs: bool,
}

impl SweepCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let SweepCommand {
            scenario,
            scenarios,
            grids,
            sweep_file,
            mut overrides,
            require,
            random,
            seed,
            ranges,
            threads,
            shard,
            out,
            progress,
            dry_run,
            fail_on_collision,
            no_logs,
        } = self;
        for flag in &require {
            overrides.push(scenario::require_override(flag)?);
        }
        let scenarios = sweep::expand_scenarios(&scenarios).map_err(|e| anyhow::anyhow!("--scenarios {e}"))?;
        let args = SweepArgs {
            scenario,
            scenarios,
            sweep_file,
            set: overrides,
            grids,
            random,
            seed,
            ranges,
        };
        let options = SweepOptions {
            threads,
            shard,
            out,
            progress,
            dry_run,
            fail_on_collision,
            logs: !no_logs,
        };
        run_sweep(&args, &options)
    }
}

/// `mjsafe plot-sweep`: Plot a metric of a sweep against one swept key (e.g. min_h against delays.steering):
#[derive(Debug, clap::Args)]
pub struct PlotSweepCommand {
    /// The sweep's directory (with summary.json) or a summary.json.
    summary: PathBuf,
    /// The swept key on the x axis (e.g. delays.steering).
    #[arg(long, value_name = "KEY")]
    x: String,
    /// The metric on the y axis (a numeric metric of the summary: min_h, min_clearance, …).
    #[arg(long, value_name = "METRIC", default_value = "min_h")]
    y: String,
    /// The PNG to write (default: <sweep dir>/<metric>-vs-<key>.png).
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
}

impl PlotSweepCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let PlotSweepCommand { summary, x, y, out } = self;
        plot_sweep_command(summary, &x, &y, out)
    }
}

/// The progress line on stderr: rewritten in place on a terminal, one line per run otherwise.
pub(super) struct Progress {
    enabled: bool,
    terminal: bool,
    total: usize,
    done: usize,
    failed: usize,
    started: Instant,
}

impl Progress {
    fn line(&self) -> String {
        let elapsed = self.started.elapsed().as_secs_f64();
        let eta = if self.done > 0 {
            format!("{:.0} s", elapsed / self.done as f64 * (self.total - self.done) as f64)
        } else {
            "?".into()
        };
        format!(
            "sweep: {}/{} done, {} failed, {:.0} s elapsed, ETA {eta}",
            self.done, self.total, self.failed, elapsed
        )
    }

    fn show(&self) {
        if self.enabled && self.terminal {
            eprint!("\r{}\x1b[K", self.line());
            let _ = std::io::stderr().flush();
        }
    }

    fn update(&mut self, row: &Row) {
        self.done += 1;
        self.failed += usize::from(row.error.is_some());
        if !self.enabled {
            return;
        }
        if self.terminal {
            self.show();
        } else {
            eprintln!("{} (run {})", self.line(), row.index);
        }
    }

    fn finish(&self) {
        if self.enabled && self.terminal {
            eprintln!();
        }
    }
}
