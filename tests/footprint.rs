//! Footprints as covering circles (docs/actors.md, "Footprints"): a 4.6 × 1.8 m car on the
//! analytic bicycle (4.78) passes a 4.02 × 1.71 m box (the Euro NCAP car target) whose edge is
//! 1.5 m beside its side, where the old 3 m hull circle collides or must swerve; a box 2 m
//! further in is hit without a filter. Each verdict is checked against an independent overlap
//! test of the two rectangles from the logged states.

mod common;
use common::*;

use mjsafe::log::proto;

const CAR: [f64; 2] = [4.6, 1.8];
const BOX: [f64; 2] = [4.02, 1.71];
/// The box's centre beside the path y = 0: its edge 1.5 m from the car's side.
const BESIDE: f64 = 0.9 + 1.5 + 0.855;

/// Table 4.1's γm scenario on the ODE plant with the box at (0, `y`) instead of its obstacle,
/// with the car's footprint or the hull circle.
fn scenario_text(y: f64, footprint: bool) -> String {
    let base = std::fs::read_to_string(scenario("bicycle_obstacle_gamma_m.toml")).unwrap();
    let model = root().join("models/bicycle.xml");
    let base = base.replace("\"../models/bicycle.xml\"", &format!("{:?}", model.to_str().unwrap()));
    let (head, tail) = base.split_at(base.find("[[obstacles]]").unwrap());
    let goal = &tail[tail.find("[goal]").unwrap()..];
    let vehicle = if footprint {
        "timestep = 0.002\nfootprint = { length = 4.6, width = 1.8 }\n"
    } else {
        "timestep = 0.002\n"
    };
    let head = head.replace("[delays]", &format!("{vehicle}\n[delays]"));
    format!(
        "plant = \"ode\"\n{head}[[obstacles]]\nname = \"box\"\ncentre = [0.0, {y}]\nshape = {{ kind = \"box\", length = {}, width = {} }}\n\n{goal}",
        BOX[0], BOX[1]
    )
}

fn run(dir: &std::path::Path, name: &str, text: &str, extra: &[&str]) -> std::path::PathBuf {
    let file = write(dir, &format!("{name}.toml"), text);
    let log = dir.join(format!("{name}.mcap"));
    run_ok(&file, &log, extra);
    log
}

const NO_FILTER: &str = "filter={kind=\"none\"}";

/// Independent of the covering circles: whether the car's rectangle (at the state's position
/// and heading) and the box's overlap, by sampling each boundary every 5 mm against the other
/// rectangle (convex rectangles overlap iff a boundary point of one lies in the other, or one
/// holds the other's centre).
fn rectangles_overlap(car: ([f64; 2], f64), boxed: [f64; 2]) -> bool {
    let inside = |p: [f64; 2], (c, h, size): ([f64; 2], f64, [f64; 2])| {
        let (s, co) = h.sin_cos();
        let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
        (co * dx + s * dy).abs() <= size[0] / 2.0 && (-s * dx + co * dy).abs() <= size[1] / 2.0
    };
    let boundary = |(c, h, size): ([f64; 2], f64, [f64; 2])| {
        let (s, co) = h.sin_cos();
        let n = ((2.0 * (size[0] + size[1])) / 0.005) as usize;
        (0..n).map(move |k| {
            // Walk the perimeter: bottom, right, top, left side.
            let t = k as f64 * 0.005;
            let (l, w) = (size[0], size[1]);
            let (u, v) = if t < l {
                (t - l / 2.0, -w / 2.0)
            } else if t < l + w {
                (l / 2.0, t - l - w / 2.0)
            } else if t < 2.0 * l + w {
                (l / 2.0 - (t - l - w), w / 2.0)
            } else {
                (-l / 2.0, w / 2.0 - (t - 2.0 * l - w))
            };
            [c[0] + co * u - s * v, c[1] + s * u + co * v]
        })
    };
    let a = (car.0, car.1, CAR);
    let b = (boxed, 0.0, BOX);
    boundary(a).any(|p| inside(p, b)) || boundary(b).any(|p| inside(p, a)) || inside(a.0, b) || inside(b.0, a)
}

/// Whether the car's rectangle ever overlaps the box, over the logged states.
fn ever_overlaps(log: &std::path::Path, y: f64) -> bool {
    read_topic::<proto::State>(log, "/state")
        .iter()
        .any(|s| rectangles_overlap(([s.values[0], s.values[1]], s.values[2]), [0.0, y]))
}

fn max_lateral(log: &std::path::Path) -> f64 {
    read_topic::<proto::State>(log, "/state")
        .iter()
        .map(|s| s.values[1].abs())
        .fold(0.0, f64::max)
}

#[test]
fn the_car_passes_a_box_the_hull_circle_cannot() {
    let dir = tempfile::tempdir().unwrap();
    // The footprint with γm: no collision, on its path, every pair's h ≥ 0.
    let car = run(dir.path(), "car", &scenario_text(BESIDE, true), &[]);
    let m = analyze_json(&car);
    assert!(m["collision"].is_null(), "{m}");
    assert!(m["min_h"].as_f64().unwrap() > 0.0, "{m}");
    assert!(max_lateral(&car) < 0.05, "{}", max_lateral(&car));
    assert!(!ever_overlaps(&car, BESIDE));
    // The filter has one barrier per (car circle, box circle) pair, 3 × 3 (each named
    // `box/i-j` where it reports one unmet); the log one entry named as the box, their least.
    let barriers = read_topic::<proto::Barrier>(&car, "/barrier");
    let names: Vec<&str> = barriers[0].barriers.iter().map(|b| b.name.as_str()).collect();
    assert_eq!(names, ["box"]);
    // Without a filter too: the rectangles never touch and no pair's clearance is negative.
    let free = run(dir.path(), "free", &scenario_text(BESIDE, true), &["--set", NO_FILTER]);
    assert!(analyze_json(&free)["collision"].is_null());
    assert!(!ever_overlaps(&free, BESIDE));

    // The 3 m hull circle on the same path collides with the box's circles (the rectangles
    // never touch: the hull's conservatism), and γm has to swerve around it.
    let hull = run(dir.path(), "hull", &scenario_text(BESIDE, false), &["--set", NO_FILTER]);
    assert_eq!(analyze_json(&hull)["collision"]["with"], "box");
    assert!(!ever_overlaps(&hull, BESIDE));
    let swerve = run(dir.path(), "swerve", &scenario_text(BESIDE, false), &[]);
    assert!(max_lateral(&swerve) > 0.5, "{}", max_lateral(&swerve));
}

#[test]
fn a_box_further_in_is_hit_without_a_filter_and_the_rectangles_agree() {
    let dir = tempfile::tempdir().unwrap();
    // 2 m further in: the box reaches 0.5 m into the car's path.
    let y = BESIDE - 2.0;
    let hit = run(dir.path(), "hit", &scenario_text(y, true), &["--set", NO_FILTER]);
    let m = analyze_json(&hit);
    // The collision names the obstacle, not a pair.
    assert_eq!(m["collision"]["with"], "box", "{m}");
    assert!(ever_overlaps(&hit, y));
    let events = read_topic::<proto::Event>(&hit, "/event");
    let start = events.iter().find(|e| e.kind == "collision_start").unwrap();
    assert_eq!(start.participants, ["vehicle", "box"]);
    // The first collision's state: the rectangles overlap there too (at most the circles'
    // overreach, 0.28 + 0.23 m, earlier).
    let states = read_topic::<proto::State>(&hit, "/state");
    let first_overlap = states
        .iter()
        .find(|s| rectangles_overlap(([s.values[0], s.values[1]], s.values[2]), [0.0, y]))
        .unwrap();
    assert!(
        start.time <= first_overlap.time + 1e-9,
        "{} vs {}",
        start.time,
        first_overlap.time
    );
    assert!(
        first_overlap.time - start.time < 0.6 / 3.0,
        "{} vs {}",
        start.time,
        first_overlap.time
    );
}

/// The covering circles (offset along the body, radius) of a rectangle L × W, recomputed
/// here from the rule in docs/actors.md: n = ⌈L/W⌉, ρ = √((L/2n)² + (W/2)²).
fn covering_circles([length, width]: [f64; 2]) -> Vec<(f64, f64)> {
    let n = (length / width).ceil() as usize;
    let piece = length / n as f64;
    let radius = ((piece / 2.0).powi(2) + (width / 2.0).powi(2)).sqrt();
    (0..n)
        .map(|k| (-length / 2.0 + (k as f64 + 0.5) * piece, radius))
        .collect()
}

/// The smallest gap (m) between any car circle and any box circle over the logged states.
fn min_circle_gap(log: &std::path::Path, y: f64) -> f64 {
    let (car, boxed) = (covering_circles(CAR), covering_circles(BOX));
    read_topic::<proto::State>(log, "/state")
        .iter()
        .flat_map(|s| {
            let (p, heading) = ([s.values[0], s.values[1]], s.values[2]);
            let (car, boxed) = (&car, &boxed);
            car.iter().flat_map(move |&(along, rho)| {
                let q = [p[0] + along * heading.cos(), p[1] + along * heading.sin()];
                boxed
                    .iter()
                    .map(move |&(x, sigma)| (q[0] - x).hypot(q[1] - y) - rho - sigma)
            })
        })
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn the_mixed_relative_degree_condition_keeps_every_circle_clear() {
    // The box reaches 0.5 m into the car's path: the filters must brake or steer round it,
    // and the steering swings the front circle at first order (docs/actors.md, "Footprints").
    // Without the first-order rows γm touched the box's circles (5.6 mm deep at 7.05 s).
    let dir = tempfile::tempdir().unwrap();
    let y = BESIDE - 2.0;
    for (name, filter) in [
        ("gamma_m", "filter={kind=\"gamma_m\",l0=4.0,l1=4.0,m=50.0}"),
        ("cbf_qp", "filter={kind=\"cbf_qp\",l0=4.0,l1=4.0}"),
    ] {
        let log = run(dir.path(), name, &scenario_text(y, true), &["--set", filter]);
        let m = analyze_json(&log);
        assert!(m["collision"].is_null(), "{name}: {m}");
        let gap = min_circle_gap(&log, y);
        assert!(gap >= 0.0, "{name}: the covering circles overlap by {} m", -gap);
        assert!(!ever_overlaps(&log, y), "{name}");
        // The filter acted: the nominal alone hits the box (the test above).
        assert!(gap < 0.5, "{name}: the car never came near the box ({gap} m)");
    }
}

/// `mjsafe run` of `text` fails with every needle on stderr.
fn fails(dir: &std::path::Path, text: &str, sets: &[&str], needles: &[&str]) {
    let file = write(dir, "bad.toml", text);
    let mut args = vec!["run", file.to_str().unwrap()];
    for s in sets {
        args.extend_from_slice(&["--set", s]);
    }
    let o = mjsafe(&args);
    let err = stderr(&o);
    assert!(!o.status.success(), "expected failure; stdout: {}", stdout(&o));
    for n in needles {
        assert!(err.contains(n), "stderr lacks `{n}`: {err}");
    }
}

#[test]
fn footprints_and_boxes_are_validated_with_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let dir = dir.path();
    let car = scenario_text(BESIDE, true);
    // (Footprints and boxes run on MuJoCo too: tests/mujoco_shapes.rs.)
    fails(
        dir,
        &car,
        &["vehicle.footprint.length=-1.0"],
        &["vehicle.footprint.length", "expected a positive length"],
    );
    fails(
        dir,
        &car,
        &["vehicle.footprint.circles=9"],
        &["vehicle.footprint.circles", "1 to 8"],
    );
    fails(
        dir,
        &car,
        &["obstacles.0.radius=2.0"],
        &["obstacles.0.radius", "not both"],
    );
    fails(
        dir,
        &car,
        &["obstacles.0.shape.width=0.0"],
        &["obstacles.0.shape.width"],
    );
    fails(
        dir,
        &car,
        &[
            "obstacles.0.shape.heading=0.3",
            "obstacles.0.motion={direction=[0.0,1.0],speed=1.0}",
        ],
        &["obstacles.0.shape.heading", "follows its motion"],
    );
    fails(
        dir,
        &car,
        &["obstacles.0.shape.kind=\"ellipse\""],
        &["shape.kind", "expected `box`"],
    );
    // Overlapping at the start: refused, as a circle obstacle is.
    fails(
        dir,
        &car,
        &["obstacles.0.centre=[-20.0,2.0]"],
        &["obstacles.0", "overlaps the vehicle at the start"],
    );
}

/// A box driving across the car's path (its covering circles moving with it, heading along its
/// motion) drawn as a cube, and the car as its footprint.
#[test]
fn a_moving_box_and_the_footprint_are_drawn_as_cubes() {
    let dir = tempfile::tempdir().unwrap();
    let text = scenario_text(-12.0, true);
    let log = run(
        dir.path(),
        "crossing",
        &text,
        &[
            "--set",
            "obstacles.0.motion={direction=[0.0,1.0],speed=2.0}",
            "--set",
            "duration=4.0",
        ],
    );
    let m = analyze_json(&log);
    assert!(m["collision"].is_null(), "{m}");
    let scenes = read_topic::<foxglove::messages::SceneUpdate>(&log, "/scene");
    let entity = |id: &str| {
        scenes
            .iter()
            .flat_map(|s| &s.entities)
            .rfind(|e| e.id == id)
            .cloned()
            .unwrap()
    };
    let vehicle = entity("vehicle");
    let size = vehicle.cubes[0].size.unwrap();
    assert_eq!([size.x, size.y], CAR);
    let boxed = entity("box");
    let size = boxed.cubes[0].size.unwrap();
    assert_eq!([size.x, size.y], BOX);
    // Heading π/2 (along its motion): a yaw quaternion with z = w.
    let q = boxed.cubes[0].pose.unwrap().orientation.unwrap();
    assert!((q.z - q.w).abs() < 1e-12, "{q:?}");
    // Its centre moves at 2 m/s from y = −12.
    let p = boxed.cubes[0].pose.unwrap().position.unwrap();
    assert!((p.y - (-12.0 + 2.0 * 4.0)).abs() < 0.1, "{p:?}");
}

/// scenarios/bicycle_narrow_road.toml with the car's footprint, the box in place of its
/// obstacle, and the road's edges at x2 = `left` and x2 = `right`.
fn road_text(left: f64, right: f64, footprint: bool) -> String {
    let base = std::fs::read_to_string(scenario("bicycle_narrow_road.toml")).unwrap();
    let model = root().join("models/bicycle.xml");
    let base = base.replace("\"../models/bicycle.xml\"", &format!("{:?}", model.to_str().unwrap()));
    let base = base.replace("point = [0.0, 5.0]", &format!("point = [0.0, {left}]"));
    let base = base.replace("point = [0.0, -7.0]", &format!("point = [0.0, {right}]"));
    let base = base.replace(
        "centre = [-3.0, 0.5]\nradius = 3.0",
        &format!(
            "centre = [-3.0, 1.5]\nshape = {{ kind = \"box\", length = {}, width = {} }}",
            BOX[0], BOX[1]
        ),
    );
    let vehicle = if footprint {
        "plant = \"ode\"\n[vehicle]\nfootprint = { length = 4.6, width = 1.8 }"
    } else {
        "plant = \"ode\"\n[vehicle]"
    };
    base.replacen("[vehicle]", vehicle, 1)
}

#[test]
fn the_footprint_keeps_to_the_road_between_edges_the_hull_cannot_fit() {
    let dir = tempfile::tempdir().unwrap();
    // 5 m between the edges: the 6 m hull starts off the road and is refused, naming the edge.
    fails(
        dir.path(),
        &road_text(2.5, -2.5, false),
        &[],
        &["road.edges.0", "starts off the road"],
    );
    // The footprint fits; γm passes the box (its near edge 0.645 m into the car's half of
    // the road) and keeps every covering circle inside both edges.
    let log = run(dir.path(), "road", &road_text(2.5, -2.5, true), &[]);
    let m = analyze_json(&log);
    assert!(m["collision"].is_null(), "{m}");
    // (min_h is absent: the edges' h is in m, the obstacle's in m².)
    for (name, h) in m["min_h_by_barrier"].as_object().unwrap() {
        assert!(h.as_f64().unwrap() >= 0.0, "{name}: {m}");
    }
    let barriers = read_topic::<proto::Barrier>(&log, "/barrier");
    let names: Vec<&str> = barriers[0].barriers.iter().map(|b| b.name.as_str()).collect();
    for edge in ["left_edge", "right_edge"] {
        for i in 0..3 {
            assert!(names.contains(&format!("{edge}/{i}").as_str()), "{names:?}");
        }
    }
    // Independently from /state: every covering circle and every corner of the car between
    // x2 = -2.5 and 2.5.
    let circles = covering_circles(CAR);
    let mut lowest_margin = f64::INFINITY;
    let states = read_topic::<proto::State>(&log, "/state");
    for s in &states {
        let (p, heading) = ([s.values[0], s.values[1]], s.values[2]);
        for &(along, rho) in &circles {
            let y = p[1] + along * heading.sin();
            lowest_margin = lowest_margin.min(2.5 - (y + rho)).min((y - rho) + 2.5);
        }
        for (u, v) in [(2.3, 0.9), (2.3, -0.9), (-2.3, 0.9), (-2.3, -0.9)] {
            let y = p[1] + u * heading.sin() + v * heading.cos();
            assert!(y.abs() <= 2.5, "t = {}: a corner at x2 = {y}", s.time);
        }
    }
    assert!(
        lowest_margin >= 0.0,
        "a covering circle crosses an edge by {}",
        -lowest_margin
    );
    // It got past the box (the goal is 13 m beyond it).
    let last = states.last().unwrap();
    assert!(last.values[0] > 2.0, "stopped at x1 = {}", last.values[0]);
}
