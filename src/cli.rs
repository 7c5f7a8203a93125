//! The `mjsafe` command line: run, sweep, analyze, info, bench, completions, man (and replay,
//! with the `rerun` feature).

// The arguments' doc comments are `--help` text for a terminal, not rustdoc.
#![allow(rustdoc::broken_intra_doc_links, rustdoc::invalid_html_tags)]

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};

/// `print!` to stdout that ends the process quietly with 141 (128 + SIGPIPE, what a shell
/// reports for a program killed by a closed pipe) when stdout is a closed pipe, e.g.
/// `mjsafe info LOG | head`, instead of panicking.
macro_rules! out {
    ($($arg:tt)*) => { write_stdout(format_args!($($arg)*)) };
}

/// `println!` with the same closed-pipe handling as `out!`.
macro_rules! outln {
    () => { write_stdout(format_args!("\n")) };
    ($($arg:tt)*) => { write_stdout(format_args!("{}\n", format_args!($($arg)*))) };
}

fn write_stdout(args: std::fmt::Arguments) {
    let mut stdout = std::io::stdout().lock();
    if let Err(e) = stdout.write_fmt(args).and_then(|()| stdout.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(exit::BROKEN_PIPE.into());
        }
        eprintln!("error: cannot write to stdout: {e}");
        std::process::exit(1);
    }
}

use crate::analyze::{self, FlatMetrics, RunMetrics};
use crate::episode;
use crate::falsify;
use crate::log::Sink;
use crate::scenario;
use crate::sweep::{self, Row, Summary, SweepArgs, SweepSpec};

/// The process exit codes (README "Exit codes", `mjsafe --help`).
pub mod exit {
    /// Done: the run or sweep completed (a collision is a result), the analysis succeeded.
    pub const DONE: u8 = 0;
    /// An error: bad input, an unreadable or damaged file, a run that stopped on an error, a
    /// sweep that could not start or write its summary, a merge with missing runs.
    pub const ERROR: u8 = 1;
    /// A usage error: unknown flag, missing argument (clap's code).
    pub const USAGE: u8 = 2;
    /// `sweep`: the sweep finished and wrote its summary, but some of its runs failed (their
    /// rows hold the error). Deterministic: rerunning the same shard fails the same way.
    pub const RUNS_FAILED: u8 = 3;
    /// `--fail-on-collision`: the run (or some run of the sweep) collided.
    pub const COLLISION: u8 = 4;
    /// Interrupted by Ctrl-C / SIGTERM (128 + SIGINT).
    pub const INTERRUPTED: u8 = 130;
    /// stdout was a closed pipe (128 + SIGPIPE), e.g. `mjsafe info LOG | head`.
    pub const BROKEN_PIPE: u8 = 141;
}

/// The exit-code table of `--help` (and of the README; tests/cli.rs checks they agree).
macro_rules! exit_codes {
    () => {
        "\
Exit codes:
  0    done (a collision is a result, not an error)
  1    error: bad input, unreadable or damaged file, a run stopped on an error, a merge with
       missing runs, a sweep that could not run or write its summary
  2    usage error (unknown flag, missing argument)
  3    sweep: some runs failed (summary written, their rows hold the error); falsify: every
       candidate failed (evaluations written, their rows hold the error)
  4    --fail-on-collision: the run, or some run of the sweep, collided
  130  interrupted (Ctrl-C, SIGTERM): logs finished as incomplete
  141  stdout was a closed pipe"
    };
}

macro_rules! top_examples {
    () => {
        "\
Examples:
  mjsafe run scenarios/bicycle_obstacle.toml --set delays.steering=0.4 --out logs/slow.mcap
  mjsafe run scenarios/bicycle_obstacle_gamma_m.toml --json --fail-on-collision
  mjsafe sweep --sweep scenarios/bicycle_delays.sweep.toml --shard 0/4 --threads 8
  mjsafe analyze --merge logs/sweep-bicycle_obstacle --out logs/sweep-bicycle_obstacle
  mjsafe analyze --csv logs/*.mcap
  mjsafe completions bash > /etc/bash_completion.d/mjsafe
  mjsafe man | man -l -"
    };
}

macro_rules! run_examples {
    () => {
        "\
Examples:
  mjsafe run scenarios/bicycle_obstacle.toml
  mjsafe run scenarios/bicycle_obstacle.toml --set delays.steering=0.4 --set filter.compensation=\"'none'\"
  mjsafe run scenarios/bicycle_obstacle_gamma_m.toml --json --fail-on-collision   # CI gate: exit 4 on a collision"
    };
}

macro_rules! sweep_examples {
    () => {
        "\
Examples:
  mjsafe sweep scenarios/bicycle_obstacle.toml --grid delays.steering=0.1,0.2,0.4 --out logs/grid
  mjsafe sweep --sweep scenarios/bicycle_delays.sweep.toml --dry-run
  mjsafe sweep scenarios/bicycle_obstacle.toml --random 20 --seed 7 --range obstacles.0.radius=2.0..3.0
  mjsafe sweep --sweep scenarios/bicycle_delays.sweep.toml --shard \"$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT\"
  mjsafe sweep scenarios/bicycle_obstacle.toml --random 1000 --range obstacles.0.centre.1=-3..3 --no-logs   # summary only
Exit: 0 all runs done, 3 some runs failed (summary written), 1 the sweep could not run,
4 with --fail-on-collision some run collided, 130 interrupted."
    };
}

macro_rules! analyze_examples {
    () => {
        "\
Examples:
  mjsafe analyze logs/run.mcap
  mjsafe analyze --json logs/*.mcap
  mjsafe analyze --compare logs/a.mcap logs/b.mcap
  mjsafe analyze --merge logs/sweep-bicycle_obstacle --out logs/sweep-bicycle_obstacle
  mjsafe analyze --plot figures logs/run.mcap"
    };
}

#[derive(Debug, Parser)]
#[command(
    name = "mjsafe",
    version,
    about = "MuJoCo vehicle safety testbed: delayed actuators, safety filters, MCAP logs",
    after_help = concat!(top_examples!(), "\n\n", exit_codes!()),
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    /// Most steps one episode may take (duration / timestep); longer runs are refused before
    /// they start.
    #[arg(long, global = true, value_name = "N", default_value_t = episode::DEFAULT_MAX_STEPS,
          value_parser = clap::builder::RangedU64ValueParser::<u64>::new().range(1..))]
    pub max_steps: u64,
    /// Most integration steps one episode may take, estimated before it starts (plant steps
    /// plus predictor steps).
    #[arg(long, global = true, value_name = "N", default_value_t = episode::cost::DEFAULT_MAX_WORK,
          value_parser = clap::builder::RangedU64ValueParser::<u64>::new().range(1..))]
    pub max_work: u64,
    /// Largest log one run may write, estimated before it starts (bytes, before compression).
    #[arg(long, global = true, value_name = "BYTES", default_value_t = episode::cost::DEFAULT_MAX_LOG_BYTES,
          value_parser = clap::builder::RangedU64ValueParser::<u64>::new().range(1..))]
    pub max_log_size: u64,
}

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
    /// The metric minimised (a numeric column of `analyze --csv`): min_h, min_clearance,
    /// min_time_to_collision, …
    #[arg(long, default_value = "min_h")]
    pub objective: String,
    /// A candidate violates when the objective is below this.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub threshold: f64,
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
    /// Also run random search with the same budget and seed, and compare runs to the first
    /// violation.
    #[arg(long)]
    pub compare_random: bool,
    /// Output directory (default: logs/falsify-<scenario name>).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run one scenario headless; writes one MCAP log and prints a one-line summary.
    #[command(after_help = run_examples!())]
    Run {
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
        #[command(flatten)]
        rerun: RerunArgs,
    },
    /// Rebuild the rerun recording of a run from its MCAP log alone (no re-simulation):
    /// save it (--rrd), stream it to a viewer (--connect), or spawn a viewer (default).
    #[cfg(feature = "rerun")]
    Replay {
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
    },
    /// Per-run metrics of MCAP logs; or two runs compared; or sweep shard summaries merged.
    #[command(after_help = analyze_examples!())]
    Analyze {
        /// Logs (.mcap); with --merge, sweep directories or summary-shard-*.json files.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// Print CSV instead of a table.
        #[arg(long, conflicts_with = "json")]
        csv: bool,
        /// Print a compact comparison instead: filter (by equation number), collision, min h,
        /// min clearance, one row per log.
        #[arg(long, conflicts_with_all = ["json", "csv", "compare", "merge"])]
        brief: bool,
        /// Compare two logs A B: one row per metric with A, B and B − A.
        #[arg(long, conflicts_with = "merge")]
        compare: bool,
        /// Merge the shard summaries of one sweep (checks they agree, reports missing runs).
        #[arg(long)]
        merge: bool,
        /// With --merge: also write DIR/summary.csv and DIR/summary.json.
        #[arg(long, value_name = "DIR", requires = "merge")]
        out: Option<PathBuf>,
        /// Also write PNG plots of each log into DIR (h(t), issued vs applied inputs,
        /// trajectory with obstacles and reference path); with several logs, also overlays of
        /// the runs (overlay-trajectory.png, overlay-barriers.png, overlay-inputs.png), each
        /// run named by its filter's equation number.
        #[arg(long, value_name = "DIR", conflicts_with = "merge")]
        plot: Option<PathBuf>,
        /// On a damaged log, still report the metrics of what was read before the damage (the
        /// chunks that passed their CRC), marked incomplete; the exit status is still non-zero.
        #[arg(long, conflicts_with = "merge")]
        recover: bool,
    },
    /// Run a scenario over a grid of overrides and/or seeded random draws, in parallel;
    /// writes one log per run and summary.csv / summary.json (see docs/sweeps.md).
    #[command(after_help = sweep_examples!())]
    Sweep {
        /// Scenario file (TOML); or name it in the sweep file.
        scenario: Option<PathBuf>,
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
    },
    /// Search the --range box for a run that violates safety: CMA-ES minimises an analysis
    /// metric (default min_h) and stops at the first violation (metric < threshold). Writes
    /// the counterexample as a scenario file plus its log, every evaluation (CSV, JSON) and a
    /// convergence plot.
    Falsify(FalsifyArgs),
    /// The time series of logs as tables: one wide, time-indexed CSV or Parquet file per topic
    /// (`<log stem>-<topic>.csv|parquet`: state names, per-channel commands, barriers per
    /// obstacle, predictions, events), streamed from the log (src/export.rs lists the columns).
    Export {
        /// Logs (.mcap).
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Table format.
        #[arg(long, value_enum, default_value = "csv")]
        format: crate::export::Format,
        /// Topics to export, comma-separated (default: every table topic the log has:
        /// /state, /command/issued, /command/applied, /barrier, /filter, /event, /prediction,
        /// /state/measured, /command/actuated).
        #[arg(long, value_name = "T1,T2,…", value_delimiter = ',')]
        topics: Vec<String>,
        /// Directory of the tables (default: each log's directory).
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
    /// Plot a metric of a sweep against one swept key (e.g. min_h against delays.steering):
    /// one line per combination of the other swept keys, collisions marked.
    PlotSweep {
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
    },
    /// Topics, message counts, schemas, time span, mjsafe metadata and scenario of a log.
    Info {
        /// The MCAP log written by `mjsafe run`, `sweep` or `falsify`.
        file: PathBuf,
        /// Also print the effective scenario (after --set overrides).
        #[arg(long)]
        resolved: bool,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// On a damaged log, still show what was read before the damage (counted from the
        /// messages read); the exit status is still non-zero.
        #[arg(long)]
        recover: bool,
    },
    /// End-to-end speed of a scenario on this thread: the bare physics loop over its model,
    /// the full pipeline, and the pipeline with MCAP logging (median of --repeat runs), as
    /// real-time factors and ratios to the bare loop (docs/performance.md).
    Bench {
        /// Scenario file (TOML).
        #[arg(default_value = "scenarios/bicycle_obstacle_gamma_m.toml")]
        scenario: PathBuf,
        /// Override a field: KEY.PATH=VALUE in TOML value syntax, or a bare word as a string (`plant=ode`) (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
        /// Predictor RK4 steps (seconds, multiples of the timestep, as `control.predictor_step`) to compare, one row
        /// each with its measured prediction error (default: the scenario's).
        #[arg(
            long = "predictor-step",
            value_name = "S1,S2,…",
            value_delimiter = ',',
            allow_negative_numbers = true
        )]
        predictor_steps: Vec<f64>,
        /// Chain-reuse tolerances of the recursive predictors (control.chain_tolerance) to
        /// compare, one row each with the largest difference reuse made to a prediction
        /// (default: the scenario's).
        #[arg(
            long = "chain-tolerance",
            value_name = "T1,T2,…",
            value_delimiter = ',',
            allow_negative_numbers = true
        )]
        chain_tolerances: Vec<f64>,
        /// Runs per configuration (the median is reported).
        #[arg(long, default_value_t = 5, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..))]
        repeat: usize,
        /// Directory for the benchmark's MCAP logs.
        #[arg(long, default_value = "logs")]
        log_dir: PathBuf,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// List every metric `analyze` computes: its JSON name, flat column, unit and meaning
    /// (docs/metrics.md's table is this output with --markdown).
    Metrics {
        /// Print the Markdown table of docs/metrics.md instead of aligned text.
        #[arg(long)]
        markdown: bool,
    },
    /// Print a shell completion script on stdout, e.g.
    /// `mjsafe completions bash > ~/.local/share/bash-completion/completions/mjsafe`.
    Completions {
        /// The shell.
        shell: clap_complete::Shell,
    },
    /// Print the man page (roff) on stdout (`mjsafe man | man -l -`), or write mjsafe.1 and one
    /// page per subcommand (mjsafe-run.1, ...) into --dir.
    Man {
        /// Write the pages into this directory instead.
        #[arg(long, value_name = "DIR")]
        dir: Option<PathBuf>,
    },
}

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

/// Parses arguments, runs the command, returns the process exit code.
pub fn run() -> ExitCode {
    install_stop_handler();
    let cli = Cli::parse();
    episode::set_max_steps(cli.max_steps);
    episode::cost::set_max_work(cli.max_work);
    episode::cost::set_max_log_bytes(cli.max_log_size);
    match dispatch(cli.command) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", crate::message::shorten_numbers(&format!("{e:#}")));
            ExitCode::from(exit::ERROR)
        }
    }
}

fn dispatch(command: Command) -> Result<ExitCode> {
    match command {
        Command::Run {
            scenario,
            overrides,
            out,
            json,
            fail_on_collision,
            rerun,
        } => run_scenario(
            &scenario,
            &overrides,
            out,
            &rerun,
            RunOutput {
                json,
                fail_on_collision,
            },
        ),
        #[cfg(feature = "rerun")]
        Command::Replay {
            file,
            rrd,
            connect,
            recover,
        } => replay(&file, rrd, connect, recover),
        Command::Analyze {
            files,
            json,
            csv,
            brief,
            compare,
            merge,
            out,
            plot,
            recover,
        } => {
            let format = if brief {
                Format::Brief
            } else if json {
                Format::Json
            } else if csv {
                Format::Csv
            } else {
                Format::Table
            };
            let mode = match (compare, merge) {
                (true, _) => AnalyzeMode::Compare,
                (_, true) => AnalyzeMode::Merge(out),
                _ => AnalyzeMode::Metrics,
            };
            analyze_command(&files, format, mode, plot.as_deref(), recover)
        }
        Command::Sweep {
            scenario,
            grids,
            sweep_file,
            overrides,
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
        } => {
            let args = SweepArgs {
                scenario,
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
                keep: if no_logs {
                    sweep::Keep::Metrics
                } else {
                    sweep::Keep::Logs
                },
            };
            run_sweep(&args, &options)
        }
        Command::Falsify(args) => falsify_command(args),
        Command::Export {
            files,
            format,
            topics,
            out,
        } => export(&files, format, &topics, out.as_deref()),
        Command::PlotSweep { summary, x, y, out } => plot_sweep_command(summary, &x, &y, out),
        Command::Info {
            file,
            resolved,
            json,
            recover,
        } => info(&file, resolved, json, recover),
        Command::Bench {
            scenario,
            overrides,
            predictor_steps,
            chain_tolerances,
            repeat,
            log_dir,
            json,
        } => bench_command(
            &scenario,
            &overrides,
            (predictor_steps, chain_tolerances),
            repeat,
            &log_dir,
            json,
        ),
        Command::Completions { shell } => {
            let mut text = Vec::new();
            clap_complete::generate(
                shell,
                &mut <Cli as clap::CommandFactory>::command(),
                "mjsafe",
                &mut text,
            );
            out!("{}", String::from_utf8_lossy(&text));
            Ok(ExitCode::SUCCESS)
        }
        Command::Man { dir } => man_command(dir),
        Command::Metrics { markdown } => {
            let table = crate::metrics::reference_table();
            if markdown {
                out!("{table}");
            } else {
                outln!("{}", crate::metrics::report::markdown_as_text(&table));
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// How every man page clap_mangen renders starts: an existing file that does not start so is
/// never replaced.
const MAN_START: &[u8] = b".ie \\n(.g .ds Aq \\(aq\n";

/// (file name, roff text) of the page of `command` and of each of its subcommands, as
/// `clap_mangen::generate_to` names and renders them.
fn man_pages(command: clap::Command) -> std::io::Result<Vec<(String, Vec<u8>)>> {
    fn collect(command: clap::Command, pages: &mut Vec<(String, Vec<u8>)>) -> std::io::Result<()> {
        for sub in command.get_subcommands().filter(|s| !s.is_hide_set()).cloned() {
            collect(sub, pages)?;
        }
        let man = clap_mangen::Man::new(command);
        let mut text = Vec::new();
        man.render(&mut text)?;
        pages.push((man.get_filename(), text));
        Ok(())
    }
    let mut command = command.disable_help_subcommand(true);
    command.build();
    let mut pages = Vec::new();
    collect(command, &mut pages)?;
    Ok(pages)
}

/// How `mjsafe run` reports: the text line or JSON, and whether a collision fails the process.
#[derive(Debug, Clone, Copy)]
struct RunOutput {
    json: bool,
    fail_on_collision: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Table,
    /// `analyze --brief`.
    Brief,
    Json,
    Csv,
}

/// Ctrl-C and SIGTERM, from process start: while episodes or a sweep run, they ask them to
/// stop (logs finished as incomplete, summaries written); in any other phase (validation,
/// model loading, analysis), or at a second signal, the process exits at once with 130,
/// removing the `.partial` files it was writing.
fn install_stop_handler() {
    // A second installation (e.g. in tests driving the library) is not an error worth failing.
    let _ = ctrlc::set_handler(|| {
        if episode::stop_requested() || !episode::graceful_stop_active() {
            crate::files::remove_partials();
            eprintln!("error: interrupted");
            std::process::exit(exit::INTERRUPTED.into());
        }
        episode::request_stop();
    });
}

/// A progress line on a terminal (stderr) for a run that takes more than two seconds: the
/// simulated time reached, the fraction done and the speed, once a second; cleared when the
/// value is dropped. Nothing when stderr is not a terminal.
struct RunProgress {
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

fn run_scenario(
    path: &Path,
    overrides: &[String],
    out: Option<PathBuf>,
    rerun: &RerunArgs,
    report: RunOutput,
) -> Result<ExitCode> {
    let loaded = scenario::load(path, overrides)?;
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
        let rtf = summary.real_time_factor();
        let value = serde_json::json!({
            "scenario": loaded.scenario.name,
            "collision": metrics.collision(),
            "min_h": metrics.min_h(),
            "steps": summary.steps,
            "simulated_time": summary.simulated_time,
            "real_time_factor": rtf.is_finite().then_some(rtf),
            "log": log_path.display().to_string(),
            "complete": summary.error.is_none(),
            "error": summary.error.as_ref().map(ToString::to_string),
        });
        let mut value = value;
        // Only with warnings, so the object of a clean run keeps its keys.
        if !metrics.warnings.is_empty() {
            value["warnings"] = serde_json::json!(metrics.warnings);
        }
        outln!("{value}");
    } else {
        outln!(
            "{}: {}{} | min h = {} | {} steps, {:.2} s simulated, {}x real time | log: {}",
            loaded.scenario.name,
            metrics.collision().map_or("no collision".to_string(), |c| format!(
                "COLLISION at t = {:.3} s with {} ({})",
                c.time,
                c.with,
                if c.depth.is_nan() {
                    "depth not in the log".to_string()
                } else {
                    format!("depth {:.3} m", c.depth)
                }
            )),
            match metrics.warnings.len() {
                0 => String::new(),
                n => format!(
                    " | {n} MUJOCO WARNING{}: physics not the model's",
                    if n > 1 { "S" } else { "" }
                ),
            },
            metrics.min_h().map_or("-".into(), |h| format!("{h:.3}")),
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
    for warning in &metrics.warnings {
        eprintln!("warning: MuJoCo: {warning}; the run's metrics describe that physics, not the model's");
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
    Ok(ExitCode::SUCCESS)
}

#[cfg(feature = "rerun")]
fn replay(file: &Path, rrd: Option<PathBuf>, connect: Option<String>, recover: bool) -> Result<ExitCode> {
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

/// The metrics of a log; with `recover`, a damaged log gives the metrics of what was read
/// before the damage (marked incomplete, with the damage as their error) and the error.
fn analyze_or_recover(
    file: &Path,
    recover: bool,
) -> Result<(RunMetrics, Option<analyze::AnalyzeError>), analyze::AnalyzeError> {
    match analyze::analyze_file(file) {
        Ok(m) => Ok((m, None)),
        Err(analyze::AnalyzeError::Corrupt {
            damage,
            partial: Some(partial),
        }) if recover => Ok((*partial, Some(analyze::AnalyzeError::Read(damage)))),
        Err(e) => Err(e),
    }
}

fn analyze_files(files: &[PathBuf], format: Format, recover: bool) -> ExitCode {
    let mut runs: Vec<RunMetrics> = Vec::new();
    let mut failed = false;
    for file in files {
        match analyze_or_recover(file, recover) {
            Ok((m, None)) => runs.push(m),
            Ok((m, Some(e))) => {
                eprintln!("error: {e} (--recover: reporting the metrics of what was read before)");
                runs.push(m);
                failed = true;
            }
            Err(e) => {
                eprintln!("error: {e}");
                failed = true;
            }
        }
    }
    if format != Format::Json {
        // JSON names them in `missing`; the table and CSV show them as empty.
        for run in runs.iter().filter(|r| !r.missing.is_empty()) {
            let absent: Vec<String> = run.missing.iter().map(|(m, why)| format!("{m} ({why})")).collect();
            eprintln!("warning: {}: metrics absent: {}", run.file, absent.join(", "));
        }
        for run in &runs {
            for warning in &run.warnings {
                eprintln!(
                    "warning: {}: MuJoCo: {warning}; the metrics describe that physics, not the model's",
                    run.file
                );
            }
        }
    }
    match format {
        Format::Json => outln!("{}", serde_json::to_string_pretty(&runs).expect("metrics serialise")),
        Format::Csv if !runs.is_empty() => out!("{}", crate::metrics::report::csv(&runs)),
        Format::Table if !runs.is_empty() => outln!("{}", crate::metrics::report::table(&runs)),
        Format::Brief if !runs.is_empty() => outln!("{}", crate::metrics::report::brief_table(&runs)),
        _ => {}
    }
    if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}

fn compare_files(files: &[PathBuf], format: Format, recover: bool) -> Result<ExitCode> {
    let [a, b] = files else {
        bail!("--compare takes exactly two logs A B, {} given", files.len());
    };
    let (ma, damage_a) = analyze_or_recover(a, recover)?;
    let (mb, damage_b) = analyze_or_recover(b, recover)?;
    let rows = crate::metrics::report::compare(&ma, &mb);
    match format {
        Format::Json => {
            // Why a metric is absent on either side (as `analyze --json` names it).
            let mut value = serde_json::json!({
                "a": a.display().to_string(),
                "b": b.display().to_string(),
                "metrics": crate::metrics::report::comparison_json(&rows),
            });
            for (key, m) in [("missing_a", &ma), ("missing_b", &mb)] {
                if !m.missing.is_empty() {
                    value[key] = serde_json::json!(m.missing);
                }
            }
            outln!(
                "{}",
                serde_json::to_string_pretty(&value).expect("JSON values serialise")
            );
        }
        Format::Csv => out!("{}", crate::metrics::report::comparison_csv(&rows)),
        Format::Table | Format::Brief => {
            outln!("A: {}\nB: {}\n", a.display(), b.display());
            outln!("{}", crate::metrics::report::comparison_table(&rows));
        }
    }
    if format != Format::Json {
        // An absent value is not "not applicable": its reason, as `analyze` warns.
        for (side, m) in [("A", &ma), ("B", &mb)] {
            if !m.missing.is_empty() {
                let absent: Vec<String> = m.missing.iter().map(|(k, why)| format!("{k} ({why})")).collect();
                eprintln!("warning: {side} {}: metrics absent: {}", m.file, absent.join(", "));
            }
        }
    }
    let damaged: Vec<_> = [damage_a, damage_b].into_iter().flatten().collect();
    for e in &damaged {
        eprintln!("error: {e} (--recover: compared what was read before)");
    }
    Ok(if damaged.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

fn merge_summaries(args: &[PathBuf], format: Format, out: Option<&Path>) -> Result<ExitCode> {
    let mut inputs = Vec::new();
    for arg in args {
        for file in Summary::merge_inputs(arg)? {
            let summary = Summary::read(&file)?;
            inputs.push((file.display().to_string(), summary));
        }
    }
    let (merged, missing) = Summary::merge(&inputs)?;
    print_summary(&merged, format);
    let mut shards: Vec<String> = inputs
        .iter()
        .map(|(_, s)| s.shard.map_or("all".into(), |s| format!("{}/{}", s.index, s.count)))
        .collect();
    shards.dedup();
    if !missing.is_empty() {
        eprintln!(
            "error: {} of {} runs are missing from the merge: {} (shards given: {}){}",
            missing.len(),
            merged.sweep.runs,
            abbreviate(&missing),
            shards.join(", "),
            if out.is_some() { "; nothing written" } else { "" }
        );
        return Ok(ExitCode::FAILURE);
    }
    // Runs an interrupted shard never started or stopped are as missing as runs of a shard not
    // given (a failed run is a result: its row holds the error).
    let not_run: Vec<usize> = merged
        .runs
        .iter()
        .filter(|r| r.not_run || r.interrupted)
        .map(|r| r.index)
        .collect();
    if !not_run.is_empty() {
        eprintln!(
            "error: {} of {} runs were not run to their end (their shard was interrupted): {}; run those shards again and merge{}",
            not_run.len(),
            merged.sweep.runs,
            abbreviate(&not_run),
            if out.is_some() { "; nothing written" } else { "" }
        );
        return Ok(ExitCode::FAILURE);
    }
    // Shards of one sweep run with and without --no-logs: the same metrics, but only some
    // rows have a log to open.
    let without_log: Vec<usize> = merged
        .runs
        .iter()
        .filter(|r| r.log.is_none() && r.error.is_none())
        .map(|r| r.index)
        .collect();
    if !without_log.is_empty() && merged.runs.iter().any(|r| r.log.is_some()) {
        eprintln!(
            "warning: {} of {} runs have no log (their shards ran with --no-logs): {}",
            without_log.len(),
            merged.sweep.runs,
            abbreviate(&without_log)
        );
    }
    if let Some(dir) = out {
        let merged_files: Vec<&Path> = inputs.iter().map(|(file, _)| Path::new(file.as_str())).collect();
        let (json, csv) = merged
            .write(dir, &merged_files)
            .with_context(|| format!("writing the merged summary into {}", dir.display()))?;
        eprintln!(
            "merged {} summaries ({} runs): {}, {}",
            inputs.len(),
            merged.runs.len(),
            csv.display(),
            json.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// `arg` as a shell reads it back, on one line: as is when it holds only safe characters, in
/// single quotes (a quote inside written `'\''`) when it holds no control character, else
/// ANSI-C quoted (`$'…\n…'`: bash, zsh).
fn shell_quoted(arg: &str) -> String {
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

/// The first two different files whose outputs `name` names alike (the same file given twice
/// writes the same outputs, and is allowed).
fn same_output_names(files: &[PathBuf], name: impl Fn(&Path) -> PathBuf) -> Option<(&Path, &Path)> {
    let mut seen: std::collections::BTreeMap<PathBuf, &Path> = std::collections::BTreeMap::new();
    files.iter().find_map(|file| {
        let other = seen.insert(name(file), file)?;
        (!crate::files::same_path(other, file)).then_some((other, file.as_path()))
    })
}

/// `1, 2, 3, …` cut after 20 entries.
fn abbreviate(indices: &[usize]) -> String {
    let mut text: Vec<String> = indices.iter().take(20).map(|i| i.to_string()).collect();
    if indices.len() > 20 {
        text.push(format!("… ({} more)", indices.len() - 20));
    }
    text.join(", ")
}

fn print_summary(summary: &Summary, format: Format) {
    match format {
        Format::Json => out!("{}", summary.to_json()),
        Format::Csv => out!("{}", summary.to_csv()),
        Format::Table | Format::Brief => outln!("{}", sweep_table(summary)),
    }
}

/// A short aligned table of a sweep: index, parameters, collision, min h, status.
fn sweep_table(summary: &Summary) -> String {
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

struct SweepOptions {
    threads: Option<usize>,
    shard: Option<String>,
    out: Option<PathBuf>,
    progress: bool,
    dry_run: bool,
    fail_on_collision: bool,
    keep: sweep::Keep,
}

fn run_sweep(args: &SweepArgs, options: &SweepOptions) -> Result<ExitCode> {
    let spec = SweepSpec::build(args)?;
    let shard = options.shard.as_deref().map(sweep::parse_shard).transpose()?;
    let threads = match options.threads {
        Some(0) => bail!("--threads: expected at least 1"),
        Some(k) => k,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    let dir = options
        .out
        .clone()
        .unwrap_or_else(|| Path::new("logs").join(format!("sweep-{}", spec.name)));
    let indices = spec.indices(shard);
    if options.dry_run {
        for &i in &indices {
            let run = spec.run(i);
            let log = match options.keep {
                sweep::Keep::Logs => dir.join(spec.log_name(i)).display().to_string(),
                sweep::Keep::Metrics => "(no log)".into(),
            };
            outln!("{i}  {log}  {}", run.overrides.join(" "));
        }
        return Ok(ExitCode::SUCCESS);
    }
    if dir.exists() && !dir.is_dir() {
        bail!(
            "--out {}: expected a directory for the sweep's logs and summary, found a file",
            dir.display()
        );
    }
    Summary::check_outputs(&dir, shard).with_context(|| format!("writing the summary into {}", dir.display()))?;
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
    let rows = sweep::execute(&spec, &indices, &dir, (threads, options.keep), |row| {
        progress.update(row)
    })
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
        match options.keep {
            sweep::Keep::Logs => format!("logs in {}", dir.display()),
            sweep::Keep::Metrics => "no logs kept".into(),
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

/// `mjsafe bench`: its checks, the runs and the table (or JSON).
fn bench_command(
    scenario: &Path,
    overrides: &[String],
    (predictor_steps, chain_tolerances): (Vec<f64>, Vec<f64>),
    repeat: usize,
    log_dir: &Path,
    json: bool,
) -> Result<ExitCode> {
    let or_default = |values: Vec<f64>| -> Vec<Option<f64>> {
        if values.is_empty() {
            vec![None]
        } else {
            values.into_iter().map(Some).collect()
        }
    };
    if let Some(bad) = predictor_steps.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
        bail!("--predictor-step: expected positive numbers of seconds, found {bad}");
    }
    if let Some(bad) = chain_tolerances.iter().find(|t| !(t.is_finite() && **t >= 0.0)) {
        bail!("--chain-tolerance: expected finite numbers >= 0, found {bad}");
    }
    let (steps, tolerances) = (or_default(predictor_steps), or_default(chain_tolerances));
    let rows = crate::bench::run(scenario, overrides, &steps, &tolerances, repeat, log_dir)
        .with_context(|| format!("benchmarking {}", scenario.display()))?;
    if json {
        outln!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        outln!("{}", crate::bench::table(&rows));
    }
    Ok(ExitCode::SUCCESS)
}

/// `mjsafe plot-sweep`: a sweep's metric `y` against the swept key `x`, one PNG.
fn plot_sweep_command(summary: PathBuf, x: &str, y: &str, out: Option<PathBuf>) -> Result<ExitCode> {
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

/// `mjsafe man`: the man pages, one per subcommand into `dir`, or the main page on stdout.
fn man_command(dir: Option<PathBuf>) -> Result<ExitCode> {
    // `mjsafe help CMD` is `mjsafe CMD --help`: no page of its own, so none listed.
    let mut command = <Cli as clap::CommandFactory>::command();
    command.build();
    let command = command.mut_subcommand("help", |help| help.hide(true));
    match dir {
        Some(dir) => {
            if dir.exists() && !dir.is_dir() {
                bail!(
                    "--dir {}: expected a directory for the man pages, found a file",
                    dir.display()
                );
            }
            let pages = man_pages(command)?;
            // Every page checked before any is written (the files rules: never over a
            // file that is not a man page of mjsafe's, a link or a directory), each
            // written as `.partial` and renamed.
            use crate::files::{check_output, write_atomically, Replace};
            for (name, _) in &pages {
                check_output(&dir.join(name), "man page", Replace::IfStartsWith(MAN_START), &[])?;
            }
            for (name, text) in &pages {
                write_atomically(&dir.join(name), "man page", Replace::IfStartsWith(MAN_START), &[], text)?;
            }
            eprintln!("{} man pages written into {}", pages.len(), dir.display());
        }
        None => {
            let mut text = Vec::new();
            clap_mangen::Man::new(command).render(&mut text)?;
            out!("{}", String::from_utf8_lossy(&text));
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// What `mjsafe analyze` does with its files.
enum AnalyzeMode {
    Metrics,
    Compare,
    Merge(Option<PathBuf>),
}

/// `mjsafe analyze`: the plots first (with `--plot`), then the metrics, the comparison or the
/// merge. A plot that cannot be drawn (a damaged log: no plot of part of a run) fails the
/// command after the metrics are printed, not instead of them.
fn analyze_command(
    files: &[PathBuf],
    format: Format,
    mode: AnalyzeMode,
    plot: Option<&Path>,
    recover: bool,
) -> Result<ExitCode> {
    let plots_failed = match plot {
        Some(dir) => plot_logs(files, dir)?,
        None => false,
    };
    let code = match mode {
        AnalyzeMode::Compare => compare_files(files, format, recover)?,
        AnalyzeMode::Merge(out) => merge_summaries(files, format, out.as_deref())?,
        AnalyzeMode::Metrics => analyze_files(files, format, recover),
    };
    Ok(if plots_failed { ExitCode::FAILURE } else { code })
}

/// `analyze --plot DIR`: each log's plots and, for several logs, the overlays; each written
/// plot on stderr. Ok(true) when a plot could not be drawn (an error line for it), after the
/// others are written; Err for a directory or names that cannot take them.
fn plot_logs(files: &[PathBuf], dir: &Path) -> Result<bool> {
    let mut failed = false;
    if dir.exists() && !dir.is_dir() {
        bail!(
            "--plot {}: expected a directory for the plots, found a file",
            dir.display()
        );
    }
    // Plots are named by the log's file name: two logs of one name, or a log named
    // like the overlays, would overwrite each other's plots.
    let stem = |file: &Path| PathBuf::from(file.file_stem().unwrap_or_default());
    if let Some(file) = files
        .iter()
        .find(|f| stem(f) == Path::new("overlay") && files.len() > 1)
    {
        bail!(
            "{}: its plots would be named like the overlays (overlay-*.png); rename the log",
            file.display()
        );
    }
    if let Some((a, b)) = same_output_names(files, stem) {
        bail!(
            "{} and {}: both would write {}-*.png in {}; plot them into different --plot directories",
            a.display(),
            b.display(),
            stem(a).display(),
            dir.display()
        );
    }
    // Each written plot on stderr; an error line for a plot that failed.
    let report = |result: Result<Vec<std::path::PathBuf>, crate::plot::PlotError>| match result {
        Ok(written) => {
            for w in written {
                eprintln!("plot: {}", w.display());
            }
            true
        }
        Err(e) => {
            eprintln!("error: {e}");
            false
        }
    };
    for file in files {
        failed |= !report(crate::plot::plot_log(file, dir));
    }
    if files.len() > 1 && !failed {
        failed |= !report(crate::plot::plot_overlay(files, dir));
    }
    Ok(failed)
}

/// `mjsafe falsify`: its checks, the problem, the search and the report.
fn falsify_command(args: FalsifyArgs) -> Result<ExitCode> {
    let FalsifyArgs {
        scenario,
        ranges,
        overrides,
        objective,
        threshold,
        budget,
        seed,
        threads,
        worst,
        baseline_threshold,
        baseline,
        compare_random,
        out,
    } = args;
    let ranges = ranges
        .iter()
        .map(|r| sweep::parse_range(r))
        .collect::<Result<Vec<_>, _>>()?;
    if let Some(twice) = sweep::swept_twice(ranges.iter().map(|r| r.key.as_str())) {
        bail!("--range {twice}: the key is given twice (each key takes one --range)");
    }
    falsify::check_objective(&objective)?;
    if !threshold.is_finite() {
        bail!("--threshold: expected a finite number, found {threshold}");
    }
    if !baseline_threshold.is_finite() {
        bail!("--baseline-threshold: expected a finite number, found {baseline_threshold}");
    }
    let threads = match threads {
        Some(0) => bail!("--threads: expected at least 1"),
        Some(k) => k,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    // The scenario and every override are checked once before the search starts.
    let base = scenario::load(&scenario, &overrides)?;
    if let Some((group, _)) = objective.split_once('.') {
        // A per-channel metric names a channel of the vehicle: told by one run of the
        // scenario as given (when it runs), not by a whole budget of absent values.
        let run = sweep::Run {
            index: 0,
            overrides: overrides.clone(),
            parameters: Vec::new(),
        };
        let row = sweep::execute_analysed(&scenario, &run, "the scenario's run");
        if let Some(metrics) = &row.metrics {
            let columns = FlatMetrics::columns([metrics]);
            if !columns.contains(&objective) {
                let prefix = format!("{group}.");
                let known: Vec<&str> = columns
                    .iter()
                    .map(String::as_str)
                    .filter(|c| c.starts_with(&prefix))
                    .collect();
                bail!(
                    "--objective {objective}: not a metric of this scenario's runs; its per-channel {group} metrics: {}",
                    if known.is_empty() { "none".to_string() } else { known.join(", ") }
                );
            }
        }
    }
    let problem = falsify::Problem {
        scenario,
        set: overrides,
        ranges,
        objective,
        threshold,
        baseline_threshold,
        baseline,
        budget,
        seed,
        threads,
        worst,
    };
    let out = out.unwrap_or_else(|| Path::new("logs").join(format!("falsify-{}", base.scenario.name)));
    run_falsify(&problem, &out, compare_random)
}

fn run_falsify(problem: &falsify::Problem, out: &Path, compare_random: bool) -> Result<ExitCode> {
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
        outln!(
            "{}: {} runs, {}; best {} = {}{}",
            s.method.name(),
            s.evaluations.len(),
            s.runs_to_first_violation()
                .map_or("no violation".to_string(), |n| format!("first violation at run {n}")),
            problem.objective,
            best.and_then(|e| e.objective)
                .map_or("absent".into(), |v| format!("{v:.4}")),
            best.and_then(|e| e.baseline)
                .map_or(String::new(), |b| format!(" (baseline {b:.4})")),
        );
    }
    if let Some(e) = &report.chosen {
        outln!(
            "{} violation: index {} in evaluations.csv, {} = {}{} | {}",
            if problem.worst { "most severe" } else { "first" },
            e.index,
            problem.objective,
            e.objective.map_or("absent".into(), |v| format!("{v:.4}")),
            e.baseline.map_or(String::new(), |b| format!(" (baseline {b:.4})")),
            e.severity.describe()
        );
    }
    match &report.counterexample {
        Some((scenario, log)) => outln!(
            "counterexample: {} ({}) | evaluations: {}, {}{}",
            scenario.display(),
            match report.reproduced {
                Some(v) => format!("its run: {}, {} = {v:.4}", log.display(), problem.objective),
                None if report.rerun_interrupted => format!("its run was interrupted: {} is incomplete", log.display()),
                None => "not re-run: the search was interrupted".into(),
            },
            report.evaluations_csv.display(),
            report.evaluations_json.display(),
            report
                .convergence_png
                .as_ref()
                .map_or(String::new(), |p| format!(" | plot: {}", p.display()))
        ),
        None => outln!(
            "no counterexample within {} runs | evaluations: {}, {}",
            report.searches[0].evaluations.len(),
            report.evaluations_csv.display(),
            report.evaluations_json.display()
        ),
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

/// The progress line on stderr: rewritten in place on a terminal, one line per run otherwise.
struct Progress {
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

fn export(files: &[PathBuf], format: crate::export::Format, topics: &[String], out: Option<&Path>) -> Result<ExitCode> {
    let explicit = !topics.is_empty();
    let topics = crate::export::parse_topics(topics)?;
    // Two logs whose tables would have the same names (the same stem into one directory)
    // would overwrite each other's tables: refused before any is written.
    let dir = |file: &Path| {
        out.map_or_else(
            || file.parent().unwrap_or(Path::new("")).to_path_buf(),
            Path::to_path_buf,
        )
    };
    let tables = |file: &Path| dir(file).join(crate::export::table_stem(file));
    if let Some((a, b)) = same_output_names(files, tables) {
        let shown = match dir(b).display().to_string() {
            d if d.is_empty() => ".".to_string(),
            d => d,
        };
        bail!(
            "{} and {}: both would write {}-*.{} in {shown}; export them into different --out directories",
            a.display(),
            b.display(),
            crate::export::table_stem(b),
            format.extension()
        );
    }
    let mut failed = false;
    for file in files {
        match crate::export::export_log(file, out, &topics, format) {
            Ok(exported) => {
                for (topic, path, rows) in &exported.tables {
                    outln!("{topic}: {rows} rows -> {}", path.display());
                }
                for topic in exported.empty.iter().filter(|_| explicit) {
                    eprintln!("note: {}: no messages on {topic}, no table written", file.display());
                }
                if !exported.complete {
                    eprintln!(
                        "note: {}: the run did not complete (interrupted or stopped on an error): its tables end where its log does",
                        file.display()
                    );
                }
            }
            Err(e) => {
                eprintln!("error: {e}");
                failed = true;
            }
        }
    }
    Ok(if failed { ExitCode::FAILURE } else { ExitCode::SUCCESS })
}

fn info(file: &Path, resolved: bool, json: bool, recover: bool) -> Result<ExitCode> {
    let info = if recover {
        crate::log::info::log_info_recover(file)?
    } else {
        crate::log::info::log_info(file)?
    };
    let code = match &info.error {
        Some(e) => {
            eprintln!("error: {e} (--recover: showing what was read before)");
            ExitCode::FAILURE
        }
        None => ExitCode::SUCCESS,
    };
    if json {
        outln!("{}", serde_json::to_string_pretty(&info).expect("info serialises"));
        return Ok(code);
    }
    outln!("file:      {} ({} bytes)", info.file, info.bytes);
    if info.error.is_some() {
        outln!("messages:  {} read before the damage", info.messages);
    } else {
        match info.chunks {
            Some(chunks) => outln!("messages:  {} in {chunks} chunks", info.messages),
            None => outln!("messages:  {} (counted: no statistics record)", info.messages),
        }
    }
    outln!(
        "time:      {:.3} .. {:.3} s ({:.3} s of simulation time)",
        info.start,
        info.end,
        info.end - info.start
    );
    outln!("channels:");
    let topic_width = info.channels.iter().map(|c| c.topic.len()).max().unwrap_or(0);
    let count_width = info
        .channels
        .iter()
        .map(|c| c.messages.to_string().len())
        .max()
        .unwrap_or(0);
    for c in &info.channels {
        outln!(
            "  ({}) {:<topic_width$}  {:>count_width$} msgs  {} [{}]",
            c.id,
            c.topic,
            c.messages,
            c.schema,
            c.schema_encoding
        );
    }
    let mut scenario_text = None;
    let mut resolved_text = None;
    for (name, entries) in &info.metadata {
        outln!("metadata {name}:");
        let width = entries.keys().map(|k| k.len()).max().unwrap_or(0);
        for (key, value) in entries {
            match key.as_str() {
                "scenario" if name == "mjsafe" => scenario_text = Some(value.clone()),
                "scenario_resolved" if name == "mjsafe" => resolved_text = Some(value.clone()),
                _ => {
                    let mut lines = value.lines();
                    let first = lines.next().unwrap_or(if key == "overrides" { "(none)" } else { "" });
                    outln!("  {key:<width$}  {first}");
                    for line in lines {
                        outln!("  {:<width$}  {line}", "");
                    }
                }
            }
        }
    }
    if let Some(text) = scenario_text {
        outln!("scenario (as written):");
        for line in text.lines() {
            outln!("  | {line}");
        }
    }
    if resolved {
        match resolved_text {
            Some(text) => {
                outln!("scenario (resolved, after overrides):");
                for line in text.lines() {
                    outln!("  | {line}");
                }
            }
            None => eprintln!("warning: the log holds no resolved scenario"),
        }
    }
    Ok(code)
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
