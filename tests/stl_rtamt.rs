//! mjsafe's STL robustness (`mjsafe::stl`) against RTAMT's discrete-time offline monitor, the
//! independent implementation (tests/stl_rtamt.py with the test venv's `rtamt`): every
//! operator on synthetic traces and on the signals of a real run's log, the whole robustness
//! signal compared at every sample to 1e-9; and the online monitor's value against both.

mod common;

use std::path::Path;

use common::*;
use mjsafe::random::SplitMix64;
use mjsafe::stl::{parse, robustness_signal, Formula, Monitor};

const TOLERANCE: f64 = 1e-9;

/// One formula over one trace.
struct Case {
    text: String,
    formula: Formula,
    step: f64,
    /// In the order of `formula.signals()`.
    signals: Vec<Vec<f64>>,
}

/// The formula in RTAMT's syntax: signals renamed `s0`, `s1`, … (RTAMT reads `a.b` as field
/// `b` of `a`) and `!=` as RTAMT's `!==`. (RTAMT takes a unary `-` only before a number, as
/// the canonical text writes negative numbers; the formulas here negate no signal.)
fn rtamt_text(f: &Formula) -> String {
    let names: Vec<String> = (0..f.signals().len()).map(|k| format!("s{k}")).collect();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    f.rename(&names).unwrap().to_string().replace("!=", "!==")
}

/// RTAMT's robustness signals of `cases`, and its version.
fn rtamt(cases: &[Case], formulas: &[String]) -> (String, Vec<Vec<f64>>) {
    let dir = tempfile::tempdir().unwrap();
    let cases_json: Vec<serde_json::Value> = cases
        .iter()
        .zip(formulas)
        .map(|(c, text)| {
            let signals: serde_json::Map<String, serde_json::Value> = c
                .signals
                .iter()
                .enumerate()
                .map(|(k, v)| (format!("s{k}"), v.iter().map(|x| x.to_string()).collect()))
                .collect();
            serde_json::json!({
                "formula": text,
                "step_ns": (c.step * 1e9).round() as u64,
                "signals": signals,
            })
        })
        .collect();
    let input = dir.path().join("cases.json");
    let output = dir.path().join("out.json");
    std::fs::write(&input, serde_json::json!({ "cases": cases_json }).to_string()).unwrap();
    let o = std::process::Command::new(python())
        .arg(root().join("tests/stl_rtamt.py"))
        .arg(&input)
        .arg(&output)
        .output()
        .expect("python runs");
    assert!(
        o.status.success(),
        "tests/stl_rtamt.py failed (rtamt is in scripts/requirements-test.txt: scripts/setup.sh --test installs it): {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let out: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&output).unwrap()).unwrap();
    let results = out["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            r.as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_str().unwrap().parse::<f64>().unwrap())
                .collect()
        })
        .collect();
    (out["rtamt"].as_str().unwrap_or("?").to_string(), results)
}

/// Compares every case with RTAMT at every sample, and the online monitor's value with the
/// offline one; the largest difference from RTAMT.
fn compare(what: &str, cases: &[Case]) -> f64 {
    let formulas: Vec<String> = cases.iter().map(|c| rtamt_text(&c.formula)).collect();
    let (version, theirs) = rtamt(cases, &formulas);
    assert_eq!(theirs.len(), cases.len());
    let mut worst: f64 = 0.0;
    let mut samples = 0;
    let mut nan = 0;
    for ((c, text), theirs) in cases.iter().zip(&formulas).zip(&theirs) {
        let columns: Vec<&[f64]> = c.signals.iter().map(Vec::as_slice).collect();
        let ours = robustness_signal(&c.formula, &columns, c.step).unwrap();
        assert_eq!(ours.len(), theirs.len(), "{}", c.text);
        for (i, (a, b)) in ours.iter().zip(theirs).enumerate() {
            // A NaN (here only from `iff`/`xor` of two infinities of one sign, ∞ − ∞) propagates
            // in mjsafe; in RTAMT, Python's min/max keep or drop it depending on the order.
            if a.is_nan() || b.is_nan() {
                nan += 1;
                continue;
            }
            let equal = a == b || (a - b).abs() <= TOLERANCE;
            assert!(equal, "{} (RTAMT: {text}) at sample {i}: mjsafe {a}, RTAMT {b}", c.text);
            if a != b {
                worst = worst.max((a - b).abs());
            }
        }
        samples += ours.len();
        if cases.len() <= 20 {
            println!("  ρ(0) = {:<12} {}", ours[0], c.text);
        }
        if c.formula.online() {
            let mut m = Monitor::new(&c.formula, c.step).unwrap();
            let mut sample = vec![0.0; columns.len()];
            for i in 0..ours.len() {
                for (s, v) in sample.iter_mut().zip(&columns) {
                    *s = v[i];
                }
                m.push(&sample);
            }
            let online = m.finish();
            let same = online == ours[0] || (online.is_nan() && ours[0].is_nan());
            assert!(same, "{}: online {online}, offline {}", c.text, ours[0]);
        }
    }
    println!(
        "{what}: {} formulas, {samples} samples compared with RTAMT {version} ({nan} NaN left out): largest \
         difference {worst:e}",
        cases.len()
    );
    assert!(nan * 20 < samples, "{nan} of {samples} samples NaN");
    worst
}

/// Formulas over x, y, z exercising every operator (those whose bounds are not whole numbers
/// of a trace's step are left out for that trace).
const SYNTHETIC: &[&str] = &[
    "x > 0.5",
    "x >= 0.5",
    "x < 1",
    "x <= 1",
    "x == 0.25",
    "x != 0.25",
    "0.2 < x",
    "abs(x) <= 1",
    "x - y > 0",
    "x + 2 * y >= 0.5",
    "x > -1",
    "not x > 0",
    "x > 0 and y < 0.5",
    "x > 0 or y < 0.5",
    "x > 0 implies y < 0.5",
    "x > 0 -> y > 0 -> z > 0",
    "not x > 0 and y > 0 or z > 0",
    "x > 0 iff y > 0",
    "x > 0 xor y > 0",
    "always[0, 0.5] x > 0",
    "always[0.2, 0.4] x > 0",
    "eventually[0, 0.5] x > 0",
    "eventually[0.3, 1] y > 0.5",
    "always x > -2",
    "eventually y > 1",
    "historically[0, 0.5] x > 0",
    "historically[0.2, 0.4] x > 0",
    "once[0.1, 0.3] y > 0",
    "historically x > -2",
    "once x > 1",
    "x > 0 until[0, 0.5] y > 0.5",
    "x > -1 until[0.2, 0.6] y > 1",
    "x > -1 until y > 1.2",
    "x > 0 since[0, 0.5] y > 0.5",
    "x > -1 since[0.1, 0.4] y > 1",
    "x > -1 since y > 1.2",
    "always[0, 1] (x > 0 implies eventually[0, 0.5] y > 0)",
    "eventually[0, 2] always[0, 0.3] z > 0",
    "always (x > 1 implies once[0, 0.3] y > 0)",
    "eventually[0, 5] always x > 0",
    "historically eventually x > 1",
    "G[0,1] x > 0 & F[1,2] y > 0 | H z > 0",
    "(x > 0 U y > 0) S[0,0.3] z > 0",
    "always[0, 10] x > -3",
    "always[1, 2] x > 0",
    "eventually[1, 3] x > 0",
    "x > 0 until[1, 2] y > 0",
    "x > 0 since[1, 2] y > 0",
    "historically[1, 2] x > 0",
    "once[0, 3] y > 0",
    "eventually[2, 5] x > 0",
    "always (x > 0 until[0, 1] y > 0) and eventually (not z < 0 since[1, 2] x > 1)",
];

#[test]
fn every_operator_matches_rtamt_on_synthetic_traces() {
    let mut rng = SplitMix64(2026);
    let mut cases = Vec::new();
    let mut operators = std::collections::BTreeSet::new();
    // (RTAMT 0.4.10's `evaluate` fails on a trace of one sample: the unit tests cover it.)
    for (step, n) in [(0.1, 60), (1.0, 4), (1.0, 9), (0.1, 2)] {
        let trace: Vec<Vec<f64>> = (0..3)
            .map(|_| {
                (0..n)
                    .map(|_| match rng.below(8) {
                        0 => 0.25,
                        1 => 0.0,
                        _ => ((rng.next_f64() - 0.4) * 3.0 * 1000.0).round() / 1000.0,
                    })
                    .collect()
            })
            .collect();
        for text in SYNTHETIC {
            let formula = parse(text).unwrap();
            if formula.check_step(step).is_err() {
                continue;
            }
            let s = formula.to_string();
            for op in [
                "always",
                "eventually",
                "historically",
                "once",
                "until",
                "since",
                "not",
                "and",
                "or",
                "implies",
                "iff",
                "xor",
                "<",
                "<=",
                ">",
                ">=",
                "==",
                "!=",
                "abs",
            ] {
                if s.split([' ', '(', '[']).any(|w| w == op) {
                    operators.insert(format!("{op}{}", if s.contains(&format!("{op}[")) { "[]" } else { "" }));
                }
            }
            let signals = formula
                .signals()
                .iter()
                .map(|s| trace[["x", "y", "z"].iter().position(|n| n == s).unwrap()].clone())
                .collect();
            cases.push(Case {
                text: text.to_string(),
                formula,
                step,
                signals,
            });
        }
    }
    for op in [
        "always[]",
        "eventually[]",
        "historically[]",
        "once[]",
        "until[]",
        "since[]",
    ] {
        assert!(operators.contains(op), "{op} not covered: {operators:?}");
    }
    compare("synthetic traces", &cases);
}

/// A random formula over x, y, z, fully parenthesised, bounds whole multiples of 0.1 s.
fn random_formula(rng: &mut SplitMix64, depth: usize) -> String {
    const ATOMS: [&str; 8] = [
        "x > 0.5",
        "y <= -0.25",
        "z != 0.25",
        "x - y > 0",
        "abs(z) < 1",
        "0.2 < y",
        "x == 0.25",
        "x + 2 * y >= 0.5",
    ];
    let pick = |rng: &mut SplitMix64, options: &[&'static str]| options[rng.below(options.len())];
    if depth == 0 || rng.below(4) == 0 {
        return ATOMS[rng.below(ATOMS.len())].to_string();
    }
    let interval = |rng: &mut SplitMix64| {
        if rng.below(4) == 0 {
            return String::new();
        }
        let a = rng.below(4);
        let b = a + rng.below(4);
        // a/10 prints the shortest decimal (0.3, not 3 × 0.1 = 0.30000000000000004, which
        // RTAMT refuses: it takes the decimal text exactly).
        format!("[{}, {}]", a as f64 / 10.0, b as f64 / 10.0)
    };
    let sub = |rng: &mut SplitMix64| format!("({})", random_formula(rng, depth - 1));
    match rng.below(4) {
        0 => {
            let op = pick(
                rng,
                &[
                    "not",
                    "!",
                    "always",
                    "G",
                    "eventually",
                    "F",
                    "historically",
                    "H",
                    "once",
                    "O",
                ],
            );
            let i = if matches!(op, "not" | "!") {
                String::new()
            } else {
                interval(rng)
            };
            format!("{op}{i} {}", sub(rng))
        }
        1 => {
            let op = pick(rng, &["until", "U", "since", "S"]);
            let i = interval(rng);
            format!("{} {op}{i} {}", sub(rng), sub(rng))
        }
        _ => {
            let op = pick(
                rng,
                &["and", "&", "&&", "or", "|", "||", "implies", "->", "iff", "<->", "xor"],
            );
            format!("{} {op} {}", sub(rng), sub(rng))
        }
    }
}

#[test]
fn random_formulas_match_rtamt() {
    // Their canonical text (the fewest parentheses) goes to RTAMT: its precedence is checked too.
    let mut rng = SplitMix64(99);
    let step = 0.1;
    let trace: Vec<Vec<f64>> = (0..3)
        .map(|_| {
            (0..40)
                .map(|_| ((rng.next_f64() - 0.4) * 3.0 * 100.0).round() / 100.0)
                .collect()
        })
        .collect();
    let cases: Vec<Case> = (0..300)
        .map(|_| {
            let text = random_formula(&mut rng, 4);
            let formula = parse(&text).unwrap();
            let signals = formula
                .signals()
                .iter()
                .map(|s| trace[["x", "y", "z"].iter().position(|n| n == s).unwrap()].clone())
                .collect();
            Case {
                text,
                formula,
                step,
                signals,
            }
        })
        .collect();
    compare("random formulas", &cases);
}

/// A table of `mjsafe export` (CSV): its header and rows (empty cells NaN).
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<f64>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap().split(',').map(str::to_string).collect();
    let rows = lines
        .map(|l| l.split(',').map(|c| c.parse::<f64>().unwrap_or(f64::NAN)).collect())
        .collect();
    (header, rows)
}

fn column(table: &(Vec<String>, Vec<Vec<f64>>), name: &str) -> Vec<f64> {
    let k = table
        .0
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column {name}: {:?}", table.0));
    table.1.iter().map(|r| r[k]).collect()
}

#[test]
fn a_real_run_matches_rtamt() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    run_ok(&scenario("bicycle_obstacle.toml"), &log, &[]);
    let out = dir.path().join("tables");
    let o = mjsafe(&["export", log.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let state = read_csv(&out.join("run-state.csv"));
    let barrier = read_csv(&out.join("run-barrier.csv"));
    let time = column(&state, "time");
    let step = time[1] - time[0];
    let step = (step * 1e6).round() / 1e6;
    assert_eq!(step, 0.002, "the log's step");
    // /barrier on the /state grid: the latest row at or before each state sample.
    let (bt, bh) = (column(&barrier, "time"), column(&barrier, "obstacle_0.h"));
    let mut h = Vec::with_capacity(time.len());
    let mut k = 0;
    for &t in &time {
        while k + 1 < bt.len() && bt[k + 1] <= t + 1e-9 {
            k += 1;
        }
        h.push(if bt.first().is_some_and(|&b| b <= t + 1e-9) {
            bh[k]
        } else {
            f64::NAN
        });
    }
    let signal = |name: &str| -> Vec<f64> {
        match name {
            "obstacle_0.h" => h.clone(),
            _ => column(&state, name),
        }
    };
    let texts = [
        "always x2 > -5",
        "eventually[0, 2] speed > 3.2",
        "always[0, 1] (speed < 4 and abs(x2) < 2)",
        "always (obstacle_0.h >= 0)",
        "obstacle_0.h >= 0 until[0, 0.02] speed > 3.1",
        "always (obstacle_0.h < 0 implies once[0, 0.1] speed < 3)",
        "historically[0, 0.5] obstacle_0.h > 0",
        "once[0.01, 0.02] x1 > 0",
        "x1 > -5 since[0, 0.02] speed > 3",
        "eventually (x1 > 0 and abs(x2) < 1)",
        "always[0, 12] obstacle_0.h > 0",
        "not eventually[0, 3] (x1 >= 10 and speed != 3)",
        "x1 < 0 until (obstacle_0.h < 0 or speed == 3)",
        "eventually[0, 1] always x1 > -19",
        "historically x2 <= 1 since speed > 3",
        "always[2, 4] (heading > -0.5 -> eventually[0, 0.2] heading < 0.5)",
    ];
    let mut cases = Vec::new();
    for text in texts {
        // (ρ at the start is printed by `compare`.)
        let formula = parse(text).unwrap();
        let signals: Vec<Vec<f64>> = formula.signals().iter().map(|s| signal(s)).collect();
        cases.push(Case {
            text: text.to_string(),
            formula,
            step,
            signals,
        });
    }
    // RTAMT is not compared where a signal is NaN (its min/max then depend on the order).
    let first = h.iter().position(|v| !v.is_nan()).unwrap();
    for c in &mut cases {
        for s in &mut c.signals {
            s.drain(..first);
        }
    }
    println!(
        "{} samples from {:.3} s on, step {step} s",
        cases[0].signals[0].len(),
        time[first]
    );
    compare("bicycle_obstacle run", &cases);
}
