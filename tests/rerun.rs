//! The rerun recording: a live run (`mjsafe run --rrd`) and the replay of its MCAP log
//! (`mjsafe replay --rrd`) hold the same data, and a run streamed to a rerun server
//! (`--rerun-connect`) or to a spawned viewer (`--rerun`) delivers the same rows; checked with
//! the rerun CLI of PyPI `rerun-sdk` 0.36.3 (installed into the test venv by
//! `scripts/setup.sh --test`), headless (the "viewer" is rerun saving what it receives).
#![cfg(feature = "rerun")]

mod common;
use common::*;

use std::path::{Path, PathBuf};
use std::process::Command;

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
        "/plots/barrier_symlog/obstacle_0",
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
fn the_road_is_drawn_in_the_recording() {
    // Edges and the dashed lane marking go through /scene to line strips under /world/road.
    // (The multi-barrier QP until the distinct-delay filters take several barriers.)
    let dir = tempfile::tempdir().unwrap();
    let (log, rrd) = (dir.path().join("road.mcap"), dir.path().join("road.rrd"));
    run_ok(
        &scenario("bicycle_road_gamma_m.toml"),
        &log,
        &[
            "--set",
            "duration=0.5",
            "--set",
            "filter={kind='cbf_qp', l0=4.0, l1=4.0}",
            "--rrd",
            rrd.to_str().unwrap(),
        ],
    );
    let o = rerun(&["rrd", "print", "--verbose", rrd.to_str().unwrap()]);
    assert!(o.status.success(), "rerun rrd print: {}", text(&o));
    let printed = text(&o);
    for entity in [
        "/world/road/left_edge",
        "/world/road/right_edge",
        "/world/road/lane/centre",
        "/plots/barrier/left_edge",
    ] {
        assert!(printed.contains(entity), "{entity} missing from the recording");
    }
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

/// The rerun executable itself (the venv's `bin/rerun` is a Python launcher that does not pass
/// signals on to it).
fn rerun_binary() -> PathBuf {
    let venv = rerun_cli().parent().unwrap().parent().unwrap().to_path_buf();
    std::fs::read_dir(venv.join("lib"))
        .expect("venv lib/")
        .flatten()
        .map(|python| python.path().join("site-packages/rerun_sdk/rerun_cli/rerun"))
        .find(|p| p.exists())
        .expect("rerun_sdk/rerun_cli/rerun in the test venv (rerun-sdk==0.36.3)")
}

/// Kills a background process (and waits for it) when the test ends, pass or fail.
struct KillOnDrop(std::process::Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn listening(port: u16) -> bool {
    std::net::TcpStream::connect(("127.0.0.1", port)).is_ok()
}

/// Waits until `path` exists and has kept its size for a second (at most 30 s): the server
/// has written everything the run sent.
fn wait_until_settled(path: &Path) {
    let mut last = None;
    let mut stable_since = std::time::Instant::now();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    while std::time::Instant::now() < deadline {
        let size = std::fs::metadata(path).map(|m| m.len()).ok();
        if size != last {
            (last, stable_since) = (size, std::time::Instant::now());
        } else if size.is_some() && stable_since.elapsed() > std::time::Duration::from_secs(1) {
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    panic!("{} did not settle (size {last:?})", path.display());
}

/// `rerun rrd compare --unordered` of two recordings after compacting their chunks (a live
/// stream is batched by time, a saved file by row count: the rows are what must agree).
fn assert_same_rows(a: &Path, b: &Path) {
    let compact = |rrd: &Path| {
        let o = rerun(&["rrd", "optimize", rrd.to_str().unwrap()]);
        assert!(o.status.success(), "rerun rrd optimize {}: {}", rrd.display(), text(&o));
        let out = rrd.with_extension("compacted.rrd");
        std::fs::write(&out, &o.stdout).unwrap();
        out
    };
    let (a, b) = (compact(a), compact(b));
    let o = rerun(&[
        "rrd",
        "compare",
        "--unordered",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{} vs {}: {}", a.display(), b.display(), text(&o));
}

#[test]
fn rerun_connect_streams_the_run_to_a_running_server() {
    let dir = tempfile::tempdir().unwrap();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let received = dir.path().join("received.rrd");
    // A headless rerun server that saves everything it receives.
    let _server = KillOnDrop(
        Command::new(rerun_binary())
            .args(["--port", &port.to_string(), "--save", received.to_str().unwrap()])
            .env("CI", "1")
            .env("RERUN_ANALYTICS", "0")
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .expect("rerun server starts"),
    );
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    while !listening(port) {
        assert!(
            std::time::Instant::now() < deadline,
            "rerun server not listening on {port}"
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    let (log, live) = (dir.path().join("run.mcap"), dir.path().join("live.rrd"));
    let url = format!("rerun+http://127.0.0.1:{port}/proxy");
    let extra = [
        "--set",
        "duration=1.0",
        "--rerun-connect",
        &url,
        "--rrd",
        live.to_str().unwrap(),
    ];
    run_ok(&scenario("bicycle_obstacle_gamma_m.toml"), &log, &extra);
    wait_until_settled(&received);
    // The server got every row the recording holds.
    assert_same_rows(&live, &received);
}

#[test]
fn rerun_flag_spawns_a_viewer_and_streams_the_run_to_it() {
    // Headless stand-in for the viewer: a `rerun` first on PATH that runs the real rerun as a
    // server saving what it receives (the SDK spawns `rerun --port=9876 … --expect-data-soon`).
    assert!(
        !listening(9876),
        "port 9876 (the SDK's spawn port) is taken: the run would stream there, not to the spawned viewer"
    );
    let dir = tempfile::tempdir().unwrap();
    let bin = dir.path().join("bin");
    std::fs::create_dir(&bin).unwrap();
    let (received, pid_file) = (dir.path().join("received.rrd"), dir.path().join("viewer.pid"));
    let stand_in = bin.join("rerun");
    std::fs::write(
        &stand_in,
        format!(
            "#!/bin/sh\necho $$ > '{}'\nexec '{}' \"$@\" --save '{}'\n",
            pid_file.display(),
            rerun_binary().display(),
            received.display()
        ),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&stand_in, std::fs::Permissions::from_mode(0o755)).unwrap();

    let (log, live) = (dir.path().join("run.mcap"), dir.path().join("live.rrd"));
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());
    // The spawned viewer inherits the run's stdout and stderr and outlives it: send them to
    // files (waiting for pipes to close would wait for the viewer).
    let (out, err) = (dir.path().join("run.out"), dir.path().join("run.err"));
    let status = Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args(["run", scenario("bicycle_obstacle_gamma_m.toml").to_str().unwrap()])
        .args(["--out", log.to_str().unwrap(), "--set", "duration=1.0", "--rerun"])
        .args(["--rrd", live.to_str().unwrap()])
        .env("PATH", path)
        .env("CI", "1")
        .env("RERUN_ANALYTICS", "0")
        .stdout(std::fs::File::create(&out).unwrap())
        .stderr(std::fs::File::create(&err).unwrap())
        .status()
        .expect("mjsafe runs");
    // Stops the spawned viewer when the test ends, pass or fail.
    struct Viewer(Option<String>);
    impl Drop for Viewer {
        fn drop(&mut self) {
            if let Some(pid) = &self.0 {
                let _ = Command::new("kill").args(["-9", pid.trim()]).status();
            }
        }
    }
    let viewer = Viewer(std::fs::read_to_string(&pid_file).ok());
    let read = |p: &Path| std::fs::read_to_string(p).unwrap_or_default();
    assert!(
        status.success(),
        "mjsafe run --rerun failed: {}{}",
        read(&out),
        read(&err)
    );
    assert!(viewer.0.is_some(), "the run did not spawn `rerun` from PATH");
    wait_until_settled(&received);
    drop(viewer);
    assert_same_rows(&live, &received);
}
