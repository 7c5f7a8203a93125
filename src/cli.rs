//! The `mjsafe` command line: run, analyze.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

use crate::analyze::{self, RunMetrics};
use crate::episode::{self, Episode};
use crate::log::mcap::McapSink;
use crate::log::Sink;
use crate::scenario;

#[derive(Debug, Parser)]
#[command(
    name = "mjsafe",
    version,
    about = "MuJoCo vehicle safety testbed: delayed actuators, safety filters, MCAP logs"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run one scenario headless; writes one MCAP log and prints a one-line summary.
    Run {
        /// Scenario file (TOML).
        scenario: PathBuf,
        /// Override a field: KEY.PATH=VALUE in TOML value syntax (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
        /// Log file (default: logs/<name>-<UTC time>.mcap).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Per-run metrics of MCAP logs.
    Analyze {
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
}

/// Parses arguments, runs the command, returns the process exit code.
pub fn run() -> ExitCode {
    let cli = Cli::parse();
    match dispatch(cli.command) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn dispatch(command: Command) -> Result<ExitCode> {
    match command {
        Command::Run {
            scenario,
            overrides,
            out,
        } => run_scenario(&scenario, &overrides, out),
        Command::Analyze { files, json } => Ok(analyze_files(&files, json)),
    }
}

fn run_scenario(path: &Path, overrides: &[String], out: Option<PathBuf>) -> Result<ExitCode> {
    let loaded = scenario::load(path, overrides)?;
    let mut episode = Episode::new(&loaded)?;
    let log_path = out.unwrap_or_else(|| episode::default_log_path(Path::new("logs"), &loaded.scenario.name));
    let mut sink = McapSink::create(&log_path, episode.info())?;
    let summary = {
        let mut sinks: [&mut dyn Sink; 1] = [&mut sink];
        episode.run(&mut sinks)?
    };
    let metrics = analyze::analyze_file(&log_path)
        .with_context(|| format!("reading back the log just written, {}", log_path.display()))?;
    println!(
        "{}: {} | min h = {} | {} steps, {:.2} s simulated, {:.0}x real time | log: {}",
        loaded.scenario.name,
        metrics
            .collision
            .as_ref()
            .map_or("no collision".to_string(), |c| format!(
                "COLLISION at t = {:.3} s with {} (depth {:.3} m)",
                c.time, c.with, c.depth
            )),
        metrics.min_h.map_or("-".into(), |h| format!("{h:.3}")),
        summary.steps,
        summary.simulated_time,
        summary.real_time_factor(),
        log_path.display()
    );
    if let Some(error) = summary.error {
        eprintln!("error: the episode stopped early: {error} (the log holds the run up to that point)");
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

fn analyze_files(files: &[PathBuf], json: bool) -> ExitCode {
    let mut runs: Vec<RunMetrics> = Vec::new();
    let mut failed = false;
    for file in files {
        match analyze::analyze_file(file) {
            Ok(m) => runs.push(m),
            Err(e) => {
                eprintln!("error: {e}");
                failed = true;
            }
        }
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&runs).expect("metrics serialise"));
    } else if !runs.is_empty() {
        println!("{}", analyze::table(&runs));
    }
    if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}
