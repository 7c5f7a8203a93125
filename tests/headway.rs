//! The headway metrics (docs/metrics.md: `min_time_headway`, `max_brake_threat_number`, after
//! CommonRoad-CriMe's THW and BTN) against a brute-force recomputation from the logged `/state`
//! and `/actors` with the geometry of the scenario file (not the log's metadata): Euro NCAP
//! CCRm, the bicycle's 4.6 m × 1.8 m footprint centred on its position, the 4.02 m × 1.71 m
//! target ahead in its lane.

mod common;

use common::*;
use mjsafe::log::proto;

/// Time, position, unit heading, speed, and the lead's (gap, velocity, acceleration) if ahead.
type Sample = (f64, [f64; 2], [f64; 2], f64, Option<(f64, f64, f64)>);

#[test]
fn time_headway_and_brake_threat_match_a_brute_force_recomputation() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("ccrm.mcap");
    run_ok(&scenario("ncap_ccrm.toml"), &log, &[]);
    let m = analyze_json(&log);
    let states = read_topic::<proto::State>(&log, "/state");
    let actors = read_topic::<proto::Actors>(&log, "/actors");
    assert_eq!(states.len(), actors.len());
    let (front, half_width, target) = (2.3, 0.9, [4.02, 1.71]);
    // Per sample: time, position, heading, speed, and the target's gap and motion along the heading.
    let mut samples: Vec<Sample> = Vec::new();
    for (s, a) in states.iter().zip(&actors) {
        assert_eq!(s.time, a.time);
        let (p, theta, v) = ([s.values[0], s.values[1]], s.values[2], s.values[3]);
        let e = [theta.cos(), theta.sin()];
        let t = &a.actors[0];
        let d = [t.x - p[0], t.y - p[1]];
        let (along, across) = (d[0] * e[0] + d[1] * e[1], -d[0] * e[1] + d[1] * e[0]);
        let (sn, cs) = (t.heading - theta).sin_cos();
        let half_along = 0.5 * (target[0] * cs.abs() + target[1] * sn.abs());
        let half_across = 0.5 * (target[0] * sn.abs() + target[1] * cs.abs());
        let gap = along - half_along - front;
        let lead = (across.abs() < half_width + half_across && gap > 0.0).then_some((
            gap,
            t.vx * e[0] + t.vy * e[1],
            t.ax * e[0] + t.ay * e[1],
        ));
        samples.push((s.time, p, e, v, lead));
    }
    // THW(t_i): the first crossing of the front past where the target's rear was at t_i.
    let front_of = |sample: &Sample| {
        let (p, e) = (sample.1, sample.2);
        [p[0] + front * e[0], p[1] + front * e[1]]
    };
    let mut thw = f64::INFINITY;
    let mut btn: Option<f64> = None;
    for (i, sample) in samples.iter().enumerate() {
        let Some((gap, v_lead, a_lead)) = sample.4 else {
            continue;
        };
        let e0 = sample.2;
        let f0 = front_of(sample);
        let rear = f0[0] * e0[0] + f0[1] * e0[1] + gap;
        let mut previous = (sample.0, -gap);
        for later in &samples[i + 1..] {
            let f = front_of(later);
            let d = f[0] * e0[0] + f[1] * e0[1] - rear;
            if d >= 0.0 {
                let crossed = previous.0 + (later.0 - previous.0) * (-previous.1) / (d - previous.1);
                thw = thw.min(crossed - sample.0);
                break;
            }
            previous = (later.0, d);
        }
        let v_rel = v_lead - sample.3;
        let required = if v_rel < 0.0 {
            (a_lead - v_rel * v_rel / (2.0 * gap)).min(0.0)
        } else {
            0.0
        };
        btn = Some(btn.unwrap_or(0.0).max(required / -11.5));
    }
    let (got_thw, got_btn) = (
        m["min_time_headway"].as_f64().unwrap(),
        m["max_brake_threat_number"].as_f64().unwrap(),
    );
    assert!(
        thw.is_finite() && (got_thw - thw).abs() < 1e-9,
        "THW {got_thw} against {thw}"
    );
    assert!((got_btn - btn.unwrap()).abs() < 1e-12, "BTN {got_btn} against {btn:?}");
    // What CCRm's figures mean: the car closes in on the slower target and (4.67) brakes hard
    // enough that a braking threat is real but below the car's capability, and it ends close.
    assert!(got_btn > 0.05 && got_btn < 1.0, "{got_btn}");
    assert!(got_thw < 1.0, "{got_thw}");
}

#[test]
fn without_road_users_the_headway_metrics_are_absent_and_with_them_say_why() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("plain.mcap");
    run_ok(&scenario("bicycle_obstacle.toml"), &log, &["--set", "duration=1.0"]);
    let m = analyze_json(&log);
    assert!(
        m["min_time_headway"].is_null() && m["max_brake_threat_number"].is_null(),
        "{m}"
    );
    assert!(m["missing"]["min_time_headway"].is_null(), "nothing to measure: {m}");
    // A walker crossing only ever comes into the path at contact: no lead, said so.
    let log = dir.path().join("walker.mcap");
    run_ok(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/crossing_walker.toml"),
        &log,
        &["--set", "actor_knowledge.kind=\"static\""],
    );
    let m = analyze_json(&log);
    assert!(m["min_time_headway"].is_null(), "{m}");
    assert_eq!(
        m["missing"]["min_time_headway"], "no road user was ever ahead in the vehicle's path",
        "{m}"
    );
}
