//! Analysis throughput (bytes of MCAP per second): `analyze::analyze_file` on the complete
//! log of one run of scenarios/bicycle_obstacle_gamma_m.toml (12 s, 6000 steps, every
//! topic), written once into a temporary directory before the measurement.
//!
//! `cargo bench --no-default-features --bench analyze`

use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};

use mjsafe::analyze;
use mjsafe::episode::Episode;
use mjsafe::log::mcap::McapSink;
use mjsafe::scenario;

fn analyze_log(c: &mut Criterion) {
    let loaded = scenario::load(Path::new("scenarios/bicycle_obstacle_gamma_m.toml"), &[]).expect("scenario");
    let dir = tempfile::tempdir().expect("temporary directory");
    let path = dir.path().join("bicycle_obstacle_gamma_m.mcap");
    let mut episode = Episode::new(&loaded).expect("episode");
    let mut sink = McapSink::create(&path, episode.info(), &[]).expect("create the log");
    let summary = episode.run(&mut [&mut sink]).expect("run");
    assert!(summary.error.is_none(), "the run stopped early: {:?}", summary.error);
    let bytes = std::fs::metadata(&path).expect("the log exists").len();
    println!("analyze: {} ({} steps, {bytes} bytes)", path.display(), summary.steps);

    let mut group = c.benchmark_group("analyze");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(3));
    group.throughput(Throughput::Bytes(bytes));
    group.bench_function("analyze_file/bicycle_obstacle_gamma_m", |b| {
        b.iter(|| analyze::analyze_file(black_box(&path)).expect("analyze"))
    });
    group.finish();
}

criterion_group!(benches, analyze_log);
criterion_main!(benches);
