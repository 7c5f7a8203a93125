//! Bad input: a clear message naming the file, the key and what was expected, a non-zero
//! exit, and nothing half-written left behind.

mod common;
use common::*;

use std::path::Path;

const BASE: &str = r#"
name = "bad"
duration = 1.0
[vehicle]
kind = "bicycle"
model = "MODEL"
initial_state = [-20.0, 0.0, 0.0, 3.0]
[delays]
steering = 0.2
acceleration = 1.5
[nominal]
kind = "path_lqr"
reference_speed = 3.0
"#;

fn base(model: &Path) -> String {
    BASE.replace("MODEL", model.to_str().unwrap())
}

/// Runs the scenario text; asserts failure, that stderr has every `needle`, and that no
/// log (or partial log) was left behind.
fn expect_error(text: &str, needles: &[&str]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let file = write(dir.path(), "case.toml", text);
    let log = dir.path().join("out.mcap");
    let o = mjsafe(&["run", file.to_str().unwrap(), "--out", log.to_str().unwrap()]);
    let err = stderr(&o);
    assert!(!o.status.success(), "expected failure; stdout: {}", stdout(&o));
    for needle in needles {
        assert!(err.contains(needle), "stderr lacks `{needle}`:\n{err}");
    }
    assert!(err.contains("case.toml"), "the file is named:\n{err}");
    let leftovers: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(
        leftovers,
        vec![std::ffi::OsString::from("case.toml")],
        "files left behind"
    );
    println!("{}", err.trim());
    err
}

fn bicycle() -> std::path::PathBuf {
    root().join("models/bicycle.xml")
}

#[test]
fn malformed_toml() {
    expect_error(
        &format!("{}\n[filter\nkind = 1\n", base(&bicycle())),
        &["invalid TOML", "line"],
    );
}

#[test]
fn unknown_key() {
    expect_error(
        &base(&bicycle()).replace("duration = 1.0", "duration = 1.0\nduraton = 2.0"),
        &["duraton", "unknown field"],
    );
}

#[test]
fn missing_required_key() {
    expect_error(
        &base(&bicycle()).replace("duration = 1.0", ""),
        &["missing field `duration`"],
    );
}

#[test]
fn wrong_type() {
    expect_error(
        &base(&bicycle()).replace("reference_speed = 3.0", "reference_speed = \"fast\""),
        &["nominal.reference_speed", "expected a number"],
    );
}

/// The keys of a vehicle kind's own (`[vehicle]` beyond those every vehicle has) are its
/// parameter type's: an unknown one or a wrong type is one line naming `vehicle.<key>`.
#[test]
fn a_vehicle_kinds_own_keys_are_typed() {
    let linear = r#"
name = "bad"
duration = 1.0
plant = "ode"
[vehicle]
kind = "linear"
a = [[-1.0, 0.5], [-0.5, -1.0]]
b = [[1.0, 0.0], [0.0, 1.0]]
timestep = 0.01
initial_state = [1.0, 0.0]
[nominal]
kind = "constant"
input = [0.0, 0.0]
"#;
    let bicycle = base(&bicycle());
    let cases: [(String, &[&str]); 6] = [
        (
            bicycle.replace("kind = \"bicycle\"", "kind = \"bicycle\"\nfoo = 1"),
            &[
                "key `vehicle.foo`",
                "unknown field `foo`",
                "`initial_state`",
                "no keys of its own",
            ],
        ),
        (
            bicycle.replace("kind = \"bicycle\"", "kind = \"bicycle\"\na = \"x\""),
            &["key `vehicle.a`", "unknown field `a`"],
        ),
        (
            linear.replace("a = [[-1.0, 0.5], [-0.5, -1.0]]", "a = \"x\""),
            &["key `vehicle.a`", "expected an array"],
        ),
        (
            linear.replace("timestep = 0.01", "timestep = 0.01\nc = 1"),
            &["key `vehicle.c`", "unknown field `c`", "kind `linear`'s own `a`, `b`"],
        ),
        (
            linear.replace("[-0.5, -1.0]]", "[-0.5]]"),
            &["key `vehicle.a`", "square matrix"],
        ),
        (
            linear.replace("b = [[1.0, 0.0], [0.0, 1.0]]", ""),
            &["key `vehicle`", "missing field `b`"],
        ),
    ];
    for (text, needles) in cases {
        let err = expect_error(&text, needles);
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    }
}

#[test]
fn model_path_that_does_not_exist() {
    expect_error(
        &base(Path::new("/nonexistent/car.xml")),
        &["vehicle.model", "/nonexistent/car.xml"],
    );
}

#[test]
fn model_that_mujoco_rejects_shows_mujocos_message() {
    let dir = tempfile::tempdir().unwrap();
    let model = write(
        dir.path(),
        "broken.xml",
        "<mujoco><worldbody><geom type=\"sphere\"/></worldbody><bogus/></mujoco>",
    );
    expect_error(&base(&model), &["vehicle.model", "MuJoCo rejected", "bogus"]);
}

#[test]
fn negative_delay() {
    expect_error(
        &base(&bicycle()).replace("steering = 0.2", "steering = -0.2"),
        &["delays.steering", ">= 0"],
    );
}

#[test]
fn delay_not_a_multiple_of_the_timestep() {
    expect_error(
        &base(&bicycle()).replace("steering = 0.2", "steering = 0.2013"),
        &["delays.steering", "whole multiple of the timestep"],
    );
}

#[test]
fn unknown_channel_and_wrong_state_size() {
    expect_error(
        &base(&bicycle()).replace("steering = 0.2", "brake = 0.2"),
        &["brake", "steering, acceleration"],
    );
    expect_error(
        &base(&bicycle()).replace("[-20.0, 0.0, 0.0, 3.0]", "[1.0, 2.0]"),
        &["vehicle.initial_state", "expected 4 values"],
    );
}

#[test]
fn obstacle_inside_the_vehicle_at_the_start() {
    let text = format!(
        "{}\n[[obstacles]]\ncentre = [-21.0, 0.0]\nradius = 1.0\n",
        base(&bicycle())
    );
    expect_error(&text, &["obstacles.0", "overlaps the vehicle"]);
}

#[test]
fn bad_override() {
    let dir = tempfile::tempdir().unwrap();
    let file = write(dir.path(), "case.toml", &base(&bicycle()));
    // Neither a TOML value nor a bare word: refused as such.
    let o = mjsafe(&["run", file.to_str().unwrap(), "--set", "duration=very fast"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("--set duration=very fast") && stderr(&o).contains("not a TOML value or a bare word"),
        "{}",
        stderr(&o)
    );
    // A bare word is a string: the schema refuses it where a number is expected, naming the key.
    let o = mjsafe(&["run", file.to_str().unwrap(), "--set", "duration=fast"]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains("duration") && err.contains("string \"fast\""), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}

/// `--set KEY=WORD` takes a bare word as a string: no shell quotes around TOML quotes.
#[test]
fn a_bare_word_override_is_a_string() {
    let dir = tempfile::tempdir().unwrap();
    let quoted = dir.path().join("quoted.mcap");
    let bare = dir.path().join("bare.mcap");
    let gamma_m = "{kind='gamma_m', l0=4.0, l1=4.0, m=50.0}";
    let scenario = scenario("bicycle_obstacle.toml");
    run_ok(
        &scenario,
        &quoted,
        &[
            "--set",
            "duration=1.0",
            "--set",
            "plant='ode'",
            "--set",
            &format!("filter={gamma_m}"),
        ],
    );
    run_ok(
        &scenario,
        &bare,
        &[
            "--set",
            "duration=1.0",
            "--set",
            "plant=ode",
            "--set",
            &format!("filter={gamma_m}"),
            "--set",
            "filter.kind=gamma_m",
        ],
    );
    let (a, b) = (analyze_json(&quoted), analyze_json(&bare));
    assert_eq!(a["min_h"], b["min_h"]);
    assert_eq!(a["filter"], b["filter"]);
}

#[test]
fn blow_up_during_a_run_stops_with_an_error_event_and_a_readable_log() {
    // A huge initial acceleration on [-D, 0) drives the velocity past MuJoCo's limit (1e10)
    // after about 1.1 s: MuJoCo would silently reset the state; mjsafe stops the episode.
    let dir = tempfile::tempdir().unwrap();
    let text = blowup_scenario();
    let file = write(dir.path(), "blowup.toml", &text);
    let log = dir.path().join("blowup.mcap");
    let o = mjsafe(&["run", file.to_str().unwrap(), "--out", log.to_str().unwrap()]);
    assert!(!o.status.success(), "a blown-up run exits non-zero");
    assert!(stderr(&o).contains("stopped early"), "{}", stderr(&o));
    // The log is finished, readable, and says what happened.
    let m = analyze_json(&log);
    assert_eq!(m["complete"], false);
    let error = m["error"].as_str().unwrap();
    assert!(error.contains("qvel"), "{error}");
    let stopped_at = m["simulated_time"].as_f64().unwrap();
    assert!(stopped_at > 1.0 && stopped_at < 1.5, "stopped at {stopped_at}");
    let o = std::process::Command::new(python())
        .arg(root().join("tests/read_log.py"))
        .arg(&log)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "python reader: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let digest: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let events = digest["events"].as_array().unwrap();
    assert_eq!(events.last().unwrap()["kind"], "error");
}

#[test]
fn a_closed_stdout_pipe_ends_quietly_instead_of_panicking() {
    // `mjsafe info LOG | head -0`: the reader is gone before mjsafe writes.
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    run_ok(&scenario("bicycle_obstacle.toml"), &log, &["--set", "duration=0.5"]);
    // The pipe's reading end is closed before mjsafe starts (closing it after the spawn races
    // with mjsafe's first write, which may still fit in the pipe).
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .arg("info")
        .arg(&log)
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(output.status.code(), Some(141), "{stderr}");
}

#[test]
fn a_missing_file_is_named_once_with_the_reason_once() {
    for args in [
        &["run", "scenarios/missing.toml"][..],
        &["analyze", "logs/missing.mcap"][..],
        &["bench", "scenarios/missing.toml"][..],
    ] {
        let o = mjsafe(args);
        assert!(!o.status.success());
        let e = stderr(&o);
        assert!(e.contains("missing."), "{e}");
        assert_eq!(e.matches("No such file or directory").count(), 1, "{args:?}: {e}");
    }
}

#[test]
fn a_name_that_would_leave_the_output_directory_is_refused() {
    // The scenario's `name` names the default log (`logs/<name>-….mcap`).
    for name in ["../escaped", "a/b", ".."] {
        let text = base(&bicycle()).replace("name = \"bad\"", &format!("name = {name:?}"));
        expect_error(&text, &["key `name`", "one path component"]);
    }
    // A sweep file's `name` names every run's log inside --out.
    let dir = tempfile::tempdir().unwrap();
    let scenario = write(dir.path(), "case.toml", &base(&bicycle()));
    let sweep = write(
        dir.path(),
        "x.sweep.toml",
        &format!(
            "scenario = {:?}\nname = '../escaped'\n[[grid]]\nkey = 'seed'\nvalues = [1]\n",
            scenario.to_str().unwrap()
        ),
    );
    let out = dir.path().join("out");
    let o = mjsafe(&[
        "sweep",
        "--sweep",
        sweep.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("x.sweep.toml") && err.contains("key `name`"), "{err}");
    assert!(
        !dir.path().join("escaped-0.mcap").exists() && !out.exists(),
        "nothing runs"
    );
}

#[test]
fn a_sweep_whose_summary_cannot_be_written_runs_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = write(dir.path(), "case.toml", &base(&bicycle()));
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    write(&out, "summary.json", "notes\n");
    let o = mjsafe(&[
        "sweep",
        scenario.to_str().unwrap(),
        "--grid",
        "seed=1,2",
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("summary.json"), "{err}");
    let left: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, vec![std::ffi::OsString::from("summary.json")], "no run was made");
    assert_eq!(std::fs::read_to_string(out.join("summary.json")).unwrap(), "notes\n");
}

#[test]
fn falsify_refuses_a_nan_threshold_and_fails_when_every_candidate_fails() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = write(dir.path(), "case.toml", &base(&bicycle()));
    let out = dir.path().join("fz");
    let falsify = |extra: &[&str]| {
        let mut args = vec![
            "falsify",
            scenario.to_str().unwrap(),
            "--budget",
            "4",
            "--threads",
            "1",
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        mjsafe(&args)
    };
    let o = falsify(&["--range", "delays.steering=0..0.4:0.01", "--threshold", "nan"]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--threshold") && stderr(&o).contains("finite"),
        "{}",
        stderr(&o)
    );
    // Without :STEP the drawn delays are off the timestep grid (the centre, 0.2 s, which is
    // checked before the search, is on it): every candidate fails.
    let o = falsify(&["--range", "delays.steering=0..0.4"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(
        err.contains("every candidate failed") && err.contains("multiple"),
        "{err}"
    );
    assert!(out.join("evaluations.csv").exists(), "the evaluations are written");
}

#[test]
fn a_model_without_a_positive_timestep_is_named_as_the_model() {
    let dir = tempfile::tempdir().unwrap();
    let xml = std::fs::read_to_string(bicycle()).unwrap();
    for value in ["0", "-1"] {
        let model = write(
            dir.path(),
            "zero_step.xml",
            &xml.replace(r#"timestep="0.002""#, &format!(r#"timestep="{value}""#)),
        );
        expect_error(&base(&model), &["key `vehicle.model`", "<option timestep>", "positive"]);
    }
}

#[test]
fn obstacle_names_are_unique_and_not_empty() {
    // Names key the logged barrier values and the exported columns: a duplicate made a
    // Parquet table no reader opens.
    run_expecting_failure(
        "bicycle_two_obstacles.toml",
        &["obstacles.1.name=\"cone_left\""],
        &[
            "key `obstacles.1.name`",
            "`cone_left` is already the name of obstacles.0",
        ],
    );
    // A name left out is obstacle_<index>.
    run_expecting_failure(
        "bicycle_two_obstacles.toml",
        &["obstacles.0.name=\"obstacle_1\"", "obstacles.1.name=\"obstacle_1\""],
        &["key `obstacles.1.name`", "already the name of obstacles.0"],
    );
    run_expecting_failure(
        "bicycle_two_obstacles.toml",
        &["obstacles.1.name=\" \""],
        &["key `obstacles.1.name`", "not empty"],
    );
    // Far enough that h = d² − r² is inf (min h was null with no reason).
    run_expecting_failure(
        "bicycle_obstacle.toml",
        &["obstacles.0.centre=[1e300, 0.0]"],
        &["key `obstacles.0`", "within ±1e9 m"],
    );
}

#[test]
fn road_errors_are_one_line_naming_the_field() {
    let edge = |body: &str| format!("{}\n[[road.edges]]\n{body}\n", base(&bicycle()));
    for (text, needles) in [
        (
            edge("kind = \"line\"\npoint = [0.0, -10.0]\ndirection = [0.0, 0.0]\nroad = \"left\""),
            &["key `road.edges.0.direction`", "non-zero vector"][..],
        ),
        (
            edge("kind = \"arc\"\ncentre = [0.0, 0.0]\nradius = -5.0\nroad = \"outside\""),
            &["key `road.edges.0.radius`", "expected a radius > 0"],
        ),
        (
            edge("kind = \"line\"\npoint = [0.0, -10.0]\ndirection = [1.0, 0.0]\nroad = \"up\""),
            &[
                "key `road.edges[0]`",
                "unknown variant `up`, expected `left` or `right`",
            ],
        ),
        // The hull (radius 3) at x2 = 0 crosses x2 = -2: 1 m beyond the edge.
        (
            edge("kind = \"line\"\npoint = [0.0, -2.0]\ndirection = [1.0, 0.0]\nroad = \"left\""),
            &["key `road.edges.0`", "starts off the road", "1.000 m beyond this edge"],
        ),
        // Inside a circle of 50 m about (0, 0), the start (-20, 0) is on the road; outside it, not.
        (
            edge("kind = \"arc\"\ncentre = [0.0, 0.0]\nradius = 50.0\nroad = \"outside\""),
            &["key `road.edges.0`", "starts off the road"],
        ),
        (
            edge("kind = \"arc\"\ncentre = [-20.0, 0.0]\nradius = 2.0\nroad = \"inside\""),
            &["key `road.edges.0.radius`", "no room for the vehicle's hull"],
        ),
        (
            format!(
                "{}\n[[road.lanes]]\nkind = \"line\"\npoint = [0.0, 1e300]\ndirection = [1.0, 0.0]\n",
                base(&bicycle())
            ),
            &["key `road.lanes.0.point`", "within ±1e9 m"],
        ),
        (
            edge(
                "name = \"barrier_0\"\nkind = \"line\"\npoint = [0.0, -10.0]\ndirection = [1.0, 0.0]\nroad = \"left\"",
            ) + "[[barriers]]\nkind = \"half_space\"\ncoefficients = [0.0, 1.0]\noffset = 20.0\n",
            &["key `road.edges.0.name`", "already the name of barriers.0"],
        ),
    ] {
        let err = expect_error(&text, needles);
        assert_eq!(err.trim().lines().count(), 1, "one line:\n{err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}
