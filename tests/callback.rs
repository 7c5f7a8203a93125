//! The control callback: once-per-tick controller under RK4, panics caught, per-thread
//! dispatch.

mod common;
use common::*;

use std::path::Path;

use mjsafe::episode::Episode;
use mjsafe::log::mcap::McapSink;
use mjsafe::log::Sink;
use mjsafe::mujoco::{CallbackContext, ControlHook, DataView, Integrator, MjError, Model, Simulation};

#[derive(Default)]
struct Counter {
    calls: u64,
    ticks: u64,
    times_in_step: Vec<f64>,
}

impl ControlHook for Counter {
    fn on_control(&mut self, ctx: CallbackContext, data: &mut DataView<'_>) {
        self.calls += 1;
        if ctx.call_in_step == 0 {
            self.ticks += 1;
        }
        if ctx.step == 3 {
            self.times_in_step.push(ctx.time - ctx.step_start_time);
        }
        data.ctrl_mut()[0] = 1.0;
    }
}

fn count(integrator: Integrator, steps: u64) -> Counter {
    let mut model = Model::from_xml_file(&root().join("models/double_integrator_1d.xml")).unwrap();
    model.set_integrator(integrator);
    let mut sim = Simulation::new(model).unwrap();
    let mut counter = Counter::default();
    for _ in 0..steps {
        sim.step(&mut counter).unwrap();
    }
    counter
}

#[test]
fn rk4_fires_four_calls_per_step_but_the_same_ticks_as_euler() {
    let rk4 = count(Integrator::Rk4, 100);
    let euler = count(Integrator::Euler, 100);
    assert_eq!(rk4.calls, 400);
    assert_eq!(euler.calls, 100);
    assert_eq!(rk4.ticks, euler.ticks);
    assert_eq!(rk4.ticks, 100);
    let h = 0.002;
    let expected = [0.0, h / 2.0, h / 2.0, h];
    for (got, want) in rk4.times_in_step.iter().zip(expected) {
        assert!((got - want).abs() < 1e-12, "stage offsets {:?}", rk4.times_in_step);
    }
}

/// Counts of each topic in an MCAP file.
fn topic_counts(path: &Path) -> std::collections::BTreeMap<String, u64> {
    let bytes = std::fs::read(path).unwrap();
    let mut counts = std::collections::BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        *counts.entry(m.unwrap().channel.topic.clone()).or_insert(0) += 1;
    }
    counts
}

const DI_SCENARIO: &str = r#"
name = "di"
duration = 1.0
[vehicle]
kind = "double_integrator_1d"
model = "MODEL"
initial_state = [0.0, 1.0]
[delays]
acceleration = 0.1
[control]
period = 0.01
[nominal]
kind = "constant"
input = [0.5]
"#;

#[test]
fn episode_issues_one_command_per_tick_with_rk4_and_euler() {
    let dir = tempfile::tempdir().unwrap();
    let model = root().join("models/double_integrator_1d.xml");
    let text = DI_SCENARIO.replace("MODEL", model.to_str().unwrap());
    let file = write(dir.path(), "di.toml", &text);
    let mut finals = Vec::new();
    for integrator in ["rk4", "euler"] {
        let log = dir.path().join(format!("{integrator}.mcap"));
        run_ok(&file, &log, &["--set", &format!("vehicle.integrator='{integrator}'")]);
        let counts = topic_counts(&log);
        // 1 s at a 0.01 s control period: 100 ticks; 500 steps of 0.002 s.
        assert_eq!(counts["/command/issued"], 100, "{integrator}: {counts:?}");
        assert_eq!(counts["/command/applied"], 500, "{integrator}: {counts:?}");
        assert_eq!(counts["/state"], 501, "{integrator}: {counts:?}");
        finals.push(analyze_json(&log)["simulated_time"].as_f64().unwrap());
    }
    assert_eq!(finals, vec![1.0, 1.0]);
}

struct Panicker;
impl ControlHook for Panicker {
    fn on_control(&mut self, ctx: CallbackContext, _data: &mut DataView<'_>) {
        if ctx.step == 2 {
            panic!("controller bug at step {}", ctx.step);
        }
    }
}

#[test]
fn a_panic_in_the_callback_is_an_error_after_the_step_not_an_abort() {
    let model = Model::from_xml_file(&root().join("models/double_integrator_1d.xml")).unwrap();
    let mut sim = Simulation::new(model).unwrap();
    sim.step(&mut Panicker).unwrap();
    sim.step(&mut Panicker).unwrap();
    match sim.step(&mut Panicker) {
        Err(MjError::CallbackPanicked { message, .. }) => {
            assert!(message.contains("controller bug at step 2"))
        }
        other => panic!("expected CallbackPanicked, got {other:?}"),
    }
    // The simulation stays usable.
    sim.step(&mut Counter::default()).unwrap();
}

fn run_to(scenario: &Path, out: &Path) {
    let loaded = mjsafe::scenario::load(scenario, &[]).unwrap();
    let mut episode = Episode::new(&loaded).unwrap();
    let mut sink = McapSink::create(out, episode.info(), &[]).unwrap();
    let mut sinks: [&mut dyn Sink; 1] = [&mut sink];
    let summary = episode.run(&mut sinks).unwrap();
    assert!(summary.error.is_none());
}

#[test]
fn two_episodes_on_two_threads_log_the_same_as_one_after_the_other() {
    let dir = tempfile::tempdir().unwrap();
    let delayed = scenario("bicycle_obstacle.toml");
    let nodelay = scenario("bicycle_obstacle_nodelay.toml");
    let seq_a = dir.path().join("seq_a.mcap");
    let seq_b = dir.path().join("seq_b.mcap");
    run_to(&delayed, &seq_a);
    run_to(&nodelay, &seq_b);
    let par_a = dir.path().join("par_a.mcap");
    let par_b = dir.path().join("par_b.mcap");
    std::thread::scope(|s| {
        s.spawn(|| run_to(&delayed, &par_a));
        s.spawn(|| run_to(&nodelay, &par_b));
    });
    let read = |p: &Path| std::fs::read(p).unwrap();
    assert_ne!(read(&seq_a), read(&seq_b), "the two scenarios differ");
    assert!(read(&seq_a) == read(&par_a), "delayed run differs when run in parallel");
    assert!(
        read(&seq_b) == read(&par_b),
        "no-delay run differs when run in parallel"
    );
}
