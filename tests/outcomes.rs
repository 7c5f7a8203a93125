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

/// Contact events carry the time of the state whose overlap they report: on both plants the
/// first `collision_start` is at the first `/barrier` time with negative clearance, each
/// `collision_end` at the next time the clearance is back to ≥ 0, and on the ODE plant (the
/// overlap of circles) the start's depth is that state's −clearance.
#[test]
fn collision_events_carry_the_time_of_the_state_they_measure() {
    use mjsafe::log::proto;
    let dir = tempfile::tempdir().unwrap();
    for plant in ["mujoco", "ode"] {
        let log = dir.path().join(format!("{plant}.mcap"));
        let set_plant = format!("plant='{plant}'");
        run_ok(&scenario("bicycle_obstacle.toml"), &log, &["--set", &set_plant]);
        // (time, clearance) of obstacle_0 at every step.
        let clearance: Vec<(f64, f64)> = read_topic::<proto::Barrier>(&log, "/barrier")
            .iter()
            .filter_map(|b| {
                let value = b.barriers.iter().find(|v| v.name == "obstacle_0" && v.known)?;
                Some((b.time, value.clearance))
            })
            .collect();
        // Sign changes: into contact (clearance < 0) and out of it.
        let mut expected = Vec::new();
        let mut touching = false;
        for &(time, c) in &clearance {
            if (c < 0.0) != touching {
                touching = c < 0.0;
                expected.push((if touching { "collision_start" } else { "collision_end" }, time, -c));
            }
        }
        let events: Vec<proto::Event> = read_topic::<proto::Event>(&log, "/event")
            .into_iter()
            .filter(|e| e.kind.starts_with("collision"))
            .collect();
        assert!(!expected.is_empty(), "{plant}: bicycle_obstacle collides");
        // The last end may be the episode's own (a run ending in contact).
        for (i, (kind, time, depth)) in expected.iter().enumerate() {
            let event = &events[i];
            assert_eq!(
                (event.kind.as_str(), event.time),
                (*kind, *time),
                "{plant}: event {i}: {event:?}"
            );
            if plant == "ode" && *kind == "collision_start" {
                assert!(
                    (event.depth - depth).abs() < 1e-12,
                    "{plant}: {event:?} against {depth}"
                );
            }
        }
    }
}
