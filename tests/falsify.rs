//! `mjsafe falsify` (issue 17): the optimiser finds a violation where one exists and the
//! written scenario reproduces it; on a problem proven safe it reports none; the same seed
//! gives the same search on any number of threads; a baseline keeps only the filter's own
//! failures; bad input is one clear error line.

mod common;

use std::path::Path;

use common::*;

/// The Ch. 4 bicycle with (4.67) over start x, obstacle offset and acceleration delay.
const GAMMA_M_BOX: [&str; 6] = [
    "--range",
    "vehicle.initial_state.0=-26..-16",
    "--range",
    "obstacles.0.centre.1=-3..3",
    "--range",
    "delays.acceleration=0.5..2.0:0.1",
];

/// The delay-free CBF-QP without delays as every candidate's baseline.
const DELAY_FREE_BASELINE: [&str; 6] = [
    "--baseline",
    "delays.steering=0.0",
    "--baseline",
    "delays.acceleration=0.0",
    "--baseline",
    "filter={kind=\"cbf_qp\", l0=4.0, l1=4.0}",
];

fn falsify(scenario: &str, extra: &[&str], out: &Path) -> std::process::Output {
    let path = format!("scenarios/{scenario}");
    let out = out.to_str().unwrap();
    let mut args = vec!["falsify", path.as_str()];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", out]);
    mjsafe(&args)
}

/// `mjsafe falsify` of the γm bicycle over [`GAMMA_M_BOX`] with `extra`, into `out`, running.
fn spawn_gamma_m_search(extra: &[&str], out: &Path) -> std::process::Child {
    use std::process::Stdio;
    std::process::Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args(["falsify", "scenarios/bicycle_obstacle_gamma_m.toml"])
        .args(GAMMA_M_BOX)
        .args(extra)
        .arg("--out")
        .arg(out)
        .current_dir(root())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Ctrl-C to `child`, and what it printed until it ended.
fn interrupt(child: std::process::Child) -> std::process::Output {
    let kill = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    child.wait_with_output().unwrap()
}

fn evaluations(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("evaluations.json")).unwrap()).unwrap()
}

#[test]
fn finds_a_violation_of_gamma_m_and_the_written_scenario_reproduces_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f");
    let mut args = GAMMA_M_BOX.to_vec();
    args.extend_from_slice(&["--budget", "40", "--seed", "1"]);
    let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &out);
    assert!(o.status.success(), "{}", text(&o));
    println!("{}", stdout(&o));
    let e = evaluations(&out);
    let search = &e["searches"][0];
    assert_eq!(search["method"], "guided");
    let first = search["runs_to_first_violation"]
        .as_u64()
        .expect("a violation within 40 runs") as usize;
    let violation = &search["evaluations"][first - 1];
    assert_eq!(violation["violation"], true);
    let min_h = violation["objective"].as_f64().unwrap();
    assert!(min_h < 0.0);
    // The counterexample alone (no overrides) collides, with the search's min h.
    let scenario = out.join("counterexample.toml");
    let text = std::fs::read_to_string(&scenario).unwrap();
    assert!(text.starts_with("# Counterexample found by `mjsafe falsify`"), "{text}");
    // It names its row of evaluations.csv by the row's index, and the search as a shell takes it.
    assert!(
        text.contains(&format!("index {} in evaluations.csv", first - 1)),
        "{text}"
    );
    assert!(
        text.contains("# search: mjsafe falsify scenarios/bicycle_obstacle_gamma_m.toml --range"),
        "{text}"
    );
    let log = dir.path().join("again.mcap");
    let summary = run_ok(&scenario, &log, &[]);
    assert!(summary.contains("COLLISION"), "{summary}");
    let again = analyze_json(&log)["min_h"].as_f64().unwrap();
    assert!(
        (again - min_h).abs() <= 1e-9 * (1.0 + min_h.abs()),
        "{again} vs {min_h}"
    );
    assert_eq!(
        analyze_json(&out.join("counterexample.mcap"))["min_h"].as_f64(),
        Some(again)
    );
    // Every evaluation is in the CSV, and the plot is a PNG.
    let csv = std::fs::read_to_string(out.join("evaluations.csv")).unwrap();
    assert!(csv.starts_with(
        "method,index,generation,vehicle.initial_state.0,obstacles.0.centre.1,delays.acceleration,min_h,"
    ));
    assert_eq!(
        csv.lines().count(),
        1 + search["evaluations_run"].as_u64().unwrap() as usize
    );
    assert!(std::fs::read(out.join("convergence.png"))
        .unwrap()
        .starts_with(b"\x89PNG"));
    assert!(
        listing(&out)
            .iter()
            .all(|f| !f.contains("partial") && !f.starts_with(".evaluations")),
        "{:?}",
        listing(&out)
    );
}

#[test]
fn the_delay_free_filter_without_delays_has_no_counterexample() {
    // The CBF-QP (4.9) with relative degree 2 (4.83), obstacle known from t = 0, on the ODE
    // plant: h >= 0 is guaranteed for every start in the box (h(x0) > 0, ḣ + l0 h > 0).
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f");
    let o = falsify(
        "bicycle_obstacle_nodelay.toml",
        &[
            "--set",
            "obstacles.0.appear_at=0.0",
            "--set",
            "plant=\"ode\"",
            "--range",
            "vehicle.initial_state.0=-26..-16",
            "--range",
            "obstacles.0.centre.1=-3..3",
            "--range",
            "vehicle.initial_state.3=1..6",
            "--budget",
            "48",
        ],
        &out,
    );
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        stdout(&o).contains("no counterexample within 48 runs"),
        "{}",
        stdout(&o)
    );
    let e = evaluations(&out);
    assert!(e["searches"][0]["runs_to_first_violation"].is_null());
    let best = e["searches"][0]["best_score"].as_f64().unwrap();
    assert!(
        (0.0..1e-3).contains(&best),
        "the optimiser drives min h to the boundary: {best}"
    );
    assert!(!out.join("counterexample.toml").exists());
}

#[test]
fn the_same_seed_gives_the_same_search_on_any_number_of_threads() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, seed: &str, threads: &str| {
        let out = dir.path().join(name);
        let mut args = GAMMA_M_BOX.to_vec();
        args.extend_from_slice(&["--budget", "24", "--worst", "--seed", seed, "--threads", threads]);
        let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &out);
        assert!(o.status.success(), "{}", text(&o));
        // What the search cost is reported, not written into its (deterministic) files; its
        // own work is told apart from the runs' on one thread only.
        let stdout = String::from_utf8_lossy(&o.stdout).to_string();
        let cost = (stdout.lines())
            .find(|l| l.starts_with("guided search: ") && l.contains(" s in the runs of "))
            .unwrap_or_else(|| panic!("no cost line: {stdout}"));
        assert!(cost.contains(&format!(" on {threads} thread")), "{cost}");
        assert_eq!(cost.contains("the search's own work"), threads == "1", "{cost}");
        [out.join("evaluations.csv"), out.join("evaluations.json")].map(|p| std::fs::read(p).unwrap())
    };
    let one = run("a", "3", "1");
    assert_eq!(one, run("b", "3", "2"), "1 vs 2 threads");
    assert_ne!(one[0], run("c", "4", "2")[0], "another seed searches elsewhere");
    // Long enough for the guided search's local model (after the spread generation and the
    // brackets): its fits and samples follow the canonical order only.
    let longer = |name: &str, threads: &str| {
        let out = dir.path().join(name);
        let mut args = GAMMA_M_BOX.to_vec();
        args.extend_from_slice(&["--budget", "80", "--worst", "--seed", "3", "--threads", threads]);
        let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &out);
        assert!(o.status.success(), "{}", text(&o));
        std::fs::read(out.join("evaluations.csv")).unwrap()
    };
    assert_eq!(longer("l1", "1"), longer("l2", "2"), "80 runs: 1 vs 2 threads");
}

#[test]
fn a_baseline_keeps_only_candidates_the_reference_survives_and_random_search_is_compared() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f");
    let mut args = GAMMA_M_BOX.to_vec();
    args.extend_from_slice(&DELAY_FREE_BASELINE);
    args.extend_from_slice(&["--budget", "48", "--seed", "2", "--compare-random"]);
    let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &out);
    assert!(o.status.success(), "{}", text(&o));
    println!("{}", stdout(&o));
    let e = evaluations(&out);
    let searches = e["searches"].as_array().unwrap();
    assert_eq!(searches.len(), 2);
    assert_eq!(searches[1]["method"], "random");
    for s in searches {
        for e in s["evaluations"].as_array().unwrap() {
            let (Some(m), Some(b)) = (e["objective"].as_f64(), e["baseline"].as_f64()) else {
                continue;
            };
            // Qualified (the baseline safe: b >= 0): the score is m − T; else a positive
            // penalty max(m − T, 0) + (T_b − b).
            assert_eq!(e["qualified"].as_bool().unwrap(), b >= 0.0, "{e}");
            assert_eq!(e["violation"].as_bool().unwrap(), m < 0.0 && b >= 0.0, "{e}");
            let expected = if b >= 0.0 { m } else { m.max(0.0) - b };
            assert_eq!(e["score"].as_f64().unwrap(), expected, "{e}");
        }
    }
    // Candidates that collide with the baseline too are not counterexamples.
    let both_collide = searches
        .iter()
        .flat_map(|s| s["evaluations"].as_array().unwrap())
        .filter(|e| e["objective"].as_f64() < Some(0.0) && e["baseline"].as_f64() < Some(0.0))
        .count();
    assert!(both_collide > 0, "the box has scenarios no filter survives");
}

/// The rare-failure box of scripts/falsify-study.sh (problem 5): qualified violations only in
/// a slab of start x about 1 m wide.
const RARE_BOX: [&str; 6] = [
    "--range",
    "vehicle.initial_state.0=-50..-10",
    "--range",
    "obstacles.0.centre.1=-3..3",
    "--range",
    "delays.acceleration=0.5..2.0:0.1",
];

/// The largest difference of a coordinate between two rows of evaluations.csv, in units of
/// each range (an independent reading of the parameters, not the search's own distance).
fn box_distance(a: &std::collections::HashMap<String, String>, b: &std::collections::HashMap<String, String>) -> f64 {
    [
        ("vehicle.initial_state.0", 40.0),
        ("obstacles.0.centre.1", 6.0),
        ("delays.acceleration", 1.5),
    ]
    .iter()
    .map(|(key, width)| {
        let v = |r: &std::collections::HashMap<String, String>| r[*key].parse::<f64>().unwrap();
        (v(a) - v(b)).abs() / width
    })
    .fold(0.0, f64::max)
}

#[test]
fn counterexamples_k_are_distinct_failure_modes_each_reproduced() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f");
    let mut args = RARE_BOX.to_vec();
    args.extend_from_slice(&DELAY_FREE_BASELINE);
    args.extend_from_slice(&["--budget", "240", "--seed", "1", "--counterexamples", "3"]);
    let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &out);
    assert!(o.status.success(), "{}", text(&o));
    println!("{}", stdout(&o));
    let rows = evaluation_rows(&out);
    // Each counterexample file names its row; the rows are violations, pairwise distinct: a
    // different failure mode, or a quarter of a range apart.
    let mut chosen = Vec::new();
    for name in ["counterexample", "counterexample-2", "counterexample-3"] {
        let scenario = out.join(format!("{name}.toml"));
        let header = std::fs::read_to_string(&scenario).unwrap();
        let index: usize = header
            .split("index ")
            .nth(1)
            .and_then(|t| t.split(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("{header}"));
        let row = rows.iter().find(|r| r["index"] == index.to_string()).unwrap().clone();
        assert_eq!(row["violation"], "true", "{row:?}");
        // Its own log reproduces the row's min h.
        let min_h: f64 = row["min_h"].parse().unwrap();
        let logged = analyze_json(&out.join(format!("{name}.mcap")))["min_h"]
            .as_f64()
            .unwrap();
        assert!(
            (logged - min_h).abs() <= 1e-9 * (1.0 + min_h.abs()),
            "{logged} vs {min_h}"
        );
        chosen.push(row);
    }
    for i in 0..chosen.len() {
        for j in 0..i {
            let (a, b) = (&chosen[i], &chosen[j]);
            assert!(
                a["failure_mode"] != b["failure_mode"] || box_distance(a, b) >= 0.25,
                "{a:?} and {b:?} are one failure mode"
            );
        }
    }
    // The first is the search's first violation.
    let first = rows.iter().find(|r| r["violation"] == "true").unwrap();
    assert_eq!(first["index"], chosen[0]["index"]);
}

/// On the rare-failure box the guided search finds a qualified violation within 40 runs for
/// each of five seeds, and its median is below random search's with the same seeds and budget
/// (one seed can favour random search: seed 2 finds one at run 14).
#[test]
fn the_guided_search_finds_rare_failures_sooner_than_random_search() {
    let dir = tempfile::tempdir().unwrap();
    let first = |method: &str, seed: &str| {
        let out = dir.path().join(format!("{method}-{seed}"));
        let mut args = RARE_BOX.to_vec();
        args.extend_from_slice(&DELAY_FREE_BASELINE);
        args.extend_from_slice(&["--budget", "200", "--seed", seed, "--method", method]);
        let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &out);
        assert!(o.status.success(), "{}", text(&o));
        let e = evaluations(&out);
        assert_eq!(e["searches"][0]["method"], method);
        e["searches"][0]["runs_to_first_violation"].as_u64().unwrap_or(u64::MAX)
    };
    let median = |method: &str| {
        let mut counts: Vec<u64> = ["1", "2", "3", "4", "5"].iter().map(|s| first(method, s)).collect();
        counts.sort();
        (counts[2], counts)
    };
    let (guided, all) = median("guided");
    assert!(all.iter().all(|&n| n <= 40), "guided search: {all:?}");
    let (random, all_random) = median("random");
    assert!(
        guided < random,
        "medians: guided {guided} {all:?}, random {random} {all_random:?}"
    );
}

/// `--objective req.NAME` with a baseline: a counterexample violates the requirement while
/// its baseline satisfies it. `always obstacle_0.h >= 0` has robustness min h, so every row's
/// objective (the STL monitor's) equals its candidate_min_h (the min_h metric's).
#[test]
fn a_requirements_robustness_is_an_objective_qualified_by_the_baselines() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f");
    let mut args = GAMMA_M_BOX.to_vec();
    args.extend_from_slice(&DELAY_FREE_BASELINE);
    args.extend_from_slice(&[
        "--require",
        "clear=always obstacle_0.h >= 0",
        "--objective",
        "req.clear",
        "--budget",
        "80",
        "--seed",
        "1",
    ]);
    let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &out);
    assert!(o.status.success(), "{}", text(&o));
    let rows = evaluation_rows(&out);
    let number = |r: &std::collections::HashMap<String, String>, k: &str| r[k].parse::<f64>().unwrap();
    for r in &rows {
        let (m, b) = (number(r, "req.clear"), number(r, "baseline"));
        assert_eq!(m, number(r, "candidate_min_h"), "{r:?}");
        assert_eq!(r["qualified"], (b >= 0.0).to_string(), "{r:?}");
        // A violation lies beyond the default tolerance of 1e-4 (a round-off graze is none).
        assert_eq!(r["violation"], (m < -1e-4 && b >= 0.0).to_string(), "{r:?}");
    }
    let first = rows
        .iter()
        .find(|r| r["violation"] == "true")
        .expect("a violation within 80 runs");
    let logged = analyze_json(&out.join("counterexample.mcap"))["req"]["clear"]
        .as_f64()
        .unwrap();
    assert_eq!(logged, number(first, "req.clear"));
}

#[test]
fn bad_falsify_input_is_one_error_line_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    for (args, needle) in [
        (
            vec!["--range", "vehicle.initial_state[0]=-26..-16"],
            "unknown field `initial_state[0]`",
        ),
        (vec!["--range", "delays.steering=0.3..0.1"], "LO <= HI"),
        (
            vec!["--range", "delays.steering=0.1..0.3:0.5"],
            "STEP 0.5 exceeds the width",
        ),
        (vec!["--range", "obstacles.0.centre.1=-1e308..1e308"], "overflows"),
        (
            vec!["--range", "delays.steering=0..0.3", "--baseline-threshold", "nan"],
            "--baseline-threshold",
        ),
        (
            vec!["--range", "delays.steering=0..0.3", "--objective", "min_hh"],
            "--objective min_hh",
        ),
        (vec!["--range", "delays.steering=0..0.3", "--budget", "0"], "--budget"),
        (
            vec!["--range", "delays.steering=0..0.3", "--counterexamples", "101"],
            "--counterexamples: expected 1 to 100 failure modes, found 101",
        ),
        (
            vec!["--range", "delays.steering=0..0.3", "--counterexamples", "0"],
            "--counterexamples: expected 1 to 100 failure modes, found 0",
        ),
        (
            vec!["--range", "delays.steering=0..0.3", "--baseline", "delays.brake=0"],
            "delays.brake",
        ),
        (
            vec![
                "--range",
                "obstacles.0.centre.1=-3..3",
                "--range",
                "obstacles.0.centre.1=-1..1",
            ],
            "obstacles.0.centre.1: the key is given twice",
        ),
        (
            vec![
                "--range",
                "obstacles.0.centre.1=-3..3",
                "--objective",
                "max_correction.brake",
            ],
            "its per-channel max_correction metrics: max_correction.acceleration, max_correction.steering",
        ),
    ] {
        let out = dir.path().join("f");
        let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &out);
        assert!(!o.status.success(), "{args:?}: {}", text(&o));
        let err = stderr(&o);
        assert!(err.contains(needle), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!out.join("evaluations.csv").exists());
    }
}

#[test]
fn ctrl_c_keeps_what_the_search_found() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f");
    let child = spawn_gamma_m_search(&["--worst", "--budget", "100000", "--threads", "1"], &out);
    // Until the first generation is written to stderr… then interrupt.
    std::thread::sleep(std::time::Duration::from_millis(2500));
    let o = interrupt(child);
    assert_eq!(o.status.code(), Some(130), "{}", text(&o));
    assert!(stderr(&o).contains("interrupted"), "{}", stderr(&o));
    let e = evaluations(&out);
    let search = &e["searches"][0];
    assert_eq!(search["interrupted"], true);
    let n = search["evaluations_run"].as_u64().unwrap();
    assert!((8..100000).contains(&n), "{n}");
    // A violation found before the interruption is written as the counterexample.
    if !search["runs_to_first_violation"].is_null() {
        assert!(out.join("counterexample.toml").exists());
    }
    assert!(
        listing(&out)
            .iter()
            .all(|f| !f.contains("partial") && !f.starts_with(".evaluations")),
        "{:?}",
        listing(&out)
    );
}

/// Outputs in the way are refused before the first run (not after the whole budget), and the
/// evaluations are written before the counterexample is re-run.
#[test]
fn outputs_in_the_way_are_refused_before_the_search() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("counterexample.mcap"), "notes, not a log").unwrap();
    let o = falsify("bicycle_obstacle_gamma_m.toml", &GAMMA_M_BOX, &out);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let err = stderr(&o);
    assert!(
        err.contains("counterexample.mcap") && err.contains("not an mjsafe MCAP log"),
        "{err}"
    );
    assert!(!err.contains("runs |"), "no run before the refusal: {err}");
    assert_eq!(
        std::fs::read_to_string(out.join("counterexample.mcap")).unwrap(),
        "notes, not a log"
    );
    let file = dir.path().join("file");
    std::fs::write(&file, "").unwrap();
    let o = falsify("bicycle_obstacle_gamma_m.toml", &GAMMA_M_BOX, &file);
    assert!(stderr(&o).contains("expected a directory"), "{}", stderr(&o));
}

/// Candidates that fail score worse than any real candidate, whatever the threshold (their
/// score cell is empty), and are never violations.
#[test]
fn failed_candidates_score_worse_than_any_real_one() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f");
    let args = [
        "--range",
        "obstacles.0.radius=-3..5",
        "--threshold",
        "-1e13",
        "--budget",
        "16",
    ];
    let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &out);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let e = evaluations(&out);
    let rows = e["searches"][0]["evaluations"].as_array().unwrap();
    let (failed, real): (Vec<&serde_json::Value>, Vec<&serde_json::Value>) =
        rows.iter().partition(|r| !r["error"].is_null());
    assert!(!failed.is_empty() && !real.is_empty(), "{rows:?}");
    let worst_real = real
        .iter()
        .map(|r| r["score"].as_f64().unwrap())
        .fold(f64::MIN, f64::max);
    for r in &failed {
        assert!(
            r["score"].as_f64().unwrap() > worst_real && r["violation"] == false,
            "{r}"
        );
    }
    let csv = std::fs::read_to_string(out.join("evaluations.csv")).unwrap();
    let failed_line = csv.lines().find(|l| l.contains("expected a positive radius")).unwrap();
    assert!(
        failed_line.contains(",,,false,"),
        "no objective, baseline or score: {failed_line}"
    );
}

/// Ctrl-C while the counterexample is re-run: exit 130, the evaluations written, and the
/// counterexample not reported as reproduced (its log is incomplete).
#[test]
fn ctrl_c_during_the_counterexample_run_is_not_a_reproduction() {
    use std::time::{Duration, Instant};
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f");
    // A long counterexample run (the search's own runs are analysed in memory and leave no file).
    let child = spawn_gamma_m_search(&["--set", "duration=600.0", "--budget", "8", "--threads", "2"], &out);
    // Until the counterexample's log is being written… then interrupt.
    let partial = out.join("counterexample.mcap.partial");
    let started = Instant::now();
    while !partial.exists() {
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "no counterexample run began"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    let o = interrupt(child);
    assert_eq!(o.status.code(), Some(130), "{}", text(&o));
    assert!(stdout(&o).contains("its run was interrupted"), "{}", stdout(&o));
    assert!(!stdout(&o).contains("its run: "), "{}", stdout(&o));
    assert!(out.join("evaluations.json").exists() && out.join("counterexample.toml").exists());
    let m = analyze_json(&out.join("counterexample.mcap"));
    assert_eq!(m["complete"], false, "{m}");
}

/// The counterexample's objective, from the header of counterexample.toml.
fn reported_objective(out: &Path) -> f64 {
    let text = std::fs::read_to_string(out.join("counterexample.toml")).unwrap();
    let header = text.lines().next().unwrap();
    let value = header.split("min_h = ").nth(1).unwrap();
    value.split([' ', '(']).next().unwrap().parse().unwrap()
}

/// The rows of evaluations.csv as maps of column → cell.
fn evaluation_rows(out: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(out.join("evaluations.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(str::to_string).collect();
    lines
        .map(|l| header.iter().cloned().zip(l.split(',').map(str::to_string)).collect())
        .collect()
}

/// `--worst` reports the most severe qualified violation evaluated: the lowest min h among the
/// rows of evaluations.csv whose baseline is safe by its own threshold (0), for --threshold 0
/// and −0.5; the header and the report give its severity.
#[test]
fn worst_is_the_lowest_qualified_row_of_the_evaluations_for_any_threshold() {
    let dir = tempfile::tempdir().unwrap();
    for threshold in ["0", "-0.5"] {
        let out = dir.path().join(format!("worst{threshold}"));
        let mut args = GAMMA_M_BOX.to_vec();
        args.extend_from_slice(&DELAY_FREE_BASELINE);
        args.extend_from_slice(&["--worst", "--budget", "48", "--seed", "7", "--threshold", threshold]);
        let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &out);
        assert!(o.status.success(), "{}", text(&o));
        let t: f64 = threshold.parse().unwrap();
        let rows = evaluation_rows(&out);
        let number = |r: &std::collections::HashMap<String, String>, k: &str| r[k].parse::<f64>().ok();
        // Independently of the search's own flags: qualified = baseline >= 0, violation = m < T.
        let worst = rows
            .iter()
            .filter(|r| number(r, "baseline").is_some_and(|b| b >= 0.0))
            .filter_map(|r| number(r, "min_h"))
            .filter(|&m| m < t)
            .fold(f64::INFINITY, f64::min);
        // A baseline that collides never qualifies, whatever --threshold is.
        for r in &rows {
            if number(r, "baseline").is_some_and(|b| b < 0.0) {
                assert_eq!(r["qualified"], "false", "{r:?}");
                assert_eq!(r["violation"], "false", "{r:?}");
            }
        }
        // The box holds qualified violations below both thresholds (seed 7: −0.539 at run 8).
        assert!(
            worst.is_finite(),
            "threshold {threshold}: no qualified violation evaluated"
        );
        {
            let reported = reported_objective(&out);
            assert_eq!(
                reported, worst,
                "threshold {threshold}: reported {reported}, evaluated {worst}"
            );
            let header = std::fs::read_to_string(out.join("counterexample.toml")).unwrap();
            assert!(header.contains("# severity: min h"), "{header}");
            assert!(stdout(&o).contains("most severe violation"), "{}", stdout(&o));
        }
    }
}

/// An --out directory that exists but cannot take files is refused before the first run.
#[test]
fn an_unwritable_out_directory_is_refused_before_the_search() {
    // sysfs refuses new files even to root.
    let o = falsify("bicycle_obstacle_gamma_m.toml", &GAMMA_M_BOX, Path::new("/sys/kernel"));
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let err = stderr(&o);
    assert!(err.contains("--out /sys/kernel: cannot write"), "{err}");
    assert!(!err.contains("runs |"), "no run before the refusal: {err}");
}

/// The rows of one search's evaluations.csv grouped by generation, each row as its point in
/// box units (the order of `ranges`: key, lo, hi) and its class along a bracket: 0 holds
/// (qualified), 1 a violation, 2 fails with a failing baseline, 3 holds while its baseline
/// fails.
fn generations_in_box_units(out: &Path, ranges: &[(&str, f64, f64)]) -> Vec<Vec<(Vec<f64>, u8)>> {
    let mut generations: Vec<Vec<(Vec<f64>, u8)>> = Vec::new();
    for row in evaluation_rows(out) {
        let g: usize = row["generation"].parse().unwrap();
        let point = ranges
            .iter()
            .map(|(key, lo, hi)| (row[*key].parse::<f64>().unwrap() - lo) / (hi - lo))
            .collect();
        let class = match (row["violation"].as_str(), row["qualified"].as_str()) {
            ("true", _) => 1,
            (_, "true") => 0,
            _ if row["candidate_min_h"].parse::<f64>().unwrap() < 0.0 => 2,
            _ => 3,
        };
        if generations.len() <= g {
            generations.resize(g + 1, Vec::new());
        }
        generations[g].push((point, class));
    }
    generations
}

/// The guided search's bracket generations, found independently of its code: a generation of
/// two points at the thirds of the segment between two earlier points (box units, to
/// `tolerance`: the rounding of quantised ranges). Each comes with whether the classes of all
/// points evaluated so far on its line are ordered as a bracket assumes (holding, violations,
/// failing; none that holds while its baseline fails).
fn bracket_generations(generations: &[Vec<(Vec<f64>, u8)>], tolerance: f64) -> Vec<(usize, bool)> {
    let distance = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt();
    let at = |a: &[f64], b: &[f64], t: f64| -> Vec<f64> { a.iter().zip(b).map(|(x, y)| x + t * (y - x)).collect() };
    let mut brackets = Vec::new();
    for (g, points) in generations.iter().enumerate() {
        if points.len() != 2 {
            continue;
        }
        let earlier: Vec<&(Vec<f64>, u8)> = generations[..g].iter().flatten().collect();
        let ends = earlier.iter().enumerate().find_map(|(i, a)| {
            earlier[i + 1..].iter().find_map(|b| {
                let thirds = [at(&a.0, &b.0, 1.0 / 3.0), at(&a.0, &b.0, 2.0 / 3.0)];
                let hits =
                    |p: &[f64], q: &[f64]| distance(p, &thirds[0]) < tolerance && distance(q, &thirds[1]) < tolerance;
                (hits(&points[0].0, &points[1].0) || hits(&points[1].0, &points[0].0)).then_some((a, b))
            })
        });
        let Some((a, b)) = ends else { continue };
        // The line's points, ranked from the end that holds.
        let (a, b) = if a.1 == 0 { (a, b) } else { (b, a) };
        let length = distance(&a.0, &b.0);
        let mut along: Vec<(f64, u8)> = earlier
            .iter()
            .copied()
            .chain(points.iter())
            .filter_map(|(p, class)| {
                let t = p
                    .iter()
                    .zip(&a.0)
                    .zip(&b.0)
                    .map(|((x, s), e)| (x - s) * (e - s))
                    .sum::<f64>()
                    / length.powi(2);
                (distance(p, &at(&a.0, &b.0, t)) < tolerance).then_some((t, *class))
            })
            .collect();
        along.sort_by(|x, y| x.0.total_cmp(&y.0));
        let ordered = along.iter().all(|(_, c)| *c != 3) && along.windows(2).all(|w| w[0].1 <= w[1].1);
        brackets.push((g, ordered));
    }
    brackets
}

/// Where actuation jitter and its seed decide the outcome (docs/falsification.md, problem 4),
/// the classes on a bracket's line soon interleave and the guided search brackets no more (the
/// rest is uniform draws); where the outcome is a function of the box (problem 5) the brackets
/// stay ordered and go on until they find the violation.
#[test]
fn a_bracket_whose_classes_interleave_ends_the_bracketing() {
    let dir = tempfile::tempdir().unwrap();
    let jitter = dir.path().join("jitter");
    let o = falsify(
        "bicycle_obstacle_gamma_m.toml",
        &[
            "--range", "vehicle.initial_state.0=-26..-16",
            "--range", "obstacles.0.centre.1=-3..3",
            "--set", "actuation={steering={extra_latency={distribution=\"uniform\", max=0.0}}, acceleration={extra_latency={distribution=\"uniform\", max=0.0}}}",
            "--range", "actuation.steering.extra_latency.max=0..0.1",
            "--range", "actuation.acceleration.extra_latency.max=0..0.1",
            "--range", "seed=0..1000:1",
            "--baseline", "actuation.steering.extra_latency.max=0.0",
            "--baseline", "actuation.acceleration.extra_latency.max=0.0",
            "--budget", "96", "--seed", "1",
        ],
        &jitter,
    );
    assert!(o.status.success(), "{}", text(&o));
    let ranges = [
        ("vehicle.initial_state.0", -26.0, -16.0),
        ("obstacles.0.centre.1", -3.0, 3.0),
        ("actuation.steering.extra_latency.max", 0.0, 0.1),
        ("actuation.acceleration.extra_latency.max", 0.0, 0.1),
        ("seed", 0.0, 1000.0),
    ];
    let generations = generations_in_box_units(&jitter, &ranges);
    let brackets = bracket_generations(&generations, 1e-3);
    let (last, ordered) = *brackets.last().expect("a bracket generation");
    assert!(!ordered, "the last bracket's line is ordered: {brackets:?}");
    assert!(
        brackets[..brackets.len() - 1].iter().all(|(_, ordered)| *ordered),
        "a bracket after an interleaved line: {brackets:?}"
    );
    assert!(generations.len() > last + 2, "no uniform draws after the brackets");
    assert!(generations[last + 1..].iter().all(|points| points.len() == 8));

    let ranges = [
        ("vehicle.initial_state.0", -50.0, -10.0),
        ("obstacles.0.centre.1", -3.0, 3.0),
        ("delays.acceleration", 0.5, 2.0),
    ];
    let mut bracket_count = 0;
    for seed in ["1", "2", "3", "4"] {
        let rare = dir.path().join(format!("rare-{seed}"));
        let mut args = RARE_BOX.to_vec();
        args.extend_from_slice(&DELAY_FREE_BASELINE);
        args.extend_from_slice(&["--budget", "200", "--seed", seed]);
        let o = falsify("bicycle_obstacle_gamma_m.toml", &args, &rare);
        assert!(o.status.success(), "{}", text(&o));
        let generations = generations_in_box_units(&rare, &ranges);
        // D2's step of 0.1 rounds a point by up to 0.033 box units.
        let brackets = bracket_generations(&generations, 0.04);
        assert!(
            brackets.iter().all(|(_, ordered)| *ordered),
            "seed {seed}: {brackets:?}"
        );
        let last = brackets.last().map(|b| b.0);
        assert_eq!(
            last,
            Some(generations.len() - 1),
            "seed {seed}: the violation is a bracket's"
        );
        assert!(generations.last().unwrap().iter().any(|(_, class)| *class == 1));
        bracket_count += brackets.len();
    }
    assert!(bracket_count > 4, "one bracket generation per seed: {bracket_count}");
}
