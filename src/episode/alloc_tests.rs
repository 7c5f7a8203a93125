//! The control callback allocates nothing once an episode is in steady state (issue 9): a
//! counting global allocator (this test binary only) counts the allocations made on this
//! thread while the controller runs inside the plant's step.

use std::path::Path;

use super::Episode;
use crate::mujoco::counting_alloc::{allocations, count_allocations};
use crate::plant::Controller;
use crate::scenario;

/// Counts the allocations of the wrapped controller's calls (the body of the control callback).
struct Counted<'a>(&'a mut dyn Controller);

impl Controller for Counted<'_> {
    fn input(&mut self, step: u64, call_in_step: u32, offset: f64, state: &dyn Fn(&mut [f64])) -> &[f64] {
        count_allocations(true);
        let input = self.0.input(step, call_in_step, offset, state);
        count_allocations(false);
        input
    }
}

/// Runs the episode's control loop as `Episode::run` does (without sinks) and returns the
/// allocations counted in the controller during steps starting at or after `steady_from`,
/// and before it.
fn callback_allocations(file: &str, overrides: &[&str], steady_from: f64) -> (u64, u64) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(file);
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    let loaded = scenario::load(&path, &overrides).unwrap();
    let mut episode = Episode::new(&loaded).unwrap();
    let h = episode.control.timestep();
    let (mut warm_up, mut steady) = (0, 0);
    for k in 0..episode.steps {
        let time = k as f64 * h;
        episode.reveal_obstacles(time);
        let x = episode.plant.state();
        for c in episode.control.realize(time, &x, false).unwrap() {
            episode.control.recycle(c);
        }
        allocations(true);
        episode.plant.step(&mut Counted(&mut episode.control)).unwrap();
        if let Some(e) = episode.control.take_error() {
            panic!("{file}: {e}");
        }
        let counted = allocations(false);
        if time >= steady_from {
            steady += counted;
        } else {
            warm_up += counted;
        }
        episode.control.take_tick();
    }
    (warm_up, steady)
}

#[test]
fn control_callback_allocates_nothing_in_steady_state() {
    // (scenario, overrides, steady state from): after the longest delay has filled the
    // pending predictions and the obstacle (t = 2.75 s, 2.18 s at 10 m/s) is known. Every
    // scenario in scenarios/ that runs a filter: the numerical QP (two obstacles and input
    // limits), Ch. 3's κ_LB, and the Ch. 5 chain filters (PTSf, ESf) across their prescribed
    // time T (the ramp (5.28) after it).
    let cases: &[(&str, &[&str], f64)] = &[
        ("bicycle_obstacle.toml", &[], 3.0),
        ("bicycle_obstacle_gamma_m.toml", &[], 3.0),
        ("car_obstacle_gamma_m.toml", &[], 3.0),
        (
            "bicycle_obstacle.toml",
            &["filter={kind='fixed_channel', l0=4.0, l1=4.0, phi=2}"],
            3.0,
        ),
        (
            "bicycle_obstacle.toml",
            &["filter={kind='cbf_qp', l0=4.0, l1=4.0, compensation='predictor'}"],
            3.0,
        ),
        ("bicycle_obstacle_nodelay.toml", &[], 3.0),
        ("unicycle_tv_delay.toml", &["duration=4.0"], 2.0),
        ("nonlinear_example1.toml", &[], 1.0),
        ("scalar_tv_delay.toml", &["duration=4.0"], 2.0),
        ("car_obstacle_gamma_m_10.toml", &["duration=4.0"], 2.5),
        ("bicycle_two_obstacles.toml", &["duration=12.0"], 2.0),
        ("linear_distinct_delays.toml", &["duration=6.0"], 1.0),
        ("chain3_ptsf.toml", &[], 0.5),
        ("red_light.toml", &[], 0.5),
        ("red_light.toml", &["filter={kind='esf', rate=3.2, horizon=4.0}"], 0.5),
        ("strict_feedback_pts.toml", &[], 0.2),
    ];
    let mut failed = Vec::new();
    for (file, overrides, steady_from) in cases {
        let (warm_up, steady) = callback_allocations(file, overrides, *steady_from);
        println!("{file} {overrides:?}: {warm_up} allocations while warming up, {steady} from t = {steady_from} s");
        if steady != 0 {
            failed.push(format!("{file} {overrides:?}: {steady}"));
        }
    }
    assert!(failed.is_empty(), "the control callback allocated: {failed:?}");
}

#[test]
fn the_counter_sees_allocations() {
    // The harness itself: an allocating controller is counted.
    struct Allocating(Vec<f64>);
    impl Controller for Allocating {
        fn input(&mut self, _: u64, _: u32, _: f64, _: &dyn Fn(&mut [f64])) -> &[f64] {
            self.0 = vec![0.0; 2];
            &self.0
        }
    }
    let mut inner = Allocating(Vec::new());
    allocations(true);
    Counted(&mut inner).input(0, 0, 0.0, &|_| {});
    assert_eq!(allocations(false), 1);
}
