//! Box obstacles, the vehicle's footprint and a lead to follow on the MuJoCo plant
//! (docs/actors.md, "On MuJoCo"): contacts and depths from MuJoCo's own box geoms, checked on
//! the real binary against the ODE plant (covering circles, the headway's gap) and against an
//! exact overlap test of the shapes at the logged states, independent of both.

mod common;
use common::*;

use mjsafe::log::proto;
use std::path::{Path, PathBuf};

/// The bicycle's MuJoCo step (models/bicycle.xml).
const STEP: f64 = 0.002;
/// The car's footprint and the Euro NCAP car target (tests/footprint.rs).
const CAR: [f64; 2] = [4.6, 1.8];
const BOX: [f64; 2] = [4.02, 1.71];
/// The bicycle's hull radius (models/bicycle.xml).
const HULL: f64 = 3.0;
/// How far the covering circles reach beyond their rectangle at most, beside it (ρ − W/2) or
/// beyond its ends (ρ − L/2n), recomputed here from the rule of docs/actors.md.
fn overreach([length, width]: [f64; 2]) -> f64 {
    let n = (length / width).ceil();
    let rho = ((length / (2.0 * n)).powi(2) + (width / 2.0).powi(2)).sqrt();
    (rho - width / 2.0).max(rho - length / (2.0 * n))
}

/// The obstacle: a static box at `centre` turned by `heading`, or a box starting there and
/// moving along +y at `speed` (its heading then π/2, its motion's direction).
#[derive(Clone, Copy)]
enum Target {
    Static { centre: [f64; 2], heading: f64 },
    Crossing { centre: [f64; 2], speed: f64 },
}

/// The bicycle on `plant` driving along y = 0 at 3 m/s from x = −20, with the car's footprint
/// or its 3 m hull circle, towards `target`, no safety filter.
fn bicycle(dir: &Path, name: &str, plant: &str, footprint: bool, target: Target) -> PathBuf {
    let footprint = if footprint {
        format!("footprint = {{ length = {}, width = {} }}", CAR[0], CAR[1])
    } else {
        String::new()
    };
    let obstacle = match target {
        Target::Static { centre, heading } => format!(
            "centre = [{}, {}]\nshape = {{ kind = \"box\", length = {}, width = {}, heading = {heading} }}\n",
            centre[0], centre[1], BOX[0], BOX[1]
        ),
        Target::Crossing { centre, speed } => format!(
            "centre = [{}, {}]\nshape = {{ kind = \"box\", length = {}, width = {} }}\n[obstacles.motion]\ndirection = [0.0, 1.0]\nspeed = {speed}\n",
            centre[0], centre[1], BOX[0], BOX[1]
        ),
    };
    let text = format!(
        r#"
name = "{name}"
duration = 10.0
plant = "{plant}"
[vehicle]
kind = "bicycle"
model = "{model}"
timestep = {STEP}
{footprint}
initial_state = [-20.0, 0.0, 0.0, 3.0]
[control]
period = 0.01
[nominal]
kind = "path_lqr"
reference_speed = 3.0
path_point = [0.0, 0.0]
path_heading = 0.0
[filter]
kind = "none"
[[obstacles]]
name = "box"
{obstacle}"#,
        model = root().join("models/bicycle.xml").display(),
    );
    write(dir, &format!("{name}.toml"), &text)
}

fn run(scenario: &Path) -> PathBuf {
    let log = scenario.with_extension("mcap");
    run_ok(scenario, &log, &[]);
    log
}

fn events(log: &Path, kind: &str) -> Vec<proto::Event> {
    read_topic::<proto::Event>(log, "/event")
        .into_iter()
        .filter(|e| e.kind == kind)
        .collect()
}

/// A rectangle's corners: centre, heading, [length, width].
fn corners(centre: [f64; 2], heading: f64, [l, w]: [f64; 2]) -> [[f64; 2]; 4] {
    let (s, c) = heading.sin_cos();
    [[0.5, 0.5], [-0.5, 0.5], [-0.5, -0.5], [0.5, -0.5]].map(|[u, v]| {
        let (u, v) = (u * l, v * w);
        [centre[0] + c * u - s * v, centre[1] + s * u + c * v]
    })
}

/// How deep two rectangles overlap along their least-overlapping axis (separating axis test;
/// negative when apart).
fn rectangles_overlap(a: [[f64; 2]; 4], b: [[f64; 2]; 4]) -> f64 {
    let axes = [a[0], a[1], a[0], a[3], b[0], b[1], b[0], b[3]];
    (0..4)
        .map(|k| {
            let (p, q) = (axes[2 * k], axes[2 * k + 1]);
            let d = [q[0] - p[0], q[1] - p[1]];
            let n = d[0].hypot(d[1]);
            let axis = [-d[1] / n, d[0] / n];
            let project = |r: &[[f64; 2]; 4]| {
                let values = r.map(|c| c[0] * axis[0] + c[1] * axis[1]);
                (
                    values.iter().copied().fold(f64::INFINITY, f64::min),
                    values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                )
            };
            let ((a0, a1), (b0, b1)) = (project(&a), project(&b));
            a1.min(b1) - a0.max(b0)
        })
        .fold(f64::INFINITY, f64::min)
}

/// How deep a circle reaches into a rectangle (r minus the distance from its centre to the
/// rectangle; negative when apart), the rectangle given by centre, heading and size.
fn circle_into_rectangle(p: [f64; 2], r: f64, (centre, heading, [l, w]): ([f64; 2], f64, [f64; 2])) -> f64 {
    let (s, c) = heading.sin_cos();
    let (dx, dy) = (p[0] - centre[0], p[1] - centre[1]);
    let (u, v) = (c * dx + s * dy, -s * dx + c * dy);
    let outside = [(u.abs() - l / 2.0).max(0.0), (v.abs() - w / 2.0).max(0.0)];
    r - outside[0].hypot(outside[1])
}

/// Per logged state (time, overlap depth of the vehicle's exact shape with the box's exact
/// shape), the box at its logged position (/actors) when it moves.
fn exact_overlaps(log: &Path, footprint: bool, target: Target) -> Vec<(f64, f64)> {
    let actors = read_topic::<proto::Actors>(log, "/actors");
    read_topic::<proto::State>(log, "/state")
        .iter()
        .map(|s| {
            let (p, heading) = ([s.values[0], s.values[1]], s.values[2]);
            let (centre, box_heading) = match target {
                Target::Static { centre, heading } => (centre, heading),
                Target::Crossing { .. } => {
                    let a = actors
                        .iter()
                        .find(|a| a.time == s.time)
                        .expect("an /actors record per state");
                    ([a.actors[0].x, a.actors[0].y], std::f64::consts::FRAC_PI_2)
                }
            };
            let depth = if footprint {
                rectangles_overlap(corners(p, heading, CAR), corners(centre, box_heading, BOX))
            } else {
                circle_into_rectangle(p, HULL, (centre, box_heading, BOX))
            };
            (s.time, depth)
        })
        .collect()
}

fn first_overlap(overlaps: &[(f64, f64)]) -> f64 {
    overlaps.iter().find(|(_, d)| *d > 0.0).expect("the shapes overlap").0
}

/// A static box turned by 0.3 rad reaching into the path, and a box crossing it: on MuJoCo the
/// first contact is where the exact shapes first overlap at the logged states (with the hull
/// sphere or the footprint's box), deeper than 0; the ODE plant's covering circles touch
/// earlier, by at most their overreach at the closing speed.
#[test]
fn static_and_moving_boxes_are_hit_on_mujoco_where_the_exact_shapes_first_overlap() {
    let dir = tempfile::tempdir().unwrap();
    let targets = [
        (
            "static",
            Target::Static {
                centre: [0.0, 1.255],
                heading: 0.3,
            },
        ),
        (
            "crossing",
            Target::Crossing {
                centre: [0.0, -12.0],
                speed: 1.4,
            },
        ),
    ];
    for (target_name, target) in targets {
        for footprint in [false, true] {
            let name = format!("{target_name}_{}", if footprint { "footprint" } else { "hull" });
            let mut starts = Vec::new();
            for plant in ["ode", "mujoco"] {
                let log = run(&bicycle(
                    dir.path(),
                    &format!("{name}_{plant}"),
                    plant,
                    footprint,
                    target,
                ));
                let start = events(&log, "collision_start").first().cloned().expect("a collision");
                assert_eq!(start.participants, ["vehicle", "box"]);
                starts.push((start, exact_overlaps(&log, footprint, target)));
            }
            let [(ode, ode_exact), (mujoco, mujoco_exact)] = &starts[..] else {
                unreachable!()
            };
            let (ode_geometry, mujoco_geometry) = (first_overlap(ode_exact), first_overlap(mujoco_exact));
            let exact_depth = mujoco_exact.iter().find(|(t, _)| *t == mujoco.time).unwrap().1;
            println!(
                "{name}: collision_start ode {:.3} s (depth {:.2e} m), mujoco {:.3} s (depth {:.2e} m, exact overlap {:.2e} m); exact shapes first overlap at {:.3} s (ode states), {:.3} s (mujoco states)",
                ode.time, ode.depth, mujoco.time, mujoco.depth, exact_depth, ode_geometry, mujoco_geometry
            );
            // MuJoCo: at the first state whose exact shapes overlap, and as deep as they do.
            assert!((mujoco.time - mujoco_geometry).abs() <= STEP + 1e-9, "{name}");
            assert!(mujoco.depth > 0.0, "{name}: {mujoco:?}");
            assert!(exact_depth > 0.0 && exact_depth < 0.05, "{name}: {exact_depth}");
            // Sphere and box: MuJoCo's depth; box and box: the boxes' exact penetration
            // (MuJoCo 2.2.2's collider reports half of it; docs/actors.md, "On MuJoCo").
            assert!(
                (mujoco.depth - exact_depth).abs() < 1e-6,
                "{name}: {} vs {exact_depth}",
                mujoco.depth
            );
            // ODE: the circles reach out first, by at most their overreach at the closing speed
            // (at least the car's 3 m/s towards the static box; the crossing box's 1.4 m/s
            // towards the car's side).
            let reach = overreach(BOX) + if footprint { overreach(CAR) } else { 0.0 };
            let closing = match target {
                Target::Static { .. } => 3.0,
                Target::Crossing { speed, .. } => speed,
            };
            assert!(ode.time <= ode_geometry + 1e-9, "{name}");
            assert!(ode.time <= mujoco.time, "{name}");
            assert!(
                mujoco.time - ode.time <= reach / closing + (mujoco_geometry - ode_geometry).abs() + 2.0 * STEP,
                "{name}: {} vs {} (overreach {reach} m)",
                mujoco.time,
                ode.time
            );
            // The two plants' trajectories agree: the exact shapes meet within a few steps.
            assert!((mujoco_geometry - ode_geometry).abs() <= 5.0 * STEP, "{name}");
        }
    }
}

/// tests/footprint.rs `the_car_passes_a_box_the_hull_circle_cannot` on MuJoCo: the box's edge
/// 1.5 m beside the car's side; the footprint's box never touches it (no contact, and the exact
/// rectangles never overlap), the 3 m hull sphere without a footprint does.
#[test]
fn the_footprint_on_mujoco_passes_a_box_the_hull_would_hit() {
    let dir = tempfile::tempdir().unwrap();
    let beside = Target::Static {
        centre: [0.0, CAR[1] / 2.0 + 1.5 + BOX[1] / 2.0],
        heading: 0.0,
    };
    let car = run(&bicycle(dir.path(), "car", "mujoco", true, beside));
    assert!(analyze_json(&car)["collision"].is_null());
    assert!(events(&car, "collision_start").is_empty());
    let overlaps = exact_overlaps(&car, true, beside);
    assert!(
        overlaps.iter().all(|(_, d)| *d < -1.0),
        "the rectangles stay 1.5 m apart"
    );
    // It drove past the box on its path: nothing pushed it aside (the hull sphere, which would
    // reach the box, collides with nothing once the footprint's box takes its contacts).
    let states = read_topic::<proto::State>(&car, "/state");
    assert!(states.last().unwrap().values[0] > 5.0);
    let lateral = states.iter().map(|s| s.values[1].abs()).fold(0.0, f64::max);
    println!("beside: the footprint's largest lateral offset {lateral:.2e} m");
    assert!(lateral < 1e-3, "{lateral}");

    let hull = run(&bicycle(dir.path(), "hull", "mujoco", false, beside));
    let start = events(&hull, "collision_start");
    assert_eq!(start.len(), 1, "{start:?}");
    let exact = exact_overlaps(&hull, false, beside);
    assert!((start[0].time - first_overlap(&exact)).abs() <= STEP + 1e-9);
    println!(
        "beside: the hull sphere touches at {:.3} s ({:.4} m deep); the footprint never (closest {:.3} m)",
        start[0].time,
        start[0].depth,
        -overlaps.iter().map(|(_, d)| *d).fold(f64::NEG_INFINITY, f64::max)
    );
}

/// scenarios/molnar_truck.toml (a lead braking to a stop at up to 10 m/s²) with `plant` and
/// `sets`.
fn truck(dir: &Path, name: &str, plant: &str, sets: &[&str]) -> PathBuf {
    truck_with(dir, name, plant, sets, "radius = 2.0")
}

/// As [`truck`] with the lead's `radius = 2.0` line replaced by `lead`.
fn truck_with(dir: &Path, name: &str, plant: &str, sets: &[&str], lead: &str) -> PathBuf {
    let text = std::fs::read_to_string(scenario("molnar_truck.toml")).unwrap();
    let model = root().join("models/double_integrator_1d.xml");
    let text = text
        .replace(
            "\"../models/double_integrator_1d.xml\"",
            &format!("{:?}", model.to_str().unwrap()),
        )
        .replace("radius = 2.0", lead);
    let file = write(dir, &format!("{name}.toml"), &text);
    let log = dir.join(format!("{name}.mcap"));
    let plant = format!("plant=\"{plant}\"");
    let mut extra = vec!["--set", &plant];
    for s in sets {
        extra.extend_from_slice(&["--set", s]);
    }
    run_ok(&file, &log, &extra);
    log
}

/// The first time the logged gap to the lead (`clearance` of its headway barrier) is < 0.
fn gap_closes(log: &Path) -> f64 {
    read_topic::<proto::Barrier>(log, "/barrier")
        .iter()
        .find(|b| b.barriers.iter().any(|v| v.name == "lead" && v.clearance < 0.0))
        .expect("the gap closes")
        .time
}

/// A braking lead on MuJoCo (a mocap sphere on the truck's line, the truck's contact box ending
/// at its position): without a filter the contact comes when the gap reaches 0, as on the ODE
/// plant (within two steps: under RK4 MuJoCo's contacts after a step are those of its last
/// stage, near the step's end); the predictor CBF-QP keeps the headway and touches nothing.
#[test]
fn a_braking_lead_on_mujoco_is_hit_when_the_gap_closes_unless_the_filter_keeps_the_headway() {
    let dir = tempfile::tempdir().unwrap();
    let step = 0.01;
    // No filter, and a driver who does not react (the file's nominal brakes for the lead).
    let none = "filter={kind=\"none\"}";
    let still = "nominal={kind=\"constant\", input=[0.0]}";
    let ode = truck(dir.path(), "ode", "ode", &[none, still]);
    let mujoco = truck(dir.path(), "mujoco", "mujoco", &[none, still]);
    let (ode_start, mujoco_start) = (
        events(&ode, "collision_start")[0].clone(),
        events(&mujoco, "collision_start")[0].clone(),
    );
    println!(
        "lead: collision_start ode {:.3} s, mujoco {:.3} s ({:.4} m deep); the gap closes at {:.3} s (ode), {:.3} s (mujoco)",
        ode_start.time,
        mujoco_start.time,
        mujoco_start.depth,
        gap_closes(&ode),
        gap_closes(&mujoco)
    );
    assert!((ode_start.time - gap_closes(&ode)).abs() < 1e-9);
    assert!((mujoco_start.time - ode_start.time).abs() <= 2.0 * step + 1e-9);
    assert!((mujoco_start.time - gap_closes(&mujoco)).abs() <= 2.0 * step + 1e-9);
    assert!(mujoco_start.depth > 0.0 && mujoco_start.depth < 0.5, "{mujoco_start:?}");
    // MuJoCo's contact pushes the truck back; the ODE truck drives through the lead.
    let deepest = |log: &Path| events(log, "collision_end").iter().map(|e| e.depth).fold(0.0, f64::max);
    assert!(deepest(&mujoco) < 1.0 && deepest(&ode) > 10.0);

    // A box lead 4 m long (its rear 2 m behind its centre, as the 2 m radius): the same contact.
    let boxed = truck_with(
        dir.path(),
        "boxed",
        "mujoco",
        &[none, still],
        "shape = { kind = \"box\", length = 4.0, width = 1.8 }",
    );
    let boxed_start = events(&boxed, "collision_start")[0].clone();
    println!(
        "box lead: collision_start mujoco {:.3} s ({:.4} m deep)",
        boxed_start.time, boxed_start.depth
    );
    assert!((boxed_start.time - mujoco_start.time).abs() <= step + 1e-9);
    assert!(boxed_start.depth > 0.0);

    let filtered = truck(dir.path(), "filtered", "mujoco", &[]);
    let m = analyze_json(&filtered);
    assert!(m["collision"].is_null(), "{m}");
    assert!(events(&filtered, "collision_start").is_empty());
    assert!(m["min_h"].as_f64().unwrap() > -1e-3, "{m}");
}

/// The longitudinal car of Ames et al. on MuJoCo (models/longitudinal.xml, its 4.5 m hull box
/// centred on its position) behind a lead obstacle braking at 6 m/s²: the contact box ends at
/// the car's position, so MuJoCo's contact comes when the headway's gap closes, as on the ODE
/// plant.
#[test]
fn a_lead_on_the_longitudinal_mujoco_car_is_hit_when_the_gap_closes() {
    let dir = tempfile::tempdir().unwrap();
    let base = std::fs::read_to_string(scenario("acc_ames2014_mujoco.toml")).unwrap();
    let model = root().join("models/longitudinal.xml");
    let text = base.replace("\"../models/longitudinal.xml\"", &format!("{:?}", model.to_str().unwrap()))
        + "\n[[obstacles]]\nname = \"lead\"\ncentre = [60.0, 0.0]\nradius = 2.0\n[obstacles.motion]\ndirection = [1.0, 0.0]\nspeed = 20.0\nacceleration = [[3.0, 0.0], [3.0, -6.0]]\n[obstacles.following]\nstandstill = 3.0\ntime_headway = 1.0\n";
    let file = write(dir.path(), "acc_lead.toml", &text);
    let mut times = Vec::new();
    for plant in ["ode", "mujoco"] {
        let log = dir.path().join(format!("{plant}.mcap"));
        let set = format!("plant=\"{plant}\"");
        run_ok(&file, &log, &["--set", &set, "--set", "filter={kind=\"none\"}"]);
        let start = events(&log, "collision_start")[0].clone();
        assert!(start.depth > 0.0);
        times.push((start.time, gap_closes(&log)));
    }
    println!(
        "longitudinal lead: (collision_start, gap closes) ode {:?}, mujoco {:?}",
        times[0], times[1]
    );
    assert!((times[0].0 - times[0].1).abs() < 1e-9);
    assert!((times[1].0 - times[0].0).abs() <= 0.02 + 1e-9, "{times:?}");
}

/// Same inputs, same bytes: the MuJoCo run with the footprint and a moving box.
#[test]
fn the_mujoco_run_with_a_footprint_and_a_moving_box_gives_byte_identical_logs() {
    let dir = tempfile::tempdir().unwrap();
    let target = Target::Crossing {
        centre: [0.0, -12.0],
        speed: 1.4,
    };
    let scenario = bicycle(dir.path(), "twice", "mujoco", true, target);
    let (a, b) = (dir.path().join("a.mcap"), dir.path().join("b.mcap"));
    run_ok(&scenario, &a, &[]);
    run_ok(&scenario, &b, &[]);
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(), "logs differ");
}

/// What is still refused names its key: a footprint needs the hull in a named body of the
/// vehicle (the contact box goes there).
#[test]
fn a_footprint_needs_the_hull_in_the_vehicle_s_body() {
    let dir = tempfile::tempdir().unwrap();
    let xml = std::fs::read_to_string(root().join("models/bicycle.xml")).unwrap();
    let hull = "      <geom name=\"hull\" type=\"sphere\" size=\"3\" contype=\"1\" conaffinity=\"0\" rgba=\"0.2 0.4 0.9 0.4\"/>\n";
    assert!(xml.contains(hull));
    // The hull moved to the world body.
    let moved = xml.replace(hull, "").replace(
        "    <body name=\"vehicle\"",
        &format!("{hull}    <body name=\"vehicle\""),
    );
    let model = write(dir.path(), "world_hull.xml", &moved);
    let scenario = bicycle(
        dir.path(),
        "world_hull",
        "mujoco",
        true,
        Target::Static {
            centre: [0.0, 5.0],
            heading: 0.0,
        },
    );
    let text = std::fs::read_to_string(&scenario).unwrap().replace(
        &format!("{:?}", root().join("models/bicycle.xml").display().to_string()),
        &format!("{:?}", model.display().to_string()),
    );
    let scenario = write(dir.path(), "world_hull.toml", &text);
    let o = mjsafe(&[
        "run",
        scenario.to_str().unwrap(),
        "--out",
        dir.path().join("x.mcap").to_str().unwrap(),
    ]);
    let err = stderr(&o);
    assert!(!o.status.success());
    assert!(
        err.contains("world_hull.toml") && err.contains("vehicle.model"),
        "{err}"
    );
    assert!(err.contains("named body of the vehicle"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
}

#[test]
fn a_model_that_already_names_a_geom_as_mjsafe_would_is_refused_with_one_line() {
    // MuJoCo refuses a repeated name with its own text about the modified model; mjsafe says
    // which name, before MuJoCo sees it.
    let dir = tempfile::tempdir().unwrap();
    let xml = std::fs::read_to_string(root().join("models/bicycle.xml")).unwrap();
    for name in ["vehicle_contact", "obstacle_0"] {
        let taken = xml.replacen(
            "<geom name=\"hull\"",
            &format!("<geom name=\"{name}\" type=\"sphere\" size=\"0.1\" contype=\"0\" conaffinity=\"0\"/><geom name=\"hull\""),
            1,
        );
        let model = write(dir.path(), &format!("{name}.xml"), &taken);
        let scenario = bicycle(
            dir.path(),
            name,
            "mujoco",
            true,
            Target::Static {
                centre: [0.0, 5.0],
                heading: 0.0,
            },
        );
        let text = std::fs::read_to_string(&scenario).unwrap().replace(
            &format!("{:?}", root().join("models/bicycle.xml").display().to_string()),
            &format!("{:?}", model.display().to_string()),
        );
        let scenario = write(dir.path(), &format!("{name}.toml"), &text);
        let o = mjsafe(&[
            "run",
            scenario.to_str().unwrap(),
            "--out",
            dir.path().join("x.mcap").to_str().unwrap(),
        ]);
        let err = stderr(&o);
        assert!(!o.status.success());
        assert!(
            err.contains("vehicle.model") && err.contains(&format!("`{name}`")),
            "{err}"
        );
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    }
}
