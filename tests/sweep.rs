//! `mjsafe sweep`, `analyze --merge/--csv/--compare` and `info` on the real binary.

mod common;
use common::*;

use std::path::{Path, PathBuf};

use mjsafe::log::proto;
use serde_json::Value;

const SCENARIO: &str = "scenarios/bicycle_obstacle.toml";
const CBF: &str = "{kind='cbf_qp', l0=4.0, l1=4.0}";
const GAMMA_M: &str = "{kind='gamma_m', l0=4.0, l1=4.0, m=50.0}";

/// The 2×2 grid: steering delay × filter (the filter values hold commas inside braces).
fn grid_args(out: &Path, extra: &[&str]) -> Vec<String> {
    let mut args: Vec<String> = [
        "sweep",
        SCENARIO,
        "--set",
        "duration=5.0",
        "--grid",
        "delays.steering=0.1,0.2",
        "--grid",
        &format!("filter={CBF},{GAMMA_M}"),
        "--out",
        out.to_str().unwrap(),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    args.extend(extra.iter().map(|s| s.to_string()));
    args
}

fn sweep_ok(args: &[String]) -> String {
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = mjsafe(&args);
    assert!(
        o.status.success(),
        "mjsafe {args:?} failed:\nstdout: {}\nstderr: {}",
        stdout(&o),
        stderr(&o)
    );
    assert!(
        stderr(&o).is_empty(),
        "stderr is not a terminal: no progress expected: {}",
        stderr(&o)
    );
    stdout(&o)
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn json(path: &Path) -> Value {
    serde_json::from_slice(&read(path)).unwrap()
}

/// Fields of one CSV line (RFC 4180 quoting).
fn csv_fields(line: &str) -> Vec<String> {
    let mut fields = vec![String::new()];
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                chars.next();
                fields.last_mut().unwrap().push('"');
            }
            ('"', _) => quoted = !quoted,
            (',', false) => fields.push(String::new()),
            _ => fields.last_mut().unwrap().push(c),
        }
    }
    fields
}

/// One column of a CSV text, by header name.
fn csv_column(text: &str, column: &str) -> Vec<String> {
    let mut lines = text.lines();
    let header = csv_fields(lines.next().unwrap());
    let at = header
        .iter()
        .position(|h| h == column)
        .unwrap_or_else(|| panic!("no {column} in {header:?}"));
    lines.map(|l| csv_fields(l)[at].clone()).collect()
}

#[test]
fn grid_runs_match_the_same_overrides_run_alone() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("grid");
    let printed = sweep_ok(&grid_args(&out, &["--threads", "2"]));
    assert!(printed.contains("4 of 4 runs"), "{printed}");

    let summary = json(&out.join("summary.json"));
    let runs = summary["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 4);
    assert_eq!(summary["parameters"], serde_json::json!(["delays.steering", "filter"]));
    // First grid slowest: (0.1, CBF), (0.1, gamma-m), (0.2, CBF), (0.2, gamma-m).
    let expected = [("0.1", CBF), ("0.1", GAMMA_M), ("0.2", CBF), ("0.2", GAMMA_M)];
    for (i, (run, (delay, filter))) in runs.iter().zip(expected).enumerate() {
        assert_eq!(run["index"], i);
        assert_eq!(run["parameters"]["delays.steering"], delay);
        assert_eq!(run["parameters"]["filter"], filter);
        assert!(run["error"].is_null(), "{run}");
        let log = out.join(run["log"].as_str().unwrap());
        assert_eq!(log, out.join(format!("bicycle_obstacle-{i:03}.mcap")));

        // The same overrides, run alone.
        let alone = dir.path().join(format!("alone-{i}.mcap"));
        let set_delay = format!("delays.steering={delay}");
        let set_filter = format!("filter={filter}");
        run_ok(
            Path::new(SCENARIO),
            &alone,
            &["--set", "duration=5.0", "--set", &set_delay, "--set", &set_filter],
        );
        assert!(
            read(&alone) == read(&log),
            "run {i}: the sweep's log differs from `mjsafe run`'s"
        );
        let m = analyze_json(&alone);
        let s = &run["metrics"];
        assert_eq!(s["min_h"], m["min_h"], "run {i}");
        assert_eq!(s["steps"], m["steps"]);
        assert_eq!(s["simulated_time"], m["simulated_time"]);
        assert_eq!(s["filter_active_fraction"], m["filter_active_fraction"]);
        assert_eq!(s["time_h_negative"], m["time_h_negative"]);
        for (channel, value) in m["max_correction"].as_object().unwrap() {
            assert_eq!(&s[format!("max_correction.{channel}")], value, "run {i}");
        }
        assert_eq!(s["complete"], true);
        match m["collision"].as_object() {
            Some(c) => {
                assert_eq!(s["collision_time"], c["time"]);
                assert_eq!(s["collision_with"], c["with"]);
                assert_eq!(s["collision_depth"], c["depth"]);
            }
            None => assert!(s["collision_time"].is_null()),
        }
    }
    // The grid reaches the runs: the delay-free CBF-QP collides, gamma-m does not (Fig. 4.6).
    for run in runs {
        let collided = !run["metrics"]["collision_time"].is_null();
        assert_eq!(collided, run["parameters"]["filter"] == CBF, "{run}");
    }
    let csv = String::from_utf8(read(&out.join("summary.csv"))).unwrap();
    assert_eq!(csv.lines().count(), 5, "{csv}");
    assert!(csv.starts_with("index,log,delays.steering,filter,scenario,"), "{csv}");
    assert!(
        csv.contains(&format!("\"{CBF}\"")),
        "values with commas are quoted: {csv}"
    );
    assert_eq!(csv_column(&csv, "filter"), [CBF, GAMMA_M, CBF, GAMMA_M]);
    let min_h: Vec<f64> = csv_column(&csv, "min_h").iter().map(|v| v.parse().unwrap()).collect();
    let from_json: Vec<f64> = runs.iter().map(|r| r["metrics"]["min_h"].as_f64().unwrap()).collect();
    assert_eq!(min_h, from_json);
}

#[test]
fn summaries_do_not_depend_on_the_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let one = dir.path().join("one");
    let two = dir.path().join("two");
    sweep_ok(&grid_args(&one, &["--threads", "1"]));
    sweep_ok(&grid_args(&two, &["--threads", "2"]));
    for file in ["summary.json", "summary.csv", "bicycle_obstacle-003.mcap"] {
        assert!(read(&one.join(file)) == read(&two.join(file)), "{file} differs");
    }
}

#[test]
fn a_metrics_only_sweep_gives_the_logged_sweeps_summary_without_logs() {
    let dir = tempfile::tempdir().unwrap();
    let logged = dir.path().join("logged");
    let metrics_only = dir.path().join("metrics-only");
    // A steering delay the episode rejects (0.123 is not a whole number of steps) makes a row
    // with an error; the γm runs log predictions, so their prediction errors are compared too.
    let args = |out: &Path, extra: &[&str]| {
        let mut args = grid_args(out, extra);
        let at = args.iter().position(|a| a == "delays.steering=0.1,0.2").unwrap();
        args[at] = "delays.steering=0.1,0.2,0.123".into();
        args
    };
    for (out, extra) in [(&logged, &[][..]), (&metrics_only, &["--no-logs"][..])] {
        let o = mjsafe(&args(out, extra).iter().map(String::as_str).collect::<Vec<_>>());
        assert_eq!(o.status.code(), Some(3), "one run fails: {}", stderr(&o));
    }
    let kept: Vec<String> = std::fs::read_dir(&metrics_only)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| !name.starts_with("summary."))
        .collect();
    assert!(kept.is_empty(), "--no-logs keeps only the summary: {kept:?}");

    let mut with_logs = json(&logged.join("summary.json"));
    let without = json(&metrics_only.join("summary.json"));
    let runs = with_logs["runs"].as_array_mut().unwrap();
    assert_eq!(runs.len(), 6);
    let predicted = |run: &Value| {
        // Flat columns: `prediction_count.<channel>`.
        let metrics = run["metrics"].as_object();
        metrics.is_some_and(|m| {
            m.iter()
                .any(|(column, n)| column.starts_with("prediction_count.") && n.as_u64() > Some(0))
        })
    };
    assert!(runs.iter().any(predicted), "some run predicts");
    for (i, run) in runs.iter_mut().enumerate() {
        assert_eq!(run["log"].is_string(), i < 4, "{run}");
        assert!(without["runs"][i]["log"].is_null(), "{}", without["runs"][i]);
        run["log"] = Value::Null;
    }
    assert_eq!(
        with_logs, without,
        "the metrics analysed while running are the logs' metrics"
    );
    // Shards of one sweep with and without logs merge (the same metrics), with a warning.
    let mixed = dir.path().join("mixed");
    for (shard, extra) in [("0/2", &[][..]), ("1/2", &["--no-logs"][..])] {
        let mut shard_args = args(&mixed, extra);
        shard_args.extend(["--shard".to_string(), shard.to_string()]);
        let o = mjsafe(&shard_args.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(o.status.code().is_some_and(|c| c == 0 || c == 3), "{}", stderr(&o));
    }
    let o = mjsafe(&["analyze", "--merge", mixed.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("have no log (their shards ran with --no-logs): 1, 3"),
        "{}",
        stderr(&o)
    );
    assert!(without["runs"][4]["error"]
        .as_str()
        .unwrap()
        .contains("delays.steering"));
}

#[test]
fn shards_merge_into_the_unsharded_summary() {
    let dir = tempfile::tempdir().unwrap();
    let whole = dir.path().join("whole");
    let shards = dir.path().join("shards");
    sweep_ok(&grid_args(&whole, &[]));
    let printed = sweep_ok(&grid_args(&shards, &["--shard", "0/2"]));
    assert!(printed.contains("2 of 4 runs (shard 0/2)"), "{printed}");
    let shard0 = json(&shards.join("summary-shard-0-of-2.json"));
    let indices: Vec<u64> = shard0["runs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["index"].as_u64().unwrap())
        .collect();
    assert_eq!(indices, [0, 2]);
    assert!(shards.join("bicycle_obstacle-002.mcap").exists());
    assert!(!shards.join("bicycle_obstacle-001.mcap").exists());

    // One shard alone: the missing runs are reported and nothing is written.
    let partial = dir.path().join("partial");
    let o = mjsafe(&[
        "analyze",
        "--merge",
        shards.to_str().unwrap(),
        "--out",
        partial.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("2 of 4 runs are missing from the merge: 1, 3"),
        "{}",
        stderr(&o)
    );
    assert!(!partial.exists());

    sweep_ok(&grid_args(&shards, &["--shard", "1/2"]));
    let merged = dir.path().join("merged");
    let o = mjsafe(&[
        "analyze",
        "--merge",
        shards.to_str().unwrap(),
        "--out",
        merged.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for file in ["summary.json", "summary.csv"] {
        assert!(
            read(&merged.join(file)) == read(&whole.join(file)),
            "merged {file} differs"
        );
    }
    // Printed forms: --json is summary.json, --csv is summary.csv.
    let o = mjsafe(&["analyze", "--merge", "--json", shards.to_str().unwrap()]);
    assert_eq!(o.stdout, read(&whole.join("summary.json")));
    let o = mjsafe(&["analyze", "--merge", "--csv", shards.to_str().unwrap()]);
    assert_eq!(o.stdout, read(&whole.join("summary.csv")));

    // A shard started from another directory (the scenario path spelled otherwise, the same
    // file) is the same sweep.
    let elsewhere = dir.path().join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    std::fs::copy(
        shards.join("summary-shard-0-of-2.json"),
        elsewhere.join("summary-shard-0-of-2.json"),
    )
    .unwrap();
    let mut args = grid_args(&elsewhere, &["--shard", "1/2"]);
    args[1] = "bicycle_obstacle.toml".into();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args(&args)
        .current_dir(root().join("scenarios"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let o = mjsafe(&["analyze", "--merge", "--csv", elsewhere.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(o.stdout, read(&whole.join("summary.csv")));

    // A shard whose runs were interrupted or never started (Ctrl-C, a preempted task) is as
    // incomplete as a missing shard: exit 1, nothing written.
    for field in ["not_run", "interrupted"] {
        let cut = dir.path().join(format!("cut-{field}"));
        std::fs::create_dir_all(&cut).unwrap();
        std::fs::copy(
            shards.join("summary-shard-0-of-2.json"),
            cut.join("summary-shard-0-of-2.json"),
        )
        .unwrap();
        let mut shard1 = json(&shards.join("summary-shard-1-of-2.json"));
        shard1["runs"][1][field] = Value::Bool(true);
        std::fs::write(
            cut.join("summary-shard-1-of-2.json"),
            serde_json::to_string_pretty(&shard1).unwrap(),
        )
        .unwrap();
        let target = dir.path().join(format!("merged-{field}"));
        let o = mjsafe(&[
            "analyze",
            "--merge",
            cut.to_str().unwrap(),
            "--out",
            target.to_str().unwrap(),
        ]);
        assert_eq!(o.status.code(), Some(1), "{field}: {}", stderr(&o));
        assert!(
            stderr(&o).contains("1 of 4 runs were not run to their end"),
            "{}",
            stderr(&o)
        );
        assert!(stderr(&o).contains(": 3;"), "{}", stderr(&o));
        assert!(!target.exists());
    }

    // Shards of another sweep do not merge.
    let other = dir.path().join("other");
    let args: Vec<String> = grid_args(&other, &["--shard", "1/2", "--set", "duration=4.0"]);
    sweep_ok(&args);
    let o = mjsafe(&[
        "analyze",
        "--merge",
        shards.join("summary-shard-0-of-2.json").to_str().unwrap(),
        other.join("summary-shard-1-of-2.json").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("different sweeps") && stderr(&o).contains("--set"),
        "{}",
        stderr(&o)
    );
}

fn random_sweep(out: &Path, seed: &str, threads: &str) -> Value {
    sweep_ok(
        &[
            "sweep",
            SCENARIO,
            "--set",
            "duration=2.0",
            "--random",
            "5",
            "--seed",
            seed,
            "--range",
            "obstacles.0.radius=2.0..3.0",
            "--range",
            "delays.steering=0.0..0.4:0.01",
            "--threads",
            threads,
            "--out",
            out.to_str().unwrap(),
        ]
        .map(String::from),
    );
    json(&out.join("summary.json"))
}

#[test]
fn random_draws_are_seeded_and_in_range() {
    let dir = tempfile::tempdir().unwrap();
    let a = random_sweep(&dir.path().join("a"), "7", "2");
    let b = random_sweep(&dir.path().join("b"), "7", "1");
    let c = random_sweep(&dir.path().join("c"), "8", "2");
    assert!(
        read(&dir.path().join("a/summary.json")) == read(&dir.path().join("b/summary.json")),
        "same seed, different summaries"
    );
    assert_eq!(a, b);
    let draws = |s: &Value, key: &str| -> Vec<f64> {
        s["runs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["parameters"][key].as_str().unwrap().parse::<f64>().unwrap())
            .collect()
    };
    let radii = draws(&a, "obstacles.0.radius");
    let delays = draws(&a, "delays.steering");
    assert_eq!(radii.len(), 5);
    assert!(radii.iter().all(|r| (2.0..3.0).contains(r)), "{radii:?}");
    assert!(radii.windows(2).any(|w| w[0] != w[1]), "{radii:?}");
    for d in &delays {
        assert!((0.0..=0.4).contains(d), "{delays:?}");
        assert!(
            (d * 100.0 - (d * 100.0).round()).abs() < 1e-9,
            "{d} is not a multiple of 0.01"
        );
    }
    assert_ne!(radii, draws(&c, "obstacles.0.radius"), "another seed, the same draws");
    // The draws reach the runs: every run completed, and its log records the drawn overrides.
    for run in a["runs"].as_array().unwrap() {
        assert!(run["error"].is_null(), "{run}");
        let log = dir.path().join("a").join(run["log"].as_str().unwrap());
        let info = stdout(&mjsafe(&["info", log.to_str().unwrap()]));
        let radius = run["parameters"]["obstacles.0.radius"].as_str().unwrap();
        assert!(info.contains(&format!("obstacles.0.radius={radius}")), "{info}");
    }
}

#[test]
fn failing_runs_are_rows_with_their_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fail");
    // -1.0 is rejected by the scenario checks; 0.123 by the episode (not a multiple of h).
    let o = mjsafe(&[
        "sweep",
        SCENARIO,
        "--set",
        "duration=2.0",
        "--grid",
        "delays.steering=0.1,-1.0,0.123",
        "--out",
        out.to_str().unwrap(),
    ]);
    // 3: the sweep ran and wrote its summary, some runs failed (1 would be a broken sweep).
    assert_eq!(o.status.code(), Some(3), "failed runs exit 3: {}", stderr(&o));
    assert!(stderr(&o).contains("2 of 3 runs failed"), "{}", stderr(&o));
    let s = json(&out.join("summary.json"));
    let runs = s["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 3);
    assert!(
        runs[0]["error"].is_null() && runs[0]["metrics"]["complete"] == true,
        "{}",
        runs[0]
    );
    for run in &runs[1..] {
        let error = run["error"].as_str().unwrap_or_else(|| panic!("{run}"));
        assert!(error.contains("delays.steering"), "{error}");
        assert!(run["log"].is_null() && run["metrics"].is_null(), "{run}");
    }
    assert!(runs[1]["error"].as_str().unwrap().contains(">= 0"), "{}", runs[1]);
    let csv = String::from_utf8(read(&out.join("summary.csv"))).unwrap();
    assert_eq!(csv.lines().count(), 4, "{csv}");
}

/// A row's error is in the one-line form people read: a 1e300 mjsafe printed in full (301
/// digits) is shortened in the table and both summary files.
#[test]
fn row_errors_are_shortened_as_the_error_line_is() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("huge");
    let o = mjsafe(&[
        "sweep",
        SCENARIO,
        "--grid",
        "filter.l0=1e300",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
    assert!(stdout(&o).contains("1.000000e300"), "{}", stdout(&o));
    for file in ["summary.csv", "summary.json"] {
        let text = String::from_utf8(read(&out.join(file))).unwrap();
        assert!(
            text.contains("1.000000e300") && !text.contains("0000000000000000000000"),
            "{file}: {text}"
        );
    }
}

#[test]
fn sweep_file_expands_grids_in_order() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("file");
    let o = mjsafe(&[
        "sweep",
        "--sweep",
        "scenarios/bicycle_delays.sweep.toml",
        "--set",
        "duration=1.0",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = json(&out.join("summary.json"));
    assert_eq!(s["sweep"]["runs"], 12);
    assert_eq!(s["sweep"]["scenario"], "scenarios/bicycle_obstacle.toml");
    assert_eq!(s["sweep"]["set"], serde_json::json!(["duration=1.0"]));
    let runs = s["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 12);
    let delays: Vec<&str> = runs
        .iter()
        .map(|r| r["parameters"]["delays.steering"].as_str().unwrap())
        .collect();
    assert_eq!(
        delays,
        ["0.0", "0.0", "0.0", "0.1", "0.1", "0.1", "0.2", "0.2", "0.2", "0.4", "0.4", "0.4"]
    );
    assert!(runs
        .iter()
        .all(|r| r["error"].is_null() && r["metrics"]["simulated_time"] == 1.0));
}

#[test]
fn bad_sweep_arguments_name_the_argument() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("never");
    let cases: [(&[&str], &str); 10] = [
        (
            &["--grid", "delays.steering=0.1,[0.2"],
            "--grid delays.steering=0.1,[0.2: missing closing `]`",
        ),
        (
            &["--grid", "filter.kind=cbf qp"],
            "--grid filter.kind=cbf qp: `cbf qp` is not a TOML value or a bare word",
        ),
        (
            &["--grid", "delays.steering"],
            "--grid delays.steering: expected KEY=V1,V2",
        ),
        (
            &["--grid", "delays.steering=0.1,,0.2"],
            "--grid delays.steering=0.1,,0.2: value 2 of 3 is empty",
        ),
        (
            &["--random", "3", "--range", "obstacles.0.radius=3..2"],
            "--range obstacles.0.radius=3..2: expected finite LO <= HI",
        ),
        (
            &["--grid", "delays.steering=0.1", "--shard", "2/2"],
            "--shard 2/2: expected 0 <= INDEX < COUNT",
        ),
        (&["--range", "obstacles.0.radius=2..3"], "--range needs --random N"),
        // Base overrides every run shares: the sweep's error (exit 1), not a failed row per run.
        (
            &["--grid", "delays.steering=0.1,0.2", "--set", "duration"],
            "--set duration: expected KEY=VALUE",
        ),
        (
            &["--grid", "delays.steering=0.1,0.2", "--set", "bogus=1"],
            "every run would fail: ",
        ),
        // Two spellings of one field (an index is a number): swept twice.
        (
            &[
                "--grid",
                "obstacles.0.radius=1.0,2.0",
                "--grid",
                "obstacles.00.radius=3.0",
            ],
            "`obstacles.00.radius` is swept twice",
        ),
    ];
    for (extra, expected) in cases {
        let mut args = vec!["sweep", SCENARIO, "--out", out.to_str().unwrap()];
        args.extend_from_slice(extra);
        let o = mjsafe(&args);
        assert_eq!(o.status.code(), Some(1), "{extra:?}: {}", stderr(&o));
        assert!(stderr(&o).contains(expected), "{extra:?}: {}", stderr(&o));
    }
    assert!(!out.exists(), "a rejected sweep writes nothing");
}

/// Two short runs of the scalar example (ODE plant): different initial states.
fn two_logs(dir: &Path) -> (PathBuf, PathBuf) {
    let a = dir.join("a.mcap");
    let b = dir.join("b.mcap");
    let scalar = scenario("scalar_tv_delay.toml");
    run_ok(&scalar, &a, &["--set", "duration=2.0"]);
    run_ok(
        &scalar,
        &b,
        &["--set", "duration=2.0", "--set", "vehicle.initial_state=[-0.5]"],
    );
    (a, b)
}

#[test]
fn info_lists_topics_metadata_and_scenario() {
    let dir = tempfile::tempdir().unwrap();
    let (_, b) = two_logs(dir.path());
    let o = mjsafe(&["info", b.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    let states = read_topic::<proto::State>(&b, "/state").len();
    let predictions = read_topic::<proto::Prediction>(&b, "/prediction").len();
    assert!(states > 0 && predictions > 0);
    let line = |topic: &str| {
        text.lines()
            .find(|l| l.split_whitespace().nth(1) == Some(topic))
            .unwrap_or_else(|| panic!("no {topic} line in\n{text}"))
            .to_string()
    };
    assert!(
        line("/state").contains(&format!(" {states} msgs  mjsafe.State [protobuf]")),
        "{text}"
    );
    assert!(
        line("/prediction").contains(&format!(" {predictions} msgs  mjsafe.Prediction")),
        "{text}"
    );
    for expected in [
        "time:      0.000 .. 2.0",
        "scenario_name       scalar_tv_delay",
        "overrides           duration=2.0",
        "                    vehicle.initial_state=[-0.5]",
        "complete  true",
        "scenario (as written):",
        "  | name = \"scalar_tv_delay\"",
        "  | kind = \"linear\"",
    ] {
        // The metadata column is as wide as its longest key.
        let collapse = |s: &str| s.split(' ').filter(|w| !w.is_empty()).collect::<Vec<_>>().join(" ");
        assert!(
            collapse(&text).contains(&collapse(expected)),
            "missing `{expected}` in\n{text}"
        );
    }
    let o = mjsafe(&["info", "--resolved", b.to_str().unwrap()]);
    assert!(stdout(&o).contains("scenario (resolved, after overrides):"));
    assert!(stdout(&o).contains("initial_state = [-0.5]"), "{}", stdout(&o));
    let o = mjsafe(&["info", "Cargo.toml"]);
    assert!(
        !o.status.success() && stderr(&o).contains("Cargo.toml"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn analyze_csv_and_compare() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = two_logs(dir.path());
    let (ma, mb) = (analyze_json(&a), analyze_json(&b));
    let o = mjsafe(&["analyze", "--csv", a.to_str().unwrap(), b.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = stdout(&o);
    assert_eq!(csv.lines().count(), 3, "{csv}");
    assert!(csv.starts_with("file,scenario,simulated_time,steps,"), "{csv}");
    let min_h: Vec<f64> = csv_column(&csv, "min_h").iter().map(|v| v.parse().unwrap()).collect();
    assert_eq!(min_h, [ma["min_h"].as_f64().unwrap(), mb["min_h"].as_f64().unwrap()]);
    let rms: Vec<f64> = csv_column(&csv, "prediction_rms_error.u1")
        .iter()
        .map(|v| v.parse().unwrap())
        .collect();
    assert_eq!(rms[1], mb["prediction"]["u1"]["rms_error"].as_f64().unwrap());

    let o = mjsafe(&[
        "analyze",
        "--compare",
        "--json",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let cmp: Value = serde_json::from_slice(&o.stdout).unwrap();
    let metric = |name: &str| {
        cmp["metrics"]
            .as_array()
            .unwrap()
            .iter()
            .find(|m| m["metric"] == name)
            .unwrap_or_else(|| panic!("no {name} in {cmp}"))
            .clone()
    };
    let h = metric("min_h");
    let (ha, hb) = (ma["min_h"].as_f64().unwrap(), mb["min_h"].as_f64().unwrap());
    assert_ne!(ha, hb, "the two runs differ");
    assert_eq!((h["a"].as_f64(), h["b"].as_f64()), (Some(ha), Some(hb)));
    assert_eq!(h["difference"].as_f64(), Some(hb - ha));
    assert_eq!(metric("scenario")["difference"], "same");
    assert_eq!(metric("steps")["difference"].as_f64(), Some(0.0));

    let o = mjsafe(&["analyze", "--compare", a.to_str().unwrap(), b.to_str().unwrap()]);
    let table = stdout(&o);
    let row = table
        .lines()
        .find(|l| l.starts_with("min_h "))
        .unwrap_or_else(|| panic!("{table}"));
    // metric, unit, A, B, B − A.
    assert_eq!(
        row.split_whitespace().collect::<Vec<_>>()[..2],
        ["min_h", "h-units"],
        "{row}"
    );
    assert_eq!(row.split_whitespace().count(), 5, "{row}");
    assert!(
        table.lines().any(|l| l.starts_with("metric") && l.contains("B-A")),
        "{table}"
    );

    let o = mjsafe(&["analyze", "--compare", a.to_str().unwrap()]);
    assert!(
        !o.status.success() && stderr(&o).contains("exactly two logs"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn keys_that_move_with_a_grid_axis_take_their_value_in_each_run() {
    // ncap_cpna.sweep.toml: the initial speed, the nominal's reference speed and the start x
    // move together; each run's resolved scenario (the log's) has all three, and its speed
    // stays at the reference (path_lqr holds it until the filter acts).
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cpna");
    let o = mjsafe(&[
        "sweep",
        "--sweep",
        "scenarios/ncap_cpna.sweep.toml",
        "--set",
        "duration=0.5",
        "--set",
        "filter={kind=\"none\"}",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = json(&out.join("summary.json"));
    let runs = s["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 44);
    // Columns: only the grid keys.
    let keys: Vec<&String> = runs[0]["parameters"].as_object().unwrap().keys().collect();
    assert_eq!(
        keys,
        [
            "actor_knowledge.kind",
            "obstacles.0.motion.acceleration",
            "vehicle.initial_state.3"
        ]
    );
    assert_eq!(s["sweep"]["grids"][0]["with"][0]["key"], "nominal.reference_speed");
    for (index, speed, x0) in [
        (0, 2.778, 53.1 - 2.3 - 4.572 * 2.778),
        (43, 16.667, 53.1 - 2.3 - 4.572 * 16.667),
    ] {
        let log = out.join(runs[index]["log"].as_str().unwrap());
        let states = read_topic::<mjsafe::log::proto::State>(&log, "/state");
        assert!(
            (states[0].values[0] - x0).abs() < 1e-3,
            "run {index}: x0 {}",
            states[0].values[0]
        );
        assert_eq!(states[0].values[3], speed, "run {index}");
        let last = states.last().unwrap();
        assert!(
            (last.values[3] - speed).abs() < 1e-6,
            "run {index}: the reference speed is {speed}"
        );
    }
    // A companion with the wrong number of values is refused, naming it.
    let bad = dir.path().join("bad.sweep.toml");
    std::fs::write(
        &bad,
        format!(
            "scenario = \"{}\"\n[[grid]]\nkey = \"vehicle.initial_state.3\"\nvalues = [1.0, 2.0]\nwith = [{{ key = \"nominal.reference_speed\", values = [1.0] }}]\n",
            root().join("scenarios/ncap_cpna.toml").display()
        ),
    )
    .unwrap();
    let o = mjsafe(&[
        "sweep",
        "--sweep",
        bad.to_str().unwrap(),
        "--out",
        out.join("x").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("grid[0].with[0].values`: expected one value per value of the grid (2), found 1"),
        "{}",
        stderr(&o)
    );
}
