//! Helpers shared by the integration tests: drive the real `mjsafe` binary.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

pub fn scenario(name: &str) -> PathBuf {
    root().join("scenarios").join(name)
}

/// Runs `mjsafe ARGS` in the repository root.
pub fn mjsafe(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args(args)
        .current_dir(root())
        .output()
        .expect("mjsafe binary runs")
}

pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Runs a scenario into `out`, asserting success; returns stdout.
pub fn run_ok(scenario: &Path, out: &Path, extra: &[&str]) -> String {
    let mut args = vec!["run", scenario.to_str().unwrap(), "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    let o = mjsafe(&args);
    assert!(
        o.status.success(),
        "mjsafe run failed:\nstdout: {}\nstderr: {}",
        stdout(&o),
        stderr(&o)
    );
    stdout(&o)
}

/// `mjsafe analyze --json FILE` parsed.
pub fn analyze_json(file: &Path) -> serde_json::Value {
    let o = mjsafe(&["analyze", "--json", file.to_str().unwrap()]);
    assert!(o.status.success(), "analyze failed: {}", stderr(&o));
    let runs: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("analyze --json prints JSON");
    runs[0].clone()
}

/// The Python interpreter with the `mcap` readers (set by scripts/test.sh).
pub fn python() -> String {
    std::env::var("MJSAFE_PYTHON").unwrap_or_else(|_| {
        let venv = std::env::var("HOME").unwrap_or_default() + "/.cache/mjsafe/venv/bin/python";
        assert!(
            Path::new(&venv).exists(),
            "no Python with the mcap readers: run scripts/test.sh (it creates {venv}) or set MJSAFE_PYTHON"
        );
        venv
    })
}

/// A text file written into a temporary directory.
pub fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Every message of `topic`, decoded with mjsafe's own schema types.
pub fn read_topic<T: prost::Message + Default>(file: &Path, topic: &str) -> Vec<T> {
    let bytes = std::fs::read(file).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| m.channel.topic == topic)
        .map(|m| T::decode(&m.data[..]).unwrap())
        .collect()
}

/// Runs `mjsafe run scenarios/FILE --set …` expecting a failure whose stderr holds every
/// needle; returns stderr.
pub fn run_expecting_failure(file: &str, sets: &[&str], needles: &[&str]) -> String {
    let scenario = format!("scenarios/{file}");
    let mut args = vec!["run", scenario.as_str()];
    for s in sets {
        args.extend_from_slice(&["--set", s]);
    }
    let o = mjsafe(&args);
    let err = stderr(&o);
    assert!(!o.status.success(), "expected failure; stdout: {}", stdout(&o));
    for n in needles {
        assert!(err.contains(n), "stderr lacks `{n}`: {err}");
    }
    println!("{}", err.trim());
    err
}

/// The files in `dir`, sorted.
pub fn listing(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// A run that blows up: a huge initial acceleration on [-D, 0) drives the velocity past
/// MuJoCo's limit (1e10) after about 1.1 s (MuJoCo warns and would reset the state).
pub fn blowup_scenario() -> String {
    format!(
        r#"
name = "blowup"
duration = 2.0
[vehicle]
kind = "double_integrator_1d"
model = "{}"
initial_state = [0.0, 0.0]
[delays]
acceleration = 1.5
[initial_input]
acceleration = 9e9
[nominal]
kind = "constant"
input = [0.0]
"#,
        root().join("models/double_integrator_1d.xml").display()
    )
}

/// The `rerun` CLI: `$MJSAFE_VENV/bin/rerun`, else next to `MJSAFE_PYTHON`, else in the default venv.
pub fn rerun_cli() -> PathBuf {
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
pub fn rerun(args: &[&str]) -> Output {
    Command::new(rerun_cli())
        .args(args)
        .env("CI", "1")
        .env("RERUN_ANALYTICS", "0")
        .output()
        .expect("rerun CLI runs")
}

pub fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// Every message of a topic, as its bytes.
pub fn raw_topic(file: &Path, topic: &str) -> Vec<Vec<u8>> {
    let bytes = std::fs::read(file).unwrap();
    mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| m.channel.topic == topic)
        .map(|m| m.data.to_vec())
        .collect()
}

/// Asserts that two logs hold byte-identical messages on every topic of `topics`, and that the
/// first of them has messages on each topic except those in `may_be_empty`.
pub fn assert_same_messages(a: &Path, b: &Path, topics: &[&str], may_be_empty: &[&str]) {
    for topic in topics {
        let (x, y) = (raw_topic(a, topic), raw_topic(b, topic));
        assert!(!x.is_empty() || may_be_empty.contains(topic), "{topic} is empty");
        assert!(x == y, "{topic} differs");
    }
}

/// The digest of tests/read_log.py: an independent reader (Python `mcap`, CRCs checked,
/// messages decoded from the embedded schemas).
pub fn python_digest(log: &std::path::Path) -> serde_json::Value {
    let o = std::process::Command::new(python())
        .arg(root().join("tests/read_log.py"))
        .arg(log)
        .output()
        .expect("python runs");
    assert!(
        o.status.success(),
        "python reader failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).unwrap()
}
