//! The adaptive cruise control of Ames et al. (CDC 2014) on the `longitudinal` vehicle:
//! outcomes recomputed from the logged /state, and its parameters refused with one line.

mod common;
use common::*;
use mjsafe::log::proto;

/// c_d g (m/s²), T (s), v_L (m/s) of Table 1.
const BRAKE: f64 = 0.3 * 9.81;
const HEADWAY: f64 = 1.8;
const LEAD: f64 = 14.0;

/// h = z − T v − (v_L − v)² / (2 c_d g) in metres, from a logged (position, speed, gap).
fn headway_h(x: &[f64]) -> f64 {
    x[2] - HEADWAY * x[1] - (LEAD - x[1]).powi(2) / (2.0 * BRAKE)
}

/// (min h, final state) of a run, h recomputed from /state.
fn run_and_recompute(file: &str, extra: &[&str]) -> (f64, Vec<f64>) {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("acc.mcap");
    run_ok(&scenario(file), &log, extra);
    let states = read_topic::<proto::State>(&log, "/state");
    assert_eq!(states[0].names, ["position", "speed", "gap"]);
    assert_eq!(states.len(), 2001);
    let min_h = states
        .iter()
        .map(|s| headway_h(&s.values))
        .fold(f64::INFINITY, f64::min);
    // The logged metric is the same h, in metres, over the states `/barrier` samples (the
    // start of every step: all but the last state).
    let sampled = states[..states.len() - 1]
        .iter()
        .map(|s| headway_h(&s.values))
        .fold(f64::INFINITY, f64::min);
    let metric = analyze_json(&log)["min_h"].as_f64().unwrap();
    assert!((metric - sampled).abs() < 1e-9, "{metric} vs {sampled} m");
    (min_h, states.last().unwrap().values.clone())
}

#[test]
fn acc_delay_free_cbf_qp_keeps_the_headway_and_settles_behind_the_lead() {
    let (min_h, last) = run_and_recompute("acc_ames2014.toml", &[]);
    println!("acc_ames2014: min h = {min_h:e} m, final {last:?}");
    assert!(min_h >= 0.0, "{min_h}");
    // Settled at the lead's speed, the gap at T v_L (h → 0 from above).
    assert!((last[1] - LEAD).abs() < 0.05, "{last:?}");
    assert!((last[2] - HEADWAY * LEAD).abs() < 0.1, "{last:?}");
}

/// Bound on the largest |MuJoCo − ODE| of the speed and of the gap, each relative to that
/// trajectory's largest magnitude (20 m/s, 100 m): measured 7e-14 and 5e-14 (the same RK4 at
/// h = 0.01 s, F_r evaluated at every stage), so 1e-11 leaves rounding a factor 100.
const MUJOCO_AGREEMENT: f64 = 1e-11;

/// The logged states of a run.
fn states(file: &str, extra: &[&str]) -> Vec<Vec<f64>> {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("acc.mcap");
    run_ok(&scenario(file), &log, extra);
    let states = read_topic::<proto::State>(&log, "/state");
    assert_eq!(states[0].names, ["position", "speed", "gap"]);
    states.into_iter().map(|s| s.values).collect()
}

/// Largest relative differences (speed, gap) of `run` to `reference`.
fn relative_differences(reference: &[Vec<f64>], run: &[Vec<f64>]) -> [f64; 2] {
    assert_eq!(run.len(), reference.len());
    [1, 2].map(|i| {
        let scale = reference.iter().map(|x| x[i].abs()).fold(0.0, f64::max);
        reference
            .iter()
            .zip(run)
            .map(|(a, b)| (a[i] - b[i]).abs() / scale)
            .fold(0.0, f64::max)
    })
}

#[test]
fn acc_on_mujoco_agrees_with_the_ode_run() {
    let ode = states("acc_ames2014.toml", &[]);
    let mujoco = states("acc_ames2014_mujoco.toml", &[]);
    let worst = relative_differences(&ode, &mujoco);
    let min_h = mujoco.iter().map(|x| headway_h(x)).fold(f64::INFINITY, f64::min);
    let last = mujoco.last().unwrap();
    println!(
        "acc_ames2014_mujoco: max relative difference to the ODE run: speed {:e}, gap {:e}; min h = {min_h:e} m, final {last:?}",
        worst[0], worst[1]
    );
    assert!(worst.iter().all(|&w| w <= MUJOCO_AGREEMENT), "{worst:?}");
    // h >= 0 up to the agreement (on the 100 m gap).
    assert!(min_h >= -100.0 * MUJOCO_AGREEMENT, "{min_h}");
    assert!((last[1] - LEAD).abs() < 0.05, "{last:?}");
    assert!((last[2] - HEADWAY * LEAD).abs() < 0.1, "{last:?}");
    // The comparison sees a first-order integrator and a resistance the MJCF does not have.
    let euler = states("acc_ames2014_mujoco.toml", &["--set", "vehicle.integrator='euler'"]);
    let other_f2 = states("acc_ames2014.toml", &["--set", "vehicle.f2=0.3"]);
    for (what, other) in [
        ("Euler", relative_differences(&ode, &euler)),
        ("f2 = 0.3", relative_differences(&other_f2, &mujoco)),
    ] {
        println!("  {what}: {:e}, {:e}", other[0], other[1]);
        assert!(other.iter().all(|&w| w > 1e3 * MUJOCO_AGREEMENT), "{what}: {other:?}");
    }
}

#[test]
fn acc_predictor_keeps_the_headway_under_a_half_second_delay_and_no_compensation_does_not() {
    let (min_h, last) = run_and_recompute("acc_ames2014_delay.toml", &[]);
    println!("acc_ames2014_delay: min h = {min_h:e} m, final {last:?}");
    assert!(min_h >= 0.0, "{min_h}");
    assert!((last[1] - LEAD).abs() < 0.05, "{last:?}");
    let (uncompensated, _) = run_and_recompute("acc_ames2014_delay.toml", &["--set", "filter.compensation='none'"]);
    println!("without compensation: min h = {uncompensated} m");
    assert!(uncompensated < -1.0, "{uncompensated}");
}

#[test]
fn acc_bad_vehicle_parameters_are_one_line_naming_the_key() {
    let cases: [(&str, &[&str]); 4] = [
        ("vehicle.mass=0.0", &["key `vehicle.mass`", "mass > 0"]),
        ("vehicle.f2=-0.25", &["key `vehicle.f2`", ">= 0"]),
        (
            "vehicle.lead_speed=\"fast\"",
            &["key `vehicle.lead_speed`", "expected a number"],
        ),
        (
            "vehicle.drag=1.0",
            &[
                "key `vehicle.drag`",
                "unknown field `drag`",
                "kind `longitudinal`'s own",
            ],
        ),
    ];
    for (set, needles) in cases {
        let err = run_expecting_failure("acc_ames2014.toml", &[set], needles);
        assert!(err.contains("acc_ames2014.toml"), "{err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    }
    run_expecting_failure(
        "acc_ames2014.toml",
        &["nominal.gain=-1.0"],
        &["key `nominal.gain`", "rate > 0"],
    );
}

#[test]
fn acc_mujoco_model_numbers_are_read_and_checked() {
    use mjsafe::mujoco::Model;
    use mjsafe::vehicle::{MujocoLongitudinal, MujocoVehicle};
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/longitudinal.xml");
    let xml = std::fs::read_to_string(&path).unwrap();
    let bind = |xml: &str| MujocoLongitudinal::bind(&Model::from_xml_string(xml, "longitudinal").unwrap());
    // Table 1: the model of the MJCF is the ODE scenario's.
    let vehicle = bind(&xml).unwrap();
    let dynamics = vehicle.dynamics();
    let mut f = [0.0; 3];
    dynamics.drift_into(&[0.0, 20.0, 100.0], &mut f);
    assert_eq!(f, [20.0, -(0.1 + 5.0 * 20.0 + 0.25 * 400.0) / 1650.0, 14.0 - 20.0]);
    let refused = |from: &str, to: &str, needle: &str| {
        assert!(xml.contains(from), "{from}");
        let err = bind(&xml.replace(from, to)).err().expect(to).to_string();
        assert!(err.contains(needle), "{err}");
    };
    refused(
        r#"data="0.25""#,
        r#"data="-0.25""#,
        "f2 is -0.25: expected a finite resistance coefficient >= 0",
    );
    refused(
        r#"name="lead_speed""#,
        r#"name="lead""#,
        "custom numeric named `lead_speed`",
    );
    refused(
        r#"joint name="lead_x""#,
        r#"joint name="lead_y""#,
        "joint named `lead_x`",
    );
}
