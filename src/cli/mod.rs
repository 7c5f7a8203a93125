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

use crate::analyze::{self, RunMetrics};
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
    /// `run --fail-on-violation`: a requirement's robustness is negative.
    pub const VIOLATION: u8 = 5;
    /// `scorecard --fail-below`: some filter's overall score is below the threshold;
    /// `scorecard --compare`: some item is worse in the second scorecard.
    pub const BELOW: u8 = 6;
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
  5    run --fail-on-violation: a requirement is violated (robustness < 0)
  6    scorecard --fail-below: some filter's overall score is below the threshold;
       scorecard --compare: some item is worse in the second scorecard
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

mod analyze_command;
mod bench_command;
mod falsify_command;
mod import_command;
mod log_commands;
mod man_command;
mod run_command;
mod scorecard_command;
mod sweep_command;

use analyze_command::*;
use bench_command::*;
use falsify_command::*;
use import_command::*;
use log_commands::*;
use man_command::*;
use run_command::*;
use scorecard_command::*;
use sweep_command::*;

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

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run one scenario headless; writes one MCAP log and prints a one-line summary.
    #[command(after_help = run_examples!())]
    Run(RunCommand),
    /// Rebuild the rerun recording of a run from its MCAP log alone (no re-simulation):
    /// save it (--rrd), stream it to a viewer (--connect), or spawn a viewer (default).
    #[cfg(feature = "rerun")]
    Replay(ReplayCommand),
    /// Per-run metrics of MCAP logs; or two runs compared; or sweep shard summaries merged.
    #[command(after_help = analyze_examples!())]
    Analyze(AnalyzeCommand),
    /// Run a scenario over a grid of overrides and/or seeded random draws, in parallel;
    /// writes one log per run and summary.csv / summary.json (see docs/sweeps.md).
    #[command(after_help = sweep_examples!())]
    Sweep(SweepCommand),
    /// Score safety filters over a suite (`--suite standard`): the dissertation's examples,
    /// Euro NCAP's tests scored as Euro NCAP scores them, car following, margins; one table
    /// (items by filters) and scorecard.json (see docs/scorecard.md).
    Scorecard(ScorecardCommand),
    /// Search the --range box for a run that violates safety: CMA-ES minimises an analysis
    /// metric (default min_h) and stops at the first violation (metric < threshold). Writes
    /// the counterexample as a scenario file plus its log, every evaluation (CSV, JSON) and a
    /// convergence plot.
    Falsify(FalsifyArgs),
    /// The time series of logs as tables: one wide, time-indexed CSV or Parquet file per topic
    /// (`<log stem>-<topic>.csv|parquet`: state names, per-channel commands, barriers per
    /// obstacle, predictions, events), streamed from the log (src/export.rs lists the columns).
    Export(ExportCommand),
    /// Plot a metric of a sweep against one swept key (e.g. min_h against delays.steering):
    /// one line per combination of the other swept keys, collisions marked.
    PlotSweep(PlotSweepCommand),
    /// Topics, message counts, schemas, time span, mjsafe metadata and scenario of a log.
    Info(InfoCommand),
    /// End-to-end speed of a scenario on this thread: the bare physics loop over its model,
    /// the full pipeline, and the pipeline with MCAP logging (median of --repeat runs), as
    /// real-time factors and ratios to the bare loop (docs/performance.md).
    Bench(BenchCommand),
    /// List every metric `analyze` computes: its JSON name, flat column, unit and meaning
    /// (docs/metrics.md's table is this output with --markdown).
    Metrics(MetricsCommand),
    /// Write the scenario a file of another format runs as, every default spelled out:
    /// `mjsafe import commonroad FILE.xml --out X.toml` (docs/commonroad.md).
    Import(ImportCommand),
    /// Print a shell completion script on stdout, e.g.
    /// `mjsafe completions bash > ~/.local/share/bash-completion/completions/mjsafe`.
    Completions(CompletionsCommand),
    /// Print the man page (roff) on stdout (`mjsafe man | man -l -`), or write mjsafe.1 and one
    /// page per subcommand (mjsafe-run.1, ...) into --dir.
    Man(ManCommand),
}

/// Parses arguments, runs the command, returns the process exit code.
pub fn run() -> ExitCode {
    run_with_args(std::env::args_os())
}

/// The command line given as `args` (the program's name first), in this process: what the
/// binary does, and what Python's `python -m mjsafe` runs after loading the user's modules
/// (their kinds registered in this process's registry).
pub fn run_with_args<I, T>(args: I) -> ExitCode
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    install_stop_handler();
    let cli = match Cli::try_parse_from(args) {
        Ok(cli) => cli,
        Err(e) => {
            // clap's own rendering (usage, --help, --version) and its exit status.
            let _ = e.print();
            return ExitCode::from(u8::try_from(e.exit_code()).unwrap_or(exit::ERROR));
        }
    };
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
        Command::Run(command) => command.execute(),
        #[cfg(feature = "rerun")]
        Command::Replay(command) => command.execute(),
        Command::Analyze(command) => command.execute(),
        Command::Sweep(command) => command.execute(),
        Command::Scorecard(command) => command.execute(),
        Command::Falsify(args) => args.execute(),
        Command::Export(command) => command.execute(),
        Command::PlotSweep(command) => command.execute(),
        Command::Info(command) => command.execute(),
        Command::Bench(command) => command.execute(),
        Command::Metrics(command) => command.execute(),
        Command::Import(command) => command.execute(),
        Command::Completions(command) => command.execute(),
        Command::Man(command) => command.execute(),
    }
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
