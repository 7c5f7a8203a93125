//! `mjsafe scorecard`: every filter over a suite; one table, `scorecard.json` (docs/scorecard.md).

use super::*;
use crate::scorecard;

/// `mjsafe scorecard`: score safety filters over a suite of items.
#[derive(Debug, clap::Args)]
pub struct ScorecardCommand {
    /// A filter to score: a preset of the suite (`gamma_m`, `cbf_qp`, …) or a TOML inline
    /// table '{ kind = "…", … }'; it replaces each item's own filter (repeatable, one column each).
    #[arg(long = "filter", value_name = "NAME|TABLE", required_unless_present = "compare")]
    filters: Vec<String>,
    /// The suite: `standard`, `quick` (suites/NAME.toml) or a suite file.
    #[arg(long, value_name = "standard|quick|FILE", default_value = "standard")]
    suite: String,
    /// Directory of scorecard.json (and logs/).
    #[arg(long, value_name = "DIR", required_unless_present = "compare")]
    out: Option<PathBuf>,
    /// Compare two scorecards item by item instead of running a suite: what got worse or
    /// better from A to B (exit 6 when something got worse).
    #[arg(long, num_args = 2, value_names = ["A/scorecard.json", "B/scorecard.json"], conflicts_with_all = ["filters", "out", "fail_below"])]
    compare: Option<Vec<PathBuf>>,
    /// Runs executed at once (default: all cores).
    #[arg(long, value_name = "K")]
    threads: Option<usize>,
    /// Exit with 6 when some filter's overall score is below SCORE percent.
    #[arg(long, value_name = "SCORE")]
    fail_below: Option<f64>,
    /// Which runs keep an MCAP log under DIR/logs/: `failing` (each cell's failing run, run
    /// again with its log), `all` (every run of a grid item too) or `none`.
    #[arg(long, value_enum, value_name = "WHICH", default_value = "failing")]
    keep_logs: scorecard::KeepLogs,
    /// Print scorecard.json on stdout instead of the table.
    #[arg(long)]
    json: bool,
}

impl ScorecardCommand {
    pub(super) fn execute(&self) -> Result<ExitCode> {
        if let Some(files) = &self.compare {
            return compare(&files[0], &files[1]);
        }
        let out = self.out.as_ref().context("--out DIR: required")?;
        if let Some(s) = self.fail_below {
            if !(0.0..=100.0).contains(&s) {
                bail!("--fail-below {s}: expected a percentage in [0, 100]");
            }
        }
        let _graceful = episode::GracefulStop::begin();
        let terminal = std::io::stderr().is_terminal();
        let request = scorecard::Request {
            suite: &self.suite,
            filters: &self.filters,
            threads: self.threads,
            keep_logs: self.keep_logs,
            out: Some(out),
        };
        let mut reported = 0;
        let card = scorecard::score(&request, |p| {
            if terminal {
                eprint!("\r{}/{} jobs", p.done, p.total);
                if p.done == p.total {
                    eprintln!();
                }
            } else if p.done * 10 >= (reported + 1) * p.total {
                // A log file or CI: a line at each tenth, not a carriage return per run.
                reported = p.done * 10 / p.total.max(1);
                eprintln!("scorecard: {}/{} jobs", p.done, p.total);
            }
        })?;
        let (target, report) = (out.join("scorecard.json"), out.join("report.html"));
        if self.json {
            out!("{}", card.to_json());
        } else {
            outln!("{}", card.table());
            outln!(
                "{} runs in {:.1} s; {} and {}{}",
                card.runs,
                card.wall_seconds,
                target.display(),
                report.display(),
                if card.complete {
                    ""
                } else {
                    " (incomplete: interrupted)"
                }
            );
        }
        if !card.complete {
            return Ok(ExitCode::from(exit::INTERRUPTED));
        }
        let below = self
            .fail_below
            .is_some_and(|s| card.overall.iter().any(|o| o.is_none_or(|o| 100.0 * o < s)));
        Ok(ExitCode::from(if below { exit::BELOW } else { exit::DONE }))
    }
}

/// `--compare A B`: the regression report of two scorecards.
fn compare(a: &Path, b: &Path) -> Result<ExitCode> {
    let read = |path: &Path| -> Result<serde_json::Value> {
        let text = crate::files::read_text_limited(path, "scorecard", crate::files::SWEEP_FILE_LIMIT)?;
        serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: expected a scorecard.json: {e}", path.display()))
    };
    let (va, vb) = (read(a)?, read(b)?);
    let (na, nb) = (a.display().to_string(), b.display().to_string());
    let comparison = scorecard::compare::compare(&va, &vb, (&na, &nb)).map_err(anyhow::Error::msg)?;
    outln!("A: {na}\nB: {nb}");
    outln!("{}", comparison.table());
    Ok(ExitCode::from(if comparison.worse() > 0 {
        exit::BELOW
    } else {
        exit::DONE
    }))
}
