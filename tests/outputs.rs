//! Output paths: a device, a directory, an input of the run or a foreign file is never
//! replaced; a second writer to the same path is refused; `--rrd` and sweep summaries are
//! written then renamed like the log. Every refusal is one error line, a non-zero exit, and
//! nothing under a final name that is not complete.

mod common;
use common::*;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const SCENARIO: &str = "scenarios/bicycle_obstacle.toml";

/// `mjsafe run SCENARIO --set duration=1 ARGS`, expecting a failure whose stderr holds every
/// needle; returns stderr.
fn run_fails(scenario: &str, args: &[&str], needles: &[&str]) -> String {
    let mut all = vec!["run", scenario, "--set", "duration=1.0"];
    all.extend_from_slice(args);
    let o = mjsafe(&all);
    let err = stderr(&o);
    assert!(!o.status.success(), "expected failure; stdout: {}", stdout(&o));
    assert_eq!(err.trim().lines().count(), 1, "one error line:\n{err}");
    for n in needles {
        assert!(err.contains(n), "stderr lacks `{n}`:\n{err}");
    }
    println!("{}", err.trim());
    err
}

/// A copy of the bicycle scenario in `dir` (its model named by an absolute path).
fn scenario_copy(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join(SCENARIO)).unwrap().replace(
        "\"../models/bicycle.xml\"",
        &format!("\"{}\"", root().join("models/bicycle.xml").display()),
    );
    write(dir, "scenario.toml", &text)
}

#[test]
fn dev_null_is_never_replaced() {
    use std::os::unix::fs::FileTypeExt;
    run_fails(SCENARIO, &["--out", "/dev/null"], &["/dev/null", "a character device"]);
    let meta = std::fs::metadata("/dev/null").unwrap();
    assert!(meta.file_type().is_char_device(), "/dev/null is still a device");
    assert!(!Path::new("/dev/null.partial").exists());
}

#[test]
fn inputs_of_the_run_are_never_replaced() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = scenario_copy(dir.path());
    let before = std::fs::read(&scenario).unwrap();
    let s = scenario.to_str().unwrap();
    run_fails(s, &["--out", s], &["scenario.toml", "is an input of this run"]);
    assert_eq!(std::fs::read(&scenario).unwrap(), before, "the scenario is unchanged");
    // The same file by another spelling, and the model.
    let other = dir.path().join(".").join("scenario.toml");
    run_fails(s, &["--out", other.to_str().unwrap()], &["is an input of this run"]);
    let model = root().join("models/bicycle.xml");
    let model_before = std::fs::read(&model).unwrap();
    run_fails(
        s,
        &["--out", model.to_str().unwrap()],
        &["bicycle.xml", "is an input of this run"],
    );
    assert_eq!(std::fs::read(&model).unwrap(), model_before);
    assert_eq!(listing(dir.path()), ["scenario.toml"]);
}

#[test]
fn a_foreign_file_is_kept_and_an_earlier_log_replaced() {
    let dir = tempfile::tempdir().unwrap();
    let notes = write(dir.path(), "notes.mcap", "not a log\n");
    run_fails(
        SCENARIO,
        &["--out", notes.to_str().unwrap()],
        &["notes.mcap", "not an mjsafe MCAP log"],
    );
    assert_eq!(std::fs::read_to_string(&notes).unwrap(), "not a log\n");

    let log = dir.path().join("run.mcap");
    run_ok(&root().join(SCENARIO), &log, &["--set", "duration=0.5"]);
    run_ok(&root().join(SCENARIO), &log, &["--set", "duration=1.0"]);
    let m = analyze_json(&log);
    assert_eq!(m["complete"], true);
    assert!(
        (m["simulated_time"].as_f64().unwrap() - 1.0).abs() < 1e-6,
        "the second run's log: {m}"
    );
    assert_eq!(listing(dir.path()), ["notes.mcap", "run.mcap"]);
}

#[test]
fn a_directory_fails_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("sub");
    std::fs::create_dir(&target).unwrap();
    let started = Instant::now();
    run_fails(
        SCENARIO,
        &["--out", target.to_str().unwrap()],
        &[target.to_str().unwrap(), "a directory"],
    );
    assert!(started.elapsed() < Duration::from_secs(5));
    assert_eq!(listing(dir.path()), ["sub"], "no .partial left");
    assert!(listing(&target).is_empty());
}

#[test]
fn a_second_writer_to_the_same_log_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    let partial = dir.path().join("run.mcap.partial");
    // Long enough to still be running when the second starts.
    let first = Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args([
            "run",
            SCENARIO,
            "--set",
            "duration=600.0",
            "--out",
            log.to_str().unwrap(),
        ])
        .current_dir(root())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    while !partial.exists() {
        assert!(
            Instant::now() < deadline,
            "the first run never created {}",
            partial.display()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    run_fails(
        SCENARIO,
        &["--out", log.to_str().unwrap()],
        &["run.mcap", "another process is writing it"],
    );
    let first = first.wait_with_output().unwrap();
    assert!(first.status.success(), "first run: {}", stderr(&first));
    let m = analyze_json(&log);
    assert_eq!(m["complete"], true);
    assert!((m["simulated_time"].as_f64().unwrap() - 600.0).abs() < 1e-6);
    assert_eq!(listing(dir.path()), ["run.mcap"]);
}

#[cfg(feature = "rerun")]
#[test]
fn rrd_must_differ_from_the_log_and_be_writable() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    let l = log.to_str().unwrap();
    run_fails(SCENARIO, &["--out", l, "--rrd", l], &["--rrd", "MCAP log's path"]);
    let same = dir.path().join(".").join("run.mcap");
    run_fails(
        SCENARIO,
        &["--out", l, "--rrd", same.to_str().unwrap()],
        &["MCAP log's path"],
    );
    // Under a regular file: refused by the check.
    let file = write(dir.path(), "file.txt", "x");
    let under = file.join("x.rrd");
    run_fails(
        SCENARIO,
        &["--out", l, "--rrd", under.to_str().unwrap()],
        &["file.txt/x.rrd"],
    );
    // A directory nobody may create files in: refused when it is opened, after the log was
    // started: the log is abandoned.
    run_fails(SCENARIO, &["--out", l, "--rrd", "/proc/x.rrd"], &["/proc/x.rrd"]);
    // An input, a foreign file.
    let scenario = scenario_copy(dir.path());
    let s = scenario.to_str().unwrap();
    run_fails(s, &["--out", l, "--rrd", s], &["is an input of this run"]);
    run_fails(
        SCENARIO,
        &["--out", l, "--rrd", file.to_str().unwrap()],
        &["not an mjsafe rerun recording"],
    );
    assert_eq!(listing(dir.path()), ["file.txt", "scenario.toml"], "no log, no partial");
}

#[cfg(feature = "rerun")]
#[test]
fn rrd_is_written_then_renamed() {
    let dir = tempfile::tempdir().unwrap();
    let (log, rrd) = (dir.path().join("run.mcap"), dir.path().join("run.rrd"));
    for _ in 0..2 {
        run_ok(
            &root().join(SCENARIO),
            &log,
            &["--set", "duration=0.5", "--rrd", rrd.to_str().unwrap()],
        );
    }
    assert_eq!(listing(dir.path()), ["run.mcap", "run.rrd"]);
    assert!(std::fs::read(&rrd).unwrap().starts_with(b"RRF"));
}

fn sweep(out: &Path) -> std::process::Output {
    mjsafe(&[
        "sweep",
        SCENARIO,
        "--set",
        "duration=0.5",
        "--grid",
        "delays.steering=0.1,0.2",
        "--out",
        out.to_str().unwrap(),
    ])
}

#[test]
fn a_summary_that_cannot_be_written_leaves_none() {
    for blocked in ["summary.json", "summary.csv"] {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join(blocked)).unwrap();
        let o = sweep(dir.path());
        let err = stderr(&o);
        assert!(!o.status.success(), "expected failure: {}", stdout(&o));
        assert!(err.contains(blocked) && err.contains("a directory"), "{err}");
        let left: Vec<String> = listing(dir.path())
            .into_iter()
            .filter(|n| n.starts_with("summary"))
            .collect();
        assert_eq!(left, [blocked], "no other summary, no partial: {err}");
    }
    // A foreign summary.json is kept; a sweep's own summaries are replaced by the next sweep.
    let dir = tempfile::tempdir().unwrap();
    let foreign = write(dir.path(), "summary.json", "{\"mine\": 1}\n");
    let o = sweep(dir.path());
    assert!(!o.status.success());
    assert!(stderr(&o).contains("not an mjsafe sweep summary"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&foreign).unwrap(), "{\"mine\": 1}\n");
    std::fs::remove_file(&foreign).unwrap();
    for _ in 0..2 {
        let o = sweep(dir.path());
        assert!(o.status.success(), "{}", stderr(&o));
    }
    assert!(!listing(dir.path()).iter().any(|n| n.ends_with(".partial")));
    // `analyze --merge --out` never writes over a summary it merges.
    let summary = dir.path().join("summary.json");
    let before = std::fs::read(&summary).unwrap();
    let o = mjsafe(&[
        "analyze",
        "--merge",
        summary.to_str().unwrap(),
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("is an input of this run"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&summary).unwrap(), before);
}
