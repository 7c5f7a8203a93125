//! Study support: seeded random variations that re-run bit-identically, and interruption
//! (SIGTERM / Ctrl-C) that leaves a finished, readable log marked incomplete.

mod common;
use common::*;

use mjsafe::log::proto;

const RANDOM: [&str; 8] = [
    "--set",
    "vehicle.initial_perturbation=[0.5, 0.2, 0.05, 0.1]",
    "--set",
    "obstacles.0.appear_jitter=0.2",
    "--set",
    "disturbance={kind='random_input', bound=0.3, hold=0.1}",
    "--set",
    "duration=5.0",
];

fn run_seeded(dir: &std::path::Path, name: &str, seed: u64) -> std::path::PathBuf {
    let log = dir.join(format!("{name}.mcap"));
    let mut args: Vec<String> = RANDOM.iter().map(|s| s.to_string()).collect();
    args.extend(["--set".into(), format!("seed={seed}")]);
    let args: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
    run_ok(&scenario("bicycle_obstacle.toml"), &log, &args);
    log
}

#[test]
fn seeded_variations_rerun_bit_identically_and_stay_in_their_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let a = run_seeded(dir.path(), "a", 11);
    let b = run_seeded(dir.path(), "b", 11);
    let c = run_seeded(dir.path(), "c", 12);
    let bytes = |p: &std::path::Path| std::fs::read(p).unwrap();
    assert!(bytes(&a) == bytes(&b), "same seed, different logs");
    assert!(bytes(&a) != bytes(&c), "different seeds, same log");

    // x(0) within ±bounds of the file's initial state, and actually moved.
    let x0 = &read_topic::<proto::State>(&a, "/state")[0].values;
    let nominal = [-20.0, 0.0, 0.0, 3.0];
    let bounds = [0.5, 0.2, 0.05, 0.1];
    for i in 0..4 {
        assert!((x0[i] - nominal[i]).abs() <= bounds[i] + 1e-12, "x0[{i}] = {}", x0[i]);
    }
    assert!(x0.iter().zip(nominal).any(|(x, n)| (x - n).abs() > 1e-6));
    // Appearance within 2.75 ± 0.2.
    let appeared = read_topic::<proto::Event>(&a, "/event")
        .into_iter()
        .find(|e| e.kind == "obstacle_appeared")
        .unwrap();
    assert!(
        (appeared.time - 2.75).abs() <= 0.2 + 0.002,
        "appeared at {}",
        appeared.time
    );
    // The input disturbance: applied = issued (delayed) + ω with ‖ω‖ ≤ 0.3.
    let issued: std::collections::BTreeMap<u64, Vec<f64>> = read_topic::<proto::IssuedCommand>(&a, "/command/issued")
        .into_iter()
        .map(|c| ((c.time * 1e6).round() as u64, c.filtered))
        .collect();
    let mut largest: f64 = 0.0;
    for applied in read_topic::<proto::AppliedCommand>(&a, "/command/applied") {
        let mut norm2 = 0.0;
        for (i, (value, issued_at)) in applied.values.iter().zip(&applied.issued_at).enumerate() {
            let base = if *issued_at < 0.0 {
                0.0
            } else {
                issued[&((issued_at * 1e6).round() as u64)][i]
            };
            norm2 += (value - base).powi(2);
        }
        largest = largest.max(norm2.sqrt());
    }
    println!(
        "seeded run: x(0) = {x0:?}, obstacle known at {:.3}, max |applied - issued| = {largest:.3}",
        appeared.time
    );
    assert!(largest <= 0.3 + 1e-9 && largest > 0.05, "{largest}");
}

#[test]
fn sigterm_finishes_the_log_as_incomplete_and_exits_130() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("long.mcap");
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args([
            "run",
            "scenarios/bicycle_obstacle_nodelay.toml",
            "--set",
            "duration=5000.0",
            "--out",
        ])
        .arg(&log)
        .current_dir(root())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let killed = std::process::Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let output = child.wait_with_output().unwrap();
    assert_eq!(
        output.status.code(),
        Some(130),
        "stderr: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let m = analyze_json(&log);
    println!(
        "interrupted run: simulated {} s, error {}",
        m["simulated_time"], m["error"]
    );
    assert_eq!(m["complete"], false);
    assert!(m["error"].as_str().unwrap().contains("interrupted"));
    assert!(m["simulated_time"].as_f64().unwrap() > 0.0);
    let events = read_topic::<proto::Event>(&log, "/event");
    assert_eq!(events.last().unwrap().kind, "interrupted");
}

#[test]
fn analyze_plot_writes_the_three_pngs_from_the_log_alone() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("gamma.mcap");
    run_ok(&scenario("bicycle_obstacle_gamma_m.toml"), &log, &[]);
    let plots = dir.path().join("plots");
    let o = mjsafe(&["analyze", log.to_str().unwrap(), "--plot", plots.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    for kind in ["barriers", "inputs", "trajectory"] {
        let png = std::fs::read(plots.join(format!("gamma-{kind}.png"))).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "{kind} is not a PNG");
        assert!(png.len() > 10_000, "{kind}: {} bytes", png.len());
    }
}

#[test]
fn sigterm_during_a_sweep_finishes_the_running_logs_and_says_which_runs_did_not_finish() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("sweep");
    // Two long runs on one thread: the first is interrupted, the second never starts.
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args([
            "sweep",
            "scenarios/bicycle_obstacle_nodelay.toml",
            "--set",
            "duration=5000.0",
            "--grid",
            "delays.steering=0.0,0.2",
            "--threads",
            "1",
            "--out",
        ])
        .arg(&out)
        .current_dir(root())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(2000));
    assert!(std::process::Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap()
        .success());
    let output = child.wait_with_output().unwrap();
    assert_eq!(
        output.status.code(),
        Some(130),
        "stderr: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    // The summary line counts the runs that ran, not the runs planned.
    let printed = String::from_utf8_lossy(&output.stdout);
    assert!(printed.contains("1 of 2 runs (1 not run)"), "{printed}");
    assert!(
        String::from_utf8_lossy(&output.stderr).contains("interrupted after 1 of 2 runs"),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).expect("summary written")).unwrap();
    let text = summary.to_string();
    println!("interrupted sweep summary: {}", &text[..text.len().min(400)]);
    assert!(
        text.contains("interrupted by a signal"),
        "the running run is marked interrupted"
    );
    assert!(
        text.contains("not run: the sweep was interrupted"),
        "the unstarted run is named"
    );
    // The interrupted run's log is a finished, readable MCAP marked incomplete.
    let logs: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    assert_eq!(logs.len(), 1, "{logs:?}");
    assert_eq!(analyze_json(&logs[0])["complete"], false);
}
