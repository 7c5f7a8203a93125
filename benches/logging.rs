//! MCAP logging cost per physics step: `McapSink::record` for the records one step emits,
//! then `finish(true)` (last chunk compressed, summary and index written, file renamed),
//! for a 12 s run of scenarios/bicycle_obstacle_gamma_m.toml (6000 steps of 0.002 s):
//!
//! - `mcap/step_records`: /state, /command/applied and /barrier at every step;
//! - `mcap/with_tick_records`: the same plus, every fifth step (control period 0.01 s), what
//!   a control tick adds: /command/issued, /filter and one /prediction per channel.
//!
//! The records are built once beforehand; creating the sink is not timed. One iteration is
//! one whole log; the throughput line (elem/s) is steps per second.
//!
//! `cargo bench --no-default-features --bench logging`

use std::path::Path;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

use mjsafe::episode::Episode;
use mjsafe::log::mcap::McapSink;
use mjsafe::log::{proto, Record, RunInfo, Sink};
use mjsafe::scenario;

const STEPS: u64 = 6000;
const TIMESTEP: f64 = 0.002;

fn strings(names: &[&str]) -> Vec<String> {
    names.iter().map(|s| s.to_string()).collect()
}

/// The records of step k, shaped as the episode emits them (values vary along a plausible run
/// so that compression sees realistic data).
fn step_records(k: u64, tick: bool) -> Vec<Record> {
    let time = k as f64 * TIMESTEP;
    let state = vec![
        -20.0 + 3.0 * time,
        0.1 * time.sin(),
        0.01 * time.cos(),
        3.0 + 0.01 * (3.0 * time).sin(),
    ];
    let channels = strings(&["steering", "acceleration"]);
    let applied = vec![0.05 * (0.7 * time).sin(), 0.2 * (0.3 * time).cos()];
    let h = (state[0] + 3.0).powi(2) + (state[1] - 0.5).powi(2) - 36.0;
    let mut records = vec![Record::State(proto::State {
        time,
        step: k,
        names: strings(&["x1", "x2", "heading", "speed"]),
        values: state.clone(),
    })];
    if tick {
        records.push(Record::Issued(proto::IssuedCommand {
            time,
            channels: channels.clone(),
            nominal: vec![applied[0] + 0.01, applied[1] - 0.02],
            filtered: applied.clone(),
        }));
        records.push(Record::Filter(proto::Filter {
            time,
            active: h < 20.0,
            channels: channels.clone(),
            correction: vec![-0.01, 0.02],
            infeasible: false,
            mu: h - 20.0,
            ..Default::default()
        }));
        for (channel, delay) in [("steering", 0.2), ("acceleration", 1.5)] {
            let predicted: Vec<f64> = state.iter().map(|v| v + 0.01 * delay).collect();
            records.push(Record::Prediction(proto::Prediction {
                time,
                channel: channel.into(),
                issued_at: time - delay,
                horizon: delay,
                realized: state.clone(),
                predicted,
                error: 0.02 * delay,
                relative_error: 0.02 * delay / 20.0,
                reused_chain: true,
                chain_mismatch: 1e-6,
                ..Default::default()
            }));
        }
    }
    records.push(Record::Applied(proto::AppliedCommand {
        time,
        channels,
        values: applied,
        issued_at: vec![time - 0.2, time - 1.5],
    }));
    records.push(Record::Barrier(proto::Barrier {
        time,
        barriers: vec![proto::BarrierValue {
            name: "obstacle_0".into(),
            h,
            constraint: 0.5 * h - 3.0,
            known: time >= 2.75,
            relative_degree: 2,
            clearance: (h + 36.0).sqrt() - 6.0,
            time_to_collision: ((h + 36.0).sqrt() - 6.0) / 3.0,
            obstacle: true,
        }],
    }));
    records
}

/// Writes one log of `steps` and returns the time spent recording and finishing it.
fn write_log(path: &Path, info: &RunInfo, steps: &[Vec<Record>]) -> Duration {
    let mut sink = McapSink::create(path, info, &[]).expect("create the log");
    let started = Instant::now();
    for records in steps {
        for record in records {
            sink.record(record).expect("record");
        }
    }
    sink.finish(true).expect("finish the log");
    started.elapsed()
}

fn logging(c: &mut Criterion) {
    let loaded = scenario::load(Path::new("scenarios/bicycle_obstacle_gamma_m.toml"), &[]).expect("scenario");
    let info = Episode::new(&loaded).expect("episode").info().clone();
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("bench.mcap");

    let mut group = c.benchmark_group("logging");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    group.throughput(Throughput::Elements(STEPS));
    // Control period 0.01 s = every fifth step.
    for (name, tick_every) in [("step_records", None), ("with_tick_records", Some(5))] {
        let steps: Vec<Vec<Record>> = (0..STEPS)
            .map(|k| step_records(k, tick_every.is_some_and(|n| k % n == 0)))
            .collect();
        group.bench_function(BenchmarkId::new("mcap", name), |b| {
            b.iter_custom(|iters| (0..iters).map(|_| write_log(&path, &info, &steps)).sum())
        });
        let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        println!(
            "logging/mcap/{name}: {STEPS} steps -> {bytes} bytes ({:.1} bytes/step)",
            bytes as f64 / STEPS as f64
        );
    }
    group.finish();
}

criterion_group!(benches, logging);
criterion_main!(benches);
