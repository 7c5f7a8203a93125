//! Mistakes a new user makes, caught before the run with one line that says where (issue "A
//! researcher's first hour"): each replayed from the shell through the real binary.

mod common;

use common::*;

#[test]
fn a_requirement_on_an_unknown_signal_stops_before_the_run_with_did_you_mean() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("r.mcap");
    let o = mjsafe(&[
        "run",
        scenario("bicycle_obstacle_gamma_m.toml").to_str().unwrap(),
        "--require",
        "brakes=always (obstacle_0.clearence < 3 implies speed < 5)",
        "--out",
        log.to_str().unwrap(),
    ]);
    // Before: the whole episode ran, then "not evaluated (unknown signal …)", exit 0.
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    let err = stderr(&o);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains(
            "requirement `brakes`: unknown signal `obstacle_0.clearence` (did you mean `obstacle_0.clearance`?)"
        ),
        "{err}"
    );
    assert!(!log.exists(), "no log of a run that never started");
    // The same requirement spelled right runs and is reported; analyze --require shows it in
    // the table.
    let o = mjsafe(&[
        "run",
        scenario("bicycle_obstacle_gamma_m.toml").to_str().unwrap(),
        "--require",
        "brakes=always (obstacle_0.clearance > -1)",
        "--out",
        log.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(stdout(&o).contains("requirement brakes: satisfied"), "{}", stdout(&o));
    let o = mjsafe(&["analyze", log.to_str().unwrap(), "--require", "slow=always (speed < 1)"]);
    assert!(o.status.success(), "{}", text(&o));
    let table = stdout(&o);
    let header = table.lines().next().unwrap();
    assert!(header.contains("req.brakes") && header.contains("req.slow"), "{table}");
    assert!(table.lines().nth(1).unwrap().contains("VIOLATED"), "{table}");
}

#[test]
fn falsify_names_a_missing_requirement_or_its_unknown_signal() {
    let dir = tempfile::tempdir().unwrap();
    let base: [String; 10] = [
        "falsify".into(),
        scenario("bicycle_obstacle_gamma_m.toml").to_str().unwrap().to_string(),
        "--range".into(),
        "delays.acceleration=0.5..2.0:0.1".into(),
        "--budget".into(),
        "4".into(),
        "--out".into(),
        dir.path().join("f").to_str().unwrap().to_string(),
        "--objective".into(),
        "req.brakes".into(),
    ];
    let with = |extra: &[&str]| {
        let mut args: Vec<&str> = base.iter().map(String::as_str).collect();
        args.extend_from_slice(extra);
        mjsafe(&args)
    };
    let o = with(&[]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(stderr(&o).contains("no requirement `brakes`"), "{}", stderr(&o));
    let o = with(&["--require", "brakes=always (obstacle_0.clearence > 0)"]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        stderr(&o).contains("unknown signal `obstacle_0.clearence` (did you mean"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn a_sweep_file_given_to_run_and_a_set_on_a_swept_key_are_refused() {
    let sweep = scenario("ncap_ccrm.sweep.toml");
    let o = mjsafe(&["run", sweep.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    // Before: "unknown field `scenario`".
    assert!(stderr(&o).contains("this is a sweep file"), "{}", stderr(&o));
    assert!(stderr(&o).contains("mjsafe sweep --sweep"), "{}", stderr(&o));
    // Before: the --set silently replaced the axis's value in all 110 runs.
    let o = mjsafe(&[
        "sweep",
        "--sweep",
        sweep.to_str().unwrap(),
        "--set",
        "actor_knowledge.kind='constant_velocity'",
        "--no-logs",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        stderr(&o).contains("the sweep sweeps `actor_knowledge.kind`"),
        "{}",
        stderr(&o)
    );
    // A table holding the swept key is refused too; a key the sweep does not sweep is fine.
    let o = mjsafe(&[
        "sweep",
        "--sweep",
        sweep.to_str().unwrap(),
        "--set",
        "actor_knowledge={kind='static'}",
        "--no-logs",
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
}

#[test]
fn falsify_says_when_no_candidate_qualified_and_so_nothing_was_proved() {
    let dir = tempfile::tempdir().unwrap();
    // A baseline threshold no run reaches: no candidate ever qualifies.
    let o = mjsafe(&[
        "falsify",
        scenario("bicycle_obstacle_gamma_m.toml").to_str().unwrap(),
        "--range",
        "delays.acceleration=0.5..0.7:0.1",
        "--baseline",
        "obstacles.0.centre.1=0.0",
        "--baseline-threshold",
        "1000",
        "--budget",
        "4",
        "--out",
        dir.path().join("f").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let out = stdout(&o);
    // Before: "no counterexample within 4 runs", as if the box had been searched.
    assert!(out.contains("4 runs, 0 qualified"), "{out}");
    assert!(
        out.contains("no counterexample, and none of the 4 candidates qualified: this proves nothing about the box"),
        "{out}"
    );
}

/// A violation lies beyond `--tolerance` (default 1e-4 of the objective's unit): a graze is
/// not a counterexample unless asked for with `--tolerance 0`.
#[test]
fn a_graze_within_the_tolerance_is_not_a_violation() {
    let dir = tempfile::tempdir().unwrap();
    // The γm bicycle as committed: min h = 0.024 m². A threshold 5e-5 above its min h makes it
    // a graze of 5e-5 (within the tolerance), and 2e-4 above it a violation.
    let search = |threshold: f64, tolerance: Option<&str>, name: &str| {
        let threshold = format!("{}", 0.024274766 + threshold);
        let out = dir.path().join(name);
        let mut args = vec![
            "falsify",
            "--range",
            "seed=0..1:1",
            "--budget",
            "1",
            "--method",
            "random",
            "--threshold",
            &threshold,
            "--out",
            out.to_str().unwrap(),
        ];
        if let Some(t) = tolerance {
            args.extend_from_slice(&["--tolerance", t]);
        }
        let s = scenario("bicycle_obstacle_gamma_m.toml");
        let mut all = vec![args[0], s.to_str().unwrap()];
        all.extend_from_slice(&args[1..]);
        let o = mjsafe(&all);
        assert!(o.status.success(), "{}", text(&o));
        stdout(&o)
    };
    assert!(search(5e-5, None, "graze").contains("no counterexample"));
    assert!(search(5e-5, Some("0"), "strict").contains("violation: index 0"));
    assert!(search(2e-4, None, "beyond").contains("violation: index 0"));
}

/// The README's falsify example without a baseline: its first violation is an obstacle that
/// appears too close to avoid within the delay; the search says so.
#[test]
fn a_violation_within_the_delay_after_an_obstacle_appears_is_flagged() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f");
    let o = mjsafe(&[
        "falsify",
        scenario("bicycle_obstacle_gamma_m.toml").to_str().unwrap(),
        "--range",
        "vehicle.initial_state.0=-26..-16",
        "--range",
        "obstacles.0.centre.1=-3..3",
        "--range",
        "delays.acceleration=0.5..2.0:0.1",
        "--budget",
        "60",
        "--seed",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let said = stdout(&o);
    assert!(said.contains("within the delay after an obstacle appeared"), "{said}");
    // The flag is the run's own metric: the counterexample's log says the same.
    let metrics: serde_json::Value = serde_json::from_str(&stdout(&mjsafe(&[
        "analyze",
        "--json",
        out.join("counterexample.mcap").to_str().unwrap(),
    ])))
    .unwrap();
    let within = metrics[0]["delay_attributed_violation_time"].as_f64().unwrap();
    assert!(within > 0.0, "{metrics}");
}
