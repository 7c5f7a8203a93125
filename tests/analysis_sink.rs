//! The in-memory analysis of a running episode (`AnalysisSink`, what every falsification
//! candidate runs with) gives exactly the metrics `mjsafe analyze` computes from the run's log:
//! on every shipped scenario, and on a run an error stops.

mod common;

use common::{blowup_scenario, root, write};
use mjsafe::analyze::{analyze_file, AnalysisSink, RunMetrics};
use mjsafe::episode::Episode;
use mjsafe::log::mcap::McapSink;
use mjsafe::log::Sink;
use std::path::Path;

/// The metrics of one run of `scenario` from its log and from the analysis sink, the two
/// sinks observing the same run.
fn log_and_memory(scenario: &Path, overrides: &[String], log: &Path) -> (RunMetrics, RunMetrics) {
    let loaded = mjsafe::scenario::load(scenario, overrides).unwrap();
    let mut episode = Episode::new(&loaded).unwrap();
    let mut file = McapSink::create(log, episode.info(), &[]).unwrap();
    let mut memory = AnalysisSink::new(episode.info(), "in memory");
    let mut sinks: [&mut dyn Sink; 2] = [&mut file, &mut memory];
    episode.run(&mut sinks).unwrap();
    (analyze_file(log).unwrap(), memory.metrics().unwrap())
}

/// The metrics as `analyze --json` prints them, but for the name of their source.
fn json(metrics: &RunMetrics) -> serde_json::Value {
    let mut value = serde_json::to_value(metrics).unwrap();
    value["file"] = serde_json::Value::Null;
    value
}

#[test]
fn every_scenario_analysed_in_memory_gives_the_metrics_of_its_log() {
    let dir = tempfile::tempdir().unwrap();
    let mut scenarios: Vec<_> = std::fs::read_dir(root().join("scenarios"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml") && !p.to_string_lossy().ends_with(".sweep.toml"))
        .collect();
    scenarios.sort();
    assert!(scenarios.len() >= 13, "the shipped scenarios: {scenarios:?}");
    let (mut with_predictions, mut with_obstacles) = (0, 0);
    for scenario in &scenarios {
        let log = dir.path().join("run.mcap");
        let (from_log, in_memory) = log_and_memory(scenario, &[], &log);
        assert_eq!(json(&in_memory), json(&from_log), "{}", scenario.display());
        assert_eq!(in_memory.file, "in memory");
        // A whole log gives every metric; only a goal never reached, one min h across
        // barriers of different units (a road's edges beside an obstacle), the impact speed of a
        // run with moving obstacles that hits none, and the headway metrics of a run where no
        // road user is ever ahead in the path, are absent, with their reasons.
        assert!(
            in_memory.complete
                && in_memory.missing.iter().all(|(k, why)| k == "time_to_goal"
                    || k == "min_h" && in_memory.min_h_by_barrier().is_some()
                    || k == "impact_speed_by_actor" && why == "no collision"
                    || k.ends_with("_headway") && why.starts_with("the vehicle's front never reached")
                    || matches!(k.as_str(), "min_time_headway" | "max_brake_threat_number")
                        && why == "no road user was ever ahead in the vehicle's path"),
            "{}: {:?}",
            scenario.display(),
            in_memory.missing
        );
        with_predictions += usize::from(in_memory.prediction().is_some_and(|p| !p.is_empty()));
        with_obstacles += usize::from(in_memory.min_clearance().is_some());
    }
    // The comparison covers the metrics that need predictions and obstacles.
    assert!(
        with_predictions >= 5 && with_obstacles >= 4,
        "{with_predictions} {with_obstacles}"
    );
}

#[test]
fn a_run_an_error_stops_is_incomplete_with_the_same_metrics_in_memory() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = write(dir.path(), "blowup.toml", &blowup_scenario());
    let (from_log, in_memory) = log_and_memory(&scenario, &[], &dir.path().join("blowup.mcap"));
    assert!(!in_memory.complete);
    assert!(in_memory.error.is_some(), "{in_memory:?}");
    assert_eq!(json(&in_memory), json(&from_log));
}

#[test]
fn overrides_reach_the_in_memory_analysis_through_the_run_metadata() {
    // The delay-attributed violation time needs the run metadata's longest delay, and the
    // filter label its resolved scenario: with other delays, other values, equal in both.
    let dir = tempfile::tempdir().unwrap();
    let scenario = root().join("scenarios/bicycle_obstacle_gamma_m.toml");
    let overrides = [
        "delays.acceleration=0.5".to_string(),
        "obstacles.0.centre.1=1.5".to_string(),
    ];
    let (from_log, in_memory) = log_and_memory(&scenario, &overrides, &dir.path().join("run.mcap"));
    assert_eq!(json(&in_memory), json(&from_log));
    let (default_log, _) = log_and_memory(&scenario, &[], &dir.path().join("default.mcap"));
    assert_ne!(json(&in_memory), json(&default_log), "the overrides change the metrics");
}
