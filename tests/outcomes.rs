//! Outcomes the reference states, checked on the real binary and its logs.

mod common;
use common::*;

/// min h tolerance for "no collision": integration and model error of the MuJoCo bicycle
/// (fidelity test: ~1e-3 m of position error over 10 s, so h = d² − r² moves by ~2·6·1e-3).
const H_TOLERANCE: f64 = 0.02;

#[test]
fn nodelay_bicycle_avoids_the_obstacle() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("nodelay.mcap");
    let out = run_ok(&scenario("bicycle_obstacle_nodelay.toml"), &log, &[]);
    assert!(out.contains("no collision"), "{out}");
    let m = analyze_json(&log);
    println!(
        "bicycle_obstacle_nodelay: min h = {}, filter active {}",
        m["min_h"], m["filter_active_fraction"]
    );
    assert!(m["collision"].is_null(), "{m}");
    assert!(m["min_h"].as_f64().unwrap() >= -H_TOLERANCE, "{m}");
    assert!(
        m["filter_active_fraction"].as_f64().unwrap() > 0.0,
        "the filter must have acted: {m}"
    );
    assert_eq!(m["complete"], true);
}

#[test]
fn delayed_bicycle_with_delay_free_filter_hits_the_obstacle() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("delayed.mcap");
    let out = run_ok(&scenario("bicycle_obstacle.toml"), &log, &[]);
    assert!(out.contains("COLLISION"), "{out}");
    let m = analyze_json(&log);
    println!("bicycle_obstacle: collision {}, min h = {}", m["collision"], m["min_h"]);
    let t = m["collision"]["time"].as_f64().unwrap();
    // The obstacle is known from 2.75 s; the first delayed steering input arrives at 2.95 s.
    assert!(t > 2.75, "collision at {t}");
    assert!(m["min_h"].as_f64().unwrap() < -H_TOLERANCE, "{m}");
    assert_eq!(m["collision"]["with"], "obstacle_0");
}

#[test]
fn without_the_obstacle_known_the_nominal_tracks_the_path() {
    // The obstacle never becomes known: pure path tracking at the reference speed.
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("track.mcap");
    run_ok(
        &scenario("bicycle_obstacle_nodelay.toml"),
        &log,
        &[
            "--set",
            "obstacles.0.appear_at=100.0",
            "--set",
            "vehicle.initial_state=[-20.0, 1.0, 0.2, 2.0]",
        ],
    );
    let m = analyze_json(&log);
    assert_eq!(m["filter_active_fraction"], 0.0);
    // It drives into the obstacle on y = 0, which the controller never learns about.
    assert!(!m["collision"].is_null(), "{m}");
}
