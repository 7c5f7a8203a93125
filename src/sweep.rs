//! Parameter sweeps: a scenario expanded into runs (the cartesian product of grids of
//! `--set` values and/or seeded random draws of declared ranges), executed in parallel, each
//! run logged and analysed, and a summary table of every run written as CSV and JSON.
//! Shards of one sweep (`index % count == shard`) run anywhere and merge into the same table.
//! See docs/sweeps.md.

use std::collections::{BTreeMap, BTreeSet};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;

use serde::{Deserialize, Serialize};

use crate::analyze::{Cell, FlatMetrics};
use crate::files::{OutputFile, Replace};
use crate::log::mcap;
use crate::random::SplitMix64;
use crate::scenario;
use crate::table::csv_lines;

#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error("--grid {arg}: {message}")]
    Grid { arg: String, message: String },
    #[error("--range {arg}: {message}")]
    Range { arg: String, message: String },
    #[error("--shard {arg}: {message}")]
    Shard { arg: String, message: String },
    #[error("{file}: {message}")]
    File { file: String, message: String },
    #[error("{0}")]
    Spec(String),
    #[error("{path}: {reason}")]
    Io { path: String, reason: std::io::Error },
    #[error("{file}: not a sweep summary: {message}")]
    Summary { file: String, message: String },
    #[error("cannot merge: {0}")]
    Merge(String),
    #[error(transparent)]
    FileAccess(#[from] crate::files::FileError),
}

/// The most runs one sweep may have (its run list and summary are held in memory).
pub const MAX_RUNS: usize = 1_000_000;

/// One grid axis: an override key (dotted path, as `--set` takes) and its values (TOML text).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    pub key: String,
    pub values: Vec<String>,
    /// Further keys that move with it (a sweep file's `with`: e.g. a vehicle's initial speed
    /// and its nominal's reference speed), each with one value per value of `values`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub with: Vec<Companion>,
}

/// A key that moves with a grid axis: its value at each of the axis's values (TOML text).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Companion {
    pub key: String,
    pub values: Vec<String>,
}

/// A range drawn uniformly: in [lo, hi), or with `step` from {lo, lo + step, …} ≤ hi.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Range {
    pub key: String,
    pub lo: f64,
    pub hi: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub step: Option<f64>,
}

/// `count` seeded draws of every range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Random {
    pub count: usize,
    pub seed: u64,
    pub ranges: Vec<Range>,
}

/// A sweep, fully resolved: everything that decides its runs (shards must agree on it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepSpec {
    /// Prefix of the log files: `<name>-<index>.mcap`.
    pub name: String,
    /// The scenario file, as given (or joined to the sweep file's directory).
    pub scenario: String,
    /// FNV-1a 64 of the scenario file's bytes (shards must have read the same file).
    pub scenario_fnv1a: String,
    /// Overrides applied to every run, before the run's own.
    pub set: Vec<String>,
    pub grids: Vec<Grid>,
    pub random: Option<Random>,
    /// Total number of runs (all shards).
    pub runs: usize,
}

/// One run of a sweep: its overrides in order (base, grids, ranges) and its parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    pub index: usize,
    pub overrides: Vec<String>,
    /// Sweep key → value (TOML text), grid keys then range keys.
    pub parameters: Vec<(String, String)>,
}

/// What the command line (or a test) gives to build a [`SweepSpec`].
#[derive(Debug, Clone, Default)]
pub struct SweepArgs {
    pub scenario: Option<PathBuf>,
    /// CommonRoad files (`--scenarios`, patterns expanded by [`expand_scenarios`]): one axis of
    /// the sweep, `commonroad.file`, over them (docs/commonroad.md).
    pub scenarios: Vec<PathBuf>,
    pub sweep_file: Option<PathBuf>,
    pub set: Vec<String>,
    pub grids: Vec<String>,
    pub random: Option<usize>,
    pub seed: Option<u64>,
    pub ranges: Vec<String>,
}

/// A sweep file (TOML); paths relative to the file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SweepFile {
    scenario: Option<String>,
    /// CommonRoad files or patterns (`*`, `?`, `[…]`), relative to the sweep file.
    #[serde(default)]
    scenarios: Vec<String>,
    name: Option<String>,
    #[serde(default)]
    set: Vec<String>,
    #[serde(default)]
    grid: Vec<GridEntry>,
    #[serde(default)]
    range: Vec<RangeEntry>,
    random: Option<RandomEntry>,
}

/// A `[[grid]]` entry of a sweep file (or of a scorecard suite's item).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct GridEntry {
    key: String,
    values: Vec<toml::Value>,
    #[serde(default)]
    with: Vec<CompanionEntry>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CompanionEntry {
    key: String,
    /// One per value of the grid; absent: the grid's own values.
    values: Option<Vec<toml::Value>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RangeEntry {
    key: String,
    lo: f64,
    hi: f64,
    step: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RandomEntry {
    count: usize,
    #[serde(default)]
    seed: u64,
}

/// Most files one `--scenarios` sweep runs.
pub const MAX_SCENARIO_FILES: usize = 100_000;

/// The CommonRoad files `patterns` name (`*`, `?`, `[…]` as a shell expands them, each pattern's
/// matches sorted), in order, each once; a pattern that matches no `.xml` file is an error.
pub fn expand_scenarios(patterns: &[String]) -> Result<Vec<PathBuf>, String> {
    let mut files: Vec<PathBuf> = Vec::new();
    for pattern in patterns {
        let paths = glob::glob(pattern).map_err(|e| format!("`{pattern}`: {e}"))?;
        let mut matched: Vec<PathBuf> = paths.filter_map(Result::ok).filter(|p| p.is_file()).collect();
        matched.sort();
        if matched.is_empty() {
            return Err(format!("`{pattern}` names no file"));
        }
        if let Some(other) = matched
            .iter()
            .find(|p| !p.extension().is_some_and(|e| e.eq_ignore_ascii_case("xml")))
        {
            return Err(format!("expected CommonRoad files (.xml), found {}", other.display()));
        }
        for path in matched {
            if !files.contains(&path) {
                files.push(path);
            }
            if files.len() > MAX_SCENARIO_FILES {
                return Err(format!("more than {MAX_SCENARIO_FILES} files"));
            }
        }
    }
    Ok(files)
}

/// The axis `commonroad.file` over `files` (the first is the sweep's base scenario, which
/// reads the others relative to its directory: a file beside it by its name, others by their
/// absolute path).
fn scenario_axis(files: &[PathBuf]) -> Result<Grid, SweepError> {
    let base_dir = files[0].parent().map(Path::to_path_buf).unwrap_or_default();
    let mut values = Vec::with_capacity(files.len());
    for f in files {
        let relative = match (f.parent(), f.file_name()) {
            (Some(dir), Some(name)) if dir == base_dir => PathBuf::from(name),
            _ => std::fs::canonicalize(f).map_err(|e| SweepError::Spec(format!("{}: {e}", f.display())))?,
        };
        values.push(toml::Value::String(relative.display().to_string()).to_string());
    }
    Ok(Grid {
        key: "commonroad.file".into(),
        values,
        with: Vec::new(),
    })
}

/// The first key that names a field an earlier key names (spelled either way:
/// [`scenario::canonical_key`]): each swept field takes one axis.
pub fn swept_twice<'a>(keys: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let mut seen = BTreeSet::new();
    keys.into_iter().find(|key| !seen.insert(scenario::canonical_key(key)))
}

/// Splits `v1,v2,…` at the commas outside brackets, braces and quotes, so TOML arrays,
/// inline tables and strings may contain commas. Every value is trimmed and non-empty.
pub fn split_values(text: &str) -> Result<Vec<String>, String> {
    let mut values = Vec::new();
    let mut current = String::new();
    let mut closers: Vec<char> = Vec::new();
    let mut quote: Option<char> = None;
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        current.push(c);
        if let Some(q) = quote {
            if c == '\\' && q == '"' {
                if let Some(escaped) = chars.next() {
                    current.push(escaped);
                }
            } else if c == q {
                quote = None;
            }
            continue;
        }
        match c {
            '\'' | '"' => quote = Some(c),
            '[' => closers.push(']'),
            '{' => closers.push('}'),
            ']' | '}' if closers.pop() != Some(c) => return Err(format!("unbalanced `{c}`")),
            ',' if closers.is_empty() => {
                current.pop();
                values.push(std::mem::take(&mut current));
            }
            _ => {}
        }
    }
    if let Some(q) = quote {
        return Err(format!("unterminated string (missing closing {q})"));
    }
    if let Some(c) = closers.last() {
        return Err(format!("missing closing `{c}`"));
    }
    values.push(current);
    let values: Vec<String> = values.into_iter().map(|v| v.trim().to_string()).collect();
    if let Some(i) = values.iter().position(|v| v.is_empty()) {
        return Err(format!("value {} of {} is empty", i + 1, values.len()));
    }
    Ok(values)
}

/// Checks that `value` is one value as `--set` takes it (a TOML literal or a bare word).
fn check_toml_value(value: &str) -> Result<(), String> {
    crate::scenario::override_value(value).map(|_| ())
}

fn check_key(key: &str) -> Result<(), String> {
    if key.is_empty()
        || key
            .split('.')
            .any(|s| s.trim().is_empty() || s.contains(char::is_whitespace))
    {
        return Err(format!("`{key}` is not a dotted key such as delays.steering"));
    }
    Ok(())
}

/// Parses `KEY=V1,V2,…`.
pub fn parse_grid(arg: &str) -> Result<Grid, SweepError> {
    let err = |message: String| SweepError::Grid {
        arg: arg.to_string(),
        message,
    };
    let (key, values) = arg
        .split_once('=')
        .ok_or_else(|| err("expected KEY=V1,V2,… e.g. delays.steering=0.1,0.2,0.4".into()))?;
    let key = key.trim();
    check_key(key).map_err(err)?;
    let values = split_values(values).map_err(err)?;
    for v in &values {
        check_toml_value(v).map_err(err)?;
    }
    Ok(Grid {
        key: key.to_string(),
        values,
        with: Vec::new(),
    })
}

/// Parses `KEY=LO..HI` or `KEY=LO..HI:STEP`.
pub fn parse_range(arg: &str) -> Result<Range, SweepError> {
    let err = |message: String| SweepError::Range {
        arg: arg.to_string(),
        message,
    };
    let expected = "expected KEY=LO..HI or KEY=LO..HI:STEP, e.g. delays.steering=0.0..0.5:0.01";
    let (key, spec) = arg.split_once('=').ok_or_else(|| err(expected.into()))?;
    let key = key.trim();
    check_key(key).map_err(err)?;
    let (bounds, step) = match spec.split_once(':') {
        Some((b, s)) => (b, Some(s)),
        None => (spec, None),
    };
    let (lo, hi) = bounds.split_once("..").ok_or_else(|| err(expected.into()))?;
    let number = |s: &str, what: &str| {
        s.trim()
            .parse::<f64>()
            .map_err(|_| err(format!("{what} `{}` is not a number ({expected})", s.trim())))
    };
    let range = Range {
        key: key.to_string(),
        lo: number(lo, "LO")?,
        hi: number(hi, "HI")?,
        step: step.map(|s| number(s, "STEP")).transpose()?,
    };
    check_range(&range).map_err(err)?;
    Ok(range)
}

fn check_range(r: &Range) -> Result<(), String> {
    if !(r.lo.is_finite() && r.hi.is_finite() && r.lo <= r.hi) {
        return Err(format!("expected finite LO <= HI, found {}..{}", r.lo, r.hi));
    }
    let width = r.hi - r.lo;
    if !width.is_finite() {
        return Err(format!(
            "the width HI − LO of {}..{} overflows (expected a range narrower than {:e})",
            r.lo,
            r.hi,
            f64::MAX
        ));
    }
    if let Some(step) = r.step {
        if !(step.is_finite() && step > 0.0) {
            return Err(format!("expected STEP > 0, found {step}"));
        }
        if step > width {
            return Err(format!(
                "STEP {step} exceeds the width HI − LO = {width} (every value would be LO; expected STEP <= HI − LO)"
            ));
        }
    }
    Ok(())
}

/// The random draws of a sweep: `--random N` with at least one `--range`, or none of either.
fn random_of(random_count: Option<usize>, seed: Option<u64>, ranges: Vec<Range>) -> Result<Option<Random>, SweepError> {
    Ok(match (random_count, ranges.is_empty()) {
        (None, true) => None,
        (None, false) => {
            return Err(SweepError::Spec(
                "--range needs --random N (how many draws) and --seed S".into(),
            ))
        }
        (Some(_), true) => {
            return Err(SweepError::Spec(
                "--random needs at least one --range KEY=LO..HI".into(),
            ))
        }
        (Some(0), false) => return Err(SweepError::Spec("--random: expected at least one draw".into())),
        (Some(count), false) => Some(Random {
            count,
            seed: seed.unwrap_or(0),
            ranges,
        }),
    })
}

/// Parses `i/N` (0-based: 0 <= i < N).
pub fn parse_shard(arg: &str) -> Result<Shard, SweepError> {
    let err = |message: &str| SweepError::Shard {
        arg: arg.to_string(),
        message: message.to_string(),
    };
    let (i, n) = arg
        .split_once('/')
        .ok_or_else(|| err("expected INDEX/COUNT with 0 <= INDEX < COUNT, e.g. 0/4"))?;
    let index: usize = i.trim().parse().map_err(|_| err("INDEX is not a whole number"))?;
    let count: usize = n.trim().parse().map_err(|_| err("COUNT is not a whole number"))?;
    if count == 0 || index >= count {
        return Err(err("expected 0 <= INDEX < COUNT (shards are numbered from 0)"));
    }
    Ok(Shard { index, count })
}

/// FNV-1a 64-bit hash, as 16 hex digits.
pub(crate) fn fnv1a(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// The generator of draw `draw` of a sweep seeded `seed`: depends on nothing else, so a draw
/// is the same whatever the thread count, shard or order of execution.
fn draw_generator(seed: u64, draw: usize) -> SplitMix64 {
    let key = SplitMix64(seed).next_u64() ^ (draw as u64).wrapping_mul(0xd1b5_4a32_d192_ed03);
    let mut g = SplitMix64(key);
    g.next_u64();
    g
}

/// The value of `range` for a uniform `u` in [0, 1), as TOML text.
fn range_value(range: &Range, u: f64) -> String {
    match range.step {
        None => format!("{:?}", range.lo + u * (range.hi - range.lo)),
        Some(step) => {
            let choices = ((range.hi - range.lo) / step + 1e-9).floor() as u64 + 1;
            let k = ((u * choices as f64) as u64).min(choices - 1);
            step_value(range, k)
        }
    }
}

/// LO + k·STEP of a quantised range as TOML text: an integer when LO and STEP are whole
/// numbers (seeds and counts need one; a float field accepts it too), else a float with the
/// round-off of k·STEP dropped (12 significant digits: 0.30000000000000004 → 0.3).
pub fn step_value(range: &Range, k: u64) -> String {
    let step = range.step.unwrap_or(0.0);
    let v = range.lo + k as f64 * step;
    if range.lo.fract() == 0.0 && step.fract() == 0.0 {
        return format!("{}", v as i64);
    }
    let v: f64 = format!("{v:.11e}").parse().expect("formatted float parses");
    format!("{v:?}")
}

/// What a sweep file sets (paths joined to its directory).
#[derive(Default)]
struct FileParts {
    scenario: Option<PathBuf>,
    scenarios: Vec<PathBuf>,
    name: Option<String>,
    set: Vec<String>,
    grids: Vec<Grid>,
    ranges: Vec<Range>,
    /// `[random]`: count and seed.
    random: Option<(usize, u64)>,
}

/// `[[grid]]` entries checked (keys, at least one value, one companion value per value); an
/// error names the key (`grid[1].with[0].values`) and what was expected.
pub(crate) fn grids_of(entries: Vec<GridEntry>) -> Result<Vec<Grid>, (String, String)> {
    let mut grids = Vec::with_capacity(entries.len());
    for (i, g) in entries.into_iter().enumerate() {
        check_key(&g.key).map_err(|m| (format!("grid[{i}].key"), m))?;
        if g.values.is_empty() {
            return Err((format!("grid[{i}].values"), "expected at least one value".into()));
        }
        let mut with = Vec::with_capacity(g.with.len());
        for (j, c) in g.with.into_iter().enumerate() {
            check_key(&c.key).map_err(|m| (format!("grid[{i}].with[{j}].key"), m))?;
            let values = c.values.unwrap_or_else(|| g.values.clone());
            if values.len() != g.values.len() {
                return Err((
                    format!("grid[{i}].with[{j}].values"),
                    format!(
                        "expected one value per value of the grid ({}), found {}",
                        g.values.len(),
                        values.len()
                    ),
                ));
            }
            with.push(Companion {
                key: c.key,
                values: values.iter().map(|v| v.to_string()).collect(),
            });
        }
        grids.push(Grid {
            key: g.key,
            values: g.values.iter().map(|v| v.to_string()).collect(),
            with,
        });
    }
    Ok(grids)
}

/// Reads and checks the sweep file at `path` (`command_line_scenario`: the command line names
/// the scenario too, which the file may not).
fn read_sweep_file(path: &Path, command_line_scenario: bool) -> Result<FileParts, SweepError> {
    let mut parts = FileParts::default();
    let file = path.display().to_string();
    let err = |message: String| SweepError::File {
        file: file.clone(),
        message,
    };
    let text = crate::files::read_text_limited(path, "sweep file", crate::files::SWEEP_FILE_LIMIT)?;
    let parsed: SweepFile = toml::from_str(&text).map_err(|e| err(e.to_string().trim().replace('\n', " ")))?;
    if let Some(s) = parsed.scenario {
        if command_line_scenario {
            return Err(err(format!(
                "key `scenario`: the sweep file names the scenario ({s}) and so does the command line; give it once"
            )));
        }
        parts.scenario = Some(path.parent().unwrap_or(Path::new("")).join(s));
    }
    if !parsed.scenarios.is_empty() {
        let dir = path.parent().unwrap_or(Path::new(""));
        let patterns: Vec<String> = (parsed.scenarios.iter())
            .map(|p| dir.join(p).display().to_string())
            .collect();
        parts
            .scenarios
            .extend(expand_scenarios(&patterns).map_err(|e| err(format!("key `scenarios`: {e}")))?);
    }
    if let Some(problem) = parsed.name.as_deref().and_then(scenario::file_name_problem) {
        return Err(err(format!("key `name`: {problem}")));
    }
    parts.name = parsed.name;
    parts.set = parsed.set;
    parts.grids = grids_of(parsed.grid).map_err(|(key, m)| err(format!("key `{key}`: {m}")))?;
    for (i, r) in parsed.range.into_iter().enumerate() {
        let range = Range {
            key: r.key,
            lo: r.lo,
            hi: r.hi,
            step: r.step,
        };
        check_key(&range.key).map_err(|m| err(format!("key `range[{i}].key`: {m}")))?;
        check_range(&range).map_err(|m| err(format!("key `range[{i}]`: {m}")))?;
        parts.ranges.push(range);
    }
    parts.random = parsed.random.map(|r| (r.count, r.seed));
    Ok(parts)
}

/// A `--set` on a key the sweep sweeps (or on a table holding it, or inside it) would override
/// the axis in every run and leave its column lying: refused, naming both.
fn set_sweeps_nothing(set: &[String], swept: &[&str]) -> Result<(), SweepError> {
    let within = |inner: &str, outer: &str| inner == outer || inner.starts_with(&format!("{outer}."));
    for spec in set {
        let key = spec.split('=').next().unwrap_or_default().trim();
        if let Some(axis) = swept.iter().find(|s| within(s, key) || within(key, s)) {
            return Err(SweepError::Spec(format!(
                "--set {spec}: the sweep sweeps `{axis}`, and the --set would override that axis in every run; drop the --set, or change the axis's values"
            )));
        }
    }
    Ok(())
}

impl SweepSpec {
    /// Builds the sweep from a sweep file and/or command-line arguments (the arguments add
    /// grids and ranges after the file's, and `--random`/`--seed` replace the file's).
    pub fn build(args: &SweepArgs) -> Result<SweepSpec, SweepError> {
        let mut scenario_path: Option<PathBuf> = args.scenario.clone();
        let mut scenario_files = args.scenarios.clone();
        let mut name = None;
        let mut set = Vec::new();
        let mut grids = Vec::new();
        let mut ranges = Vec::new();
        let mut random_count = None;
        let mut seed = None;
        if let Some(path) = &args.sweep_file {
            let parts = read_sweep_file(path, scenario_path.is_some())?;
            scenario_path = scenario_path.or(parts.scenario);
            scenario_files.extend(parts.scenarios);
            (name, set, grids, ranges) = (parts.name, parts.set, parts.grids, parts.ranges);
            if let Some((count, s)) = parts.random {
                (random_count, seed) = (Some(count), Some(s));
            }
        }
        if let Some(first) = scenario_files.first() {
            if scenario_path.is_some() {
                return Err(SweepError::Spec(
                    "a scenario and --scenarios (or a sweep file's `scenarios`): give one, the files are the sweep's base".into(),
                ));
            }
            grids.insert(0, scenario_axis(&scenario_files)?);
            scenario_path = Some(first.clone());
            name = name.or_else(|| Some("scenarios".into()));
        }
        let scenario_path = scenario_path.ok_or_else(|| {
            SweepError::Spec("no scenario: give SCENARIO or a sweep file with `scenario = \"…\"`".into())
        })?;
        set.extend(args.set.iter().cloned());
        for g in &args.grids {
            grids.push(parse_grid(g)?);
        }
        for r in &args.ranges {
            ranges.push(parse_range(r)?);
        }
        random_count = args.random.or(random_count);
        seed = args.seed.or(seed);

        let keys = grids
            .iter()
            .flat_map(|g| std::iter::once(g.key.as_str()).chain(g.with.iter().map(|c| c.key.as_str())))
            .chain(ranges.iter().map(|r| r.key.as_str()));
        let keys: Vec<&str> = keys.collect();
        if let Some(key) = swept_twice(keys.iter().copied()) {
            return Err(SweepError::Spec(format!(
                "`{key}` is swept twice (each key takes one --grid or one --range)"
            )));
        }
        set_sweeps_nothing(&args.set, &keys)?;
        let random = random_of(random_count, seed, ranges)?;
        if grids.is_empty() && random.is_none() {
            return Err(SweepError::Spec(
                "nothing to sweep: give --grid KEY=V1,V2,…, or --random N with --range KEY=LO..HI, or a sweep file"
                    .into(),
            ));
        }
        for spec in &set {
            scenario::check_override(spec).map_err(|e| SweepError::Spec(e.to_string()))?;
        }
        let text = crate::files::read_limited(&scenario_path, "scenario", crate::files::SCENARIO_LIMIT)?;
        let name = match name {
            Some(n) => n,
            // The base scenario's name; if the base alone does not load, the file's stem.
            None => scenario::load(&scenario_path, &set)
                .map(|l| l.scenario.name)
                .unwrap_or_else(|_| {
                    scenario_path
                        .file_stem()
                        .map_or("sweep".into(), |s| s.to_string_lossy().into_owned())
                }),
        };
        let runs = grids
            .iter()
            .map(|g| g.values.len())
            .chain(random.as_ref().map(|r| r.count))
            .try_fold(1usize, usize::checked_mul)
            .filter(|&runs| runs <= MAX_RUNS)
            .ok_or_else(|| {
                let factors: Vec<String> = grids
                    .iter()
                    .map(|g| format!("{} values of {}", g.values.len(), g.key))
                    .chain(random.as_ref().map(|r| format!("{} random draws", r.count)))
                    .collect();
                SweepError::Spec(format!(
                    "the sweep has more than {MAX_RUNS} runs ({}); split it into several sweeps",
                    factors.join(" × ")
                ))
            })?;
        let spec = SweepSpec {
            name,
            scenario: scenario_path.display().to_string(),
            scenario_fnv1a: fnv1a(&text),
            set,
            grids,
            random,
            runs,
        };
        // A scenario that the base overrides break, whatever the swept values (an unknown
        // key in `--set`), is the sweep's error, not a row error in every run: told by the
        // first run failing exactly as the base does.
        if let Err(base) = scenario::load(&scenario_path, &spec.set) {
            let first = scenario::load(&scenario_path, &spec.run(0).overrides);
            if first.is_err_and(|e| e.to_string() == base.to_string()) {
                return Err(SweepError::Spec(format!("every run would fail: {base}")));
            }
        }
        Ok(spec)
    }

    /// Sweep keys in column order: grid keys, then range keys.
    /// (A sweep over CommonRoad files has the key `commonroad.file` first.)
    pub fn keys(&self) -> Vec<String> {
        self.grids
            .iter()
            .map(|g| g.key.clone())
            .chain(self.random.iter().flat_map(|r| r.ranges.iter().map(|r| r.key.clone())))
            .collect()
    }

    /// Run `index`: grid point `index / draws` (the first grid varies slowest) with random
    /// draw `index % draws` (every grid point gets the same draws).
    pub fn run(&self, index: usize) -> Run {
        let draws = self.random.as_ref().map_or(1, |r| r.count);
        let mut point = index / draws;
        let mut grid_values = vec![String::new(); self.grids.len()];
        let mut companions = Vec::new();
        for (i, g) in self.grids.iter().enumerate().rev() {
            let at = point % g.values.len();
            grid_values[i] = g.values[at].clone();
            companions.extend(g.with.iter().map(|c| format!("{}={}", c.key, c.values[at])));
            point /= g.values.len();
        }
        let mut parameters: Vec<(String, String)> = self.grids.iter().map(|g| g.key.clone()).zip(grid_values).collect();
        if let Some(random) = &self.random {
            let mut g = draw_generator(random.seed, index % draws);
            for r in &random.ranges {
                parameters.push((r.key.clone(), range_value(r, g.next_f64())));
            }
        }
        // The keys moving with a grid axis (not columns of their own).
        let overrides = self
            .set
            .iter()
            .cloned()
            .chain(parameters.iter().map(|(k, v)| format!("{k}={v}")))
            .chain(companions)
            .collect();
        Run {
            index,
            overrides,
            parameters,
        }
    }

    /// The log file name of run `index`, zero padded to the digits of the last index (at least 3).
    pub fn log_name(&self, index: usize) -> String {
        let width = self.runs.saturating_sub(1).to_string().len().max(3);
        format!("{}-{index:0width$}.mcap", self.name)
    }

    /// The run indices of a shard (all runs without one).
    pub fn indices(&self, shard: Option<Shard>) -> Vec<usize> {
        (0..self.runs)
            .filter(|i| shard.is_none_or(|s| i % s.count == s.index))
            .collect()
    }
}

/// Shard `index` of `count` (0-based): the runs with run index % count == index.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

/// One row of a sweep summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Row {
    pub index: usize,
    /// Sweep key → value (TOML text).
    pub parameters: BTreeMap<String, String>,
    /// Log file name, relative to the sweep directory (none when no log was written).
    pub log: Option<String>,
    /// Metrics of the log (none when the run has no readable log).
    pub metrics: Option<FlatMetrics>,
    /// Why the run failed (scenario rejected, episode error, stopped early); none when it completed.
    pub error: Option<String>,
    /// Whether the run was never started (the sweep was interrupted first).
    #[serde(default)]
    pub not_run: bool,
    /// Whether Ctrl-C / SIGTERM stopped the run before its end (its row holds the partial
    /// metrics and the error): a merge counts it as not run.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub interrupted: bool,
}

/// The text of a caught panic's payload.
pub(crate) fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "panic".into())
}

/// Runs one run of the sweep — logged into `logs` (the sweep directory) if given, else only
/// its metrics, analysed while it runs — and analyses it ([`crate::run::Keep`] per run). Never
/// fails: a failure is the row's `error`.
pub fn execute_run(spec: &SweepSpec, run: &Run, logs: Option<&Path>) -> Row {
    match logs {
        Some(dir) => execute_logged(Path::new(&spec.scenario), run, dir, spec.log_name(run.index)),
        None => execute_analysed(Path::new(&spec.scenario), run, &format!("run {}", run.index)),
    }
}

/// Why a sweep run has no outcome, kept typed until its row is written.
#[derive(Debug, thiserror::Error)]
enum RunFailure {
    #[error(transparent)]
    Scenario(#[from] scenario::ScenarioError),
    #[error(transparent)]
    Run(#[from] crate::run::RunError),
}

/// A run's row before it runs.
fn row_of(run: &Run) -> Row {
    Row {
        index: run.index,
        parameters: run.parameters.iter().cloned().collect(),
        log: None,
        metrics: None,
        error: None,
        not_run: false,
        interrupted: false,
    }
}

/// The row's error: `error` (the run's own, or why it could not run), else the analysis's,
/// else the metrics' (a run stopped by an error), else `incomplete` for an incomplete run.
fn settle(mut row: Row, error: Option<String>, incomplete: &str) -> Row {
    row.error = error
        .or(row.error)
        .or_else(|| row.metrics.as_ref().and_then(|m| m.error.clone()))
        .or_else(|| {
            row.metrics
                .as_ref()
                .filter(|m| !m.complete)
                .map(|_| incomplete.to_string())
        });
    // Kept in summaries and shown in tables: in the one-line form people read.
    row.error = row.error.map(|e| crate::message::shorten_numbers(&e));
    row
}

fn panicked(payload: &(dyn std::any::Any + Send)) -> String {
    format!("the run panicked: {}", panic_message(payload))
}

/// One run of `scenario` with the run's overrides into `dir/log_name`, analysed (what every
/// sweep run is). Never fails: a failure is the row's `error`.
pub fn execute_logged(scenario_path: &Path, run: &Run, dir: &Path, log_name: String) -> Row {
    let log_path = dir.join(&log_name);
    let mut row = row_of(run);
    // A log of an earlier sweep under this name must not pass for this run's (anything else
    // there is kept, and refused as this run's log).
    if mcap::check_target(&log_path, &[]).is_ok() {
        let _ = std::fs::remove_file(&log_path);
    }
    let outcome = catch_unwind(AssertUnwindSafe(|| -> Result<_, RunFailure> {
        let loaded = scenario::load(scenario_path, &run.overrides)?;
        Ok(crate::run::run(&loaded, crate::run::Keep::Log(&log_path), Vec::new())?)
    }));
    if log_path.exists() {
        row.log = Some(log_name);
    }
    settle_outcome(row, outcome, "the log is incomplete")
}

/// The row of a run that ended with `outcome` (its metrics, or why it has none).
fn settle_outcome(
    mut row: Row,
    outcome: std::thread::Result<Result<crate::run::Outcome, RunFailure>>,
    incomplete: &str,
) -> Row {
    let error = match outcome {
        Ok(Ok(outcome)) => {
            row.metrics = outcome.metrics.as_ref().map(FlatMetrics::from);
            outcome.summary.error.map(|e| e.to_string())
        }
        Ok(Err(e)) => Some(e.to_string()),
        Err(payload) => Some(panicked(payload.as_ref())),
    };
    settle(row, error, incomplete)
}

/// One run of `scenario` with the run's overrides, analysed while it runs and not logged (what
/// a falsification candidate is): the metrics its log would give (`analyze::AnalysisSink`),
/// without writing, compressing and reading the log. `name` stands for the log in the metrics
/// and errors. Never fails: a failure is the row's `error`.
pub fn execute_analysed(scenario_path: &Path, run: &Run, name: &str) -> Row {
    let outcome = catch_unwind(AssertUnwindSafe(|| -> Result<_, RunFailure> {
        let loaded = scenario::load(scenario_path, &run.overrides)?;
        Ok(crate::run::run(&loaded, crate::run::Keep::Metrics(name), Vec::new())?)
    }));
    settle_outcome(row_of(run), outcome, "the run is incomplete")
}

/// Runs `indices` of the sweep on `threads` threads (each pulls the next index from a shared
/// counter), logged into `logs` if given ([`execute_run`]), calling `done` on the calling
/// thread as each run finishes. Rows come back in the order of `indices`, whatever the thread
/// count. After [`crate::episode::request_stop`] no new run starts; the runs not started are
/// rows with that error.
pub fn execute(
    spec: &SweepSpec,
    indices: &[usize],
    logs: Option<&Path>,
    threads: usize,
    mut done: impl FnMut(&Row),
) -> Result<Vec<Row>, SweepError> {
    // Runs analysed in memory write nothing.
    if let Some(dir) = logs {
        std::fs::create_dir_all(dir).map_err(|source| SweepError::Io {
            path: dir.display().to_string(),
            reason: source,
        })?;
    }
    let rows = in_parallel(
        indices.len(),
        threads,
        "sweep",
        |position| {
            let mut row = execute_run(spec, &spec.run(indices[position]), logs);
            row.interrupted = row.error.is_some() && crate::episode::stop_requested();
            row
        },
        |_, row| done(row),
    )?;
    Ok(rows
        .into_iter()
        .zip(indices)
        .map(|(row, &index)| {
            row.unwrap_or_else(|| Row {
                index,
                parameters: spec.run(index).parameters.into_iter().collect(),
                log: None,
                metrics: None,
                not_run: true,
                interrupted: false,
                error: Some(if crate::episode::stop_requested() {
                    "not run: the sweep was interrupted".into()
                } else {
                    "not run: its worker thread stopped".into()
                }),
            })
        })
        .collect())
}

/// Calls `work(0..count)` on `threads` threads named `<name>-<k>` (each pulls the next
/// position from a shared counter), calling `done` on the calling thread as each finishes;
/// results come back by position. After [`crate::episode::request_stop`] no new work starts:
/// its positions are `None`.
pub fn in_parallel<R: Send>(
    count: usize,
    threads: usize,
    name: &str,
    work: impl Fn(usize) -> R + Sync,
    mut done: impl FnMut(usize, &R),
) -> Result<Vec<Option<R>>, SweepError> {
    let next = AtomicUsize::new(0);
    let mut results: Vec<Option<R>> = (0..count).map(|_| None).collect();
    std::thread::scope(|scope| -> Result<(), SweepError> {
        let (tx, rx) = mpsc::channel::<(usize, R)>();
        for worker in 0..threads.clamp(1, count.max(1)) {
            let (tx, next, work) = (tx.clone(), &next, &work);
            std::thread::Builder::new()
                .name(format!("{name}-{worker}"))
                .stack_size(16 << 20)
                .spawn_scoped(scope, move || loop {
                    // After Ctrl-C / SIGTERM the running episodes stop; start no new ones.
                    if crate::episode::stop_requested() {
                        break;
                    }
                    let position = next.fetch_add(1, Ordering::Relaxed);
                    if position >= count || tx.send((position, work(position))).is_err() {
                        break;
                    }
                })
                .map_err(|source| SweepError::Io {
                    path: "(worker thread)".into(),
                    reason: source,
                })?;
        }
        drop(tx);
        for (position, result) in rx {
            done(position, &result);
            results[position] = Some(result);
        }
        Ok(())
    })?;
    Ok(results)
}

/// The runs executed at once for `--threads` (`requested`): at least 1; none given, every core.
pub fn threads(requested: Option<usize>) -> Result<usize, SweepError> {
    match requested {
        Some(0) => Err(SweepError::Spec("--threads: expected at least 1".into())),
        Some(k) => Ok(k),
        None => Ok(std::thread::available_parallelism().map_or(1, |n| n.get())),
    }
}

/// Checks that `dir` may hold a sweep's logs and summary: a directory, or nothing yet.
pub fn check_out_dir(dir: &Path) -> Result<(), SweepError> {
    if dir.exists() && !dir.is_dir() {
        return Err(SweepError::Spec(format!(
            "--out {}: expected a directory for the sweep's logs and summary, found a file",
            dir.display()
        )));
    }
    Ok(())
}

/// How summary files start: an existing file that starts otherwise is never replaced.
const SUMMARY_JSON_START: &[u8] = b"{\n  \"mjsafe_version\"";
const SUMMARY_CSV_START: &[u8] = b"index,log,";

/// `summary` or `summary-shard-<i>-of-<N>`.
fn summary_stem(shard: Option<Shard>) -> String {
    match shard {
        None => "summary".into(),
        Some(s) => format!("summary-shard-{}-of-{}", s.index, s.count),
    }
}

/// The summary files of `shard` in `dir` (JSON, CSV), each with the start of the text a file
/// it may replace begins with.
fn summary_files(dir: &Path, shard: Option<Shard>) -> [(PathBuf, &'static [u8]); 2] {
    let stem = summary_stem(shard);
    [
        (dir.join(format!("{stem}.json")), SUMMARY_JSON_START),
        (dir.join(format!("{stem}.csv")), SUMMARY_CSV_START),
    ]
}

/// The registered kinds with a defining file (Python's) that the sweep's overrides or grid
/// values name (as a quoted kind, `kind="…"`), each with its file.
fn python_kinds(spec: &SweepSpec) -> BTreeMap<String, String> {
    let text: Vec<&str> = (spec.set.iter())
        .chain(
            spec.grids
                .iter()
                .flat_map(|g| g.values.iter().chain(g.with.iter().flat_map(|c| c.values.iter()))),
        )
        .map(String::as_str)
        .collect();
    let registry = crate::registry::registry();
    (registry.origins().into_iter())
        .filter(|(kind, _)| {
            text.iter()
                .any(|t| t.contains(&format!("\"{kind}\"")) || t.contains(&format!("'{kind}'")))
        })
        .map(|(kind, file)| (kind.to_string(), file.to_string()))
        .collect()
}

/// A sweep summary: the sweep, which shard (none: all runs), and one row per run by index.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub mjsafe_version: String,
    pub sweep: SweepSpec,
    pub shard: Option<Shard>,
    /// Sweep keys in column order.
    pub parameters: Vec<String>,
    /// The kinds the sweep names that a Python module registered, with the file that defines
    /// each (what `python -m mjsafe --load FILE` needs to run it again).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub python_kinds: BTreeMap<String, String>,
    pub runs: Vec<Row>,
}

impl Summary {
    pub fn new(spec: &SweepSpec, shard: Option<Shard>, mut runs: Vec<Row>) -> Summary {
        runs.sort_by_key(|r| r.index);
        Summary {
            mjsafe_version: env!("CARGO_PKG_VERSION").to_string(),
            sweep: spec.clone(),
            shard,
            parameters: spec.keys(),
            python_kinds: python_kinds(spec),
            runs,
        }
    }

    /// Base name of the summary files: `summary` or `summary-shard-<i>-of-<N>`.
    pub fn file_stem(&self) -> String {
        summary_stem(self.shard)
    }

    /// Checks before any run that [`Summary::write`] may write the summary of `shard` into
    /// `dir` (nothing there, or a summary it may replace), so a sweep does not run for hours
    /// and then fail to write it.
    pub fn check_outputs(dir: &Path, shard: Option<Shard>) -> Result<(), SweepError> {
        for (path, start) in summary_files(dir, shard) {
            crate::files::check_output(&path, "sweep summary", Replace::IfStartsWith(start), &[])?;
        }
        Ok(())
    }

    pub fn failures(&self) -> usize {
        self.runs.iter().filter(|r| r.error.is_some()).count()
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("summaries serialise") + "\n"
    }

    /// Columns: index, log, the sweep keys, every metric column, error.
    pub fn to_csv(&self) -> String {
        let metrics: Vec<&FlatMetrics> = self.runs.iter().filter_map(|r| r.metrics.as_ref()).collect();
        let metric_columns: Vec<String> = FlatMetrics::columns(metrics.iter().copied())
            .into_iter()
            .filter(|c| c != "error")
            .collect();
        let mut header = vec!["index".to_string(), "log".into()];
        header.extend(self.parameters.iter().cloned());
        header.extend(metric_columns.iter().cloned());
        header.push("error".into());
        let mut lines = vec![header];
        for r in &self.runs {
            let mut line = vec![r.index.to_string(), r.log.clone().unwrap_or_default()];
            line.extend(
                self.parameters
                    .iter()
                    .map(|k| r.parameters.get(k).cloned().unwrap_or_default()),
            );
            line.extend(metric_columns.iter().map(|c| match &r.metrics {
                Some(m) => m.cell(c).csv(),
                None if c == "complete" => Cell::Bool(Some(false)).csv(),
                None => String::new(),
            }));
            line.push(r.error.clone().unwrap_or_default());
            lines.push(line);
        }
        csv_lines(&lines)
    }

    /// Writes `<stem>.json` and `<stem>.csv` into `dir`; returns their paths. Both are written
    /// whole as `.partial` files and renamed only when both are written, so a failure (a full
    /// disk) leaves neither half-written; `inputs` (e.g. the summaries merged) are never replaced.
    pub fn write(&self, dir: &Path, inputs: &[&Path]) -> Result<(PathBuf, PathBuf), SweepError> {
        std::fs::create_dir_all(dir).map_err(|source| SweepError::Io {
            path: dir.display().to_string(),
            reason: source,
        })?;
        let [(json, json_start), (csv, csv_start)] = summary_files(dir, self.shard);
        let mut outputs = Vec::new();
        for (path, text, start) in [(&json, self.to_json(), json_start), (&csv, self.to_csv(), csv_start)] {
            let mut out = OutputFile::create(path, "sweep summary", Replace::IfStartsWith(start), inputs)?;
            out.write_all(text.as_bytes())?;
            outputs.push(out);
        }
        for out in outputs {
            out.commit()?;
        }
        Ok((json, csv))
    }

    /// Reads a `summary*.json`.
    pub fn read(path: &Path) -> Result<Summary, SweepError> {
        let file = path.display().to_string();
        let text = crate::files::read_text_limited(path, "sweep summary", crate::files::SUMMARY_LIMIT)?;
        serde_json::from_str(&text).map_err(|e| SweepError::Summary {
            file,
            message: e.to_string(),
        })
    }

    /// Files a `--merge` argument stands for: a directory's `summary-shard-*.json` (sorted),
    /// or the file itself.
    pub fn merge_inputs(arg: &Path) -> Result<Vec<PathBuf>, SweepError> {
        if !arg.is_dir() {
            return Ok(vec![arg.to_path_buf()]);
        }
        let entries = std::fs::read_dir(arg).map_err(|source| SweepError::Io {
            path: arg.display().to_string(),
            reason: source,
        })?;
        let mut files: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("summary-shard-") && n.ends_with(".json"))
            })
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(SweepError::Merge(format!(
                "{} holds no summary-shard-*.json",
                arg.display()
            )));
        }
        Ok(files)
    }

    /// Merges shard summaries (`(file, summary)`) of one sweep into the summary of the whole
    /// sweep; also returns the run indices no input holds. The inputs must agree on the
    /// sweep and mjsafe version; a run index may appear only once.
    pub fn merge(inputs: &[(String, Summary)]) -> Result<(Summary, Vec<usize>), SweepError> {
        let Some((first_file, first)) = inputs.first() else {
            return Err(SweepError::Merge("no summaries given".into()));
        };
        let mut rows: BTreeMap<usize, (&str, Row)> = BTreeMap::new();
        for (file, s) in inputs {
            // The scenario is told by its contents (hash), not by how its path was spelled:
            // shards started from other directories or checkouts are the same sweep.
            let same_sweep = SweepSpec {
                scenario: first.sweep.scenario.clone(),
                ..s.sweep.clone()
            } == first.sweep;
            if !same_sweep {
                return Err(SweepError::Merge(format!(
                    "{file} and {first_file} are summaries of different sweeps ({})",
                    describe_difference(&first.sweep, &s.sweep)
                )));
            }
            if s.mjsafe_version != first.mjsafe_version {
                return Err(SweepError::Merge(format!(
                    "{file} was written by mjsafe {}, {first_file} by mjsafe {}",
                    s.mjsafe_version, first.mjsafe_version
                )));
            }
            for r in &s.runs {
                if r.index >= s.sweep.runs {
                    return Err(SweepError::Merge(format!(
                        "{file} has run {} but the sweep has {} runs",
                        r.index, s.sweep.runs
                    )));
                }
                if let Some((other, _)) = rows.get(&r.index) {
                    return Err(SweepError::Merge(format!(
                        "run {} is in both {other} and {file}",
                        r.index
                    )));
                }
                rows.insert(r.index, (file, r.clone()));
            }
        }
        let missing: Vec<usize> = (0..first.sweep.runs).filter(|i| !rows.contains_key(i)).collect();
        let merged = Summary {
            mjsafe_version: first.mjsafe_version.clone(),
            sweep: first.sweep.clone(),
            shard: None,
            parameters: first.parameters.clone(),
            python_kinds: first.python_kinds.clone(),
            runs: rows.into_values().map(|(_, r)| r).collect(),
        };
        Ok((merged, missing))
    }
}

/// Which field of two sweeps differs, for the merge error.
fn describe_difference(a: &SweepSpec, b: &SweepSpec) -> String {
    let fields: [(&str, bool); 6] = [
        ("name", a.name != b.name),
        ("scenario file contents", a.scenario_fnv1a != b.scenario_fnv1a),
        ("--set", a.set != b.set),
        ("grids", a.grids != b.grids),
        ("random draws", a.random != b.random),
        ("run count", a.runs != b.runs),
    ];
    let differing: Vec<&str> = fields.iter().filter(|(_, d)| *d).map(|(n, _)| *n).collect();
    format!("they differ in: {}", differing.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_values_outside_brackets_and_quotes() {
        assert_eq!(split_values("0.1, 0.2,0.4").unwrap(), ["0.1", "0.2", "0.4"]);
        assert_eq!(
            split_values("{kind='cbf_qp', l0=4.0},{kind='none'}").unwrap(),
            ["{kind='cbf_qp', l0=4.0}", "{kind='none'}"]
        );
        assert_eq!(split_values("[1, 2],[3]").unwrap(), ["[1, 2]", "[3]"]);
        assert_eq!(split_values("'a,b',\"c,\\\"d\"").unwrap(), ["'a,b'", "\"c,\\\"d\""]);
        assert!(split_values("[1, 2").unwrap_err().contains("missing closing `]`"));
        assert!(split_values("1],2").unwrap_err().contains("unbalanced"));
        assert!(split_values("'a,b").unwrap_err().contains("unterminated"));
        assert!(split_values("1,,2").unwrap_err().contains("value 2 of 3 is empty"));
    }

    #[test]
    fn parses_grids_ranges_and_shards() {
        let g = parse_grid("filter.kind='cbf_qp','gamma_m'").unwrap();
        assert_eq!(g.key, "filter.kind");
        assert_eq!(g.values, ["'cbf_qp'", "'gamma_m'"]);
        // A bare word is a string; what is neither a TOML value nor a bare word is refused.
        assert_eq!(
            parse_grid("filter.kind=cbf_qp,gamma_m").unwrap().values,
            ["cbf_qp", "gamma_m"]
        );
        let e = parse_grid("filter.kind=cbf qp").unwrap_err().to_string();
        assert!(
            e.starts_with("--grid filter.kind=cbf qp:") && e.contains("not a TOML value or a bare word"),
            "{e}"
        );
        assert!(parse_grid("delays.steering")
            .unwrap_err()
            .to_string()
            .contains("KEY=V1,V2"));
        let r = parse_range("delays.steering=0.0..0.5:0.01").unwrap();
        assert_eq!((r.lo, r.hi, r.step), (0.0, 0.5, Some(0.01)));
        assert!(parse_range("x=1..0").is_err());
        assert!(parse_range("x=0..1:0").is_err());
        assert_eq!(parse_shard("1/4").unwrap(), Shard { index: 1, count: 4 });
        assert!(parse_shard("4/4").is_err());
        assert!(parse_shard("1-4").is_err());
    }

    #[test]
    fn draws_are_keyed_by_seed_and_draw_only() {
        let range = Range {
            key: "x".into(),
            lo: 0.0,
            hi: 0.5,
            step: Some(0.1),
        };
        let a: Vec<String> = (0..50)
            .map(|j| range_value(&range, draw_generator(7, j).next_f64()))
            .collect();
        let b: Vec<String> = (0..50)
            .map(|j| range_value(&range, draw_generator(7, j).next_f64()))
            .collect();
        assert_eq!(a, b);
        let allowed = ["0.0", "0.1", "0.2", "0.3", "0.4", "0.5"];
        assert!(a.iter().all(|v| allowed.contains(&v.as_str())), "{a:?}");
        for v in allowed {
            assert!(a.iter().any(|x| x == v), "{v} never drawn in {a:?}");
        }
        let c: Vec<String> = (0..50)
            .map(|j| range_value(&range, draw_generator(8, j).next_f64()))
            .collect();
        assert_ne!(a, c);
    }

    #[test]
    fn whole_number_steps_are_integers_seeds_accept() {
        let seeds = Range {
            key: "seed".into(),
            lo: 0.0,
            hi: 1000.0,
            step: Some(1.0),
        };
        let drawn: Vec<String> = (0..20)
            .map(|j| range_value(&seeds, draw_generator(3, j).next_f64()))
            .collect();
        assert!(
            drawn.iter().all(|v| v.parse::<u64>().is_ok_and(|n| n <= 1000)),
            "{drawn:?}"
        );
        let halves = Range {
            step: Some(0.5),
            ..seeds
        };
        assert_eq!(step_value(&halves, 3), "1.5");
    }
}
