//! A MuJoCo runtime error (`mju_error` inside `mj_step`) ends that run only: the run stops with
//! an `/event` error carrying MuJoCo's message, its log is finished as incomplete, `run` exits
//! 1, and a sweep records the error in that row and finishes the others. The model:
//! tests/data/pebbles.xml (a bicycle driving into pebbles whose contacts overflow a stack of
//! 1000 doubles at t ≈ 6.3 s).

mod common;

use common::{mjsafe, root, stderr, stdout};

fn scenario() -> String {
    root().join("tests/data/mujoco_error.toml").display().to_string()
}

#[test]
fn a_mujoco_error_ends_the_run_with_its_message_and_an_incomplete_log() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("error.mcap");
    let o = mjsafe(&["run", &scenario(), "--out", log.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("error: the episode stopped early: MuJoCo stopped the step at t = 6.")
            && err.contains("with an error: Stack overflow"),
        "{err}"
    );
    // The log is there, whole and readable, and says the run is incomplete with the error.
    let metrics = common::analyze_json(&log);
    assert_eq!(metrics["complete"], false, "{metrics}");
    let error = metrics["error"].as_str().unwrap_or_default();
    assert!(error.contains("Stack overflow"), "{metrics}");
    let simulated = metrics["simulated_time"].as_f64().unwrap();
    assert!((6.0..6.6).contains(&simulated), "{simulated}");
    // The same scenario beside the pebbles runs to its end in the same kind of process.
    let o = mjsafe(&[
        "run",
        &scenario(),
        "--set",
        "vehicle.initial_state.1=30.0",
        "--out",
        dir.path().join("clear.mcap").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn a_sweep_records_one_runs_mujoco_error_and_finishes_the_others() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sweep");
    let o = mjsafe(&[
        "sweep",
        &scenario(),
        "--grid",
        "vehicle.initial_state.1=30.0,0.0,-30.0",
        "--threads",
        "2",
        "--out",
        out.to_str().unwrap(),
    ]);
    // Exit 3: some runs failed (their rows hold the error); the summary is written.
    assert_eq!(o.status.code(), Some(3), "{}{}", stdout(&o), stderr(&o));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let rows = summary["runs"].as_array().expect("runs");
    assert_eq!(rows.len(), 3, "{summary}");
    let errors: Vec<String> = rows
        .iter()
        .map(|r| r["error"].as_str().unwrap_or_default().to_string())
        .collect();
    assert!(errors[0].is_empty() && errors[2].is_empty(), "{errors:?}");
    assert!(
        errors[1].contains("MuJoCo stopped the step") && errors[1].contains("Stack overflow"),
        "{errors:?}"
    );
    for k in 0..3 {
        assert!(out.join(format!("mujoco_error-00{k}.mcap")).is_file());
    }
}
