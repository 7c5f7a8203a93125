//! Moving obstacles on the MuJoCo plant (mocap bodies moved to the actor's true position before
//! every step), checked on the real binary against the ODE plant and the logged clearances.

mod common;
use common::*;
use mjsafe::log::proto;
use std::path::{Path, PathBuf};

/// The bicycle's MuJoCo step (models/bicycle.xml).
const STEP: f64 = 0.002;

/// The bicycle driving along y = 0 at 3 m/s towards a pedestrian (radius 1 m) crossing from
/// [0, −12] at 1.4 m/s; `delays` and `filter` are TOML tables' bodies.
fn crossing(dir: &Path, name: &str, plant: &str, delays: [f64; 2], filter: &str) -> PathBuf {
    let text = format!(
        r#"
name = "{name}"
duration = 10.0
plant = "{plant}"
[vehicle]
kind = "bicycle"
model = "{model}"
initial_state = [-20.0, 0.0, 0.0, 3.0]
[delays]
steering = {steering}
acceleration = {acceleration}
[initial_input]
steering = 0.0
acceleration = 0.0
[control]
period = 0.01
[nominal]
kind = "path_lqr"
reference_speed = 3.0
path_point = [0.0, 0.0]
path_heading = 0.0
[filter]
{filter}
[[obstacles]]
name = "pedestrian"
centre = [0.0, -12.0]
radius = 1.0
[obstacles.motion]
direction = [0.0, 1.0]
speed = 1.4
"#,
        model = root().join("models/bicycle.xml").display(),
        steering = delays[0],
        acceleration = delays[1],
    );
    write(dir, &format!("{name}.toml"), &text)
}

fn collision_events(log: &Path) -> Vec<proto::Event> {
    read_topic::<proto::Event>(log, "/event")
        .into_iter()
        .filter(|e| e.kind.starts_with("collision"))
        .collect()
}

fn collision_start(log: &Path) -> Option<f64> {
    collision_events(log)
        .iter()
        .find(|e| e.kind == "collision_start")
        .map(|e| e.time)
}

/// (a) Without a filter both plants hit the pedestrian, within a few steps of each other. On
/// a plant whose obstacle stayed at its start, the vehicle would pass in front of it.
#[test]
fn an_unfiltered_vehicle_hits_the_crossing_pedestrian_on_both_plants_at_the_same_time() {
    let dir = tempfile::tempdir().unwrap();
    let mut starts = Vec::new();
    for plant in ["mujoco", "ode"] {
        let scenario = crossing(dir.path(), plant, plant, [0.0, 0.0], "kind = \"none\"");
        let log = dir.path().join(format!("{plant}.mcap"));
        let out = run_ok(&scenario, &log, &[]);
        assert!(out.contains("COLLISION"), "{plant}: {out}");
        starts.push(collision_start(&log).expect("a collision_start event"));
    }
    println!("collision_start: mujoco {} s, ode {} s", starts[0], starts[1]);
    // x = −20 + 3 t meets y = −12 + 1.4 t at 4 m (hull 3 + pedestrian 1) near t = 6.05 s.
    assert!((6.0..6.1).contains(&starts[0]), "{starts:?}");
    assert!((starts[0] - starts[1]).abs() <= 3.0 * STEP + 1e-9, "{starts:?}");
}

/// (b) MuJoCo's contacts are with the sphere where the actor truly is at each step: every
/// collision event is at a sign change of the logged clearance (computed from the true
/// centres), and a start's depth is that state's −clearance (two spheres: exact).
#[test]
fn mujoco_contacts_follow_the_actor_s_true_position() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = crossing(dir.path(), "contacts", "mujoco", [0.0, 0.0], "kind = \"none\"");
    let log = dir.path().join("contacts.mcap");
    run_ok(&scenario, &log, &[]);
    let clearance: Vec<(f64, f64)> = read_topic::<proto::Barrier>(&log, "/barrier")
        .iter()
        .filter_map(|b| {
            let value = b.barriers.iter().find(|v| v.name == "pedestrian")?;
            Some((b.time, value.clearance))
        })
        .collect();
    let mut expected = Vec::new();
    let mut touching = false;
    for &(time, c) in &clearance {
        if (c < 0.0) != touching {
            touching = c < 0.0;
            expected.push((if touching { "collision_start" } else { "collision_end" }, time, -c));
        }
    }
    let events = collision_events(&log);
    assert!(!expected.is_empty(), "the vehicle overlaps the pedestrian");
    for (i, (kind, time, depth)) in expected.iter().enumerate() {
        let event = &events[i];
        assert_eq!(
            (event.kind.as_str(), event.time),
            (*kind, *time),
            "event {i}: {event:?}"
        );
        if *kind == "collision_start" {
            assert!((event.depth - depth).abs() < 1e-9, "{event:?} against {depth}");
        }
    }
}

/// (c) The variable-channel γm filter (4.67) with the delays of
/// scenarios/bicycle_obstacle_gamma_m.toml, predicting the pedestrian at constant velocity,
/// avoids it on MuJoCo as on the ODE plant; assuming it static does not.
#[test]
fn the_gamma_m_filter_with_constant_velocity_knowledge_avoids_the_pedestrian_on_mujoco() {
    let dir = tempfile::tempdir().unwrap();
    let gamma_m = "kind = \"gamma_m\"\nl0 = 4.0\nl1 = 4.0\nm = 50.0";
    for (plant, knowledge, collides) in [
        ("mujoco", "constant_velocity", false),
        ("ode", "constant_velocity", false),
        ("mujoco", "static", true),
    ] {
        let filter = format!("{gamma_m}\n[actor_knowledge]\nkind = \"{knowledge}\"");
        let name = format!("{plant}_{knowledge}");
        let scenario = crossing(dir.path(), &name, plant, [0.2, 1.5], &filter);
        let log = dir.path().join(format!("{name}.mcap"));
        run_ok(&scenario, &log, &[]);
        let m = analyze_json(&log);
        println!("{name}: collision {}, min h = {}", m["collision"], m["min_h"]);
        assert_eq!(m["complete"], true, "{name}: {m}");
        assert_eq!(!m["collision"].is_null(), collides, "{name}: {m}");
        assert_eq!(collision_start(&log).is_some(), collides, "{name}");
    }
}

/// The MuJoCo run with a moving obstacle is deterministic: the same scenario, the same bytes.
#[test]
fn the_mujoco_run_with_a_moving_obstacle_gives_byte_identical_logs() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = crossing(dir.path(), "twice", "mujoco", [0.0, 0.0], "kind = \"none\"");
    let (a, b) = (dir.path().join("a.mcap"), dir.path().join("b.mcap"));
    run_ok(&scenario, &a, &[]);
    run_ok(&scenario, &b, &[]);
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(), "logs differ");
}
