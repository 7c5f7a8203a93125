//! Fuzz suite of the inputs a user writes: seeded mutations of every scenario in `scenarios/`,
//! of the small committed CommonRoad files
//! and of the sweep file (line deletions and duplications, swapped lines, NaN/inf/huge/tiny/
//! negative numbers, type swaps, truncation, random bytes), each loaded, validated, built into
//! an episode and run for a few steps in this process. Any panic, any hang (a case over
//! `CASE_TIMEOUT`), or an error that is not one line naming the file and the key, fails it.
//!
//! `MJSAFE_FUZZ_CASES` sets the number of mutations per file (default 800: 10 400 scenario cases for the 13 files and 3200 sweep-file cases, a few seconds);
//! `scripts/fuzz.sh` runs 100k+.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use mjsafe::episode::Episode;
use mjsafe::log::{LogError, Record, Sink};

const CASE_TIMEOUT: Duration = Duration::from_secs(60);
/// Steps run of each episode that builds (enough to pass the first ticks, predictions and
/// the first contact checks).
const STEPS: u64 = 40;

/// The seeded generator of the mutations.
use mjsafe::random::SplitMix64 as Rng;

/// One of `items`, drawn.
fn pick<'a>(rng: &mut Rng, items: &[&'a str]) -> &'a str {
    items[rng.below(items.len())]
}

const NUMBERS: [&str; 21] = [
    "nan",
    "inf",
    "-inf",
    "1e300",
    "-1e300",
    "1e-300",
    "0",
    "-0.0",
    "-1",
    "99999999999999999999",
    "1e9",
    "1e-9",
    "0.5",
    "3",
    "-3.5",
    "18446744073709551616",
    // Large but in-range integers: sizes that drive allocations and loops.
    "4294967296",
    "2147483647",
    "100000",
    "1000000",
    "65536",
];
/// Tables appended to a scenario (`{}`: a number from [`NUMBERS`]): the newer tables
/// (sensing, actuation, actuator dynamics), φ's grid and an obstacle's extent and jitter.
const TABLES: [&str; 8] = [
    "[sensing]\nlatency = {}",
    "[sensing]\nnoise_std = [{}, 0.0, 0.0, 0.0]\nbias = [0.0, {}, 0.0, 0.0]",
    "[actuation.steering]\ndrop_probability = 0.1\nextra_latency = { distribution = 'uniform', max = {} }",
    "[actuation.acceleration]\nextra_latency = { distribution = 'truncated_normal', mean = {}, std = 0.1, max = 0.2 }",
    "[actuator_dynamics.steering]\ntime_constant = {}\nrate_limit = {}\nmax = {}",
    "[actuator_dynamics.u1]\nmin = -1.0\nmax = {}",
    "[filter.phi_box]\nlower = [-1.0, -1.0]\nupper = [1.0, 1.0]\npoints = {}",
    "[[obstacles]]\ncentre = [{}, 0.0]\nradius = 1.0\nappear_at = 1.0\nappear_jitter = {}",
];
const VALUES: [&str; 17] = [
    "'text'",
    "[1, 2]",
    "[]",
    "true",
    "{}",
    "{ profile = 'table' }",
    "[[1]]",
    "''",
    "[nan]",
    "'bicycle'",
    "'mujoco'",
    "'ode'",
    "'rk4'",
    "'predictor'",
    "'linear'",
    "'strict_feedback'",
    "'unicycle'",
];

/// One seeded mutation of a TOML text.
fn mutate(text: &str, rng: &mut Rng) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let rounds = 1 + rng.below(3);
    for _ in 0..rounds {
        if lines.is_empty() {
            lines.push(String::new());
        }
        let i = rng.below(lines.len());
        match rng.below(10) {
            0 => {
                lines.remove(i);
            }
            1 => {
                let line = lines[i].clone();
                lines.insert(i, line);
            }
            2 => {
                let j = rng.below(lines.len());
                lines.swap(i, j);
            }
            // A number (or the whole value) of a `key = value` line replaced.
            3..=5 => {
                if let Some((key, _)) = lines[i].split_once('=') {
                    let value = if rng.below(3) == 0 {
                        pick(rng, &VALUES)
                    } else {
                        pick(rng, &NUMBERS)
                    };
                    lines[i] = format!("{key}= {value}");
                }
            }
            // One number inside a line (e.g. an array element) replaced.
            6 => {
                let line = &lines[i];
                let starts: Vec<usize> = line
                    .char_indices()
                    .filter(|&(k, c)| c.is_ascii_digit() && (k == 0 || !line.as_bytes()[k - 1].is_ascii_alphanumeric()))
                    .map(|(k, _)| k)
                    .collect();
                if !starts.is_empty() {
                    let start = starts[rng.below(starts.len())];
                    let end = line[start..]
                        .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == 'e' || c == '-'))
                        .map_or(line.len(), |n| start + n);
                    lines[i] = format!("{}{}{}", &line[..start], pick(rng, &NUMBERS), &line[end..]);
                }
            }
            // A table appended, its numbers drawn from NUMBERS.
            8 => {
                let mut table = pick(rng, &TABLES).to_string();
                while let Some(at) = table.find("{}") {
                    table.replace_range(at..at + 2, pick(rng, &NUMBERS));
                }
                lines.push(table);
            }
            // Truncated somewhere.
            7 => {
                let joined = lines.join("\n");
                let mut cut = rng.below(joined.len() + 1);
                while !joined.is_char_boundary(cut) {
                    cut -= 1;
                }
                lines = joined[..cut].lines().map(str::to_string).collect();
            }
            // Random printable or control bytes spliced in.
            _ => {
                let noise: String = (0..1 + rng.below(8))
                    .map(|_| char::from(b" =[]{}\"'.,#\n\t0123456789aZ\x00\x7f"[rng.below(27)]))
                    .collect();
                let line = &mut lines[i];
                let mut at = rng.below(line.len() + 1);
                while !line.is_char_boundary(at) {
                    at -= 1;
                }
                line.insert_str(at, &noise);
            }
        }
    }
    lines.join("\n")
}

/// Observes records and drops them (the fuzz tests the episode, not the log file).
struct NullSink;

impl Sink for NullSink {
    fn record(&mut self, _record: &Record) -> Result<(), LogError> {
        Ok(())
    }
    fn finish(&mut self, _complete: bool) -> Result<(), LogError> {
        Ok(())
    }
}

#[derive(Debug, Default, Clone, Copy)]
struct Counts {
    cases: usize,
    rejected: usize,
    not_built: usize,
    ran: usize,
    stopped_in_run: usize,
}

/// What a user would see: one error line (as the binary prints it).
fn check_message(case: &str, message: &str, file: &str, text: &str) {
    let shown = mjsafe::message::shorten_numbers(message);
    assert!(!shown.contains('\n'), "{case}: error of more than one line: {shown}");
    assert!(
        shown.contains(file),
        "{case}: error does not name the file {file}: {shown}"
    );
    for rust in [
        "struct ", "enum ", "Option<", "Vec<", "f64", "usize", "u64", "i128", "u128", "panicked",
    ] {
        assert!(
            !shown.contains(rust),
            "{case}: error names a Rust type ({rust}): {shown}"
        );
    }
    // A long number is the user's own, quoted as written, or mjsafe's, shortened.
    assert!(
        !shown
            .split(|c: char| !c.is_ascii_digit())
            .any(|digits| digits.len() > mjsafe::message::LONGEST_NUMBER && !text.contains(digits)),
        "{case}: a long number the scenario does not hold: {shown}"
    );
}

/// Loads, validates, builds and runs one scenario text; returns which stage it reached.
fn scenario_case(path: &Path, text: String, counts: &mut Counts, case: &str) {
    counts.cases += 1;
    let file = path.display().to_string();
    let loaded = match mjsafe::scenario::from_text(path, text.clone(), &[]) {
        Ok(loaded) => loaded,
        Err(e) => {
            counts.rejected += 1;
            return check_message(case, &e.to_string(), &file, &text);
        }
    };
    let mut episode = match Episode::new(&loaded) {
        Ok(episode) => episode,
        Err(e) => {
            counts.not_built += 1;
            return check_message(case, &e.to_string(), &file, &text);
        }
    };
    episode.limit_steps(STEPS);
    let mut sink = NullSink;
    match episode.run(&mut [&mut sink]) {
        Ok(summary) => {
            counts.ran += 1;
            counts.stopped_in_run += usize::from(summary.error.is_some());
        }
        Err(e) => panic!("{case}: the run failed outside the episode (a sink error with a null sink?): {e}"),
    }
}

/// Runs `work` on a worker thread: a panic or a case slower than `CASE_TIMEOUT` fails the test
/// with the case's description (`describe` is only called on failure).
fn guarded<T: Send + 'static>(what: String, work: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = mpsc::channel();
    let handle = std::thread::spawn(move || {
        let result = work();
        let _ = tx.send(());
        result
    });
    match rx.recv_timeout(CASE_TIMEOUT) {
        Ok(()) => handle.join().unwrap_or_else(|_| panic!("{what}: panicked")),
        Err(mpsc::RecvTimeoutError::Disconnected) => match handle.join() {
            Ok(result) => result,
            Err(panic) => {
                let message = panic
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                panic!("{what}: panicked: {message}")
            }
        },
        Err(mpsc::RecvTimeoutError::Timeout) => panic!("{what}: no result after {CASE_TIMEOUT:?} (a hang)"),
    }
}

fn cases_per_file() -> usize {
    std::env::var("MJSAFE_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(800)
}

fn seed() -> u64 {
    std::env::var("MJSAFE_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1)
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn scenario_files() -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(repo().join("scenarios"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml") && !p.to_string_lossy().ends_with(".sweep.toml"))
        .collect();
    files.sort();
    files
}

#[test]
fn mutated_scenarios_never_panic_hang_or_give_unclear_errors() {
    let started = Instant::now();
    let per_file = cases_per_file();
    let files = scenario_files();
    assert!(files.len() >= 10, "scenarios/ has {} files", files.len());
    // Two workers (the machines have two cores), each over every other file.
    let workers: Vec<_> = (0..2)
        .map(|worker| {
            let files: Vec<(usize, PathBuf)> = files.iter().cloned().enumerate().skip(worker).step_by(2).collect();
            std::thread::spawn(move || {
                let mut counts = Counts::default();
                for (position, path) in files {
                    let text = std::fs::read_to_string(&path).unwrap();
                    let name = path.file_name().unwrap().to_string_lossy().into_owned();
                    let mut rng = Rng(seed().wrapping_add((position as u64) << 32));
                    for case in 0..per_file {
                        let mutated = mutate(&text, &mut rng);
                        let what = format!("{name} mutation {case} (seed {}):\n{mutated}\n---", seed());
                        let path = path.clone();
                        counts = guarded(what.clone(), move || {
                            let mut counts = counts;
                            scenario_case(&path, mutated, &mut counts, &what);
                            counts
                        });
                    }
                }
                counts
            })
        })
        .collect();
    let mut total = Counts::default();
    for worker in workers {
        let c = worker.join().unwrap_or_else(|p| std::panic::resume_unwind(p));
        total.cases += c.cases;
        total.rejected += c.rejected;
        total.not_built += c.not_built;
        total.ran += c.ran;
        total.stopped_in_run += c.stopped_in_run;
    }
    eprintln!(
        "fuzz scenarios: {} cases in {:.1} s: {} rejected by validation, {} by the model checks, {} ran ({} stopped by an in-run error)",
        total.cases,
        started.elapsed().as_secs_f64(),
        total.rejected,
        total.not_built,
        total.ran,
        total.stopped_in_run
    );
    assert_eq!(total.cases, files.len() * per_file);
    // The mutations must exercise every stage, or the suite tests nothing.
    assert!(total.ran > total.cases / 20, "{total:?}");
    assert!(total.rejected > total.cases / 10, "{total:?}");
}

#[test]
fn mutated_sweep_files_never_panic_hang_or_give_unclear_errors() {
    let started = Instant::now();
    let per_file = cases_per_file() * 4;
    let dir = tempfile::tempdir().unwrap();
    let original = repo().join("scenarios/bicycle_delays.sweep.toml");
    // The sweep file names its scenario relative to itself: make it absolute for the copies.
    let text = std::fs::read_to_string(&original).unwrap().replace(
        "\"bicycle_obstacle.toml\"",
        &format!("\"{}/scenarios/bicycle_obstacle.toml\"", repo().display()),
    );
    let mut rng = Rng(seed() ^ 0x5eed);
    let (mut rejected, mut built) = (0, 0);
    for case in 0..per_file {
        let mutated = mutate(&text, &mut rng);
        let path = dir.path().join(format!("case-{case}.sweep.toml"));
        std::fs::write(&path, &mutated).unwrap();
        let what = format!("sweep mutation {case} (seed {}):\n{mutated}\n---", seed());
        let ok = guarded(what.clone(), move || {
            let args = mjsafe::sweep::SweepArgs {
                sweep_file: Some(path.clone()),
                ..Default::default()
            };
            match mjsafe::sweep::SweepSpec::build(&args) {
                Ok(spec) => {
                    // Expand the first and last runs: every override must apply or fail cleanly.
                    let indices = spec.indices(None);
                    for &i in indices.iter().take(2).chain(indices.last()) {
                        let run = spec.run(i);
                        if let Err(e) = mjsafe::scenario::load(Path::new(&spec.scenario), &run.overrides) {
                            let message = mjsafe::message::shorten_numbers(&e.to_string());
                            assert!(!message.contains('\n'), "{what}: {message}");
                        }
                    }
                    true
                }
                Err(e) => {
                    let message = mjsafe::message::shorten_numbers(&e.to_string());
                    assert!(
                        !message.contains('\n'),
                        "{what}: error of more than one line: {message}"
                    );
                    for rust in ["struct ", "enum ", "Option<", "Vec<"] {
                        assert!(!message.contains(rust), "{what}: error names a Rust type: {message}");
                    }
                    false
                }
            }
        });
        if ok {
            built += 1;
        } else {
            rejected += 1;
        }
    }
    eprintln!(
        "fuzz sweep files: {per_file} cases in {:.1} s: {rejected} rejected, {built} expanded",
        started.elapsed().as_secs_f64()
    );
    assert!(built > 0 && rejected > 0);
}

/// MJCF size attributes (`{}`: a number from [`NUMBERS`]), put inside the bicycle's `<mujoco>`.
const MJCF_SIZES: [&str; 9] = [
    "<size nkey=\"{}\"/>",
    "<size nuserdata=\"{}\" nstack=\"{}\"/>",
    "<size njmax=\"{}\" nconmax=\"{}\"/>",
    "<size nuser_geom=\"{}\" nuser_body=\"{}\"/>",
    "<custom><numeric name=\"n\" size=\"{}\"/></custom>",
    "<asset><texture name=\"t\" builtin=\"checker\" width=\"{}\" height=\"{}\"/></asset>",
    "<asset><hfield name=\"h\" nrow=\"{}\" ncol=\"{}\" size=\"1 1 1 1\"/></asset>",
    "<size nkey=\"{}\"/><size nkey=\"{}\"/>",
    "<size nstack=\"{}\"/>",
];

#[test]
fn mjcf_size_attributes_are_bounded_and_never_panic_or_hang() {
    let started = Instant::now();
    let cases = cases_per_file() / 4;
    let dir = tempfile::tempdir().unwrap();
    let bicycle = std::fs::read_to_string(repo().join("models/bicycle.xml")).unwrap();
    let scenario_path = repo().join("scenarios/bicycle_obstacle_gamma_m.toml");
    let scenario = std::fs::read_to_string(&scenario_path).unwrap();
    let start = bicycle.find("<mujoco").unwrap();
    let at = start + bicycle[start..].find('>').unwrap() + 1;
    let mut rng = Rng(seed() ^ 0x4d4a_4346);
    let mut counts = Counts::default();
    for case in 0..cases {
        let mut size = pick(&mut rng, &MJCF_SIZES).to_string();
        while let Some(i) = size.find("{}") {
            size.replace_range(i..i + 2, pick(&mut rng, &NUMBERS));
        }
        let model = dir.path().join(format!("model-{case}.xml"));
        std::fs::write(&model, format!("{}{size}{}", &bicycle[..at], &bicycle[at..])).unwrap();
        let text = scenario.replace("../models/bicycle.xml", &model.display().to_string());
        let what = format!("MJCF case {case} (seed {}): {size}", seed());
        let path = scenario_path.clone();
        counts = guarded(what.clone(), move || {
            let mut counts = counts;
            scenario_case(&path, text, &mut counts, &what);
            counts
        });
    }
    eprintln!(
        "fuzz MJCF sizes: {} cases in {:.1} s: {} refused, {} ran",
        counts.cases,
        started.elapsed().as_secs_f64(),
        counts.rejected + counts.not_built,
        counts.ran
    );
    assert_eq!(counts.cases, cases);
    assert!(counts.ran > 0 && counts.not_built > 0, "{counts:?}");
}

/// CommonRoad files (docs/commonroad.md): seeded mutations of the small committed ones (lines
/// deleted, duplicated, swapped, truncated, random bytes), each loaded as a scenario, built and
/// run for a few steps: no panic, no hang, and every error one line naming the file.
#[test]
fn mutated_commonroad_files_never_panic_hang_or_give_unclear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let per_file = (cases_per_file() / 8).max(10);
    let mut counts = Counts::default();
    let files = [
        repo().join("data/commonroad/ZAM_Tutorial-1_1_T-1.xml"),
        repo().join("data/commonroad/OSC_CutIn-1_2_T-1.xml"),
        repo().join("tests/data/commonroad/test_reading_all.xml"),
    ];
    for (f, file) in files.iter().enumerate() {
        let text = std::fs::read_to_string(file).unwrap();
        let mut rng = Rng(seed() ^ (0xC0FF_EE00 + f as u64));
        for case in 0..per_file {
            let mutated = mutate(&text, &mut rng);
            let path = dir.path().join(format!("case-{f}-{case}.xml"));
            std::fs::write(&path, &mutated).unwrap();
            let what = format!("{} mutation {case} (seed {})", file.display(), seed());
            let (result, path_shown) = guarded(what.clone(), move || {
                let shown = path.display().to_string();
                let mut local = Counts::default();
                let outcome = match mjsafe::scenario::load(&path, &[]) {
                    Ok(loaded) => {
                        scenario_case(&path, loaded.source_text.clone(), &mut local, &what);
                        Ok(local)
                    }
                    Err(e) => Err(e.to_string()),
                };
                (outcome, shown)
            });
            match result {
                Ok(local) => {
                    counts.cases += local.cases;
                    counts.ran += local.ran;
                    counts.rejected += local.rejected;
                    counts.not_built += local.not_built;
                }
                Err(message) => {
                    counts.cases += 1;
                    counts.rejected += 1;
                    check_message(
                        &format!("mutation {case} of {}", file.display()),
                        &message,
                        &path_shown,
                        &mutated,
                    );
                }
            }
        }
    }
    // Some mutations leave a runnable world, others are refused: both paths are exercised.
    assert!(counts.ran > 0 && counts.rejected > 0, "{counts:?}");
}
