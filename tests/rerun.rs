//! The rerun recording: a live run (`mjsafe run --rrd`) and the replay of its MCAP log
//! (`mjsafe replay --rrd`) hold the same data, checked with the rerun CLI of PyPI
//! `rerun-sdk` 0.36.3 (installed into the test venv by `scripts/setup.sh --test`).
#![cfg(feature = "rerun")]

mod common;
use common::*;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The `rerun` CLI: `$MJSAFE_VENV/bin/rerun`, else next to `MJSAFE_PYTHON`, else in the default venv.
fn rerun_cli() -> PathBuf {
    let candidates = [
        std::env::var("MJSAFE_VENV")
            .ok()
            .map(|v| Path::new(&v).join("bin/rerun")),
        Some(Path::new(&python()).with_file_name("rerun")),
    ];
    candidates
        .into_iter()
        .flatten()
        .find(|p| p.exists())
        .expect("no rerun CLI next to the test Python: run scripts/setup.sh --test (installs rerun-sdk==0.36.3)")
}

/// Runs the rerun CLI with nothing going to the network (CI=1: no analytics).
fn rerun(args: &[&str]) -> Output {
    Command::new(rerun_cli())
        .args(args)
        .env("CI", "1")
        .env("RERUN_ANALYTICS", "0")
        .output()
        .expect("rerun CLI runs")
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn replay(log: &Path, rrd: &Path) {
    let o = mjsafe(&["replay", log.to_str().unwrap(), "--rrd", rrd.to_str().unwrap()]);
    assert!(o.status.success(), "mjsafe replay failed: {}{}", stdout(&o), stderr(&o));
    assert!(stdout(&o).contains("replayed"), "{}", stdout(&o));
}

#[test]
fn live_recording_equals_the_replay_of_its_log() {
    let dir = tempfile::tempdir().unwrap();
    let (log, live, replayed) = (
        dir.path().join("run.mcap"),
        dir.path().join("live.rrd"),
        dir.path().join("replay.rrd"),
    );
    // Delayed bicycle, predictor-compensated filter: scene, predictions, barrier, a collision.
    let extra = [
        "--set",
        "duration=4.0",
        "--set",
        "filter.compensation='predictor'",
        "--rrd",
        live.to_str().unwrap(),
    ];
    let summary = run_ok(&scenario("bicycle_obstacle.toml"), &log, &extra);
    assert!(summary.contains("COLLISION"), "{summary}");
    replay(&log, &replayed);

    for file in [&live, &replayed] {
        let o = rerun(&["rrd", "verify", file.to_str().unwrap()]);
        assert!(o.status.success(), "rerun rrd verify {}: {}", file.display(), text(&o));
    }
    let o = rerun(&[
        "rrd",
        "compare",
        "--unordered",
        live.to_str().unwrap(),
        replayed.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "live and replayed recordings differ:\n{}", text(&o));

    // The recording holds what the sink is for (entity paths as `rrd print` lists them).
    let o = rerun(&["rrd", "print", "--verbose", live.to_str().unwrap()]);
    assert!(o.status.success(), "rerun rrd print: {}", text(&o));
    let printed = text(&o);
    for entity in [
        "/world/vehicle",
        "/world/trail",
        "/world/obstacle_0",
        "/world/reference_path",
        "/world/collisions",
        "/world/prediction/steering",
        "/plots/barrier/obstacle_0",
        "/plots/input/steering/issued",
        "/plots/input/steering/applied",
        "/plots/command/acceleration",
        "/plots/filter",
        "/plots/prediction/steering",
        "/events",
    ] {
        assert!(printed.contains(entity), "{entity} missing from the recording");
    }
    // The recording's own chunks (not the blueprint's) are on sim_time and step only.
    let o = rerun(&["rrd", "print", "-vv", live.to_str().unwrap()]);
    assert!(o.status.success(), "rerun rrd print -vv: {}", text(&o));
    let headers = text(&o);
    let data_chunks: Vec<&str> = headers
        .split("Chunk(")
        .filter(|c| {
            let header = c.lines().next().unwrap_or("");
            header.contains(" - /world") || header.contains(" - /plots") || header.contains(" - /events")
        })
        .collect();
    assert!(data_chunks.len() > 10, "{} data chunks", data_chunks.len());
    assert!(
        data_chunks
            .iter()
            .all(|c| !c.contains("log_time") && !c.contains("log_tick")),
        "wall-clock log time must be off"
    );
    assert!(
        data_chunks
            .iter()
            .any(|c| c.contains("index_name: sim_time") && c.contains("index_name: step")),
        "timelines sim_time and step missing"
    );
}

#[test]
fn compare_tells_different_runs_apart() {
    // The check above can fail: the replay of another run (another initial state) differs.
    let dir = tempfile::tempdir().unwrap();
    let (a_log, b_log, a, b) = (
        dir.path().join("a.mcap"),
        dir.path().join("b.mcap"),
        dir.path().join("a.rrd"),
        dir.path().join("b.rrd"),
    );
    run_ok(&scenario("bicycle_obstacle.toml"), &a_log, &["--set", "duration=1.0"]);
    run_ok(
        &scenario("bicycle_obstacle.toml"),
        &b_log,
        &[
            "--set",
            "duration=1.0",
            "--set",
            "vehicle.initial_state=[-20.0, 1.0, 0.0, 3.0]",
        ],
    );
    // Same file stem, so both recordings have the same recording id.
    let b_same_stem = dir.path().join("other");
    std::fs::create_dir(&b_same_stem).unwrap();
    let b_log2 = b_same_stem.join("a.mcap");
    std::fs::rename(&b_log, &b_log2).unwrap();
    replay(&a_log, &a);
    replay(&b_log2, &b);
    let o = rerun(&[
        "rrd",
        "compare",
        "--unordered",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
    ]);
    assert!(
        !o.status.success(),
        "recordings of different runs compare equal:\n{}",
        text(&o)
    );
}

#[test]
fn replay_of_a_non_log_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let bogus = write(dir.path(), "bogus.mcap", "not an mcap file");
    let out = dir.path().join("x.rrd");
    let o = mjsafe(&["replay", bogus.to_str().unwrap(), "--rrd", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("not a readable MCAP file"), "{}", stderr(&o));
}
