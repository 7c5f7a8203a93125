//! How an item's runs become one cell of the scorecard (no MuJoCo: the runs' metrics in, a
//! score out). A value that cannot be had is absent with its reason, never a default.

use serde::Serialize;

use super::suite::{Item, Scoring};
use crate::metrics::{RunMetrics, Value};
use crate::ncap::{self, Colour};

/// One run of an item and what came of it.
#[derive(Debug, Clone)]
pub struct RunResult {
    /// Every override, in order (the filter's included).
    pub overrides: Vec<String>,
    /// The item's grid key → value (TOML text).
    pub parameters: Vec<(String, String)>,
    pub metrics: Option<RunMetrics>,
    /// Why the run has no metrics or stopped early.
    pub error: Option<String>,
    /// The run was never started (the scorecard was interrupted).
    pub not_run: bool,
}

impl RunResult {
    /// Whether the run collided (none without metrics).
    pub(crate) fn collided(&self) -> Option<bool> {
        match self.metrics.as_ref()?.value("collision")? {
            Value::Collision(c) => Some(c.is_some()),
            _ => None,
        }
    }
    fn number(&self, name: &str) -> Option<f64> {
        match self.metrics.as_ref()?.value(name)? {
            Value::Number(v) => *v,
            _ => None,
        }
    }
    fn missing(&self, name: &str) -> Option<String> {
        self.metrics.as_ref()?.missing.get(name).cloned()
    }
    fn parameter(&self, key: &str) -> Option<&str> {
        self.parameters.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
    }
    /// Why this run cannot be scored: not run, an error, or incomplete.
    fn failure(&self) -> Option<String> {
        if self.not_run {
            return Some("not run: the scorecard was interrupted".into());
        }
        if let Some(e) = &self.error {
            return Some(e.clone());
        }
        match &self.metrics {
            None => Some("the run has no metrics".into()),
            Some(m) if !m.complete => Some(m.error.clone().unwrap_or_else(|| "the run is incomplete".into())),
            Some(_) => None,
        }
    }
}

/// A figure behind a score, with its unit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Figure {
    pub name: String,
    pub value: Option<f64>,
    pub unit: String,
}

/// A cell's verdict.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    Pass,
    Fail,
    /// Scored without pass/fail (a Euro NCAP test, a margin without `at_least`).
    Scored,
    /// The filter cannot drive this item's vehicle (the reason says why).
    NotApplicable,
    /// A run failed or stopped early: the item has no score.
    Error,
    /// The scorecard was interrupted before the item's runs finished.
    NotRun,
}

/// A Euro NCAP test point.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Point {
    /// The car's speed, km/h (the grid's m/s × 3.6, to 0.1 km/h).
    pub car_speed_kmh: f64,
    pub impact_location_percent: f64,
    /// Relative impact speed with the target, km/h (0: no impact); absent with `reason`.
    pub relative_impact_kmh: Option<f64>,
    pub colour: Option<Colour>,
    pub points: f64,
    pub reason: Option<String>,
    /// The command that reproduces this run.
    pub command: String,
    /// Its overrides.
    #[serde(skip)]
    pub overrides: Vec<String>,
}

/// One item scored for one filter.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Cell {
    pub status: Status,
    /// The score (Euro NCAP points, the fraction of runs clear, the margin), absent with `reason`.
    pub score: Option<f64>,
    /// The most the score can be (absent for a margin).
    pub max: Option<f64>,
    pub unit: String,
    pub figure: Option<Figure>,
    /// One line for the table.
    pub detail: String,
    pub reason: Option<String>,
    pub runs: usize,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub points: Vec<Point>,
    /// A margin item's bisection, in the order run.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub steps: Vec<MarginStep>,
    /// A falsification item's search.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub search: Option<SearchOutcome>,
    /// Reproduces the item's first failing run (else its first run).
    pub command: String,
    /// The overrides of the failing run `command` reproduces (none when nothing failed).
    #[serde(skip)]
    pub failing_run: Option<Vec<String>>,
    /// The MCAP log of that run (`--keep-logs`), relative to the scorecard's directory.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub log: Option<String>,
}

/// One run of a margin item's bisection.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MarginStep {
    /// The value of the item's key.
    pub value: f64,
    /// Whether the run stayed clear (absent when it has no metrics).
    pub clear: Option<bool>,
}

/// What a falsification item's search found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SearchOutcome {
    pub method: String,
    pub objective: String,
    pub threshold: f64,
    pub evaluations: usize,
    /// Candidates whose baseline was safe (all of them without a baseline).
    pub qualified: usize,
    pub violations: usize,
    /// Evaluations up to and including the first qualified violation.
    pub runs_to_first_violation: Option<usize>,
    /// The lowest objective among the qualified violations.
    pub worst: Option<f64>,
    /// The lowest objective of a qualified candidate after each evaluation (absent before the
    /// first qualified one): the convergence the report draws.
    pub best_so_far: Vec<Option<f64>>,
}

impl Cell {
    /// The score as a fraction of its maximum, for the overall figure: pass 1, fail 0, a Euro
    /// NCAP test its points over its weight; none for a margin without a threshold.
    pub fn fraction(&self) -> Option<f64> {
        match self.status {
            Status::Pass => Some(1.0),
            Status::Fail => Some(self.score.zip(self.max).map_or(0.0, |(s, m)| s / m)),
            Status::Scored => self.score.zip(self.max).map(|(s, m)| s / m),
            _ => None,
        }
    }

    /// A cell without a score: `status` and why.
    pub fn without_score(status: Status, reason: String, runs: usize, command: String) -> Cell {
        Cell {
            status,
            score: None,
            max: None,
            unit: String::new(),
            figure: None,
            detail: match status {
                Status::NotApplicable => "n/a".into(),
                Status::NotRun => "not run".into(),
                _ => "error".into(),
            },
            reason: Some(reason),
            runs,
            points: Vec::new(),
            steps: Vec::new(),
            search: None,
            command,
            failing_run: None,
            log: None,
        }
    }
}

/// `mjsafe run SCENARIO --set '…' …`: the command that reproduces a run.
pub fn command(scenario: &str, overrides: &[String]) -> String {
    let quote = |s: &str| format!("'{}'", s.replace('\'', r"'\''"));
    let mut parts = vec!["mjsafe run".to_string(), quote(scenario)];
    for o in overrides {
        parts.push(format!("--set {}", quote(o)));
    }
    parts.join(" ")
}

/// The cell of `item` whose runs are `runs` (all finished), scored as the item says. (A margin
/// item's cell is made by its bisection: [`margin_cell`].)
pub fn cell(item: &Item, runs: &[RunResult]) -> Cell {
    let scenario = &item.scenario.display().to_string();
    let first_command = runs.first().map_or(String::new(), |r| command(scenario, &r.overrides));
    let failed = runs.iter().find_map(|r| r.failure().map(|f| (r, f)));
    // A run that collided before it stopped is not clear, whatever stopped it: a clear item's
    // verdict stands (an error must not take a failing run out of the score).
    let has_verdict = |r: &RunResult| r.failure().is_none() || r.collided() == Some(true);
    if let (Some((_, why)), Scoring::Clear) = (&failed, &item.score) {
        if runs.iter().all(has_verdict) {
            let mut cell = clear_cell(scenario, runs, first_command);
            cell.reason = Some(format!("a run stopped after its collision: {why}"));
            return cell;
        }
    }
    if let Some((run, why)) = failed {
        let status = if run.not_run { Status::NotRun } else { Status::Error };
        return Cell::without_score(status, why, runs.len(), command(scenario, &run.overrides));
    }
    match &item.score {
        Scoring::Clear => clear_cell(scenario, runs, first_command),
        Scoring::Progress { max_stall } => progress_cell(*max_stall, scenario, runs, first_command),
        Scoring::Ncap {
            test,
            target,
            speed_key,
            location_key,
            locations,
        } => {
            // Each value of the location axis with its percent.
            let axis = item.grids.iter().find(|g| &g.key == location_key);
            let located: Vec<(&str, f64)> = axis.map_or(Vec::new(), |g| {
                g.values
                    .iter()
                    .map(String::as_str)
                    .zip(locations.iter().copied())
                    .collect()
            });
            ncap_cell(*test, target, (speed_key, location_key, &located), scenario, runs)
        }
        Scoring::Margin { .. } => unreachable!("a margin item is scored by its bisection"),
        Scoring::Falsify { .. } => unreachable!("a falsification item is scored by its search"),
    }
}

fn clear_cell(scenario: &str, runs: &[RunResult], first_command: String) -> Cell {
    let clear = runs.iter().filter(|r| r.collided() == Some(false)).count();
    let least = runs
        .iter()
        .filter_map(|r| r.number("min_clearance"))
        .fold(None, |m: Option<f64>, c| Some(m.map_or(c, |m| m.min(c))));
    let failing = runs.iter().find(|r| r.collided() != Some(false));
    let pass = clear == runs.len();
    Cell {
        status: if pass { Status::Pass } else { Status::Fail },
        score: Some(clear as f64 / runs.len() as f64),
        max: Some(1.0),
        unit: "fraction of runs clear".into(),
        figure: Some(Figure {
            name: "min_clearance".into(),
            value: least,
            unit: "m".into(),
        }),
        detail: format!(
            "{} {clear}/{} clear, min clearance {}",
            if pass { "pass" } else { "FAIL" },
            runs.len(),
            least.map_or("-".into(), |c| format!("{c:.3} m"))
        ),
        reason: None,
        runs: runs.len(),
        points: Vec::new(),
        steps: Vec::new(),
        search: None,
        command: failing.map_or(first_command, |r| command(scenario, &r.overrides)),
        failing_run: failing.map(|r| r.overrides.clone()),
        log: None,
    }
}

fn progress_cell(max_stall: f64, scenario: &str, runs: &[RunResult], first_command: String) -> Cell {
    let mut worst: Option<(&RunResult, String)> = None;
    let mut slowest: Option<f64> = None;
    for r in runs {
        let stall = r.number("stall_time");
        let why = match (r.collided(), r.number("time_to_goal"), stall) {
            (Some(true), ..) => Some("collided".to_string()),
            (_, None, _) => Some(format!(
                "goal not reached ({})",
                r.missing("time_to_goal").unwrap_or_else(|| "no time_to_goal".into())
            )),
            (_, _, Some(s)) if s > max_stall => Some(format!("stalled {s:.2} s > {max_stall} s")),
            (_, Some(t), _) => {
                slowest = Some(slowest.map_or(t, |s: f64| s.max(t)));
                None
            }
        };
        if let (Some(why), None) = (why, &worst) {
            worst = Some((r, why));
        }
    }
    let pass = worst.is_none();
    Cell {
        status: if pass { Status::Pass } else { Status::Fail },
        score: Some(if pass { 1.0 } else { 0.0 }),
        max: Some(1.0),
        unit: "pass".into(),
        figure: Some(Figure {
            name: "time_to_goal".into(),
            value: if pass { slowest } else { None },
            unit: "s".into(),
        }),
        detail: match &worst {
            None => format!("pass, goal in {}", slowest.map_or("-".into(), |t| format!("{t:.2} s"))),
            Some((_, why)) => format!("FAIL: {why}"),
        },
        reason: worst.as_ref().map(|(_, why)| why.clone()),
        runs: runs.len(),
        points: Vec::new(),
        steps: Vec::new(),
        search: None,
        failing_run: worst.as_ref().map(|(r, _)| r.overrides.clone()),
        command: worst.map_or(first_command, |(r, _)| command(scenario, &r.overrides)),
        log: None,
    }
}

/// The relative impact speed (km/h) of a run with `target`: 0 without a collision; absent with
/// the reason when it collided with something else or its impact speed is missing.
fn relative_impact_kmh(run: &RunResult, target: &str) -> Result<f64, String> {
    let Some(metrics) = &run.metrics else {
        return Err("no metrics".into());
    };
    let with = match metrics.value("collision") {
        Some(Value::Collision(None)) => return Ok(0.0),
        Some(Value::Collision(Some(c))) => c.with.clone(),
        _ => return Err("the run has no collision metric".into()),
    };
    if with != target {
        return Err(format!("collided with `{with}`, not the target `{target}`"));
    }
    let speed = match metrics.value("impact_speed_by_actor") {
        Some(Value::PerChannel(Some(speeds))) => speeds.get(target).map(|v| v * 3.6),
        _ => None,
    };
    speed.ok_or_else(|| {
        let why = (run.missing(&format!("impact_speed_by_actor.{target}")))
            .or_else(|| run.missing("impact_speed_by_actor"))
            .unwrap_or_else(|| "no reason given".into());
        format!("no impact speed with `{target}` ({why})")
    })
}

fn ncap_cell(
    test: ncap::Test,
    target: &str,
    (speed_key, location_key, located): (&str, &str, &[(&str, f64)]),
    scenario: &str,
    runs: &[RunResult],
) -> Cell {
    let mut points = Vec::with_capacity(runs.len());
    for r in runs {
        let speed = r.parameter(speed_key).and_then(|v| v.parse::<f64>().ok());
        let car_speed_kmh = speed.map_or(f64::NAN, |v| (v * 3.6 * 10.0).round() / 10.0);
        let impact_location_percent = (r.parameter(location_key))
            .and_then(|l| located.iter().find(|(v, _)| *v == l))
            .map_or(f64::NAN, |(_, percent)| *percent);
        let impact = relative_impact_kmh(r, target);
        let coloured = impact
            .clone()
            .and_then(|v| ncap::colour(car_speed_kmh, v).map_err(|e| e.to_string()));
        points.push(Point {
            car_speed_kmh,
            impact_location_percent,
            relative_impact_kmh: impact.as_ref().ok().map(|v| ncap::round_half_up(*v, 2)),
            colour: coloured.as_ref().ok().copied(),
            // A point without a colour counts 0, as the calculator's grey cells.
            points: coloured
                .as_ref()
                .map_or(0.0, |&c| ncap::points(c, ncap::Range::Standard)),
            reason: coloured.err(),
            command: command(scenario, &r.overrides),
            overrides: r.overrides.clone(),
        });
    }
    let values: Vec<f64> = points.iter().map(|p| p.points).collect();
    let score = ncap::test_score(test, &values);
    let count = |c: Colour| points.iter().filter(|p| p.colour == Some(c)).count();
    let uncoloured = points.iter().filter(|p| p.colour.is_none()).count();
    let mut detail = format!(
        "{:.3}/{} pts: {} green, {} yellow, {} orange, {} brown, {} red",
        ncap::round_half_up(score, 3),
        test.standard_weight(),
        count(Colour::Green),
        count(Colour::Yellow),
        count(Colour::Orange),
        count(Colour::Brown),
        count(Colour::Red)
    );
    if uncoloured > 0 {
        detail.push_str(&format!(", {uncoloured} without colour"));
    }
    let worst = points
        .iter()
        .max_by(|a, b| (a.colour.is_none(), a.colour).cmp(&(b.colour.is_none(), b.colour)));
    Cell {
        status: Status::Scored,
        score: Some(ncap::round_half_up(score, 3)),
        max: Some(test.standard_weight()),
        unit: "Euro NCAP points".into(),
        figure: Some(Figure {
            name: "max relative impact speed".into(),
            value: points
                .iter()
                .filter_map(|p| p.relative_impact_kmh)
                .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v)))),
            unit: "km/h".into(),
        }),
        detail,
        reason: (uncoloured > 0).then(|| points.iter().find_map(|p| p.reason.clone()).unwrap_or_default()),
        runs: runs.len(),
        command: worst.map_or(String::new(), |p| p.command.clone()),
        // The worst point fails when it is not green.
        failing_run: worst
            .filter(|p| p.colour != Some(Colour::Green))
            .map(|p| p.overrides.clone()),
        log: None,
        points,
        steps: Vec::new(),
        search: None,
    }
}

/// The bisection of a margin item: the runs it made, (value of the key, clear?).
#[derive(Debug, Clone)]
pub struct Bisection {
    pub steps: Vec<(f64, RunResult)>,
}

/// The cell of a margin item from its bisection (`safe` towards `toward`, to `tolerance`).
pub fn margin_cell(scoring: &Scoring, scenario: &str, bisection: &Bisection) -> Cell {
    let Scoring::Margin {
        key,
        safe,
        toward,
        unit,
        at_least,
        tolerance,
    } = scoring
    else {
        unreachable!("a margin cell of a margin item")
    };
    let runs = bisection.steps.len();
    if let Some((run, why)) = bisection.steps.iter().find_map(|(_, r)| r.failure().map(|f| (r, f))) {
        let status = if run.not_run { Status::NotRun } else { Status::Error };
        return Cell::without_score(status, why, runs, command(scenario, &run.overrides));
    }
    let clear = |r: &RunResult| r.collided() == Some(false);
    let distance = |v: f64| (v - safe).abs();
    let mut largest_clear: Option<f64> = None;
    let mut least_unclear: Option<f64> = None;
    for (v, r) in &bisection.steps {
        if clear(r) {
            largest_clear = Some(largest_clear.map_or(distance(*v), |d: f64| d.max(distance(*v))));
        } else {
            least_unclear = Some(least_unclear.map_or(distance(*v), |d: f64| d.min(distance(*v))));
        }
    }
    let span = (toward - safe).abs();
    let (value, reason) = match (largest_clear, least_unclear) {
        (None, _) => (None, Some(format!("not clear even at {key} = {safe}"))),
        (Some(d), None) => (
            Some(d),
            Some(format!("clear over the whole range (to {key} = {toward})")),
        ),
        (Some(d), Some(_)) => (Some(d), None),
    };
    let pass = match (at_least, value) {
        (Some(a), Some(v)) => Some(v >= *a),
        (Some(_), None) => Some(false),
        (None, _) => None,
    };
    let failing = bisection
        .steps
        .iter()
        .find(|(_, r)| !clear(r))
        .or(bisection.steps.first());
    Cell {
        status: match pass {
            Some(true) => Status::Pass,
            Some(false) => Status::Fail,
            None => Status::Scored,
        },
        score: value,
        max: None,
        unit: unit.clone(),
        figure: Some(Figure {
            name: format!("margin of {key}"),
            value,
            unit: unit.clone(),
        }),
        detail: match value {
            Some(v) if least_unclear.is_none() => format!(">= {v:.4} {unit} (whole range)"),
            Some(v) => format!("{v:.4} {unit} (± {tolerance})"),
            None => format!("none: not clear even at {key} = {safe}"),
        },
        reason: reason.or_else(|| (span == 0.0).then(|| "empty range".into())),
        runs,
        points: Vec::new(),
        steps: (bisection.steps.iter())
            .map(|(value, r)| MarginStep {
                value: *value,
                clear: r.collided().map(|c| !c),
            })
            .collect(),
        search: None,
        command: failing.map_or(String::new(), |(_, r)| command(scenario, &r.overrides)),
        failing_run: (bisection.steps.iter())
            .find(|(_, r)| !clear(r))
            .map(|(_, r)| r.overrides.clone()),
        log: None,
    }
}

/// The cell of a falsification item: pass when its search found no qualified violation.
/// `set` is every override of its candidates before their own (the filter's included).
pub fn falsify_cell(
    scoring: &Scoring,
    scenario: &str,
    set: &[String],
    search: &Result<crate::falsify::Search, String>,
) -> Cell {
    let Scoring::Falsify {
        objective, threshold, ..
    } = scoring
    else {
        unreachable!("a falsify cell of a falsify item")
    };
    let search = match search {
        Ok(s) => s,
        Err(e) => return Cell::without_score(Status::Error, e.clone(), 0, command(scenario, set)),
    };
    let evaluations = search.evaluations.len();
    if search.interrupted {
        return Cell::without_score(
            Status::NotRun,
            "not run: the scorecard was interrupted".into(),
            evaluations,
            command(scenario, set),
        );
    }
    let overrides_of = |e: &crate::falsify::Evaluation| -> Vec<String> {
        (set.iter().cloned())
            .chain(e.parameters.iter().map(|(k, v)| format!("{k}={v}")))
            .collect()
    };
    let mut best: Option<f64> = None;
    let best_so_far = (search.evaluations.iter())
        .map(|e| {
            if let (true, Some(o)) = (e.qualified, e.objective) {
                best = Some(best.map_or(o, |b: f64| b.min(o)));
            }
            best
        })
        .collect();
    let qualified = search.evaluations.iter().filter(|e| e.qualified).count();
    let errors = search.evaluations.iter().filter(|e| e.error.is_some()).count();
    let worst = search.worst_violation();
    if qualified == 0 {
        // Nothing qualified: the search proved nothing, so the item has no score.
        return Cell::without_score(
            Status::Error,
            format!("no candidate qualified in {evaluations} runs ({errors} failed to run): the search proved nothing"),
            evaluations,
            command(scenario, set),
        );
    }
    let outcome = SearchOutcome {
        method: search.method.name().into(),
        objective: objective.clone(),
        threshold: *threshold,
        evaluations,
        qualified,
        violations: search.evaluations.iter().filter(|e| e.violation).count(),
        runs_to_first_violation: search.runs_to_first_violation(),
        worst: worst.and_then(|e| e.objective),
        best_so_far,
    };
    let detail = match (outcome.runs_to_first_violation, outcome.worst) {
        (Some(first), worst) => format!(
            "FAIL: found at run {first}/{evaluations}, worst {}",
            worst.map_or("-".into(), |w| format!("{w:.4}"))
        ),
        (None, _) => format!("pass: none in {evaluations} runs ({qualified} qualified)"),
    };
    Cell {
        status: if worst.is_some() { Status::Fail } else { Status::Pass },
        score: Some(if worst.is_some() { 0.0 } else { 1.0 }),
        max: Some(1.0),
        unit: "pass".into(),
        figure: Some(Figure {
            name: "runs to the first qualified violation".into(),
            value: outcome.runs_to_first_violation.map(|n| n as f64),
            unit: "runs".into(),
        }),
        detail,
        reason: (errors > 0).then(|| format!("{errors} of {evaluations} candidates failed to run")),
        runs: evaluations,
        points: Vec::new(),
        steps: Vec::new(),
        command: worst.map_or(command(scenario, set), |e| command(scenario, &overrides_of(e))),
        failing_run: worst.map(overrides_of),
        log: None,
        search: Some(outcome),
    }
}
