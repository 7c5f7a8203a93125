//! A suite file (`suites/standard.toml`): named filter presets and the items a filter is scored
//! on, each with its scenario, its overrides, its grid and how it is scored (docs/scorecard.md).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::ncap;
use crate::scenario;
use crate::sweep::{self, Grid, GridEntry, SweepSpec};

/// Most items one suite may have.
pub const MAX_ITEMS: usize = 1000;
/// Most runs one item may have (its grid's points).
pub const MAX_ITEM_RUNS: usize = 10_000;

/// A suite file that cannot be used: the file, the key and what was expected.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct SuiteError {
    pub file: String,
    pub message: String,
}

/// How an item's runs become its score.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Scoring {
    /// Passes when every run ends without a collision; the score is the fraction of runs that
    /// stay clear, the figure the least clearance over the runs (m).
    Clear,
    /// Passes when every run stays clear, reaches its goal (`time_to_goal`) and stalls at most
    /// `max_stall` seconds (`stall_time`): a filter safe only by stopping fails it.
    Progress { max_stall: f64 },
    /// A Euro NCAP test: each run a test point coloured by its relative impact speed with
    /// `target` and the car's speed (the grid key `speed_key`, m/s), its impact location the
    /// grid key `location_key` (`locations`: one percent per value of that grid).
    Ncap {
        test: ncap::Test,
        target: String,
        speed_key: String,
        location_key: String,
        locations: Vec<f64>,
    },
    /// The largest distance d from `safe` towards `toward` (|toward − safe| at most) at which the
    /// run with `key = safe ± d` stays clear, by bisection to `tolerance` (in `unit`). Passes
    /// when d ≥ `at_least`, if given.
    Margin {
        key: String,
        safe: f64,
        toward: f64,
        tolerance: f64,
        unit: String,
        at_least: Option<f64>,
    },
    /// A falsification search (`mjsafe falsify`) over the box `ranges` (`KEY=LO..HI[:STEP]`)
    /// with a fixed `budget`, `seed` and `method`: passes when no qualified violation (the
    /// `objective` below `threshold` where the `baseline` overrides stay at or above
    /// `baseline_threshold`) is found; the figures are the runs to the first one and the worst.
    Falsify {
        ranges: Vec<String>,
        #[serde(default)]
        baseline: Vec<String>,
        budget: usize,
        seed: u64,
        #[serde(default = "guided")]
        method: crate::falsify::Method,
        #[serde(default = "min_h")]
        objective: String,
        #[serde(default)]
        threshold: f64,
        #[serde(default)]
        baseline_threshold: f64,
        #[serde(default)]
        baseline_no_stall: bool,
    },
}

/// Most candidates a falsification item may evaluate.
pub const MAX_FALSIFY_BUDGET: usize = 10_000;

fn guided() -> crate::falsify::Method {
    crate::falsify::Method::Guided
}

fn min_h() -> String {
    "min_h".into()
}

/// One item of a suite, resolved.
#[derive(Debug, Clone, Serialize)]
pub struct Item {
    pub name: String,
    pub section: String,
    /// What the reference claims of this example (shown beside its result).
    pub claim: Option<String>,
    /// The scenario file (relative to the suite file when given so).
    pub scenario: PathBuf,
    /// Overrides before the grid's and the filter's.
    pub set: Vec<String>,
    pub grids: Vec<Grid>,
    pub score: Scoring,
}

/// A suite, resolved and checked.
#[derive(Debug, Clone, Serialize)]
pub struct Suite {
    pub name: String,
    pub file: String,
    /// FNV-1a 64 of the file's bytes (a scorecard says which suite made it).
    pub fnv1a: String,
    pub description: Option<String>,
    /// Filter presets the command line names (`--filter NAME`): their specs as TOML inline tables.
    pub filters: BTreeMap<String, String>,
    pub items: Vec<Item>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SuiteFile {
    name: Option<String>,
    description: Option<String>,
    #[serde(default)]
    filters: BTreeMap<String, toml::Value>,
    #[serde(default)]
    item: Vec<ItemEntry>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ItemEntry {
    name: String,
    section: Option<String>,
    claim: Option<String>,
    scenario: String,
    #[serde(default)]
    set: Vec<String>,
    #[serde(default)]
    grid: Vec<GridEntry>,
    score: Scoring,
}

/// The suites in the repository's `suites/` that `--suite NAME` names.
pub const BUILTIN: [&str; 2] = ["standard", "quick"];

/// The file `--suite` names: a built-in name (`suites/NAME.toml` under the working directory,
/// else under the source tree mjsafe was built from) or a path.
pub fn resolve(arg: &str) -> Result<PathBuf, SuiteError> {
    if !BUILTIN.contains(&arg) {
        return Ok(PathBuf::from(arg));
    }
    let relative = Path::new("suites").join(format!("{arg}.toml"));
    [PathBuf::new(), PathBuf::from(env!("CARGO_MANIFEST_DIR"))]
        .iter()
        .map(|base| base.join(&relative))
        .find(|p| p.is_file())
        .ok_or_else(|| SuiteError {
            file: arg.into(),
            message: format!(
                "the built-in suite `{arg}` is {} of mjsafe's source tree, found neither under the working directory nor under {}; give --suite FILE",
                relative.display(),
                env!("CARGO_MANIFEST_DIR")
            ),
        })
}

/// A TOML value as the inline text an override takes (`filter={ kind = "…", … }`).
pub fn inline(value: &toml::Value) -> String {
    match value {
        toml::Value::Table(t) => {
            let fields: Vec<String> = t.iter().map(|(k, v)| format!("{k} = {}", inline(v))).collect();
            format!("{{ {} }}", fields.join(", "))
        }
        toml::Value::Array(a) => format!("[{}]", a.iter().map(inline).collect::<Vec<_>>().join(", ")),
        other => other.to_string(),
    }
}

impl Suite {
    /// Reads and checks the suite at `path`: every item's scenario loads with its overrides,
    /// its grid's keys and sizes are bounded, and its scoring names keys it has.
    pub fn load(path: &Path) -> Result<Suite, SuiteError> {
        let file = path.display().to_string();
        let err = |message: String| SuiteError {
            file: file.clone(),
            message,
        };
        let text = crate::files::read_text_limited(path, "suite file", crate::files::SWEEP_FILE_LIMIT)
            .map_err(|e| err(e.to_string()))?;
        let parsed: SuiteFile = toml::from_str(&text).map_err(|e| err(e.to_string().trim().replace('\n', " ")))?;
        if parsed.item.is_empty() {
            return Err(err("key `item`: expected at least one [[item]]".into()));
        }
        if parsed.item.len() > MAX_ITEMS {
            return Err(err(format!(
                "key `item`: at most {MAX_ITEMS} items, found {}",
                parsed.item.len()
            )));
        }
        let mut filters = BTreeMap::new();
        for (name, value) in &parsed.filters {
            if !value.is_table() {
                return Err(err(format!(
                    "key `filters.{name}`: expected a filter table ({{ kind = \"…\", … }}), found {value}"
                )));
            }
            filters.insert(name.clone(), inline(value));
        }
        let dir = path.parent().unwrap_or(Path::new(""));
        let mut items: Vec<Item> = Vec::with_capacity(parsed.item.len());
        for (i, entry) in parsed.item.into_iter().enumerate() {
            let at = format!("item[{i}] ({})", entry.name);
            if items.iter().any(|other| other.name == entry.name) {
                return Err(err(format!("key `{at}.name`: the name is used twice")));
            }
            let item = resolve_item(entry, dir).map_err(|(key, m)| err(format!("key `{at}{key}`: {m}")))?;
            items.push(item);
        }
        Ok(Suite {
            name: parsed.name.unwrap_or_else(|| {
                path.file_stem()
                    .map_or("suite".into(), |s| s.to_string_lossy().into_owned())
            }),
            fnv1a: sweep::fnv1a(text.as_bytes()),
            file,
            description: parsed.description,
            filters,
            items,
        })
    }
}

/// An entry checked and resolved against the suite's directory; an error names the key under
/// the item (`.score.speed_key`) and what was expected.
fn resolve_item(entry: ItemEntry, dir: &Path) -> Result<Item, (String, String)> {
    let scenario = dir.join(&entry.scenario);
    for (j, spec) in entry.set.iter().enumerate() {
        scenario::check_override(spec).map_err(|e| (format!(".set[{j}]"), e.to_string()))?;
        let key = spec.split('=').next().unwrap_or_default().trim();
        if key == "filter" || key.starts_with("filter.") {
            return Err((
                format!(".set[{j}]"),
                "the scorecard sets `filter` (one per column); leave it out".into(),
            ));
        }
    }
    let grids = sweep::grids_of(entry.grid).map_err(|(key, m)| (format!(".{key}"), m))?;
    let keys: Vec<&str> = grids
        .iter()
        .flat_map(|g| std::iter::once(g.key.as_str()).chain(g.with.iter().map(|c| c.key.as_str())))
        .collect();
    if let Some(key) = sweep::swept_twice(keys.iter().copied()) {
        return Err((".grid".into(), format!("`{key}` is swept twice")));
    }
    if keys.contains(&"filter") {
        return Err((
            ".grid".into(),
            "the scorecard sets `filter` (one per column); leave it out".into(),
        ));
    }
    let runs = grids
        .iter()
        .try_fold(1usize, |n, g| n.checked_mul(g.values.len()))
        .filter(|&n| n <= MAX_ITEM_RUNS)
        .ok_or_else(|| (".grid".to_string(), format!("at most {MAX_ITEM_RUNS} runs per item")))?;
    check_scoring(&entry.score, &grids, runs)?;
    // The scenario with the item's overrides (its own filter) must load and assemble: a suite
    // error, not a filter's.
    super::assembles(&scenario, &entry.set).map_err(|e| (".scenario".to_string(), e))?;
    Ok(Item {
        name: entry.name,
        section: entry.section.unwrap_or_else(|| "Items".into()),
        claim: entry.claim,
        scenario,
        set: entry.set,
        grids,
        score: entry.score,
    })
}

fn check_scoring(score: &Scoring, grids: &[Grid], runs: usize) -> Result<(), (String, String)> {
    let bad = |key: &str, m: String| Err((format!(".score.{key}"), m));
    match score {
        Scoring::Clear => Ok(()),
        Scoring::Progress { max_stall } if !(max_stall.is_finite() && *max_stall >= 0.0) => {
            bad("max_stall", format!("expected seconds >= 0, found {max_stall}"))
        }
        Scoring::Progress { .. } => Ok(()),
        Scoring::Ncap {
            speed_key,
            location_key,
            locations,
            ..
        } => {
            if !grids.iter().any(|g| &g.key == speed_key) {
                return bad(
                    "speed_key",
                    format!("expected a key of the item's grid, found `{speed_key}`"),
                );
            }
            let Some(axis) = grids.iter().find(|g| &g.key == location_key) else {
                return bad(
                    "location_key",
                    format!("expected a grid axis of the item, found `{location_key}`"),
                );
            };
            if axis.values.len() != locations.len() {
                return bad(
                    "locations",
                    format!(
                        "expected one percent per value of `{location_key}` ({}), found {}",
                        axis.values.len(),
                        locations.len()
                    ),
                );
            }
            Ok(())
        }
        Scoring::Margin {
            key,
            safe,
            toward,
            tolerance,
            at_least,
            ..
        } => {
            if runs != 1 {
                return bad("kind", "a margin item bisects one run: it takes no grid".into());
            }
            scenario::check_override(&format!("{key}={safe}"))
                .map_err(|e| (".score.key".to_string(), e.to_string()))?;
            if !(safe.is_finite() && toward.is_finite() && safe != toward) {
                return bad(
                    "toward",
                    format!("expected a finite end other than safe = {safe}, found {toward}"),
                );
            }
            if !(tolerance.is_finite() && *tolerance > 0.0 && (toward - safe).abs() / tolerance <= 1e9) {
                return bad(
                    "tolerance",
                    format!("expected > 0 and at least 1e-9 of the range, found {tolerance}"),
                );
            }
            if at_least.is_some_and(|a| !a.is_finite()) {
                return bad("at_least", "expected a finite number".into());
            }
            Ok(())
        }
        Scoring::Falsify {
            ranges,
            baseline,
            budget,
            objective,
            threshold,
            baseline_threshold,
            baseline_no_stall,
            ..
        } => {
            if runs != 1 {
                return bad(
                    "kind",
                    "a falsification item searches its ranges: it takes no grid".into(),
                );
            }
            if ranges.is_empty() {
                return bad("ranges", "expected at least one range KEY=LO..HI[:STEP]".into());
            }
            for (j, r) in ranges.iter().enumerate() {
                let range = sweep::parse_range(r).map_err(|e| (format!(".score.ranges[{j}]"), e.to_string()))?;
                if range.key == "filter" || range.key.starts_with("filter.") {
                    return bad(
                        "ranges",
                        "the scorecard sets `filter` (one per column); leave it out".into(),
                    );
                }
            }
            for (j, b) in baseline.iter().enumerate() {
                scenario::check_override(b).map_err(|e| (format!(".score.baseline[{j}]"), e.to_string()))?;
            }
            if !(1..=MAX_FALSIFY_BUDGET).contains(budget) {
                return bad(
                    "budget",
                    format!("expected 1 to {MAX_FALSIFY_BUDGET} runs, found {budget}"),
                );
            }
            crate::falsify::check_objective(objective).map_err(|e| (".score.objective".to_string(), e.to_string()))?;
            if !(threshold.is_finite() && baseline_threshold.is_finite()) {
                return bad("threshold", "expected finite thresholds".into());
            }
            if *baseline_no_stall && baseline.is_empty() {
                return bad(
                    "baseline_no_stall",
                    "a requirement of the baseline: give `baseline` overrides".into(),
                );
            }
            Ok(())
        }
    }
}

impl Item {
    /// The item's overrides, then the filter's (`filter={ … }`).
    pub fn with_filter(&self, filter_override: &str) -> Vec<String> {
        let mut set = self.set.clone();
        set.push(filter_override.to_string());
        set
    }

    /// The item's runs as a sweep, the filter's override (`filter={ … }`) after the item's own.
    pub fn sweep(&self, filter_override: &str) -> SweepSpec {
        let set = self.with_filter(filter_override);
        let runs = self.grids.iter().map(|g| g.values.len()).product();
        SweepSpec {
            name: self.name.clone(),
            scenario: self.scenario.display().to_string(),
            scenario_fnv1a: String::new(),
            set,
            grids: self.grids.clone(),
            random: None,
            runs,
        }
    }
}
