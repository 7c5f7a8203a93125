//! The car (models/car.xml) against its analytic model, the kinematic bicycle (4.78): measured
//! fidelity at 3, 10 and 20 m/s, the model at rest, and docs/car.md's parameter table checked
//! against the MJCF, and the study of docs/studies.md (the γm filter (4.67) on the car). Prints
//! its figures (run with --nocapture to see them).

mod common;

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use common::{analyze_json, run_ok, scenario};

use mjsafe::mujoco::{CallbackContext, ControlHook, DataView, Integrator, Model, ObjKind, Simulation};
use mjsafe::plant;
use mjsafe::vehicle::{MujocoCar, MujocoVehicle, CAR_STEERING_RATE_GAIN};
use nalgebra::DVector;

fn root() -> PathBuf {
    common::root()
}

fn car_xml() -> String {
    std::fs::read_to_string(root().join("models/car.xml")).unwrap()
}

fn car_model() -> Model {
    Model::from_xml_file(&root().join("models/car.xml")).unwrap()
}

/// Writes input k (held over step k) at every callback call of step k.
struct Replay<'a> {
    vehicle: &'a dyn MujocoVehicle,
    inputs: &'a [DVector<f64>],
}

impl ControlHook for Replay<'_> {
    fn on_control(&mut self, ctx: CallbackContext, data: &mut DataView<'_>) {
        let u = &self.inputs[ctx.step as usize];
        self.vehicle.write_ctrl(data, u.as_slice());
    }
}

/// How far the car strays from (4.78) under the same inputs.
#[derive(Debug, Clone, Copy)]
struct Fidelity {
    /// Max over the run of the distance between the car's rear-axle midpoint and (4.78)'s x1, x2.
    max_position_error: f64,
    /// Final heading and speed errors (car − model; heading wrapped to (−π, π]).
    final_heading_error: f64,
    final_speed_error: f64,
    /// Largest height change of the chassis (m): the car stays on its wheels.
    max_height_change: f64,
}

fn wrap(angle: f64) -> f64 {
    (angle + PI).rem_euclid(2.0 * PI) - PI
}

fn compare(model: Model, x0: [f64; 4], duration: f64, input: impl Fn(f64) -> [f64; 2]) -> Fidelity {
    let h = model.timestep();
    let car = MujocoCar::bind(&model).unwrap();
    let mut sim = Simulation::new(model).unwrap();
    let x0 = DVector::from_column_slice(&x0);
    car.write_state(&mut sim, &x0);
    let z0 = sim.data().qpos()[2];
    let steps = (duration / h).round() as usize;
    let inputs: Vec<DVector<f64>> = (0..steps)
        .map(|k| DVector::from_column_slice(&input(k as f64 * h)))
        .collect();
    let reference = plant::integrate(car.dynamics().as_ref(), &x0, &inputs, h, 10);
    let mut hook = Replay {
        vehicle: &car,
        inputs: &inputs,
    };
    let mut f = Fidelity {
        max_position_error: 0.0,
        final_heading_error: 0.0,
        final_speed_error: 0.0,
        max_height_change: 0.0,
    };
    for k in 0..steps {
        sim.step(&mut hook).unwrap();
        let d = sim.data();
        let x = car.read_state(d.qpos(), d.qvel(), d.act());
        let r = &reference[k + 1];
        f.max_position_error = f.max_position_error.max((x[0] - r[0]).hypot(x[1] - r[1]));
        if std::env::var("CAR_TRACE").is_ok() && k % 500 == 0 && x0[3] < 5.0 {
            let (s, c) = r[2].sin_cos();
            let (ex, ey) = (x[0] - r[0], x[1] - r[1]);
            println!(
                "t={:.1} along={:.3} across={:.3} dheading={:.4} dv={:.3} steer_act={:.3} qpos_steer={:.3}",
                (k + 1) as f64 * h,
                ex * c + ey * s,
                -ex * s + ey * c,
                wrap(x[2] - r[2]),
                x[3] - r[3],
                d.act()[0],
                d.qpos()[8]
            );
        }
        f.final_heading_error = wrap(x[2] - r[2]);
        f.final_speed_error = x[3] - r[3];
        f.max_height_change = f.max_height_change.max((d.qpos()[2] - z0).abs());
    }
    f
}

/// The fidelity test's inputs (tests/fidelity.rs): u1 = 0.5 sin(2πt/5), u2 = 0, 10 s.
/// On `model` (models/car.xml, possibly with another timestep or integrator).
fn sine_steer_on(model: Model, v0: f64) -> Fidelity {
    compare(model, [0.0, 0.0, 0.0, v0], 10.0, |t| {
        [0.5 * (2.0 * PI * t / 5.0).sin(), 0.0]
    })
}

fn sine_steer(v0: f64) -> Fidelity {
    sine_steer_on(car_model(), v0)
}

/// `cargo test --release --test car fidelity -- --nocapture` prints docs/car.md's table.
#[test]
fn car_fidelity_against_the_kinematic_bicycle_at_3_10_and_20_mps() {
    let figures: Vec<(f64, Fidelity)> = [3.0, 10.0, 20.0].iter().map(|&v| (v, sine_steer(v))).collect();
    println!("| v0 (m/s) | max position error (m) | final heading error (rad) | final speed error (m/s) | max chassis height change (m) |");
    println!("|---|---|---|---|---|");
    for (v, f) in &figures {
        println!(
            "| {v} | {:.3} | {:.4} | {:.3} | {:.4} |",
            f.max_position_error, f.final_heading_error, f.final_speed_error, f.max_height_change
        );
    }
    let [(_, slow), (_, mid), (_, fast)] = [figures[0], figures[1], figures[2]];
    // No blow-up: finite, and the car stays on its wheels (rest height within 5 cm).
    for (v, f) in &figures {
        assert!(
            f.max_position_error.is_finite() && f.max_height_change < 0.05,
            "{v} m/s: {f:?}"
        );
    }
    // 3 m/s (0.04 g lateral): close to (4.78), but not a replica of it — the bicycle binding
    // stays within 5 cm (tests/fidelity.rs); the car loses speed in the turns (yaw energy,
    // tyre scrub) and lags in heading, about a metre over 10 s.
    assert!(slow.max_position_error < 1.5, "3 m/s: {slow:?}");
    assert!(slow.max_position_error > 0.2, "3 m/s is a replica of (4.78)? {slow:?}");
    assert!(slow.final_heading_error.abs() < 0.02, "3 m/s: {slow:?}");
    // 10 m/s (0.85 g demanded: at the friction limit mu = 0.9): metres, not tens.
    assert!(
        mid.max_position_error > 2.0 && mid.max_position_error < 10.0,
        "10 m/s: {mid:?}"
    );
    // 20 m/s (3.4 g demanded): the tyres slide, the car leaves the model's path by tens of
    // metres and loses speed.
    assert!(
        fast.max_position_error > 30.0,
        "20 m/s: the tyres should slip: {fast:?}"
    );
    assert!(fast.final_speed_error < -2.0, "20 m/s: {fast:?}");
}

/// The model's 2 ms implicit step is converged: RK4 at 0.5 ms gives the same fidelity figures
/// within 5 % at 3 and 10 m/s (measured: 1.6 % and 3.1 %).
#[test]
fn car_timestep_and_integrator_are_converged() {
    for v0 in [3.0, 10.0] {
        let mut fine = car_model();
        fine.set_timestep(0.0005);
        fine.set_integrator(Integrator::Rk4);
        let (a, b) = (sine_steer(v0), sine_steer_on(fine, v0));
        let rel = (a.max_position_error - b.max_position_error).abs() / b.max_position_error;
        println!(
            "v0 = {v0}: max position error {:.3} m (implicit, 2 ms) vs {:.3} m (RK4, 0.5 ms): {:.1} %",
            a.max_position_error,
            b.max_position_error,
            100.0 * rel
        );
        assert!(rel < 0.05, "{v0} m/s: {a:?} vs {b:?}");
        assert!(
            (a.final_speed_error - b.final_speed_error).abs() < 0.05,
            "{v0} m/s: {a:?} vs {b:?}"
        );
    }
}

/// Runs `steps` steps from `x0` with input `u(t)`, returning the states after every step and the
/// front-left commanded steering angle (activation) after every step.
fn run_car(x0: [f64; 4], duration: f64, input: impl Fn(f64) -> [f64; 2]) -> (Vec<DVector<f64>>, Vec<f64>, f64) {
    let model = car_model();
    let h = model.timestep();
    let car = MujocoCar::bind(&model).unwrap();
    let steer_act = model
        .actuator_act_addr(model.require(ObjKind::Actuator, "steer_fl").unwrap())
        .unwrap();
    let mut sim = Simulation::new(model).unwrap();
    car.write_state(&mut sim, &DVector::from_column_slice(&x0));
    let steps = (duration / h).round() as usize;
    let inputs: Vec<DVector<f64>> = (0..steps)
        .map(|k| DVector::from_column_slice(&input(k as f64 * h)))
        .collect();
    let mut hook = Replay {
        vehicle: &car,
        inputs: &inputs,
    };
    let (mut states, mut steer) = (Vec::new(), Vec::new());
    for _ in 0..steps {
        sim.step(&mut hook).unwrap();
        let d = sim.data();
        states.push(car.read_state(d.qpos(), d.qvel(), d.act()));
        steer.push(d.act()[steer_act]);
    }
    (states, steer, h)
}

#[test]
fn car_rests_accelerates_brakes_and_steers_at_its_rate_limit() {
    // At rest on its wheels: no creep.
    let (rest, _, _) = run_car([5.0, -2.0, 0.7, 0.0], 2.0, |_| [0.0, 0.0]);
    let last = rest.last().unwrap();
    let drift = (last[0] - 5.0).hypot(last[1] + 2.0);
    println!(
        "at rest 2 s: drift {drift:.2e} m, heading change {:.2e}, speed {:.2e}",
        last[2] - 0.7,
        last[3]
    );
    assert!(
        drift < 1e-3 && (last[2] - 0.7).abs() < 1e-3 && last[3].abs() < 1e-3,
        "{last:?}"
    );

    // u2 = 2 m/s² for 4 s from rest: 8 m/s less the 0.1 s torque lag (0.2 m/s) and losses.
    let (accel, _, _) = run_car([0.0, 0.0, 0.0, 0.0], 4.0, |_| [0.0, 2.0]);
    let v = accel.last().unwrap()[3];
    println!("u2 = 2 for 4 s from rest: speed {v:.3} m/s (4.78 with the lag: 7.8)");
    assert!((v - 7.8).abs() < 0.3, "speed {v}");
    // Braking u2 = -3 m/s² for 2 s from 15 m/s: 9 m/s (lag: +0.3).
    let (brake, _, _) = run_car([0.0, 0.0, 0.0, 15.0], 2.0, |_| [0.0, -3.0]);
    let v = brake.last().unwrap()[3];
    println!("u2 = -3 for 2 s from 15 m/s: speed {v:.3} m/s (4.78 with the lag: 9.3)");
    assert!((v - 9.3).abs() < 0.4, "speed {v}");
    // Beyond the torque limit (2000 N m per wheel, about 6.4 m/s²): u2 = 20 gives far less.
    let (limited, _, _) = run_car([0.0, 0.0, 0.0, 0.0], 1.0, |_| [0.0, 20.0]);
    let v = limited.last().unwrap()[3];
    println!("u2 = 20 for 1 s from rest: speed {v:.3} m/s");
    assert!(v > 4.0 && v < 7.0, "speed {v}");

    // Steering step u1: 0 → tan(0.4) at 3 m/s: the commanded angle ramps at the 1 rad/s limit.
    let (_, steer, h) = run_car([0.0, 0.0, 0.0, 3.0], 1.0, |_| [0.4f64.tan(), 0.0]);
    let max_rate = steer.windows(2).map(|w| (w[1] - w[0]) / h).fold(0.0, f64::max);
    let at_100ms = steer[(0.1 / h).round() as usize - 1];
    println!(
        "steering step to tan(0.4): max rate {max_rate:.4} rad/s, angle after 0.1 s {at_100ms:.4} rad, after 1 s {:.4}",
        steer.last().unwrap()
    );
    assert!(max_rate <= 1.0 + 1e-9 && max_rate > 0.99, "rate {max_rate}");
    assert!((at_100ms - 0.1).abs() < 1e-6, "{at_100ms}");
    // Ackermann: the left (inner) wheel's target is atan(L u1 / (L - w u1)) > 0.4.
    let inner = (6.0 * 0.4f64.tan()).atan2(6.0 - 0.4f64.tan());
    assert!(
        (steer.last().unwrap() - inner).abs() < 1e-3,
        "{} vs {inner}",
        steer.last().unwrap()
    );
}

#[test]
fn car_steering_targets_are_ackermann_and_limited() {
    let car = MujocoCar::bind(&car_model()).unwrap();
    let [l, r] = car.steering_targets(0.3);
    // Both wheels aim at the turn centre on the rear-axle line at radius L / u1 = 20 m.
    assert!((l.tan() - 6.0 / (20.0 - 1.0)).abs() < 1e-12 && (r.tan() - 6.0 / (20.0 + 1.0)).abs() < 1e-12);
    assert_eq!(car.steering_targets(-0.3), [-r, -l]);
    assert_eq!(
        car.steering_targets(12.0),
        [0.6, 0.6f64.tan().atan2(1.0 + 0.6f64.tan() / 6.0)]
    );
    assert_eq!(car.steering_targets(f64::NAN), [0.0, 0.0]);
    // Feed-forward torque: (2500 + 4·40 + 2·10 kg + 4·4.05 / 0.45² kg) · 0.45 m / 4.
    let expected = (2680.0 + 4.0 * 4.05 / 0.45f64.powi(2)) * 0.45 / 4.0;
    assert!((car.torque_per_acceleration() - expected).abs() < 1e-9);
}

/// The attribute `attr` of the first element matching `selector` in the MJCF text: `tag`,
/// `tag[key=value]`, optionally followed by `>child` (the first `<child` inside that element).
fn mjcf_attribute(xml: &str, selector: &str, attr: &str) -> Option<String> {
    let (outer, child) = match selector.split_once('>') {
        Some((o, c)) => (o, Some(c)),
        None => (selector, None),
    };
    let (tag, filter) = match outer.split_once('[') {
        Some((t, f)) => {
            let (k, v) = f.trim_end_matches(']').split_once('=')?;
            (t, Some((k, v)))
        }
        None => (outer, None),
    };
    let element_at = |from: usize, tag: &str| -> Option<(usize, &str)> {
        let open = format!("<{tag}");
        let mut at = from;
        loop {
            let start = at + xml[at..].find(&open)?;
            let after = start + open.len();
            let end = after + xml[after..].find('>')?;
            let next = xml[after..].chars().next()?;
            if next.is_whitespace() || next == '/' || next == '>' {
                return Some((start, &xml[start..=end]));
            }
            at = after;
        }
    };
    let value_of = |element: &str, key: &str| -> Option<String> {
        let needle = format!(" {key}=\"");
        let i = element.find(&needle)? + needle.len();
        Some(element[i..i + element[i..].find('"')?].to_string())
    };
    let mut at = 0;
    let (start, element) = loop {
        let (start, element) = element_at(at, tag)?;
        if filter.is_none_or(|(k, v)| value_of(element, k).as_deref() == Some(v)) {
            break (start, element);
        }
        at = start + 1;
    };
    match child {
        None => value_of(element, attr),
        Some(child) => value_of(element_at(start + element.len(), child)?.1, attr),
    }
}

/// Same numbers (whitespace-separated, compared as f64) or the same word.
fn same_value(doc: &str, model: &str) -> bool {
    let parse = |s: &str| {
        s.split_whitespace()
            .map(str::parse::<f64>)
            .collect::<Result<Vec<_>, _>>()
    };
    match (parse(doc), parse(model)) {
        (Ok(a), Ok(b)) => a == b,
        _ => doc.trim() == model.trim(),
    }
}

#[test]
fn docs_car_parameter_table_matches_models_car_xml() {
    let doc = std::fs::read_to_string(root().join("docs/car.md")).unwrap();
    let xml = car_xml();
    let mut checked = 0;
    for line in doc.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        // | parameter | value | unit | `selector@attribute` |
        if cells.len() != 6 || !cells[4].starts_with('`') {
            continue;
        }
        let (value, source) = (cells[2].trim_matches('`'), cells[4].trim_matches('`'));
        let actual = if source == "CAR_STEERING_RATE_GAIN" {
            CAR_STEERING_RATE_GAIN.to_string()
        } else {
            let (selector, attr) = source.split_once('@').unwrap_or_else(|| panic!("{line}"));
            mjcf_attribute(&xml, selector, attr).unwrap_or_else(|| panic!("models/car.xml has no {source} ({line})"))
        };
        assert!(
            same_value(value, &actual),
            "docs/car.md says {} = {value}, models/car.xml has {actual}",
            cells[1]
        );
        checked += 1;
    }
    println!("docs/car.md: {checked} parameters match models/car.xml");
    assert!(checked >= 20, "only {checked} rows of the parameter table found");
    // The symmetric parts the table shows once are the same on every wheel, and the compiled
    // model agrees with the text.
    for w in ["rr", "fl", "fr"] {
        for (sel, attr) in [
            ("body[name=wheel_{w}]>inertial", "mass"),
            ("body[name=wheel_{w}]>inertial", "diaginertia"),
        ] {
            let sel = sel.replace("{w}", w);
            assert_eq!(
                mjcf_attribute(&xml, &sel, attr),
                mjcf_attribute(&xml, "body[name=wheel_rl]>inertial", attr)
            );
        }
        for attr in ["dynprm", "ctrlrange", "gainprm"] {
            assert_eq!(
                mjcf_attribute(&xml, &format!("general[name=torque_{w}]"), attr),
                mjcf_attribute(&xml, "general[name=torque_rl]", attr)
            );
        }
    }
    for attr in ["gainprm", "biasprm", "ctrlrange"] {
        assert_eq!(
            mjcf_attribute(&xml, "general[name=steer_fr]", attr),
            mjcf_attribute(&xml, "general[name=steer_fl]", attr)
        );
    }
    let model = car_model();
    let mass: f64 = (1..model.nbody()).map(|b| model.body_mass(b)).sum();
    assert_eq!(mass, 2500.0 + 4.0 * 40.0 + 2.0 * 10.0);
    assert_eq!(model.timestep(), 0.002);
    let tyre = model.require(ObjKind::Geom, "tyre_fr").unwrap();
    assert_eq!(model.geom_size(tyre)[0], 0.45);
    let steer = model.require(ObjKind::Joint, "steer_fr").unwrap();
    assert_eq!(model.joint_range(steer), Some([-0.6, 0.6]));
}

/// Runs `scenario` with the given vehicle (kind and model) and returns analyze's JSON.
fn study_run(dir: &Path, file: &str, label: &str, kind: &str, model: &str) -> serde_json::Value {
    let log = dir.join(format!("{file}-{label}.mcap"));
    let kind_arg = format!("vehicle.kind=\"{kind}\"");
    let model_arg = format!("vehicle.model=\"{model}\"");
    run_ok(&scenario(file), &log, &["--set", &kind_arg, "--set", &model_arg]);
    analyze_json(&log)
}

/// The diagnostic variants of docs/studies.md: models/car.xml with every occurrence of each
/// `from` replaced by `to` (each must occur), written into `dir`.
fn car_variant(dir: &Path, name: &str, edits: &[(&str, &str)]) -> PathBuf {
    let mut xml = car_xml();
    for (from, to) in edits {
        assert!(xml.contains(from), "models/car.xml has no {from}");
        xml = xml.replace(from, to);
    }
    let path = dir.join(format!("{name}.xml"));
    std::fs::write(&path, xml).unwrap();
    path
}

/// Steering lock ±1.5 rad (tan = 14, beyond the filter's largest tan δ) and rate ±20 rad/s.
const WIDE_STEERING: [(&str, &str); 2] = [
    ("range=\"-0.6 0.6\"", "range=\"-1.5 1.5\""),
    ("ctrlrange=\"-1 1\"", "ctrlrange=\"-20 20\""),
];
/// WIDE_STEERING plus tyre/ground friction 3 and ten times the torque limit.
const WIDE_STEERING_AND_GRIP: [(&str, &str); 4] = [
    WIDE_STEERING[0],
    WIDE_STEERING[1],
    ("friction=\"0.9 ", "friction=\"3 "),
    ("ctrlrange=\"-2000 2000\"", "ctrlrange=\"-20000 20000\""),
];

/// docs/studies.md, "Does (4.67) designed on (4.78) keep the car safe?".
#[test]
fn gamma_m_filter_keeps_the_bicycle_but_not_the_car_clear_at_3_and_10_mps() {
    let dir = tempfile::tempdir().unwrap();
    let bicycle_model = root().join("models/bicycle.xml");
    let car_model = root().join("models/car.xml");
    let wide = car_variant(dir.path(), "car_wide", &WIDE_STEERING);
    let grip = car_variant(dir.path(), "car_grip", &WIDE_STEERING_AND_GRIP);
    let figures = |m: &serde_json::Value| {
        format!(
            "collision {} | min h {:.3} | prediction max error steering {:.2e}, acceleration {:.2e} | max correction steering {:.2}, acceleration {:.2}",
            m["collision"]["time"],
            m["min_h"].as_f64().unwrap(),
            m["prediction"]["steering"]["max_error"].as_f64().unwrap(),
            m["prediction"]["acceleration"]["max_error"].as_f64().unwrap(),
            m["max_correction"]["steering"].as_f64().unwrap(),
            m["max_correction"]["acceleration"].as_f64().unwrap(),
        )
    };
    let collides = |m: &serde_json::Value| !m["collision"].is_null() && m["min_h"].as_f64().unwrap() < 0.0;
    let clear = |m: &serde_json::Value| m["collision"].is_null() && m["min_h"].as_f64().unwrap() > 0.0;
    let steering = |m: &serde_json::Value| m["prediction"]["steering"]["max_error"].as_f64().unwrap();
    for file in ["car_obstacle_gamma_m.toml", "car_obstacle_gamma_m_10.toml"] {
        let run = |label: &str, model: &Path| {
            let kind = if label == "bicycle" { "bicycle" } else { "car" };
            study_run(dir.path(), file, label, kind, model.to_str().unwrap())
        };
        let bicycle = run("bicycle", &bicycle_model);
        let car = run("car", &car_model);
        let car_wide = run("car_wide", &wide);
        let car_grip = run("car_grip", &grip);
        for (name, m) in [
            ("bicycle", &bicycle),
            ("car", &car),
            ("car, wide steering", &car_wide),
            ("car, wide steering + grip", &car_grip),
        ] {
            println!("{file} {name}: {}", figures(m));
            assert_eq!(m["complete"], true, "{file} {name}");
        }
        // The model the filter was designed on stays clear; the realistic car hits the obstacle.
        assert!(clear(&bicycle), "{file}: bicycle collides");
        assert!(collides(&car), "{file}: the car stays clear");
        // The predictions (4.23) on (4.78) lose consistency on the car: the steering channel's
        // one-delay-ahead prediction misses by metres instead of millimetres to centimetres.
        assert!(steering(&bicycle) < 0.05, "{file}: bicycle {}", steering(&bicycle));
        assert!(steering(&car) > 1.0, "{file}: car {}", steering(&car));
        // Steering lock and rate alone do not explain it: with them opened up the car still
        // collides at both speeds.
        assert!(collides(&car_wide), "{file}: wide steering stays clear");
        if file.ends_with("_10.toml") {
            // At 10 m/s the tyres' grip is what is missing: with it (and the steering) it is clear.
            assert!(clear(&car_grip), "{file}: grip variant collides");
        } else {
            // At 3 m/s even then it grazes the obstacle (millimetres), much later.
            assert!(collides(&car_grip), "{file}: grip variant stays clear");
            let depth = |m: &serde_json::Value| m["collision"]["depth"].as_f64().unwrap();
            assert!(depth(&car_grip) < 0.01 && depth(&car) > depth(&car_grip));
        }
    }
}
