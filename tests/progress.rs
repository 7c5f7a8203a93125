//! Progress (issue 36 part 3): the goal and path metrics and the stall event agree with an
//! independent reading of the log (tests/progress_check.py: the Python `mcap` reader and the
//! documented definitions); a goal never reached is absent with its reason; a `[goal]` is
//! validated; falsify's baseline can be required to make progress.

mod common;

use std::path::Path;

use common::*;

/// tests/progress_check.py's reading of `log`.
fn independent(log: &Path) -> serde_json::Value {
    let o = std::process::Command::new(python())
        .arg(root().join("tests/progress_check.py"))
        .arg(log)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    serde_json::from_str(&stdout(&o)).unwrap()
}

fn close(a: &serde_json::Value, b: &serde_json::Value, what: &str) {
    let (a, b) = (a.as_f64().unwrap(), b.as_f64().unwrap());
    assert!((a - b).abs() <= 1e-9 * (1.0 + b.abs()), "{what}: {a} vs {b}");
}

#[test]
fn progress_metrics_and_the_stall_event_agree_with_an_independent_reading() {
    let dir = tempfile::tempdir().unwrap();
    // The delay-free CBF-QP stalls in front of the obstacle; (4.67) passes it and reaches the goal.
    let stalled = dir.path().join("nodelay.mcap");
    run_ok(&scenario("bicycle_obstacle_nodelay.toml"), &stalled, &[]);
    let passing = dir.path().join("gamma_m.mcap");
    run_ok(&scenario("bicycle_obstacle_gamma_m.toml"), &passing, &[]);

    let m = analyze_json(&stalled);
    let py = independent(&stalled);
    for metric in ["distance_to_goal", "progress_along_path", "stall_time"] {
        close(&m[metric], &py[metric], metric);
    }
    assert_eq!(m["units"]["distance_to_goal"], "m");
    assert_eq!(m["units"]["time_to_goal"], "s");
    assert_eq!(m["units"]["progress_along_path"], "m");
    // Never reached: absent, with the closest approach as the reason.
    assert!(py["time_to_goal"].is_null() && m["time_to_goal"].is_null(), "{m}");
    let why = m["missing"]["time_to_goal"].as_str().unwrap();
    assert!(why.contains("never reached the goal"), "{why}");
    assert!(m["distance_to_goal"].as_f64().unwrap() > 10.0, "{m}");
    // One stall event, logged when the stall is one STALL_DURATION (1 s) old, naming its start.
    let t = m["stall_time"].as_f64().unwrap();
    let events = py["events"].as_array().unwrap();
    assert_eq!(events.len(), 1, "{py}");
    close(&events[0]["time"], &serde_json::json!(t + 1.0), "stall event time");
    let message = events[0]["message"].as_str().unwrap();
    assert!(message.contains(&format!("since t = {t} s")), "{message}");

    let m = analyze_json(&passing);
    let py = independent(&passing);
    for metric in ["distance_to_goal", "time_to_goal", "progress_along_path"] {
        close(&m[metric], &py[metric], metric);
    }
    assert_eq!(m["distance_to_goal"].as_f64(), Some(0.0));
    assert!(m.get("missing").is_none(), "{m}");
    assert!(py["events"].as_array().unwrap().is_empty(), "no stall: {py}");

    // CSV: a column each; empty for the goal never reached.
    let o = mjsafe(&["analyze", "--csv", stalled.to_str().unwrap(), passing.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("time_to_goal (the vehicle never reached"),
        "{}",
        stderr(&o)
    );
    let csv = stdout(&o);
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = |name: &str| {
        header
            .iter()
            .position(|c| *c == name)
            .unwrap_or_else(|| panic!("{name}"))
    };
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows[0][column("time_to_goal")], "");
    assert!(rows[1][column("time_to_goal")].parse::<f64>().unwrap() > 0.0);
    assert!(rows[0][column("progress_along_path")].parse::<f64>().unwrap() > 0.0);
}

#[test]
fn a_deadline_limits_distance_to_goal_and_a_run_without_goal_has_none() {
    let dir = tempfile::tempdir().unwrap();
    // Reached at 10.7 s: by 5 s it is still far away, yet time_to_goal is when it arrived.
    let late = dir.path().join("late.mcap");
    run_ok(
        &scenario("bicycle_obstacle_gamma_m.toml"),
        &late,
        &["--set", "goal.by=5.0"],
    );
    let m = analyze_json(&late);
    let py = independent(&late);
    close(
        &m["distance_to_goal"],
        &py["distance_to_goal"],
        "distance_to_goal by 5 s",
    );
    assert!(m["distance_to_goal"].as_f64().unwrap() > 1.0, "{m}");
    close(&m["time_to_goal"], &py["time_to_goal"], "time_to_goal");

    // Without a goal or a path the metrics do not apply: null, nothing missing.
    let free = dir.path().join("free.mcap");
    run_ok(&scenario("unicycle_tv_delay.toml"), &free, &[]);
    let m = analyze_json(&free);
    for metric in ["distance_to_goal", "time_to_goal", "progress_along_path"] {
        assert!(m[metric].is_null(), "{metric}: {m}");
    }
    assert!(m.get("missing").is_none(), "{m}");
}

/// A goal without a region (a CommonRoad goal without a position; its check against
/// commonroad-io is tests/commonroad.rs): reached at the first state from `after` on with the
/// speed in its interval; never, with the reason, when the speed never is; no distance.
#[test]
fn a_goal_without_a_region_is_its_window_and_intervals() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("window.mcap");
    run_ok(
        &scenario("bicycle_obstacle_gamma_m.toml"),
        &log,
        &["--set", "goal={after=1.0, by=2.0, speed=[-1.0, 1000.0]}"],
    );
    let m = analyze_json(&log);
    let t = m["time_to_goal"].as_f64().unwrap();
    assert!((t - 1.0).abs() < 1e-9, "{m}");
    assert!(m["distance_to_goal"].is_null(), "{m}");
    let why = m["missing"]["distance_to_goal"].as_str().unwrap();
    assert!(why.contains("no region"), "{why}");

    let never = dir.path().join("never.mcap");
    run_ok(
        &scenario("bicycle_obstacle_gamma_m.toml"),
        &never,
        &["--set", "goal={after=1.0, speed=[100.0, 200.0]}"],
    );
    let m = analyze_json(&never);
    assert!(m["time_to_goal"].is_null(), "{m}");
    let why = m["missing"]["time_to_goal"].as_str().unwrap();
    assert!(
        why.contains("never met the goal (no region, speed in [100, 200] m/s) from 1 s on"),
        "{why}"
    );
}

#[test]
fn a_bad_goal_is_one_error_line_naming_the_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    for (set, key) in [
        ("goal={}", "goal"),
        (
            "goal={position=[0.0, 0.0], radius=1.0, states=[{after=1.0}, {position=[1.0, 0.0], radius=-1.0}]}",
            "goal.states.1.radius",
        ),
        (
            "goal={position=[0.0, 0.0], radius=1.0, states=[{offset=1.0}]}",
            "goal.states.0",
        ),
        ("goal.radius=0.0", "goal.radius"),
        ("goal.position=[1e300, 0.0]", "goal.position"),
        ("goal.by=-1.0", "goal.by"),
        ("goal.speed=1.0", "goal"),
    ] {
        let o = mjsafe(&[
            "run",
            "scenarios/bicycle_obstacle.toml",
            "--set",
            set,
            "--out",
            dir.path().join("x.mcap").to_str().unwrap(),
        ]);
        assert!(!o.status.success(), "{set}");
        let err = stderr(&o);
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(
            err.contains("bicycle_obstacle.toml") && err.contains(key),
            "{set}: {err}"
        );
    }
    // A vehicle without a planar position has no place to reach.
    let o = mjsafe(&[
        "run",
        "scenarios/red_light.toml",
        "--set",
        "goal={position=[1.0, 0.0], radius=0.5}",
        "--out",
        dir.path().join("y.mcap").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("`goal`") && stderr(&o).contains("planar"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_baseline_that_stalls_disqualifies_its_candidate() {
    let dir = tempfile::tempdir().unwrap();
    // The baseline (the delay-free CBF-QP without delays) stays safe by stalling head-on.
    let search = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut args = vec![
            "falsify",
            "scenarios/bicycle_obstacle_gamma_m.toml",
            "--range",
            "obstacles.0.centre.1=0.3..0.7",
            "--baseline",
            "delays.steering=0.0",
            "--baseline",
            "delays.acceleration=0.0",
            "--baseline",
            "filter={kind=\"cbf_qp\", l0=4.0, l1=4.0}",
            "--objective",
            "min_clearance",
            "--threshold",
            "1.0",
            "--budget",
            "8",
        ];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--out", out.to_str().unwrap()]);
        let o = mjsafe(&args);
        assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
        let text = std::fs::read_to_string(out.join("evaluations.json")).unwrap();
        let json: serde_json::Value = serde_json::from_str(&text).unwrap();
        json["searches"][0]["evaluations"].as_array().unwrap().clone()
    };
    // Staying clear is enough without the requirement: the candidates qualify.
    let plain = search("plain", &[]);
    assert!(plain.iter().any(|e| e["qualified"] == true), "{plain:?}");
    // With it, every baseline here stalls (checked on its own run below): none qualifies, and
    // each says why.
    let strict = search("strict", &["--baseline-no-stall"]);
    assert!(!strict.is_empty());
    for e in &strict {
        assert_eq!(e["qualified"], false, "{e}");
        assert_eq!(e["violation"], false, "{e}");
        assert!(e["score"].as_f64().unwrap() > 0.0, "{e}");
        let why = e["baseline_progress"].as_str().unwrap();
        assert!(why.contains("the baseline stalled from t = "), "{why}");
    }
    // The baseline of one candidate, run on its own: it stalls where the search says.
    let e = &strict[0];
    let offset = e["parameters"][0][1].as_str().unwrap();
    let log = dir.path().join("baseline.mcap");
    run_ok(
        &scenario("bicycle_obstacle_gamma_m.toml"),
        &log,
        &[
            "--set",
            &format!("obstacles.0.centre.1={offset}"),
            "--set",
            "delays.steering=0.0",
            "--set",
            "delays.acceleration=0.0",
            "--set",
            "filter={kind=\"cbf_qp\", l0=4.0, l1=4.0}",
        ],
    );
    let py = independent(&log);
    let t = py["stall_time"].as_f64().expect("the baseline stalls");
    let why = e["baseline_progress"].as_str().unwrap();
    assert!(why.contains(&format!("from t = {t} s")), "{why} vs {t}");

    // A requirement of the baseline needs a baseline; a goal requirement needs a goal.
    let o = mjsafe(&[
        "falsify",
        "scenarios/bicycle_obstacle_gamma_m.toml",
        "--range",
        "obstacles.0.centre.1=0.3..0.7",
        "--baseline-no-stall",
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("--baseline-no-stall"),
        "{}",
        stderr(&o)
    );
    let o = mjsafe(&[
        "falsify",
        "scenarios/unicycle_tv_delay.toml",
        "--range",
        "seed=0..3:1",
        "--baseline",
        "seed=0",
        "--baseline-reaches-goal",
    ]);
    assert!(
        !o.status.success() && stderr(&o).contains("no [goal]"),
        "{}",
        stderr(&o)
    );
}

/// `--objective=-distance_to_goal` searches for runs that end far from their goal: on the road
/// too narrow to pass, every candidate stalls short of it; the objective of each evaluation is
/// minus its run's own distance_to_goal.
#[test]
fn a_negated_objective_finds_runs_that_miss_their_goal() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("far");
    let o = mjsafe(&[
        "falsify",
        "scenarios/bicycle_narrow_road.toml",
        "--range",
        "obstacles.0.centre.1=0.3..0.7",
        "--objective=-distance_to_goal",
        "--threshold=-5",
        "--budget",
        "8",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("evaluations.json")).unwrap()).unwrap();
    let evaluations = json["searches"][0]["evaluations"].as_array().unwrap();
    let first = evaluations
        .iter()
        .find(|e| e["violation"] == true)
        .expect("a violation");
    let objective = first["objective"].as_f64().unwrap();
    assert!(objective < -5.0, "{first}");
    // The candidate's own run, analysed from its log.
    let offset = first["parameters"][0][1].as_str().unwrap();
    let log = dir.path().join("candidate.mcap");
    run_ok(
        &scenario("bicycle_narrow_road.toml"),
        &log,
        &["--set", &format!("obstacles.0.centre.1={offset}")],
    );
    let m = analyze_json(&log);
    assert_eq!(-m["distance_to_goal"].as_f64().unwrap(), objective, "{m}");
    // A bad negated name is one error line.
    let o = mjsafe(&[
        "falsify",
        "scenarios/bicycle_narrow_road.toml",
        "--range",
        "obstacles.0.centre.1=0.3..0.7",
        "--objective=-no_such_metric",
    ]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains("-no_such_metric") && err.lines().count() == 1, "{err}");
}

/// A goal's speed and heading intervals: (4.67) enters the goal disc at about 3 m/s heading
/// along the path, so the goal is reached with intervals holding that state and not with an
/// interval of speeds it never has (then absent, the reason naming the intervals).
#[test]
fn the_goal_speed_and_heading_intervals_decide_reaching_it() {
    let dir = tempfile::tempdir().unwrap();
    let reach = |name: &str, sets: &[&str]| {
        let log = dir.path().join(format!("{name}.mcap"));
        let mut extra = Vec::new();
        for s in sets {
            extra.extend(["--set", s]);
        }
        run_ok(&scenario("bicycle_obstacle_gamma_m.toml"), &log, &extra);
        analyze_json(&log)
    };
    let plain = reach("plain", &[]);
    let within = reach("within", &["goal.speed=[1.0, 5.0]", "goal.heading=[-0.5, 0.5]"]);
    assert!(plain["time_to_goal"].as_f64().is_some(), "{plain}");
    assert_eq!(within["time_to_goal"], plain["time_to_goal"]);
    let too_fast = reach("fast", &["goal.speed=[20.0, 30.0]"]);
    assert!(too_fast["time_to_goal"].is_null(), "{too_fast}");
    let why = too_fast["missing"]["time_to_goal"].as_str().unwrap();
    assert!(why.contains("speed in [20, 30] m/s"), "{why}");
    let turned = reach("turned", &["goal.heading=[3.0, 3.3]"]);
    assert!(turned["time_to_goal"].is_null(), "{turned}");
    // The spatial distance does not depend on the intervals.
    assert_eq!(too_fast["distance_to_goal"], plain["distance_to_goal"]);
}
