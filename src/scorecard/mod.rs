//! `mjsafe scorecard`: one verdict per filter over a suite (docs/scorecard.md). Every run goes
//! through the one run path ([`crate::run`], analysed in memory); the filter replaces the
//! scenario's own; the Euro NCAP items are scored as Euro NCAP's 2026 calculator scores
//! ([`crate::ncap`]), gate included.

pub mod compare;
pub mod report;
pub mod score;
pub mod suite;

use std::panic::{catch_unwind, AssertUnwindSafe};

use serde::Serialize;

use crate::ncap::{self, Colour};
use crate::run::{self, Keep};
use crate::scenario;
use crate::sweep::{self, SweepError};
pub use score::{Cell, Point, RunResult, Status};
pub use suite::{Item, Scoring, Suite, SuiteError};

/// A filter the scorecard scores: its column name and its spec (a TOML inline table).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FilterChoice {
    pub name: String,
    pub spec: String,
    /// The filter's label from its runs (equation number), once one has run.
    pub label: Option<String>,
}

/// `--filter NAME` (a preset of the suite) or `--filter '{ kind = "…", … }'`.
pub fn choose_filter(arg: &str, suite: &Suite) -> Result<FilterChoice, String> {
    let trimmed = arg.trim();
    if trimmed.starts_with('{') {
        let value: toml::Table = toml::from_str(&format!("filter = {trimmed}"))
            .map_err(|e| format!("--filter {arg}: expected a TOML inline table: {}", e.message()))?;
        let spec = value.get("filter").map(suite::inline).unwrap_or_default();
        // Named by its table written out one way, so that `{kind="none"}` and `{ kind = "none" }`
        // (or Python's dict) are one column.
        return Ok(FilterChoice {
            name: spec.clone(),
            spec,
            label: None,
        });
    }
    match suite.filters.get(trimmed) {
        Some(spec) => Ok(FilterChoice {
            name: trimmed.to_string(),
            spec: spec.clone(),
            label: None,
        }),
        None => Err(format!(
            "--filter {arg}: expected a preset of {} ({}) or an inline table '{{ kind = \"…\", … }}'",
            suite.file,
            suite.filters.keys().cloned().collect::<Vec<_>>().join(", ")
        )),
    }
}

/// An item's row of the scorecard: one cell per filter.
#[derive(Debug, Clone, Serialize)]
pub struct ItemCard {
    pub name: String,
    pub section: String,
    pub scoring: Scoring,
    pub claim: Option<String>,
    pub scenario: String,
    pub cells: Vec<Cell>,
}

/// The gate of the Euro NCAP frontal-collision scores for one filter.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NcapTotal {
    /// Sum of the test scores (after the gate), Euro NCAP points.
    pub score: f64,
    /// Sum of the weights of the tests in the suite.
    pub max: f64,
    /// Whether the gate passed; absent when the suite lacks its points (`gate_reason`).
    pub gate_passed: Option<bool>,
    pub gate_reason: Option<String>,
}

/// The whole scorecard (`scorecard.json`).
#[derive(Debug, Clone, Serialize)]
pub struct Scorecard {
    pub mjsafe_version: String,
    pub suite: SuiteRef,
    pub filters: Vec<FilterChoice>,
    pub items: Vec<ItemCard>,
    /// Per filter: the Euro NCAP total (absent without Euro NCAP items).
    pub ncap: Vec<Option<NcapTotal>>,
    /// Per filter: the mean over items of score / max (pass 1, fail 0), items without one left out.
    pub overall: Vec<Option<f64>>,
    /// False when interrupted: some cells are `not_run`.
    pub complete: bool,
    pub runs: usize,
    pub wall_seconds: f64,
}

/// Which suite made a scorecard.
#[derive(Debug, Clone, Serialize)]
pub struct SuiteRef {
    pub name: String,
    pub file: String,
    pub fnv1a: String,
}

/// One unit of work: a run of an item, or a margin item's whole bisection (its runs depend on
/// each other).
enum Job<'a> {
    Run {
        column: usize,
        item: usize,
        run: sweep::Run,
    },
    Margin {
        column: usize,
        item: usize,
        filter: &'a str,
    },
    /// A falsification item's whole search (run on one thread: the jobs fill the cores).
    Falsify {
        column: usize,
        item: usize,
        filter: &'a str,
    },
}

enum JobResult {
    Run(Box<RunResult>),
    Margin(score::Bisection),
    Falsify(Box<Result<crate::falsify::Search, String>>),
}

/// Why a scorecard could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ScorecardError {
    #[error(transparent)]
    Suite(#[from] SuiteError),
    /// A filter argument: the argument and what was expected.
    #[error("{0}")]
    Filter(String),
    #[error(transparent)]
    Sweep(#[from] SweepError),
    #[error(transparent)]
    Output(#[from] crate::files::FileError),
    #[error("{path}: {reason}")]
    Io { path: String, reason: std::io::Error },
}

/// What `mjsafe scorecard` (and Python's `mjsafe.scorecard`) is asked.
#[derive(Debug, Clone)]
pub struct Request<'a> {
    /// `standard`, `quick` or a suite file.
    pub suite: &'a str,
    /// Presets of the suite or inline tables, one column each.
    pub filters: &'a [String],
    /// Runs at once (None: every core).
    pub threads: Option<usize>,
    pub keep_logs: KeepLogs,
    /// The directory of scorecard.json, report.html and logs/ (None: nothing written, no logs).
    pub out: Option<&'a std::path::Path>,
}

const JSON_START: &[u8] = b"{";
const HTML_START: &[u8] = b"<!DOCTYPE html>";

/// Makes the scorecard `request` asks for: the suite loaded, the filters chosen, every run made
/// (`progress` told after each), and with `out` scorecard.json, report.html and the logs
/// written there (checked before the first run: a clobbered foreign file is refused).
pub fn score(request: &Request<'_>, progress: impl FnMut(Progress)) -> Result<Scorecard, ScorecardError> {
    use crate::files::{check_output, write_atomically, Replace};
    let path = suite::resolve(request.suite)?;
    let suite = Suite::load(&path)?;
    let mut filters: Vec<FilterChoice> = Vec::with_capacity(request.filters.len());
    if request.filters.is_empty() {
        return Err(ScorecardError::Filter("--filter: expected at least one filter".into()));
    }
    for arg in request.filters {
        let choice = choose_filter(arg, &suite).map_err(ScorecardError::Filter)?;
        if filters.iter().any(|f| f.name == choice.name) {
            return Err(ScorecardError::Filter(format!("--filter {arg}: given twice")));
        }
        filters.push(choice);
    }
    let threads = sweep::threads(request.threads)?;
    if let Some(out) = request.out {
        check_output(
            &out.join("scorecard.json"),
            "scorecard",
            Replace::IfStartsWith(JSON_START),
            &[&path],
        )?;
        check_output(
            &out.join("report.html"),
            "scorecard report",
            Replace::IfStartsWith(HTML_START),
            &[&path],
        )?;
    }
    let logs = LogPolicy {
        which: if request.out.is_some() {
            request.keep_logs
        } else {
            KeepLogs::None
        },
        dir: request.out.map(std::path::Path::to_path_buf).unwrap_or_default(),
    };
    let card = run_suite(&suite, &mut filters, threads, &logs, progress)?;
    if let Some(out) = request.out {
        std::fs::create_dir_all(out).map_err(|reason| ScorecardError::Io {
            path: out.display().to_string(),
            reason,
        })?;
        let json = card.to_json();
        write_atomically(
            &out.join("scorecard.json"),
            "scorecard",
            Replace::IfStartsWith(JSON_START),
            &[&path],
            json.as_bytes(),
        )?;
        let html = report::html(&card);
        write_atomically(
            &out.join("report.html"),
            "scorecard report",
            Replace::IfStartsWith(HTML_START),
            &[&path],
            html.as_bytes(),
        )?;
    }
    Ok(card)
}

/// Which runs keep their MCAP log (`--keep-logs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum KeepLogs {
    /// No log: every run analysed in memory.
    None,
    /// The failing run of each cell (a collision, a goal missed, the worst Euro NCAP point when
    /// it is not green, a margin's first unclear run, a search's worst counterexample), run
    /// again with its log.
    Failing,
    /// Every run of a grid item, and the failing run of a margin or falsification item.
    All,
}

/// Where the logs go and which runs keep one.
#[derive(Debug, Clone)]
pub struct LogPolicy {
    pub which: KeepLogs,
    /// The scorecard's directory (the logs go under `logs/`).
    pub dir: std::path::PathBuf,
}

impl LogPolicy {
    /// `logs/<column>-<filter>/<item>[/<run>].mcap`, relative to the scorecard's directory.
    fn relative(&self, column: usize, filter: &str, item: &str, run: Option<usize>) -> String {
        let slug = |s: &str| -> String {
            let kept: String = (s.chars())
                .map(|c| {
                    if c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.' {
                        c
                    } else {
                        '_'
                    }
                })
                .take(48)
                .collect();
            kept.trim_matches('_').to_string()
        };
        let filter = format!("{}-{}", column + 1, slug(filter));
        match run {
            Some(k) => format!("logs/{filter}/{}/{k}.mcap", slug(item)),
            None => format!("logs/{filter}/{}.mcap", slug(item)),
        }
    }
}

/// Runs the item's scenario with `overrides` through the one run path, analysed in memory, or
/// into the MCAP log `log` (its parent directory made) and analysed from it.
pub fn run_once(
    item: &Item,
    overrides: Vec<String>,
    parameters: Vec<(String, String)>,
    log: Option<&std::path::Path>,
) -> RunResult {
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        let loaded = scenario::load(&item.scenario, &overrides).map_err(|e| e.to_string())?;
        let keep = match log {
            Some(path) => {
                if let Some(parent) = path.parent() {
                    std::fs::create_dir_all(parent).map_err(|e| format!("{}: {e}", parent.display()))?;
                }
                Keep::Log(path)
            }
            None => Keep::Metrics(&item.name),
        };
        run::run(&loaded, keep, Vec::new()).map_err(|e| e.to_string())
    }));
    let (metrics, error) = match outcome {
        Ok(Ok(o)) => (o.metrics, o.summary.error.map(|e| e.to_string())),
        Ok(Err(e)) => (None, Some(e)),
        Err(payload) => (
            None,
            Some(format!("the run panicked: {}", sweep::panic_message(payload.as_ref()))),
        ),
    };
    RunResult {
        overrides,
        parameters,
        metrics,
        error: error.map(|e| crate::message::shorten_numbers(&e)),
        not_run: false,
    }
}

/// Bisects a margin item (its scoring is [`Scoring::Margin`]) for the filter override `filter`.
fn bisect(item: &Item, filter: &str) -> score::Bisection {
    let Scoring::Margin {
        key,
        safe,
        toward,
        tolerance,
        ..
    } = &item.score
    else {
        unreachable!("bisect is called for margin items")
    };
    let direction = (toward - safe).signum();
    // Values on the tolerance's lattice from `safe` (a delay stays a multiple of the timestep
    // when the tolerance is one); k steps of `tolerance`, at most span / tolerance ≤ 1e9.
    let last = ((toward - safe).abs() / tolerance + 1e-9).floor() as u64;
    let at = |k: u64| {
        let value = crate::ncap::round_half_up(safe + direction * k as f64 * tolerance, 12);
        let mut overrides = item.set.clone();
        overrides.push(filter.to_string());
        overrides.push(format!("{key}={value}"));
        (
            value,
            run_once(item, overrides, vec![(key.clone(), value.to_string())], None),
        )
    };
    let clear = |r: &RunResult| r.collided() == Some(false) && r.error.is_none();
    let mut steps = Vec::new();
    let (first, whole) = (at(0), at(last));
    let (first_clear, whole_clear) = (clear(&first.1), clear(&whole.1));
    steps.push(first);
    steps.push(whole);
    if first_clear && !whole_clear {
        // Invariant: clear at lo, not at hi; halves each step (at most 30 for 1e9 steps).
        let (mut lo, mut hi) = (0, last);
        while hi - lo > 1 && !crate::episode::stop_requested() {
            let mid = lo + (hi - lo) / 2;
            let step = at(mid);
            if clear(&step.1) {
                lo = mid;
            } else {
                hi = mid;
            }
            steps.push(step);
        }
    }
    score::Bisection { steps }
}

/// Runs a falsification item's search (its scoring is [`Scoring::Falsify`]) for the filter
/// override `filter`, on this thread.
fn search(item: &Item, filter: &str) -> Result<crate::falsify::Search, String> {
    let Scoring::Falsify {
        ranges,
        baseline,
        budget,
        seed,
        method,
        objective,
        threshold,
        baseline_threshold,
        baseline_no_stall,
    } = &item.score
    else {
        unreachable!("search is called for falsification items")
    };
    let request = crate::falsify::Request {
        scenario: item.scenario.clone(),
        ranges: ranges.clone(),
        set: item.with_filter(filter),
        objective: objective.clone(),
        threshold: *threshold,
        tolerance: crate::falsify::DEFAULT_TOLERANCE,
        budget: *budget,
        seed: *seed,
        threads: Some(1),
        worst: true,
        baseline_threshold: *baseline_threshold,
        baseline: baseline.clone(),
        baseline_no_stall: *baseline_no_stall,
        baseline_reaches_goal: false,
        method: *method,
        counterexamples: 1,
    };
    let (problem, _) = request.problem().map_err(|e| e.to_string())?;
    crate::falsify::search(&problem, *method, |_| {}).map_err(|e| e.to_string())
}

/// Whether `scenario` with `overrides` loads and assembles (model, filter, predictors): the
/// error of the first that fails.
pub fn assembles(scenario: &std::path::Path, overrides: &[String]) -> Result<(), String> {
    let loaded = scenario::load(scenario, overrides).map_err(|e| e.to_string())?;
    let prepared = run::Prepared::new(&loaded, Keep::Nothing).map_err(|e| e.to_string())?;
    prepared.abandon();
    Ok(())
}

/// What [`run_suite`] reports as it goes.
pub struct Progress {
    pub done: usize,
    pub total: usize,
}

/// Scores every filter of `filters` on every item of `suite`, `threads` runs at once.
pub fn run_suite(
    suite: &Suite,
    filters: &mut [FilterChoice],
    threads: usize,
    logs: &LogPolicy,
    mut progress: impl FnMut(Progress),
) -> Result<Scorecard, SweepError> {
    let started = std::time::Instant::now();
    let overrides: Vec<String> = filters.iter().map(|f| format!("filter={}", f.spec)).collect();
    let (jobs, not_applicable) = plan(suite, &overrides);
    let total = jobs.len();
    let mut finished = 0;
    let results = sweep::in_parallel(
        total,
        threads,
        "scorecard",
        |position| match &jobs[position] {
            Job::Run { column, item, run } => {
                let item = &suite.items[*item];
                let log = (logs.which == KeepLogs::All).then(|| {
                    logs.dir
                        .join(logs.relative(*column, &filters[*column].name, &item.name, Some(run.index)))
                });
                JobResult::Run(Box::new(run_once(
                    item,
                    run.overrides.clone(),
                    run.parameters.clone(),
                    log.as_deref(),
                )))
            }
            Job::Margin { item, filter, .. } => JobResult::Margin(bisect(&suite.items[*item], filter)),
            Job::Falsify { item, filter, .. } => JobResult::Falsify(Box::new(search(&suite.items[*item], filter))),
        },
        |_, _| {
            finished += 1;
            progress(Progress { done: finished, total });
        },
    )?;
    let gathered = Gathered::of(&jobs, results, suite.items.len(), filters.len());
    for (column, filter) in filters.iter_mut().enumerate() {
        filter.label = gathered.filter_label(column);
    }
    let items = (suite.items.iter().enumerate())
        .map(|(i, item)| item_card(item, i, &overrides, &not_applicable, &gathered))
        .collect();
    let mut card = Scorecard {
        mjsafe_version: env!("CARGO_PKG_VERSION").into(),
        suite: SuiteRef {
            name: suite.name.clone(),
            file: suite.file.clone(),
            fnv1a: suite.fnv1a.clone(),
        },
        filters: filters.to_vec(),
        items,
        ncap: Vec::new(),
        overall: Vec::new(),
        complete: gathered.complete,
        // Runs made, a margin's bisection and a search counted run by run.
        runs: 0,
        wall_seconds: 0.0,
    };
    if logs.which != KeepLogs::None {
        keep_failing_logs(suite, &mut card, logs, threads)?;
    }
    card.runs = card.items.iter().flat_map(|i| i.cells.iter().map(|c| c.runs)).sum();
    card.ncap = (0..filters.len()).map(|c| apply_gate(&mut card.items, c)).collect();
    card.overall = (0..filters.len()).map(|c| overall(&card.items, c)).collect();
    card.wall_seconds = started.elapsed().as_secs_f64();
    Ok(card)
}

/// [column][item]: why the filter does not apply to the item (none: it does).
type NotApplicable = Vec<Vec<Option<String>>>;

/// The jobs of every (filter, item) pair, and the pairs whose scenario refuses the filter (the
/// item itself assembles with its own filter: the suite checked it).
fn plan<'a>(suite: &Suite, overrides: &'a [String]) -> (Vec<Job<'a>>, NotApplicable) {
    let mut not_applicable = vec![vec![None; suite.items.len()]; overrides.len()];
    let mut jobs = Vec::new();
    for (column, filter) in overrides.iter().enumerate() {
        for (i, item) in suite.items.iter().enumerate() {
            if let Err(reason) = assembles(&item.scenario, &item.with_filter(filter)) {
                not_applicable[column][i] = Some(reason);
                continue;
            }
            match item.score {
                Scoring::Margin { .. } => jobs.push(Job::Margin {
                    column,
                    item: i,
                    filter,
                }),
                Scoring::Falsify { .. } => jobs.push(Job::Falsify {
                    column,
                    item: i,
                    filter,
                }),
                _ => {
                    let spec = item.sweep(filter);
                    jobs.extend((0..spec.runs).map(|k| Job::Run {
                        column,
                        item: i,
                        run: spec.run(k),
                    }));
                }
            }
        }
    }
    (jobs, not_applicable)
}

/// Each (filter, item)'s results, [column][item], in job order.
struct Gathered {
    runs: Vec<Vec<Vec<RunResult>>>,
    margins: Vec<Vec<Option<score::Bisection>>>,
    searches: Vec<Vec<Option<Result<crate::falsify::Search, String>>>>,
    /// False when some job never ran (interrupted).
    complete: bool,
}

impl Gathered {
    fn of(jobs: &[Job<'_>], results: Vec<Option<JobResult>>, items: usize, columns: usize) -> Gathered {
        let mut g = Gathered {
            runs: vec![vec![Vec::new(); items]; columns],
            margins: vec![vec![None; items]; columns],
            searches: vec![vec![None; items]; columns],
            complete: true,
        };
        for (job, result) in jobs.iter().zip(results) {
            match (job, result) {
                (Job::Run { column, item, .. }, Some(JobResult::Run(r))) => g.runs[*column][*item].push(*r),
                (Job::Margin { column, item, .. }, Some(JobResult::Margin(b))) => g.margins[*column][*item] = Some(b),
                (Job::Falsify { column, item, .. }, Some(JobResult::Falsify(s))) => {
                    g.searches[*column][*item] = Some(*s)
                }
                (Job::Run { column, item, run }, _) => {
                    g.complete = false;
                    g.runs[*column][*item].push(RunResult {
                        overrides: run.overrides.clone(),
                        parameters: run.parameters.clone(),
                        metrics: None,
                        error: None,
                        not_run: true,
                    });
                }
                (Job::Margin { .. } | Job::Falsify { .. }, _) => g.complete = false,
            }
        }
        g
    }

    /// The filter's label (equation number) from the first of its runs that has one.
    fn filter_label(&self, column: usize) -> Option<String> {
        (self.runs[column].iter().flatten())
            .chain(
                self.margins[column]
                    .iter()
                    .flatten()
                    .flat_map(|b| b.steps.iter().map(|(_, r)| r)),
            )
            .find_map(|r| r.metrics.as_ref().and_then(|m| m.filter_label.clone()))
    }
}

/// Item `i`'s row: one cell per filter column.
fn item_card(item: &Item, i: usize, overrides: &[String], not_applicable: &NotApplicable, g: &Gathered) -> ItemCard {
    let scenario = item.scenario.display().to_string();
    let interrupted = || {
        Cell::without_score(
            Status::NotRun,
            "not run: the scorecard was interrupted".into(),
            0,
            String::new(),
        )
    };
    let cells = (0..overrides.len())
        .map(|column| {
            if let Some(reason) = &not_applicable[column][i] {
                return Cell::without_score(
                    Status::NotApplicable,
                    reason.clone(),
                    0,
                    score::command(&scenario, &[overrides[column].clone()]),
                );
            }
            match &item.score {
                Scoring::Margin { .. } => g.margins[column][i]
                    .as_ref()
                    .map_or_else(interrupted, |b| score::margin_cell(&item.score, &scenario, b)),
                Scoring::Falsify { .. } => g.searches[column][i].as_ref().map_or_else(interrupted, |s| {
                    score::falsify_cell(&item.score, &scenario, &item.with_filter(&overrides[column]), s)
                }),
                _ => score::cell(item, &g.runs[column][i]),
            }
        })
        .collect();
    ItemCard {
        name: item.name.clone(),
        section: item.section.clone(),
        scoring: item.score.clone(),
        claim: item.claim.clone(),
        scenario,
        cells,
    }
}

/// Runs each cell's failing run again into its log (with [`KeepLogs::All`], a grid item's
/// runs have theirs already: the failing run's is pointed to).
fn keep_failing_logs(suite: &Suite, card: &mut Scorecard, logs: &LogPolicy, threads: usize) -> Result<(), SweepError> {
    let mut wanted = Vec::new();
    for (i, item) in card.items.iter().enumerate() {
        for (column, cell) in item.cells.iter().enumerate() {
            if let Some(overrides) = &cell.failing_run {
                wanted.push((i, column, overrides.clone()));
            }
        }
    }
    let results = sweep::in_parallel(
        wanted.len(),
        threads,
        "scorecard-logs",
        |k| {
            let (i, column, overrides) = &wanted[k];
            let relative = logs.relative(*column, &card.filters[*column].name, &suite.items[*i].name, None);
            let run = run_once(
                &suite.items[*i],
                overrides.clone(),
                Vec::new(),
                Some(&logs.dir.join(&relative)),
            );
            run.metrics.is_some().then_some(relative)
        },
        |_, _| {},
    )?;
    for ((i, column, _), relative) in wanted.iter().zip(results) {
        card.items[*i].cells[*column].log = relative.flatten();
    }
    Ok(())
}

/// The mean of the items' fractions for filter `column`.
fn overall(items: &[ItemCard], column: usize) -> Option<f64> {
    let fractions: Vec<f64> = items.iter().filter_map(|i| i.cells[column].fraction()).collect();
    (!fractions.is_empty()).then(|| fractions.iter().sum::<f64>() / fractions.len() as f64)
}

/// Euro NCAP's gate for filter `column` ([`ncap::gate_passes`]): when it fails, every Euro NCAP
/// item's score becomes 0 (its reason says why). Returns the total.
fn apply_gate(items: &mut [ItemCard], column: usize) -> Option<NcapTotal> {
    let test_of = |i: &ItemCard| match &i.scoring {
        Scoring::Ncap { test, .. } => Some(*test),
        _ => None,
    };
    if !items.iter().any(|i| test_of(i).is_some()) {
        return None;
    }
    let points_of = |test: ncap::Test| -> Vec<&Point> {
        (items.iter())
            .filter(|i| test_of(i) == Some(test))
            .flat_map(|i| i.cells[column].points.iter())
            .collect()
    };
    let ccrs: Vec<&Point> = points_of(ncap::Test::Ccrs)
        .into_iter()
        .filter(|p| p.car_speed_kmh <= 20.0)
        .collect();
    let cpna = points_of(ncap::Test::Cpna)
        .into_iter()
        .find(|p| p.car_speed_kmh == 10.0 && p.impact_location_percent == 75.0);
    let (gate_passed, gate_reason) = match (ccrs.is_empty(), cpna) {
        (true, _) => (None, Some("the suite has no CCRs point at <= 20 km/h".to_string())),
        (_, None) => (
            None,
            Some("the suite has no CPNA point at 75 % and 10 km/h".to_string()),
        ),
        (false, Some(cpna)) => {
            // A point without a colour is not green (the calculator: any non-green fails).
            let colours: Vec<Colour> = ccrs.iter().map(|p| p.colour.unwrap_or(Colour::Red)).collect();
            let passed = ncap::gate_passes(&colours, cpna.colour.unwrap_or(Colour::Red));
            let reason = (!passed).then(|| {
                let failing: Vec<String> = (ccrs.iter())
                    .filter(|p| p.colour != Some(Colour::Green))
                    .map(|p| format!("CCRs {} km/h at {} %", p.car_speed_kmh, p.impact_location_percent))
                    .chain((cpna.colour != Some(Colour::Green)).then(|| "CPNA 10 km/h at 75 %".to_string()))
                    .collect();
                format!("not green: {}", failing.join(", "))
            });
            (Some(passed), reason)
        }
    };
    let mut total = NcapTotal {
        score: 0.0,
        max: 0.0,
        gate_passed,
        gate_reason: gate_reason.clone(),
    };
    for item in items.iter_mut() {
        let Some(test) = test_of(item) else { continue };
        total.max += test.standard_weight();
        let cell = &mut item.cells[column];
        if gate_passed == Some(false) && cell.score.is_some() {
            cell.score = Some(0.0);
            cell.detail = format!("0 (gate failed) {}", cell.detail);
            cell.reason = gate_reason
                .clone()
                .map(|r| format!("Euro NCAP's gate zeroes every test: {r}"));
        }
        total.score += cell.score.unwrap_or(0.0);
    }
    total.score = ncap::round_half_up(total.score, 3);
    total.max = ncap::round_half_up(total.max, 3);
    Some(total)
}

impl Scorecard {
    /// The table people read: rows the items, columns the filters.
    pub fn table(&self) -> String {
        let mut rows = vec![std::iter::once("item".to_string())
            .chain(self.filters.iter().map(|f| f.name.clone()))
            .collect::<Vec<_>>()];
        let mut section = "";
        for item in &self.items {
            if item.section != section {
                section = &item.section;
                rows.push(vec![format!("[{section}]")]);
            }
            rows.push(
                std::iter::once(item.name.clone())
                    .chain(item.cells.iter().map(|c| match (&c.status, &c.reason) {
                        (Status::NotApplicable | Status::Error | Status::NotRun, Some(r)) => {
                            format!("{}: {}", c.detail, r.lines().next().unwrap_or_default())
                        }
                        _ => c.detail.clone(),
                    }))
                    .collect(),
            );
        }
        if self.ncap.iter().any(Option::is_some) {
            rows.push(
                std::iter::once("Euro NCAP total".to_string())
                    .chain(self.ncap.iter().map(|t| match t {
                        Some(t) => format!(
                            "{:.3}/{:.3} pts, gate {}",
                            t.score,
                            t.max,
                            match t.gate_passed {
                                Some(true) => "passed",
                                Some(false) => "FAILED",
                                None => "not evaluated",
                            }
                        ),
                        None => "-".into(),
                    }))
                    .collect(),
            );
        }
        rows.push(
            std::iter::once("overall".to_string())
                .chain(
                    self.overall
                        .iter()
                        .map(|o| o.map_or("-".into(), |o| format!("{:.1} %", 100.0 * o))),
                )
                .collect(),
        );
        crate::table::align_columns(&rows)
    }

    /// The JSON of `scorecard.json`.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a scorecard serializes") + "\n"
    }
}
