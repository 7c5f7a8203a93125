//! Metrics a run does not have are absent (null), never 0 from a default; a run that ends in
//! contact reports its deepest penetration, not the depth at first contact.

mod common;
use common::*;

fn run(dir: &std::path::Path, name: &str, sets: &[&str]) -> serde_json::Value {
    let log = dir.join(format!("{name}.mcap"));
    let scenario = root().join("scenarios/bicycle_obstacle.toml");
    let mut args = vec!["run", scenario.to_str().unwrap(), "--out", log.to_str().unwrap()];
    for s in sets {
        args.extend(["--set", s]);
    }
    let o = mjsafe(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    analyze_json(&log)
}

#[test]
fn a_run_that_ends_in_contact_reports_its_deepest_penetration() {
    let dir = tempfile::tempdir().unwrap();
    // The bicycle hits the obstacle at 3.684 s and is still inside it at 5 s.
    let m = run(dir.path(), "mid", &["duration=5.0"]);
    let depth = m["collision"]["depth"].as_f64().unwrap();
    let clearance = m["min_clearance"].as_f64().unwrap();
    // The depth is the contact distance, the clearance its negative (equal on every closed
    // contact); at first contact the depth was 3 mm.
    assert!(depth > 1.0, "{m}");
    assert!(
        (depth + clearance).abs() < 1e-9,
        "depth {depth} vs clearance {clearance}"
    );
    // Cut at 5 s the run has not reached its goal: only that is missing (tests/progress.rs).
    let missing = m
        .get("missing")
        .and_then(|m| m.as_object())
        .cloned()
        .unwrap_or_default();
    assert!(missing.keys().all(|k| k == "time_to_goal"), "{m}");
}

#[test]
fn metrics_without_the_data_they_need_are_null() {
    let dir = tempfile::tempdir().unwrap();
    // No filter: never an override, so no pair of commands around one.
    let m = run(dir.path(), "none", &["filter={kind='none'}"]);
    assert!(m["first_override_time"].is_null(), "{m}");
    assert!(m["max_input_rate_overriding"].is_null(), "{m}");
    let rates = m["max_input_rate"].as_object().unwrap();
    assert!(
        rates.len() == 2 && rates.values().any(|r| r.as_f64().unwrap() > 0.0),
        "{m}"
    );
    // One step: one command, no rate of change.
    let m = run(dir.path(), "one", &["duration=0.002"]);
    assert!(
        m["max_input_rate"].is_null() && m["max_input_rate_overriding"].is_null(),
        "{m}"
    );
    // No obstacle and no barrier: nothing to be outside of, nothing that appeared.
    let m = run(dir.path(), "free", &["obstacles=[]"]);
    for metric in [
        "min_h",
        "time_h_negative",
        "min_clearance",
        "delay_attributed_violation_time",
    ] {
        assert!(m[metric].is_null(), "{metric}: {m}");
    }
    // With the obstacle they are numbers, 0 included.
    let m = run(dir.path(), "with", &[]);
    assert!(m["time_h_negative"].as_f64().unwrap() > 0.0, "{m}");
    assert!(m["delay_attributed_violation_time"].as_f64().is_some(), "{m}");
}

/// A prescribed-time run that ends at or before T has no values at T: each is null with its
/// reason, never a silent gap.
#[test]
fn values_at_the_prescribed_time_are_null_with_a_reason_when_the_run_does_not_reach_them() {
    let dir = tempfile::tempdir().unwrap();
    let at = |m: &serde_json::Value, key: &str| m["at_prescribed_time"][key].clone();
    let red_light = |sets: &[&str]| {
        let log = dir.path().join(format!("red_light-{}.mcap", sets.join("-")));
        let mut extra = Vec::new();
        for s in sets {
            extra.extend(["--set", s]);
        }
        run_ok(&scenario("red_light.toml"), &log, &extra);
        analyze_json(&log)
    };
    // T = 4 s (red_light): ends at T, before T, after T.
    let ends_at_t = red_light(&["duration=4.0"]);
    assert!(at(&ends_at_t, "barrier").is_null() && at(&ends_at_t, "input_residual").is_null());
    assert_eq!(
        at(&ends_at_t, "state_residuals").as_array().unwrap().len(),
        2,
        "the final state is at T"
    );
    let reason = ends_at_t["missing"]["at_prescribed_time.barrier"].as_str().unwrap();
    assert!(reason.contains("the run ends at T"), "{reason}");
    assert!(ends_at_t["missing"]["at_prescribed_time.input_residual"].is_string());

    let before = red_light(&["duration=2.0"]);
    for key in ["barrier", "state_residuals", "input_residual"] {
        let reason = before["missing"][format!("at_prescribed_time.{key}")]
            .as_str()
            .unwrap_or_else(|| panic!("{key}: {before}"));
        assert!(reason.contains("ends before T, at t = 2 s"), "{reason}");
    }

    let after = red_light(&[]);
    assert!(after["missing"].is_null(), "{after}");
    assert!(at(&after, "barrier").is_f64() && at(&after, "input_residual").is_f64());
}
