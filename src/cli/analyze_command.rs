//! `mjsafe analyze` (metrics, comparison, merge of sweep shards, plots) and `mjsafe metrics`.

use super::*;

/// The metrics of a log; with `recover`, a damaged log gives the metrics of what was read
/// before the damage (marked incomplete, with the damage as their error) and the error.
pub(super) fn analyze_or_recover(
    file: &Path,
    recover: bool,
    requirements: &[(String, String)],
) -> Result<(RunMetrics, Option<analyze::AnalyzeError>), analyze::AnalyzeError> {
    match analyze::analyze_file_with(file, requirements) {
        Ok(m) => Ok((m, None)),
        Err(analyze::AnalyzeError::Corrupt {
            damage,
            partial: Some(partial),
        }) if recover => Ok((*partial, Some(analyze::AnalyzeError::Read(damage)))),
        Err(e) => Err(e),
    }
}

pub(super) fn analyze_files(
    files: &[PathBuf],
    format: Format,
    recover: bool,
    requirements: &[(String, String)],
) -> ExitCode {
    let mut runs: Vec<RunMetrics> = Vec::new();
    let mut failed = false;
    for file in files {
        match analyze_or_recover(file, recover, requirements) {
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
            if let Some(past) = run.past_vehicle_limits() {
                eprintln!("warning: {}: {past}", run.file);
            }
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

pub(super) fn compare_files(
    files: &[PathBuf],
    format: Format,
    recover: bool,
    requirements: &[(String, String)],
) -> Result<ExitCode> {
    let [a, b] = files else {
        bail!("--compare takes exactly two logs A B, {} given", files.len());
    };
    let (ma, damage_a) = analyze_or_recover(a, recover, requirements)?;
    let (mb, damage_b) = analyze_or_recover(b, recover, requirements)?;
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

pub(super) fn merge_summaries(args: &[PathBuf], format: Format, out: Option<&Path>) -> Result<ExitCode> {
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

/// What `mjsafe analyze` does with its files.
pub(super) enum AnalyzeMode {
    Metrics,
    Compare,
    Merge(Option<PathBuf>),
}

/// `mjsafe analyze`: the plots first (with `--plot`), then the metrics, the comparison or the
/// merge. A plot that cannot be drawn (a damaged log: no plot of part of a run) fails the
/// command after the metrics are printed, not instead of them.
pub(super) fn analyze_command(
    files: &[PathBuf],
    format: Format,
    mode: AnalyzeMode,
    plot: Option<(&Path, crate::plot::Format)>,
    recover: bool,
    requirements: &[(String, String)],
) -> Result<ExitCode> {
    let plots_failed = match plot {
        Some((dir, plot_format)) => plot_logs(files, dir, plot_format)?,
        None => false,
    };
    let code = match mode {
        AnalyzeMode::Compare => compare_files(files, format, recover, requirements)?,
        AnalyzeMode::Merge(out) => merge_summaries(files, format, out.as_deref())?,
        AnalyzeMode::Metrics => analyze_files(files, format, recover, requirements),
    };
    Ok(if plots_failed { ExitCode::FAILURE } else { code })
}

/// `analyze --plot DIR`: each log's plots and, for several logs, the overlays; each written
/// plot on stderr. Ok(true) when a plot could not be drawn (an error line for it), after the
/// others are written; Err for a directory or names that cannot take them.
pub(super) fn plot_logs(files: &[PathBuf], dir: &Path, plot_format: crate::plot::Format) -> Result<bool> {
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
        failed |= !report(crate::plot::plot_log(file, dir, plot_format));
    }
    if files.len() > 1 && !failed {
        failed |= !report(crate::plot::plot_overlay(files, dir, plot_format));
    }
    Ok(failed)
}

/// `mjsafe analyze`: Per-run metrics of MCAP logs; or two runs compared; or sweep shard summaries merged.
#[derive(Debug, clap::Args)]
pub struct AnalyzeCommand {
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
    /// The plots' format: `png` (antialiased) or `svg` (vector, for papers).
    #[arg(
        long = "plot-format",
        value_enum,
        value_name = "png|svg",
        default_value = "png",
        requires = "plot"
    )]
    plot_format: crate::plot::Format,
    /// On a damaged log, still report the metrics of what was read before the damage (the
    /// chunks that passed their CRC), marked incomplete; the exit status is still non-zero.
    #[arg(long, conflicts_with = "merge")]
    recover: bool,
    /// A requirement to evaluate on every log besides its run's own: an STL formula over the
    /// run's signals, reported as `req.NAME` (docs/requirements.md) (repeatable).
    #[arg(long = "require", value_name = "NAME=FORMULA", conflicts_with = "merge")]
    require: Vec<String>,
}

impl AnalyzeCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let AnalyzeCommand {
            files,
            json,
            csv,
            brief,
            compare,
            merge,
            out,
            plot,
            recover,
            require,
            plot_format,
        } = self;
        let requirements = (require.iter())
            .map(|flag| scenario::parse_require_flag(flag).map_err(|e| anyhow::anyhow!("--require {flag}: {e}")))
            .collect::<Result<Vec<_>>>()?;
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
        analyze_command(
            &files,
            format,
            mode,
            plot.as_deref().map(|d| (d, plot_format)),
            recover,
            &requirements,
        )
    }
}

/// `mjsafe metrics`: List every metric `analyze` computes: its JSON name, flat column, unit and meaning
#[derive(Debug, clap::Args)]
pub struct MetricsCommand {
    /// Print the Markdown table of docs/metrics.md instead of aligned text.
    #[arg(long)]
    markdown: bool,
}

impl MetricsCommand {
    /// Runs the command; its exit code.
    pub fn execute(self) -> Result<ExitCode> {
        let MetricsCommand { markdown } = self;
        let table = crate::metrics::reference_table();
        if markdown {
            out!("{table}");
        } else {
            outln!("{}", crate::metrics::report::markdown_as_text(&table));
        }
        Ok(ExitCode::SUCCESS)
    }
}
