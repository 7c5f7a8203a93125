//! Stochastic actuation (issue 16, part 2): seeded extra latency and dropped commands on the
//! actuators, delays that are not multiples of the timestep. The latency of each command is
//! read from the log: the first `/command/applied` record carrying its `issued_at`.

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use common::*;
use mjsafe::log::proto;

/// Per channel: issue time → the time it first applied.
fn first_applied(log: &Path) -> Vec<BTreeMap<u64, f64>> {
    let mut out: Vec<BTreeMap<u64, f64>> = Vec::new();
    for m in read_topic::<proto::AppliedCommand>(log, "/command/applied") {
        out.resize(m.issued_at.len(), BTreeMap::new());
        for (i, issued) in m.issued_at.iter().enumerate() {
            if *issued >= 0.0 {
                out[i].entry((issued * 1e6).round() as u64).or_insert(m.time);
            }
        }
    }
    out
}

fn issue_times(log: &Path) -> Vec<f64> {
    read_topic::<proto::IssuedCommand>(log, "/command/issued")
        .iter()
        .map(|m| m.time)
        .collect()
}

const GAMMA_M: &str = "bicycle_obstacle_gamma_m.toml";

#[test]
fn extra_latency_is_seeded_bounded_and_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let jitter = "actuation.steering={extra_latency={distribution='uniform', max=0.05}}";
    let run = |name: &str, seed: u64| {
        let log = dir.path().join(name);
        run_ok(
            &scenario(GAMMA_M),
            &log,
            &["--set", jitter, "--set", &format!("seed={seed}")],
        );
        log
    };
    let (a, b, c) = (run("a.mcap", 1), run("b.mcap", 1), run("c.mcap", 2));
    assert_eq!(
        std::fs::read(&a).unwrap(),
        std::fs::read(&b).unwrap(),
        "same seed, same bytes"
    );
    assert_ne!(
        raw_topic(&a, "/command/applied"),
        raw_topic(&c, "/command/applied"),
        "another seed, other latencies"
    );
    // Steering (true delay 0.2 s): every command that applies does so within [0.2, 0.25 + h]
    // after its issue, and the latencies spread over that interval.
    let h = 0.002;
    let latencies: Vec<f64> = first_applied(&a)[0]
        .iter()
        .map(|(issued, applied)| applied - *issued as f64 / 1e6)
        .collect();
    assert!(latencies.len() > 500, "{}", latencies.len());
    assert!(
        latencies.iter().all(|l| (0.2 - 1e-9..=0.25 + h + 1e-9).contains(l)),
        "{latencies:?}"
    );
    let mean = latencies.iter().sum::<f64>() / latencies.len() as f64;
    assert!((0.215..0.235).contains(&mean), "mean latency {mean}");
}

#[test]
fn dropped_commands_never_apply_and_the_actuator_holds_the_last() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("drop.mcap");
    run_ok(
        &scenario(GAMMA_M),
        &log,
        &["--set", "actuation.steering={drop_probability=0.2}"],
    );
    let issued = issue_times(&log);
    let applied = &first_applied(&log)[0];
    // Commands that can have arrived by the end (issued before 12 − 0.2 s).
    let due: Vec<f64> = issued.iter().copied().filter(|t| *t < 11.79).collect();
    let never = due
        .iter()
        .filter(|t| !applied.contains_key(&((**t * 1e6).round() as u64)))
        .count();
    let fraction = never as f64 / due.len() as f64;
    assert!(
        (0.17..0.23).contains(&fraction),
        "dropped fraction {fraction} of {}",
        due.len()
    );
    // Without latency jitter, each command that applies does so exactly 0.2 s after its issue.
    for (issued, at) in applied {
        assert!((at - *issued as f64 / 1e6 - 0.2).abs() < 1e-9);
    }
}

#[test]
fn a_delay_off_the_step_grid_applies_from_the_next_step() {
    // True steering delay 0.205 s with h = 2 ms: the command arrives between steps and applies
    // from the first step starting after it (0.206 s after its issue); the controller assumes
    // 0.2 s.
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("off.mcap");
    run_ok(
        &scenario(GAMMA_M),
        &log,
        &[
            "--set",
            "delays.steering=0.205",
            "--set",
            "assumed_delays.steering=0.2",
            "--set",
            "actuation.steering={}",
        ],
    );
    let applied = &first_applied(&log)[0];
    assert!(applied.len() > 1000);
    for (issued, at) in applied {
        assert!((at - *issued as f64 / 1e6 - 0.206).abs() < 1e-9, "{issued} {at}");
    }
    // Without `actuation`, the controller's grid rule still holds for the true delay.
    run_expecting_failure(
        GAMMA_M,
        &["delays.steering=0.205"],
        &["key `delays.steering`", "multiple"],
    );
}

#[test]
fn an_actuation_without_randomness_changes_no_message() {
    let dir = tempfile::tempdir().unwrap();
    let (plain, line) = (dir.path().join("plain.mcap"), dir.path().join("line.mcap"));
    run_ok(&scenario(GAMMA_M), &plain, &[]);
    run_ok(
        &scenario(GAMMA_M),
        &line,
        &["--set", "actuation.steering={}", "--set", "actuation.acceleration={}"],
    );
    assert_same_messages(
        &plain,
        &line,
        &[
            "/state",
            "/command/issued",
            "/command/applied",
            "/barrier",
            "/prediction",
        ],
        &[],
    );
}

#[test]
fn bad_actuation_tables_name_the_key() {
    run_expecting_failure(
        GAMMA_M,
        &["actuation.steering={drop_probability=1.0}"],
        &["key `actuation.steering.drop_probability`", "[0, 1)"],
    );
    run_expecting_failure(
        GAMMA_M,
        &["actuation.steering={extra_latency={distribution='uniform', max=-1.0}}"],
        &["key `actuation.steering.extra_latency`"],
    );
    run_expecting_failure(
        GAMMA_M,
        &["actuation.brake={}"],
        &["key `actuation.brake`", "unknown input channel"],
    );
}

#[test]
fn jitter_study_4_67_stays_clear_where_4_34_collides_deeper() {
    // scenarios/jitter.sweep.toml, a few of its runs: uniform extra latency on both channels.
    let dir = tempfile::tempdir().unwrap();
    let jitter = |max: f64| {
        format!(
            "actuation={{steering={{extra_latency={{distribution='uniform', max={max}}}}}, acceleration={{extra_latency={{distribution='uniform', max={max}}}}}}}"
        )
    };
    let min_h = |log: &Path| analyze_json(log)["min_h"].as_f64().unwrap();
    let collides = |log: &Path| !analyze_json(log)["collision"].is_null();
    for seed in [1, 2, 3] {
        let log = dir.path().join(format!("gm{seed}.mcap"));
        run_ok(
            &scenario(GAMMA_M),
            &log,
            &["--set", &jitter(0.3), "--set", &format!("seed={seed}")],
        );
        assert!(
            !collides(&log) && min_h(&log) > 0.0,
            "(4.67), 300 ms jitter, seed {seed}"
        );
    }
    let predictor = "filter={kind='cbf_qp', l0=4.0, l1=4.0, compensation='predictor'}";
    let (calm, jittery) = (dir.path().join("p0.mcap"), dir.path().join("p3.mcap"));
    run_ok(&scenario(GAMMA_M), &calm, &["--set", predictor]);
    run_ok(
        &scenario(GAMMA_M),
        &jittery,
        &["--set", predictor, "--set", &jitter(0.3)],
    );
    assert!(collides(&calm) && collides(&jittery));
    assert!(
        min_h(&jittery) < min_h(&calm) - 0.5,
        "{} vs {}",
        min_h(&jittery),
        min_h(&calm)
    );
}

#[test]
fn the_longest_delay_in_the_metadata_includes_the_extra_latency_bound() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("bound.mcap");
    run_ok(
        &scenario(GAMMA_M),
        &log,
        &[
            "--set",
            "actuation.acceleration={extra_latency={distribution='uniform', max=0.25}}",
        ],
    );
    let o = mjsafe(&["info", "--json", log.to_str().unwrap()]);
    let text = stdout(&o);
    assert!(text.contains("\"max_delay\": \"1.75\""), "{text}");
}
