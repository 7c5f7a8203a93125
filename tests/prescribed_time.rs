//! Prescribed-time safety (Ch. 5): the outcomes of §5.4 (Figs. 5.1, 5.2) on the MuJoCo double
//! integrator, §5.7 (Figs. 5.3–5.5) on the strict-feedback system, a third-order chain, the
//! metrics `analyze` reports for them, and bad input.

mod common;
use common::*;

use mjsafe::log::proto;

struct Run {
    _dir: tempfile::TempDir,
    log: std::path::PathBuf,
    metrics: serde_json::Value,
}

fn run(scenario_file: &str, extra: &[&str]) -> Run {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    run_ok(&scenario(scenario_file), &log, extra);
    let metrics = analyze_json(&log);
    Run {
        _dir: dir,
        log,
        metrics,
    }
}

impl Run {
    /// max y = x1 over t < `until`.
    fn max_output_before(&self, until: f64) -> f64 {
        read_topic::<proto::State>(&self.log, "/state")
            .iter()
            .filter(|s| s.time < until - 1e-9)
            .map(|s| s.values[0])
            .fold(f64::NEG_INFINITY, f64::max)
    }
    /// A number metric, or the one channel's value of a per-channel metric.
    fn metric(&self, key: &str) -> f64 {
        let value = &self.metrics[key];
        value
            .as_f64()
            .or_else(|| {
                value
                    .as_object()
                    .filter(|m| m.len() == 1)
                    .and_then(|m| m.values().next()?.as_f64())
            })
            .unwrap_or_else(|| panic!("{key} missing: {}", self.metrics))
    }
}

#[test]
fn red_light_ptsf_is_safe_until_t_without_the_jerk_of_a_fast_esf() {
    let t = 4.0;
    let nominal = run("red_light.toml", &["--set", "filter={kind='none'}"]);
    let ptsf = run("red_light.toml", &[]);
    let esf_slow = run(
        "red_light.toml",
        &["--set", "filter={kind='esf', rate=0.6, horizon=4.0}"],
    );
    let esf_fast = run(
        "red_light.toml",
        &["--set", "filter={kind='esf', rate=3.2, horizon=4.0}"],
    );
    println!(
        "red_light: nominal max y on [0, T) = {:.3}; PTSf max y = {:.2e}, first override {}, peak jerk {:.2}; \
         ESf 0.6 first override {}, h(T) = {}; ESf 3.2 first override {}, peak jerk {:.2}",
        nominal.max_output_before(t),
        ptsf.max_output_before(t),
        ptsf.metrics["first_override_time"],
        ptsf.metric("max_input_rate_overriding"),
        esf_slow.metrics["first_override_time"],
        esf_slow.metrics["at_prescribed_time"]["barrier"],
        esf_fast.metrics["first_override_time"],
        esf_fast.metric("max_input_rate_overriding"),
    );
    // The nominal alone crosses the line before T; PTSf keeps y < 0 on [0, T).
    assert!(nominal.max_output_before(t) > 0.0);
    assert!(ptsf.max_output_before(t) < 0.0);
    // ESf ρ = 0.6 overrides much earlier and stays more conservative (further from the line at T).
    let ptsf_first = ptsf.metric("first_override_time");
    assert!(esf_slow.metric("first_override_time") < ptsf_first - 0.5);
    let barrier_at_t = |r: &Run| r.metrics["at_prescribed_time"]["barrier"].as_f64().unwrap();
    assert!(barrier_at_t(&esf_slow) > barrier_at_t(&ptsf));
    // ESf ρ = 3.2 reacts about when PTSf does, with several times PTSf's peak jerk.
    assert!((esf_fast.metric("first_override_time") - ptsf_first).abs() < 0.25);
    assert!(esf_fast.metric("max_input_rate_overriding") > 2.5 * ptsf.metric("max_input_rate_overriding"));
    // After T + T̄ the PTSf run issues exactly the nominal; ESf keeps overriding.
    let after = |r: &Run| -> Vec<proto::IssuedCommand> {
        read_topic::<proto::IssuedCommand>(&r.log, "/command/issued")
            .into_iter()
            .filter(|c| c.time >= t + 0.5)
            .collect()
    };
    assert!(after(&ptsf).iter().all(|c| c.filtered == c.nominal));
    assert!(after(&esf_slow).iter().any(|c| c.filtered != c.nominal));
}

#[test]
fn strict_feedback_ptsf_is_safe_and_lands_softly_at_t() {
    let ptsf = run("strict_feedback_pts.toml", &[]);
    let esf = run(
        "strict_feedback_pts.toml",
        &["--set", "filter={kind='esf', rate=1.2, horizon=1.0}"],
    );
    let at_t = &ptsf.metrics["at_prescribed_time"];
    let residual = at_t["state_residuals"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .fold(0.0, f64::max);
    let esf_y = -esf.metrics["at_prescribed_time"]["barrier"].as_f64().unwrap();
    println!(
        "strict_feedback_pts: max y on [0, 1) = {:.2e}, |x(T)| = {residual:.2e}, |u(T)| = {}; ESf 1.2 y(T) = {esf_y:.3}",
        ptsf.max_output_before(1.0),
        at_t["input_residual"]
    );
    assert!(ptsf.max_output_before(1.0) < 0.0);
    // Infinitely soft landing (Remark 5.1): x and u reach 0 at T.
    assert!(residual < 1e-3, "|x(T)| = {residual}");
    assert!(at_t["input_residual"].as_f64().unwrap() < 1e-2, "{at_t}");
    // ESf ρ = 1.2 does not get near the barrier by T.
    assert!(esf_y < -0.3, "ESf y(T) = {esf_y}");
}

#[test]
fn third_order_chain_ptsf_holds_y_below_zero_with_bounded_control() {
    let nominal = run("chain3_ptsf.toml", &["--set", "filter={kind='none'}"]);
    let ptsf = run("chain3_ptsf.toml", &[]);
    let max_input = read_topic::<proto::IssuedCommand>(&ptsf.log, "/command/issued")
        .iter()
        .filter(|c| c.time < 3.0)
        .map(|c| c.filtered[0].abs())
        .fold(0.0, f64::max);
    println!(
        "chain3_ptsf: nominal max y on [0, T) = {:.3}; PTSf max y = {:.2e}, max |u| on [0, T) = {max_input:.3}",
        nominal.max_output_before(3.0),
        ptsf.max_output_before(3.0)
    );
    assert!(nominal.max_output_before(3.0) > 0.0);
    assert!(ptsf.max_output_before(3.0) < 0.0);
    assert!(max_input.is_finite() && max_input < 100.0);
}

fn expect_error(file: &str, set: &[&str], needles: &[&str]) {
    run_expecting_failure(file, set, needles);
}

#[test]
fn prescribed_time_bad_input_is_rejected_before_the_run() {
    expect_error(
        "red_light.toml",
        &["filter.horizon=0.0"],
        &["red_light.toml", "filter.horizon", "T > 0"],
    );
    expect_error(
        "red_light.toml",
        &["vehicle.initial_state=[0.5, 0.0]"],
        &["filter", "unsafe"],
    );
    expect_error("red_light.toml", &["filter.clip=1.0"], &["filter.clip", "> 1"]);
    expect_error("chain3_ptsf.toml", &["filter.order=2"], &["filter.order", "order 3"]);
}
