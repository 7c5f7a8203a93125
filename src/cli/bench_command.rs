//! `mjsafe bench`.

use super::*;

/// `mjsafe bench`: its checks, the runs and the table (or JSON).
pub(super) fn bench_command(
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

/// `mjsafe bench`: End-to-end speed of a scenario on this thread: the bare physics loop over its model,
#[derive(Debug, clap::Args)]
pub struct BenchCommand {
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
}

impl BenchCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let BenchCommand {
            scenario,
            overrides,
            predictor_steps,
            chain_tolerances,
            repeat,
            log_dir,
            json,
        } = self;
        bench_command(
            &scenario,
            &overrides,
            (predictor_steps, chain_tolerances),
            repeat,
            &log_dir,
            json,
        )
    }
}
