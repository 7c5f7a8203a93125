//! Physics steps of a real scenario, bare and with the full control pipeline, over the same
//! 2 s (1000 steps of 0.002 s) of scenarios/bicycle_obstacle_gamma_m.toml (γm filter at the
//! recursive predictions) and scenarios/bicycle_obstacle.toml (delay-free CBF-QP at x(t)):
//!
//! - `bare`: `mj_step` over the episode's model (obstacle geoms included) with no controller;
//! - `pipeline`: `Episode::run` with no sink: delay queues, predictors, nominal, filter,
//!   records built for the sinks, barriers, contacts.
//!
//! The obstacle is made known from t = 0 (`obstacles.0.appear_at=0.0`) so that every tick of
//! the short run filters against it. One iteration is one 1000-step run; the throughput line
//! (elem/s) is steps per second, i.e. 1 / (time per step). Building the episode (MJCF parse)
//! is not timed.
//!
//! `cargo bench --no-default-features --bench physics`

use std::path::Path;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

use mjsafe::episode::Episode;
use mjsafe::scenario::{self, LoadedScenario};

const SCENARIOS: [&str; 2] = [
    "scenarios/bicycle_obstacle_gamma_m.toml",
    "scenarios/bicycle_obstacle.toml",
];

fn load(path: &str) -> LoadedScenario {
    let overrides = ["duration=2.0".to_string(), "obstacles.0.appear_at=0.0".to_string()];
    scenario::load(Path::new(path), &overrides).unwrap_or_else(|e| panic!("{path}: {e}"))
}

fn physics(c: &mut Criterion) {
    let mut group = c.benchmark_group("physics");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    for path in SCENARIOS {
        let loaded = load(path);
        let name = loaded.scenario.name.clone();
        let steps = Episode::new(&loaded).expect("episode").steps();
        // The bare loop replays the actuation of one (untimed) run: same trajectory, same contacts.
        let actuation = {
            let mut episode = Episode::new(&loaded).expect("episode");
            episode.record_actuation();
            episode.run(&mut []).expect("run");
            episode.take_actuation()
        };
        group.throughput(Throughput::Elements(steps));

        group.bench_function(BenchmarkId::new("bare", &name), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    let mut episode = Episode::new(&loaded).expect("episode");
                    let started = Instant::now();
                    episode.replay_actuation(&actuation).expect("the recorded run replays");
                    total += started.elapsed();
                }
                total
            })
        });

        group.bench_function(BenchmarkId::new("pipeline", &name), |b| {
            b.iter_custom(|iters| {
                let mut total = Duration::ZERO;
                for _ in 0..iters {
                    let mut episode = Episode::new(&loaded).expect("episode");
                    let started = Instant::now();
                    let summary = episode.run(&mut []).expect("run");
                    total += started.elapsed();
                    assert!(summary.error.is_none(), "{name} stopped early: {:?}", summary.error);
                    assert_eq!(summary.steps, steps);
                }
                total
            })
        });
    }
    group.finish();
}

criterion_group!(benches, physics);
criterion_main!(benches);
