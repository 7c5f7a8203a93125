//! Time-varying delays and predictors (Ch. 2): the outcomes of §2.4 (Figs. 2.2, 2.3),
//! prediction consistency (Definition 4.3), and delay-profile bad input.

mod common;
use common::*;

use mjsafe::log::proto;

fn run(scenario_file: &str, name: &str, extra: &[&str]) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join(format!("{name}.mcap"));
    run_ok(&scenario(scenario_file), &log, extra);
    (dir, log)
}

/// (time, x) of a one-dimensional state.
fn scalar_states(log: &std::path::Path) -> Vec<(f64, f64)> {
    read_topic::<proto::State>(log, "/state")
        .iter()
        .map(|s| (s.time, s.values[0]))
        .collect()
}

#[test]
fn scalar_compensated_from_0_15_never_leaves_the_safe_set() {
    let (_dir, log) = run("scalar_tv_delay.toml", "c015", &[]);
    let m = analyze_json(&log);
    println!("scalar_tv_delay x(0) = 0.15 compensated: min h = {}", m["min_h"]);
    assert!(m["min_h"].as_f64().unwrap() >= 0.0, "{m}");
}

#[test]
fn scalar_uncompensated_leaves_and_keeps_moving_away_for_both_starts() {
    // The uncompensated filter (2.16) reacts to x(t) with inputs that arrive 1–1.5 s later:
    // x leaves [−2, 2] and its excursions grow without bound.
    for x0 in ["0.15", "-0.5"] {
        let (_dir, log) = run(
            "scalar_tv_delay.toml",
            "u",
            &[
                "--set",
                &format!("vehicle.initial_state=[{x0}]"),
                "--set",
                "filter.compensation='none'",
                "--set",
                "duration=20.0",
            ],
        );
        let states = scalar_states(&log);
        let peak = |from: f64, to: f64| {
            states
                .iter()
                .filter(|(t, _)| *t >= from && *t < to)
                .map(|(_, x)| x.abs())
                .fold(0.0, f64::max)
        };
        let (first, second) = (peak(0.0, 10.0), peak(10.0, 20.1));
        println!(
            "scalar_tv_delay x(0) = {x0} uncompensated: max |x| on [0, 10) = {first:.3}, on [10, 20] = {second:.3}"
        );
        assert!(first > 2.0, "x(0) = {x0}: never left the safe set");
        assert!(
            second > first,
            "x(0) = {x0}: excursions did not grow ({first} -> {second})"
        );
    }
}

#[test]
fn scalar_compensated_from_minus_0_5_returns_towards_the_safe_set_after_1_5_s() {
    let (_dir, log) = run(
        "scalar_tv_delay.toml",
        "c05",
        &["--set", "vehicle.initial_state=[-0.5]"],
    );
    let states = scalar_states(&log);
    let at = |t: f64| states.iter().find(|(s, _)| (s - t).abs() < 1e-9).unwrap().1;
    // No control arrives before φ⁻¹(0) = 1.5: x(1.5) = −0.5 e^{1.5} ≈ −2.24.
    let x15 = at(1.5);
    println!(
        "scalar_tv_delay x(0) = -0.5 compensated: x(1.5) = {x15:.4}, x(10) = {:.4}",
        at(10.0)
    );
    assert!((x15 - (-0.5 * 1.5f64.exp())).abs() < 1e-6, "x(1.5) = {x15}");
    // Afterwards h = 4 − x² rises monotonically towards 0 and x never moves further out.
    let h: Vec<f64> = states
        .iter()
        .filter(|(t, _)| *t >= 1.5 - 1e-9)
        .map(|(_, x)| 4.0 - x * x)
        .collect();
    for w in h.windows(2) {
        assert!(w[1] >= w[0] - 1e-9, "h decreased after 1.5 s: {} -> {}", w[0], w[1]);
    }
    assert!(
        h.last().unwrap() <= &0.0 && *h.last().unwrap() > -0.1,
        "h(10) = {}",
        h.last().unwrap()
    );
}

#[test]
fn unicycle_compensated_never_crosses_and_uncompensated_does() {
    let (_d1, compensated) = run("unicycle_tv_delay.toml", "c", &[]);
    let (_d2, uncompensated) = run("unicycle_tv_delay.toml", "u", &["--set", "filter.compensation='none'"]);
    let c = analyze_json(&compensated);
    let u = analyze_json(&uncompensated);
    println!(
        "unicycle_tv_delay (MuJoCo): min h compensated = {}, uncompensated = {}; prediction consistency {}",
        c["min_h"], u["min_h"], c["prediction"]
    );
    // h = x + 0.1; MuJoCo's unicycle follows the ODE to ~1e-3 m (fidelity test).
    assert!(c["min_h"].as_f64().unwrap() >= -2e-3, "{c}");
    assert!(u["min_h"].as_f64().unwrap() < -0.1, "{u}");
}

#[test]
fn prediction_is_consistent_to_integration_error_on_the_ode_plant() {
    let (_dir, log) = run("scalar_tv_delay.toml", "p", &[]);
    let m = analyze_json(&log);
    let stats = &m["prediction"]["u1"];
    println!("scalar_tv_delay (ODE) prediction consistency: {stats}");
    assert!(stats["count"].as_u64().unwrap() > 900);
    assert!(stats["max_relative_error"].as_f64().unwrap() <= 1e-6, "{stats}");
    // Distinct constant delays on the ODE bicycle: the steering prediction uses only issued
    // history and is exact; the recursive acceleration prediction is exact until the obstacle
    // appears (the predicted future steering law then changes: Definition 4.3's point).
    let (_d, bicycle) = run(
        "bicycle_obstacle.toml",
        "b",
        &["--set", "plant='ode'", "--set", "filter.compensation='predictor'"],
    );
    let m = analyze_json(&bicycle);
    println!("bicycle_obstacle (ODE, predictor) consistency: {}", m["prediction"]);
    assert!(m["prediction"]["steering"]["max_relative_error"].as_f64().unwrap() <= 1e-6);
    let before: Vec<proto::Prediction> = read_topic::<proto::Prediction>(&bicycle, "/prediction")
        .into_iter()
        .filter(|p| p.channel == "acceleration" && p.issued_at < 2.75 - 1.5)
        .collect();
    assert!(!before.is_empty());
    let worst = before.iter().map(|p| p.relative_error).fold(0.0, f64::max);
    assert!(worst <= 1e-6, "recursive prediction before the obstacle: {worst}");
}

#[test]
fn bicycle_outcomes_hold_on_the_analytic_model_too() {
    let (_d1, nodelay) = run("bicycle_obstacle_nodelay.toml", "n", &["--set", "plant='ode'"]);
    let (_d2, delayed) = run("bicycle_obstacle.toml", "d", &["--set", "plant='ode'"]);
    let n = analyze_json(&nodelay);
    let d = analyze_json(&delayed);
    println!(
        "bicycle on the ODE plant: no delay min h = {}, delayed collision = {}",
        n["min_h"], d["collision"]
    );
    assert!(n["collision"].is_null() && n["min_h"].as_f64().unwrap() >= -1e-6, "{n}");
    assert!(!d["collision"].is_null(), "{d}");
}

fn expect_delay_error(set: &[&str], needles: &[&str]) {
    run_expecting_failure("scalar_tv_delay.toml", set, needles);
}

#[test]
fn delay_profiles_that_break_the_assumptions_are_rejected_before_the_run() {
    // dD/dt = 1.5 > 1 on [1, 2]: (2.6) fails at t = 1.
    expect_delay_error(
        &["delays.u1={ profile = 'table', times = [1.0, 2.0], delays = [0.5, 2.0] }"],
        &["scalar_tv_delay.toml", "delays.u1", "(2.6)", "t = 1.0"],
    );
    // |b ω| > 1: φ⁻¹ is not increasing.
    expect_delay_error(&["delays.u1.b=2.0"], &["delays.u1", "(2.6)"]);
    // D reaches 0.
    expect_delay_error(
        &["delays.u1={ profile = 'table', times = [0.0, 1.0], delays = [0.5, 0.0] }"],
        &["delays.u1", "(2.4)"],
    );
    // NaN parameters.
    expect_delay_error(&["delays.u1.omega=nan"], &["delays.u1", "omega = NaN"]);
    expect_delay_error(
        &["delays.u1={ profile = 'table', times = [0.0, nan], delays = [0.5, 0.5] }"],
        &["delays.u1", "finite"],
    );
    // A delay longer than the history kept.
    expect_delay_error(
        &["control.history=1.0"],
        &["delays.u1", "longer than the 1 s of input history"],
    );
}

/// A prediction whose target time lies past the run's end has no realised state: none is
/// logged (its "realised" state was the final state extrapolated past the run).
#[test]
fn no_prediction_is_realised_past_the_end_of_the_run() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["scalar_tv_delay", "unicycle_tv_delay"] {
        let log = dir.path().join(format!("{name}.mcap"));
        run_ok(&scenario(&format!("{name}.toml")), &log, &["--set", "duration=2.0"]);
        let end = analyze_json(&log)["simulated_time"].as_f64().unwrap();
        let predictions = read_topic::<proto::Prediction>(&log, "/prediction");
        assert!(!predictions.is_empty(), "{name}");
        let last = predictions.iter().map(|p| p.time).fold(f64::MIN, f64::max);
        assert!(
            last <= end + 1e-9,
            "{name}: a prediction realised at {last} > the end {end}"
        );
        assert!(last > end - 0.01, "{name}: predictions up to the end ({last}, {end})");
    }
}
