//! What the controller sees and what the actuators do (issue 16, parts 3 and 5): a sensor
//! (latency, bias, seeded noise) between the true state and the controller, logged on
//! `/state/measured` next to `/state`; actuator dynamics (lag, rate and magnitude limits)
//! between the delayed command and the plant, logged on `/command/actuated`.

mod common;

use std::path::{Path, PathBuf};

use common::*;
use mjsafe::log::proto;

const GAMMA_M: &str = "bicycle_obstacle_gamma_m.toml";
/// The scenario's plant step and control period.
const H: f64 = 0.002;

fn run(dir: &Path, name: &str, sets: &[&str]) -> PathBuf {
    let log = dir.join(name);
    let mut args = Vec::new();
    for s in sets {
        args.extend_from_slice(&["--set", *s]);
    }
    run_ok(&scenario(GAMMA_M), &log, &args);
    log
}

fn min_h(log: &Path) -> f64 {
    analyze_json(log)["min_h"].as_f64().expect("min_h")
}

/// True state per step (index = step).
fn states(log: &Path) -> Vec<proto::State> {
    read_topic::<proto::State>(log, "/state")
}

const TOPICS: [&str; 6] = [
    "/state",
    "/command/issued",
    "/command/applied",
    "/barrier",
    "/filter",
    "/prediction",
];

#[test]
fn an_ideal_sensor_reads_the_true_state_and_changes_nothing_else() {
    let dir = tempfile::tempdir().unwrap();
    let plain = run(dir.path(), "plain.mcap", &[]);
    let ideal = run(dir.path(), "ideal.mcap", &["sensing={latency=0.0}"]);
    assert_same_messages(&plain, &ideal, &TOPICS, &[]);
    assert!(raw_topic(&plain, "/state/measured").is_empty(), "no sensor, no topic");
    let truth = states(&ideal);
    let measured = read_topic::<proto::State>(&ideal, "/state/measured");
    assert_eq!(measured.len(), 1200, "one reading per control tick (12 s at 100 Hz)");
    for m in &measured {
        let x = &truth[m.step as usize];
        assert_eq!((m.time, &m.names, &m.values), (x.time, &x.names, &x.values));
    }
}

#[test]
fn a_late_biased_sensor_reports_the_state_latency_earlier_plus_the_bias() {
    let dir = tempfile::tempdir().unwrap();
    let log = run(
        dir.path(),
        "late.mcap",
        &["sensing={latency=0.1, bias=[0.0, 0.5, 0.0, -0.2]}"],
    );
    let truth = states(&log);
    let late_steps = (0.1 / H).round() as u64;
    for m in read_topic::<proto::State>(&log, "/state/measured") {
        let source = &truth[m.step.saturating_sub(late_steps) as usize];
        let expected: Vec<f64> = source
            .values
            .iter()
            .zip([0.0, 0.5, 0.0, -0.2])
            .map(|(x, b)| x + b)
            .collect();
        assert_eq!(m.values, expected, "t = {}", m.time);
    }
    // The controller acted on the measurement: the issued commands differ from the truth's.
    let plain = run(dir.path(), "plain.mcap", &[]);
    assert_ne!(raw_topic(&log, "/command/issued"), raw_topic(&plain, "/command/issued"));
}

#[test]
fn sensor_noise_is_seeded_deterministic_and_has_the_given_deviation() {
    let dir = tempfile::tempdir().unwrap();
    let noise = "sensing={noise_std=[0.2, 0.0, 0.0, 0.05]}";
    let a = run(dir.path(), "a.mcap", &[noise, "seed=3"]);
    let b = run(dir.path(), "b.mcap", &[noise, "seed=3"]);
    let c = run(dir.path(), "c.mcap", &[noise, "seed=4"]);
    assert_eq!(
        std::fs::read(&a).unwrap(),
        std::fs::read(&b).unwrap(),
        "same seed, same bytes"
    );
    assert_ne!(raw_topic(&a, "/state/measured"), raw_topic(&c, "/state/measured"));
    let truth = states(&a);
    let errors: Vec<[f64; 4]> = read_topic::<proto::State>(&a, "/state/measured")
        .iter()
        .map(|m| {
            let x = &truth[m.step as usize].values;
            [0, 1, 2, 3].map(|j| m.values[j] - x[j])
        })
        .collect();
    let moments = |j: usize| {
        let n = errors.len() as f64;
        let mean = errors.iter().map(|e| e[j]).sum::<f64>() / n;
        let std = (errors.iter().map(|e| (e[j] - mean).powi(2)).sum::<f64>() / n).sqrt();
        (mean, std)
    };
    let (mean0, std0) = moments(0);
    let (mean3, std3) = moments(3);
    assert!(
        mean0.abs() < 0.02 && (std0 - 0.2).abs() < 0.02,
        "x1: mean {mean0}, std {std0}"
    );
    assert!(
        mean3.abs() < 0.005 && (std3 - 0.05).abs() < 0.005,
        "speed: mean {mean3}, std {std3}"
    );
    assert!(errors.iter().all(|e| e[1] == 0.0 && e[2] == 0.0), "σ = 0: exact");
    // An independent reader (Python mcap, CRCs checked) reads the optional topic.
    let digest = python_digest(&a);
    assert_eq!(digest["counts"]["/state/measured"], 1200);
    assert_eq!(digest["schemas"]["/state/measured"], "mjsafe.State");
}

#[test]
fn position_noise_breaks_the_gamma_m_filter_that_a_late_or_biased_sensor_does_not() {
    let dir = tempfile::tempdir().unwrap();
    let clear = min_h(&run(dir.path(), "truth.mcap", &[]));
    let late = min_h(&run(dir.path(), "late.mcap", &["sensing={latency=0.1}"]));
    let later = min_h(&run(dir.path(), "later.mcap", &["sensing={latency=0.2}"]));
    let noisy = min_h(&run(
        dir.path(),
        "noisy.mcap",
        &["sensing={noise_std=[0.2, 0.2, 0.02, 0.1]}", "seed=0"],
    ));
    println!("(4.67) min h: true state {clear:.4}, sensor latency 0.1 s {late:.4}, 0.2 s {later:.4}, noise σ = 0.2 m {noisy:.4}");
    assert!(clear > 0.0 && late > 0.0, "{clear} {late}");
    assert!(later < 0.0, "0.2 s sensor latency: {later}");
    assert!(noisy < 0.0, "{noisy}");
}

#[test]
fn sensing_study_3_cm_of_position_noise_makes_half_the_runs_graze_the_obstacle() {
    // scenarios/sensing.sweep.toml, its σ = 3 cm row (docs/studies.md): 5 of 10 seeds collide,
    // each by less than a millimetre; without noise none does.
    let dir = tempfile::tempdir().unwrap();
    let mut collided = 0;
    for seed in 1..=10 {
        let log = run(
            dir.path(),
            &format!("s{seed}.mcap"),
            &[
                "sensing={noise_std=[0.03, 0.03, 0.003, 0.015]}",
                &format!("seed={seed}"),
            ],
        );
        let metrics = analyze_json(&log);
        if !metrics["collision"].is_null() {
            collided += 1;
            let clearance = metrics["min_clearance"].as_f64().unwrap();
            assert!(clearance > -0.001, "seed {seed}: a graze, not a crash ({clearance} m)");
        }
    }
    assert_eq!(collided, 5, "collisions of 10 seeds");
}

#[test]
fn limits_that_never_bind_change_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let plain = run(dir.path(), "plain.mcap", &[]);
    let loose = run(
        dir.path(),
        "loose.mcap",
        &[
            "actuator_dynamics.acceleration={min=-1e6, max=1e6}",
            "actuator_dynamics.steering={max=1e6}",
        ],
    );
    assert_same_messages(&plain, &loose, &TOPICS, &[]);
    let applied = read_topic::<proto::AppliedCommand>(&plain, "/command/applied");
    let actuated = read_topic::<proto::AppliedCommand>(&loose, "/command/actuated");
    assert_eq!(applied, actuated);
}

#[test]
fn a_lagged_actuator_follows_the_exact_first_order_response_of_the_applied_commands() {
    let dir = tempfile::tempdir().unwrap();
    let tau = 0.15;
    let log = run(
        dir.path(),
        "lag.mcap",
        &[&format!("actuator_dynamics.steering={{time_constant={tau}}}")],
    );
    let applied = read_topic::<proto::AppliedCommand>(&log, "/command/applied");
    let actuated = read_topic::<proto::AppliedCommand>(&log, "/command/actuated");
    assert_eq!(applied.len(), actuated.len());
    // Independently: a_{k+1} = u_k + (a_k − u_k) e^{−h/τ}; the step receives a's mean,
    // u_k + (a_k − u_k) (τ/h)(1 − e^{−h/τ}). Acceleration has no actuator: passed through.
    let decay = (-H / tau).exp();
    let mut a = 0.0;
    let mut largest_lag: f64 = 0.0;
    for (u, m) in applied.iter().zip(&actuated) {
        let command = u.values[0];
        let mean = command + (a - command) * (tau / H) * (1.0 - decay);
        assert!(
            (m.values[0] - mean).abs() < 1e-9,
            "t = {}: {} vs {mean}",
            m.time,
            m.values[0]
        );
        assert_eq!(m.values[1], u.values[1]);
        largest_lag = largest_lag.max((m.values[0] - command).abs());
        a = command + (a - command) * decay;
    }
    assert!(largest_lag > 0.5, "the lag shows: {largest_lag}");
    // docs/studies.md: a 0.1–0.15 s steering lag does not defeat (4.67).
    assert!(min_h(&log) > 0.0);
}

#[test]
fn rate_and_magnitude_limits_hold_and_a_steering_rate_limit_breaks_the_gamma_m_filter() {
    let dir = tempfile::tempdir().unwrap();
    let limited = run(
        dir.path(),
        "rate.mcap",
        &["actuator_dynamics.steering={rate_limit=2.0, min=-3.0, max=3.0}"],
    );
    let actuated = read_topic::<proto::AppliedCommand>(&limited, "/command/actuated");
    let steering: Vec<f64> = actuated.iter().map(|m| m.values[0]).collect();
    assert!(steering.iter().all(|u| (-3.0..=3.0).contains(u)));
    // Means of a ramp at rate ≤ R over consecutive steps differ by at most R h.
    for w in steering.windows(2) {
        assert!((w[1] - w[0]).abs() <= 2.0 * H + 1e-12, "{w:?}");
    }
    assert!(steering.iter().any(|u| u.abs() > 1.0), "the actuator moved");
    let h_rate = min_h(&limited);
    let accel_range = min_h(&run(
        dir.path(),
        "range.mcap",
        &["actuator_dynamics.acceleration={min=-2.0, max=2.0}"],
    ));
    println!("(4.67) min h: steering rate ≤ 2/s {h_rate:.3}, |acceleration| ≤ 2 m/s² {accel_range:.4}");
    assert!(h_rate < -1.0, "{h_rate}");
    assert!(accel_range > 0.0, "{accel_range}");
    let digest = python_digest(&limited);
    assert_eq!(digest["schemas"]["/command/actuated"], "mjsafe.AppliedCommand");
}

#[test]
fn bad_sensing_and_actuator_tables_name_the_field() {
    for (set, needles) in [
        (
            "sensing={noise_std=[0.1, 0.1]}",
            &["sensing.noise_std", "one value per state component (4"][..],
        ),
        ("sensing={latency=-1.0}", &["sensing.latency", ">= 0"]),
        (
            "sensing={latency=0.003}",
            &["sensing.latency", "whole multiple of the timestep"],
        ),
        ("sensing={bias=[0, 0, 0, nan]}", &["sensing.bias", "finite"]),
        ("sensing={noise=1}", &["sensing", "noise"]),
        (
            "actuator_dynamics.brake={time_constant=0.1}",
            &["actuator_dynamics.brake", "steering, acceleration"],
        ),
        (
            "actuator_dynamics.steering={time_constant=-0.1}",
            &["actuator_dynamics.steering.time_constant"],
        ),
        (
            "actuator_dynamics.steering={rate_limit=0.0}",
            &["actuator_dynamics.steering.rate_limit", "positive"],
        ),
        (
            "actuator_dynamics.steering={min=1.0, max=0.5}",
            &["actuator_dynamics.steering.max", "max >= min"],
        ),
    ] {
        run_expecting_failure(GAMMA_M, &[set], needles);
    }
}
