//! The examples/ programs are built by `cargo test`; these tests run them and assert what they
//! show (a user-defined filter registered from outside the crate, run through the facade).

mod common;

use std::path::PathBuf;
use std::process::Command;

/// target/<profile>/examples/<name>, next to this test's own binary (target/<profile>/deps).
fn example(name: &str) -> PathBuf {
    let deps = std::env::current_exe().unwrap().parent().unwrap().to_path_buf();
    deps.parent().unwrap().join("examples").join(name)
}

#[test]
fn a_user_filter_with_a_delay_margin_is_compared_with_4_67() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(example("robust_cbf")).arg(dir.path()).output().unwrap();
    let text = common::stdout(&out);
    assert!(out.status.success(), "{text}{}", common::stderr(&out));
    let row = |label: &str| -> Vec<String> {
        let line = text
            .lines()
            .find(|l| l.starts_with(label))
            .unwrap_or_else(|| panic!("no row {label}: {text}"));
        line.split(" | ").map(str::to_string).collect()
    };
    // The delay-free CBF-QP (4.9) at x(t) collides (as in scenarios/bicycle_obstacle.toml);
    // a small margin is not enough; a margin of 60 m²/s of delay keeps the bicycle clear, but
    // far more conservatively than (4.67), which skims the obstacle (min h ≈ 0).
    assert_eq!(row("(4.9)")[1], "yes", "{text}");
    assert_eq!(row("robust_cbf margin_rate = 20")[1], "yes", "{text}");
    let wide = row("robust_cbf margin_rate = 60");
    let gamma_m = row("(4.67)");
    assert_eq!(wide[1], "no", "{text}");
    assert_eq!(gamma_m[1], "no", "{text}");
    let min_h = |r: &[String]| r[2].parse::<f64>().unwrap();
    assert!(min_h(&wide) > 10.0 * min_h(&gamma_m).max(0.1), "{text}");
    // Each run left a complete log that the CLI reads like its own.
    for i in 0..4 {
        let log = dir.path().join(format!("run{i}.mcap"));
        assert!(
            common::analyze_json(&log)["complete"].as_bool().unwrap(),
            "{}",
            log.display()
        );
    }
}
