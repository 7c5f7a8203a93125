//! Hostile and careless input (issue 14): analytic vehicles on the MuJoCo plant, absurd
//! timesteps and durations, devices and huge files as inputs, signals before stepping, MuJoCo's
//! own output. Each case: one clear error line naming the file and the key, a non-zero exit,
//! quickly, and nothing left behind.

mod common;
use common::*;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Runs `mjsafe ARGS` in `dir`; asserts it fails within `limit`, with one error line that
/// holds every needle and no panic, Rust type name or overlong number; and that `dir` holds
/// only `keep` afterwards.
fn expect_clean_failure(dir: &Path, args: &[&str], needles: &[&str], keep: &[&str]) -> String {
    let started = Instant::now();
    let o = Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap();
    let elapsed = started.elapsed();
    let err = stderr(&o);
    println!("{args:?} -> {:?} in {elapsed:.2?}: {}", o.status.code(), err.trim());
    assert_eq!(o.status.code(), Some(1), "exit status; stderr: {err}");
    assert!(elapsed < Duration::from_secs(20), "took {elapsed:?}");
    assert_eq!(err.trim().lines().count(), 1, "one error line:\n{err}");
    assert!(err.starts_with("error: "), "{err}");
    for needle in needles {
        assert!(err.contains(needle), "stderr lacks `{needle}`:\n{err}");
    }
    for bad in ["panicked", "struct ", "enum ", "RUST_BACKTRACE"] {
        assert!(!err.contains(bad), "stderr has `{bad}`:\n{err}");
    }
    assert!(
        !err.split(|c: char| !c.is_ascii_digit()).any(|d| d.len() > 15),
        "an overlong number:\n{err}"
    );
    let left = listing(dir);
    let mut keep: Vec<String> = keep.iter().map(|s| s.to_string()).collect();
    keep.sort();
    assert_eq!(left, keep, "files left in {}", dir.display());
    err
}

fn scenario_arg(name: &str) -> String {
    scenario(name).display().to_string()
}

#[test]
fn analytic_vehicles_on_the_mujoco_plant_are_refused() {
    for name in [
        "strict_feedback_pts.toml",
        "nonlinear_example1.toml",
        "linear_distinct_delays.toml",
    ] {
        let dir = tempfile::tempdir().unwrap();
        expect_clean_failure(
            dir.path(),
            &["run", &scenario_arg(name), "--set", "plant='mujoco'", "--out", "x.mcap"],
            &[name, "key `plant`", "expected plant = \"ode\""],
            &[],
        );
    }
}

#[test]
fn an_analytic_vehicle_without_a_timestep_names_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let text: String = std::fs::read_to_string(scenario("nonlinear_example1.toml"))
        .unwrap()
        .lines()
        .filter(|l| !l.trim_start().starts_with("timestep"))
        .map(|l| format!("{l}\n"))
        .collect();
    write(dir.path(), "no_step.toml", &text);
    expect_clean_failure(
        dir.path(),
        &["run", "no_step.toml", "--out", "x.mcap"],
        &["no_step.toml", "key `vehicle.timestep`", "integration step"],
        &["no_step.toml"],
    );
}

#[test]
fn absurd_timesteps_and_durations_are_refused_before_anything_runs() {
    for name in [
        "linear_distinct_delays.toml",
        "nonlinear_example1.toml",
        "scalar_tv_delay.toml",
        "unicycle_tv_delay.toml",
    ] {
        let dir = tempfile::tempdir().unwrap();
        expect_clean_failure(
            dir.path(),
            &[
                "run",
                &scenario_arg(name),
                "--set",
                "vehicle.timestep=1e-300",
                "--out",
                "x.mcap",
            ],
            &[name, "key `duration`", "limit of 100000000 steps", "--max-steps"],
            &[],
        );
    }
    let dir = tempfile::tempdir().unwrap();
    expect_clean_failure(
        dir.path(),
        &[
            "run",
            &scenario_arg("bicycle_obstacle.toml"),
            "--set",
            "duration=1e9",
            "--out",
            "x.mcap",
        ],
        &["key `duration`", "500000000000 steps"],
        &[],
    );
    // The budget is the user's to move.
    expect_clean_failure(
        dir.path(),
        &[
            "run",
            &scenario_arg("bicycle_obstacle.toml"),
            "--max-steps",
            "1000",
            "--out",
            "x.mcap",
        ],
        &["6000 steps, more than the limit of 1000 steps"],
        &[],
    );
    // A delay of more steps than the budget (with a short duration) is refused too.
    expect_clean_failure(
        dir.path(),
        &[
            "run",
            &scenario_arg("linear_distinct_delays.toml"),
            "--set",
            "duration=1e-5",
            "--set",
            "vehicle.timestep=1e-12",
            "--out",
            "x.mcap",
        ],
        &[
            "key `delays.u1`",
            "200000000000 steps of 0.000000000001 s, more than the limit of 100000000 steps",
        ],
        &[],
    );
    // Less than one step is not a run; the key named is the delay that is too long, not the
    // timestep.
    for (set, needles) in [
        ("duration=0.0001", ["key `duration`", "less than one step of 0.002 s"]),
        (
            "delays.steering=1e300",
            ["key `delays.steering`", "more than the limit of 100000000 steps"],
        ),
    ] {
        let scenario = scenario_arg("bicycle_obstacle.toml");
        let args = ["run", &scenario, "--set", set, "--out", "x.mcap"];
        expect_clean_failure(dir.path(), &args, &needles, &[]);
    }
}

#[test]
fn devices_and_huge_files_as_inputs_are_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    expect_clean_failure(
        d,
        &[
            "run",
            &scenario_arg("bicycle_obstacle.toml"),
            "--set",
            "vehicle.model='/dev/zero'",
            "--out",
            "x.mcap",
        ],
        &["key `vehicle.model`", "/dev/zero", "character device"],
        &[],
    );
    expect_clean_failure(
        d,
        &["run", "/dev/zero"],
        &["/dev/zero", "scenario", "character device"],
        &[],
    );
    expect_clean_failure(d, &["run", "."], &["scenario", "a directory"], &[]);
    // A 100 MiB model (sparse: no disk used) is over the 64 MiB limit.
    let big = d.join("big.xml");
    std::fs::File::create(&big).unwrap().set_len(100 << 20).unwrap();
    expect_clean_failure(
        d,
        &[
            "run",
            &scenario_arg("bicycle_obstacle.toml"),
            "--set",
            &format!("vehicle.model='{}'", big.display()),
            "--out",
            "x.mcap",
        ],
        &["key `vehicle.model`", "larger than the limit of 64 MiB (100 MiB)"],
        &["big.xml"],
    );
    expect_clean_failure(
        d,
        &["sweep", "--sweep", "/dev/zero", "--dry-run"],
        &["/dev/zero", "sweep file", "character device"],
        &["big.xml"],
    );
    expect_clean_failure(
        d,
        &["analyze", "--merge", "/dev/zero"],
        &["/dev/zero", "sweep summary", "character device"],
        &["big.xml"],
    );
}

#[test]
fn a_sweep_of_billions_of_runs_is_refused_before_listing_them() {
    let dir = tempfile::tempdir().unwrap();
    expect_clean_failure(
        dir.path(),
        &[
            "sweep",
            &scenario_arg("bicycle_obstacle.toml"),
            "--random",
            "99999999999",
            "--range",
            "delays.steering=0..0.4",
            "--seed",
            "1",
            "--dry-run",
        ],
        &["more than 1000000 runs", "99999999999 random draws"],
        &[],
    );
}

#[test]
fn mujoco_never_writes_its_own_log_file_or_text() {
    // The blow-up of tests/bad_input.rs: MuJoCo warns about a huge qvel, which by default
    // appends to MUJOCO_LOG.TXT in the working directory and prints "WARNING" on stdout.
    let dir = tempfile::tempdir().unwrap();
    let text = blowup_scenario();
    write(dir.path(), "blowup.toml", &text);
    let o = Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args(["run", "blowup.toml", "--out", "blowup.mcap"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(
        !dir.path().join("MUJOCO_LOG.TXT").exists(),
        "MuJoCo wrote MUJOCO_LOG.TXT"
    );
    assert!(!stdout(&o).contains("WARNING"), "MuJoCo printed: {}", stdout(&o));
    let err = stderr(&o);
    assert!(err.contains("qvel") && !err.contains("WARNING:"), "{err}");
}

#[test]
fn a_signal_before_stepping_ends_the_process_at_once_and_leaves_nothing() {
    // A time-varying delay checked at 10⁸ sample times (Assumptions 1-2 before the first
    // step) takes several seconds: SIGTERM during it must end the process within a second.
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args([
            "run",
            &scenario_arg("scalar_tv_delay.toml"),
            "--max-steps",
            "1000000000",
            "--set",
            "duration=990000",
            "--out",
            "x.mcap",
        ])
        .current_dir(dir.path())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(700));
    assert!(
        child.try_wait().unwrap().is_none(),
        "the check finished too soon to test"
    );
    let signalled = Instant::now();
    assert!(Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap()
        .success());
    let o = child.wait_with_output().unwrap();
    let waited = signalled.elapsed();
    println!(
        "exit {:?} {waited:.2?} after SIGTERM: {}",
        o.status.code(),
        stderr(&o).trim()
    );
    assert_eq!(o.status.code(), Some(130));
    assert!(waited < Duration::from_secs(2), "took {waited:?} to stop");
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert!(left.is_empty(), "{left:?}");
}

/// A MuJoCo warning that changes the physics (nconmax = 1: contacts dropped) is logged once as
/// a `mujoco_warning` event and shown by `run` and `analyze`; the stock model raises none.
#[test]
fn physics_changing_mujoco_warnings_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let stock = std::fs::read_to_string(root().join("models/car.xml")).unwrap();
    let small = stock.replace(r#"<size nstack="100000"/>"#, r#"<size nstack="100000" nconmax="1"/>"#);
    assert_ne!(small, stock, "models/car.xml has no <size nstack=\"100000\"/>");
    let model = write(dir.path(), "car_ncon.xml", &small);
    let scenario = scenario("car_obstacle_gamma_m.toml");
    let run = |model: Option<&Path>, log: &str| {
        let out = dir.path().join(log);
        let set_model = model.map(|m| format!("vehicle.model='{}'", m.display()));
        let mut args = vec!["run", scenario.to_str().unwrap(), "--set", "duration=1.0", "--json"];
        if let Some(set) = &set_model {
            args.extend(["--set", set]);
        }
        args.extend(["--out", out.to_str().unwrap()]);
        let o = mjsafe(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let summary: serde_json::Value = serde_json::from_str(stdout(&o).trim()).unwrap();
        (summary, stderr(&o), out)
    };

    let (summary, err, log) = run(Some(&model), "warned.mcap");
    let warnings = summary["warnings"].as_array().expect("summary lists the warnings");
    assert_eq!(warnings.len(), 1, "{summary}");
    let message = warnings[0].as_str().unwrap();
    for needle in ["contact buffer full", "at t = 0 s", "nconmax = 1", "raise nconmax"] {
        assert!(message.contains(needle), "`{needle}` not in {message}");
    }
    assert!(err.contains("warning: MuJoCo: contact buffer full"), "{err}");
    let events = read_topic::<mjsafe::log::proto::Event>(&log, "/event");
    let warned: Vec<_> = events.iter().filter(|e| e.kind == "mujoco_warning").collect();
    assert_eq!(warned.len(), 1, "once per warning kind: {events:?}");
    assert_eq!(warned[0].participants, ["contact_buffer_full"]);
    assert_eq!(warned[0].message, message);
    assert_eq!(analyze_json(&log)["warnings"], summary["warnings"]);

    let (summary, err, log) = run(None, "stock.mcap");
    assert!(summary.get("warnings").is_none(), "{summary}");
    assert!(!err.contains("MuJoCo"), "{err}");
    assert!(analyze_json(&log).get("warnings").is_none());
    let events = read_topic::<mjsafe::log::proto::Event>(&log, "/event");
    assert!(events.iter().all(|e| e.kind != "mujoco_warning"), "{events:?}");
}

/// Issue 34, part 3: sizes that drive an allocation or a loop are bounded before use, with the
/// key and the limit in one error line (each was an abort, a panic, GBs or hours before).
#[test]
fn sizes_that_drive_allocations_or_loops_are_bounded_before_use() {
    let gamma_m = scenario_arg("bicycle_obstacle_gamma_m.toml");
    let example1 = scenario_arg("nonlinear_example1.toml");
    let scalar = scenario_arg("scalar_tv_delay.toml");
    let cases: [(Vec<&str>, Vec<&str>); 8] = [
        // A sensor ring of 10¹¹ states (an abort: "memory allocation … failed").
        (
            vec!["run", &gamma_m, "--set", "sensing={latency=1e9}"],
            vec!["sensing.latency", "duration"],
        ),
        (
            vec![
                "run",
                &gamma_m,
                "--set",
                "duration=1e6",
                "--set",
                "sensing={latency=2e5}",
                "--max-steps",
                "1000000000",
            ],
            vec!["sensing.latency", "limit"],
        ),
        // φ's grid: 4294967296^4 points (an overflow panic), 100000^2 (40 minutes).
        (
            vec![
                "run",
                &example1,
                "--set",
                "filter.phi_box={lower=[-1.0,-1.0], upper=[1.0,1.0], points=4294967296}",
            ],
            vec!["filter.phi_box.points", "1000000"],
        ),
        (
            vec![
                "run",
                &example1,
                "--set",
                "filter.phi_box={lower=[-1.0,-1.0], upper=[1.0,1.0], points=100000}",
            ],
            vec!["filter.phi_box.points"],
        ),
        // 10⁸ steps of a 1.5 s prediction window each (40 s of silence, 2.7 GB, hours).
        (
            vec!["run", &scalar, "--set", "vehicle.timestep=1e-7"],
            vec!["vehicle.timestep", "steps", "limit"],
        ),
        // Extreme finite values that silently made nothing happen.
        (
            vec![
                "run",
                &gamma_m,
                "--set",
                "actuation={steering={extra_latency={distribution='uniform', max=1e300}}}",
            ],
            vec!["actuation.steering.extra_latency.max"],
        ),
        (
            vec!["run", &gamma_m, "--set", "obstacles.0.appear_jitter=1e300"],
            vec!["obstacles.0.appear_jitter"],
        ),
        (
            vec!["run", &gamma_m, "--set", "vehicle.initial_state=[1e300, 0.0, 0.0, 3.0]"],
            vec!["vehicle.initial_state", "1e9"],
        ),
    ];
    for (args, needles) in cases {
        let dir = tempfile::tempdir().unwrap();
        expect_clean_failure(dir.path(), &args, &needles, &[]);
    }
}

/// A log estimated over the log budget, or work over the work budget, is refused before the
/// run; the flags raise the budgets.
#[test]
fn runs_over_the_work_or_log_budget_are_refused_before_they_start() {
    let scalar = scenario_arg("scalar_tv_delay.toml");
    let dir = tempfile::tempdir().unwrap();
    expect_clean_failure(
        dir.path(),
        &["run", &scalar, "--max-log-size", "100000"],
        &["duration", "log", "--max-log-size"],
        &[],
    );
    expect_clean_failure(
        dir.path(),
        &["run", &scalar, "--max-work", "1000"],
        &["duration", "integration steps", "--max-work"],
        &[],
    );
    let o = Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args(["run", &scalar, "--max-log-size", "100000000", "--out", "run.mcap"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
}

/// An MJCF whose sizes would make MuJoCo allocate gigabytes is refused before MuJoCo compiles
/// it, naming the element and the attribute.
#[test]
fn mjcf_sizes_are_bounded_before_mujoco_compiles_the_model() {
    let dir = tempfile::tempdir().unwrap();
    let bicycle = std::fs::read_to_string(root().join("models/bicycle.xml")).unwrap();
    for (size, needle) in [
        (r#"<size nkey="100000000"/>"#, r#"<size nkey="100000000">"#),
        (r#"<size nstack="1e12"/>"#, "nstack"),
        (r#"<size nuser_geom="2000000"/>"#, "nuser_geom"),
        (
            r#"<asset><texture name="t" builtin="checker" width="100000" height="100000"/></asset>"#,
            "texels",
        ),
    ] {
        // Inside <mujoco>, first.
        let start = bicycle.find("<mujoco").unwrap();
        let at = start + bicycle[start..].find('>').unwrap() + 1;
        let model = format!("{}{size}{}", &bicycle[..at], &bicycle[at..]);
        let path = write(dir.path(), "big.xml", &model);
        let model_arg = format!("vehicle.model='{}'", path.display());
        let out = dir.path().join("out");
        std::fs::create_dir_all(&out).unwrap();
        let err = expect_clean_failure(
            &out,
            &[
                "run",
                &scenario_arg("bicycle_obstacle_gamma_m.toml"),
                "--set",
                &model_arg,
            ],
            &["big.xml", needle],
            &[],
        );
        assert!(!err.contains("foreign exception"), "{err}");
    }
}

/// A run longer than two seconds shows its progress on a terminal (`script` gives it one), and
/// nothing of it when stderr is not a terminal.
#[test]
fn a_long_run_shows_progress_on_a_terminal_only() {
    let dir = tempfile::tempdir().unwrap();
    let command = format!(
        "'{}' run '{}' --set vehicle.timestep=2e-5 --out '{}'",
        env!("CARGO_BIN_EXE_mjsafe"),
        scenario_arg("scalar_tv_delay.toml"),
        dir.path().join("tty.mcap").display()
    );
    let typescript = dir.path().join("typescript");
    let o = Command::new("script")
        .args(["-qec", &command])
        .arg(&typescript)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let shown = String::from_utf8_lossy(&std::fs::read(&typescript).unwrap()).into_owned();
    assert!(
        shown.contains("run: t = ") && shown.contains(" s of 10.00 s (") && shown.contains("x real time"),
        "{shown}"
    );
    let o = Command::new(env!("CARGO_BIN_EXE_mjsafe"))
        .args([
            "run",
            &scenario_arg("scalar_tv_delay.toml"),
            "--set",
            "vehicle.timestep=2e-5",
        ])
        .arg("--out")
        .arg(dir.path().join("pipe.mcap"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(!stderr(&o).contains("run: t = "), "{}", stderr(&o));
}
