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

/// Largest |MuJoCo − ODE| of the speed and of the gap, each relative to the largest magnitude of
/// that trajectory (20 m/s, 100 m); measured 0 (bit for bit) to
/// 1e-3: the bound is [`MUJOCO_AGREEMENT`].
const MUJOCO_AGREEMENT: f64 = 1e-9;

#[test]
fn acc_on_mujoco_agrees_with_the_ode_run() {
    let states = |file: &str| {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("acc.mcap");
        run_ok(&scenario(file), &log, &[]);
        let states = read_topic::<proto::State>(&log, "/state");
        assert_eq!(states[0].names, ["position", "speed", "gap"]);
        states.into_iter().map(|s| s.values).collect::<Vec<_>>()
    };
    let ode = states("acc_ames2014.toml");
    let mujoco = states("acc_ames2014_mujoco.toml");
    assert_eq!(mujoco.len(), ode.len());
    let mut worst = [0.0f64; 2];
    for (i, w) in [1, 2].into_iter().zip(&mut worst) {
        let scale = ode.iter().map(|x| x[i].abs()).fold(0.0, f64::max);
        *w = ode
            .iter()
            .zip(&mujoco)
            .map(|(a, b)| (a[i] - b[i]).abs() / scale)
            .fold(0.0, f64::max);
    }
    let min_h = mujoco.iter().map(|x| headway_h(x)).fold(f64::INFINITY, f64::min);
    let last = mujoco.last().unwrap();
    println!(
        "acc_ames2014_mujoco: max relative difference to the ODE run: speed {:e}, gap {:e}; min h = {min_h:e} m, final {last:?}",
        worst[0], worst[1]
    );
    assert!(worst[0] <= MUJOCO_AGREEMENT && worst[1] <= MUJOCO_AGREEMENT, "{worst:?}");
    assert!(min_h >= -MUJOCO_AGREEMENT * 100.0, "{min_h}");
    assert!((last[1] - LEAD).abs() < 0.05, "{last:?}");
    assert!((last[2] - HEADWAY * LEAD).abs() < 0.1, "{last:?}");
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
