//! The one run path (`mjsafe::run`): the embedding API treats a failing sink as `mjsafe run`
//! does — the log of record gets an `/event` error naming the failure and is finished as
//! incomplete, and the run is an error that names the log.

mod common;

use common::root;
use mjsafe::embed::{self, EmbedError, RunError};
use mjsafe::log::{LogError, Record, Sink};

/// Fails at its `fail_at`-th record.
struct Failing {
    seen: usize,
    fail_at: usize,
}

impl Sink for Failing {
    fn record(&mut self, _: &Record) -> Result<(), LogError> {
        self.seen += 1;
        if self.seen == self.fail_at {
            return Err(LogError::Write {
                path: "user sink".into(),
                message: "no space left".into(),
            });
        }
        Ok(())
    }
    fn finish(&mut self, _: bool) -> Result<(), LogError> {
        Ok(())
    }
}

#[test]
fn a_failing_user_sink_stops_the_run_and_marks_its_log_incomplete() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    let loaded = embed::load_scenario(
        &root().join("scenarios/bicycle_obstacle.toml"),
        &["duration=1.0".to_string()],
    )
    .unwrap();
    let mut failing = Failing { seen: 0, fail_at: 500 };
    let error = embed::run_logged(&loaded, &log, &mut [&mut failing]).unwrap_err();
    let EmbedError::Run(RunError::Sink {
        error,
        log: Some(named),
    }) = &error
    else {
        panic!("expected a sink failure naming the log, got {error:?}");
    };
    assert_eq!(named, &log);
    assert!(error.to_string().contains("no space left"), "{error}");
    assert!(
        error.to_string().len() < 200 && !error.to_string().contains('\n'),
        "one line: {error}"
    );
    // The log is there, under its final name, and says why it is incomplete.
    let metrics = mjsafe::analyze::analyze_file(&log).unwrap();
    assert!(!metrics.complete);
    let reason = metrics.error.clone().expect("the log names the failure");
    assert!(
        reason.contains("user sink: no space left") && reason.contains("the run stopped"),
        "{reason}"
    );
    assert!(metrics.simulated_time() > 0.0 && metrics.simulated_time() < 1.0);

    // The same sink beside the in-memory analysis: the same error, and no log anywhere.
    let mut failing = Failing { seen: 0, fail_at: 500 };
    let further: Vec<Box<dyn Sink + '_>> = vec![Box::new(&mut failing)];
    let error = mjsafe::run::run(&loaded, mjsafe::run::Keep::Metrics("in memory"), further).unwrap_err();
    assert!(matches!(error, RunError::Sink { log: None, .. }), "{error:?}");
}

#[test]
fn a_run_that_stops_inside_the_episode_still_has_an_outcome_with_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("blowup.mcap");
    let scenario = common::write(dir.path(), "blowup.toml", &common::blowup_scenario());
    let loaded = embed::load_scenario(&scenario, &[]).unwrap();
    let outcome = embed::run_logged(&loaded, &log, &mut []).unwrap();
    let stopped = outcome.summary.error.expect("the episode stops early");
    let metrics = outcome.metrics.expect("a logged run is analysed");
    assert!(!metrics.complete);
    assert_eq!(metrics.error.as_deref(), Some(stopped.to_string().as_str()));
}

#[test]
fn a_users_filter_carries_its_own_label_into_the_log_and_the_analysis() {
    #[derive(serde::Serialize, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Passthrough {}
    impl mjsafe::registry::Params for Passthrough {}
    embed::register(|r| {
        r.add_filter(
            "passthrough_labelled",
            |_: &Passthrough, ctx: &mjsafe::filter::FilterContext| {
                mjsafe::filter::none::build(&Default::default(), ctx)
            },
        )
        .label("my passthrough (eq. 7)")
        .description("the nominal input, as a user's kind");
    })
    .expect("a new kind");
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("labelled.mcap");
    let loaded = embed::load_scenario(
        &root().join("scenarios/bicycle_obstacle.toml"),
        &[
            "duration=0.5".to_string(),
            "filter={kind='passthrough_labelled'}".to_string(),
        ],
    )
    .unwrap();
    let metrics = embed::run_logged(&loaded, &log, &mut []).unwrap().metrics.unwrap();
    // From the log's metadata: its label, with no suffix (the run has delays).
    assert_eq!(metrics.filter_label.as_deref(), Some("my passthrough (eq. 7)"));
    let o = common::mjsafe(&["info", "--json", log.to_str().unwrap()]);
    let info: serde_json::Value = serde_json::from_str(&common::stdout(&o)).unwrap();
    let text = info.to_string();
    for expected in [
        "the nominal input, as a user's kind",
        "passthrough_labelled",
        "kinematic bicycle (4.78)",
        "LQR path tracking",
    ] {
        assert!(text.contains(expected), "{expected} not in the run metadata: {text}");
    }
    // The brief comparison names the run by it.
    let o = common::mjsafe(&["analyze", "--brief", log.to_str().unwrap()]);
    assert!(
        common::stdout(&o).contains("my passthrough (eq. 7)"),
        "{}",
        common::stdout(&o)
    );
}

/// Stepping a run from outside (`Prepared::start`, `Running::advance`) is the run: stepped to
/// its end it writes the log `Prepared::run` writes, byte for byte; ended early by its caller
/// (`Rest::EndHere`) its log is complete up to there, with the state where it stopped, and the
/// sink failure path is the run's.
#[test]
fn a_run_stepped_from_outside_is_the_same_run() {
    use mjsafe::run::{Keep, Prepared, Rest};
    let dir = tempfile::tempdir().unwrap();
    let loaded = embed::load_scenario(
        &root().join("scenarios/bicycle_obstacle.toml"),
        &["duration=2.0".to_string(), "delays.steering=0.3".to_string()],
    )
    .unwrap();
    let whole = dir.path().join("whole.mcap");
    Prepared::new(&loaded, Keep::Log(&whole))
        .unwrap()
        .run(Vec::new())
        .unwrap();

    let stepped = dir.path().join("stepped.mcap");
    let mut running = Prepared::new(&loaded, Keep::Log(&stepped)).unwrap().start(Vec::new());
    let mut calls = 0;
    let end = loop {
        calls += 1;
        if let Some(end) = running.advance().unwrap() {
            break end;
        }
    };
    // h = 2 ms (models/bicycle.xml): 1000 steps.
    assert_eq!(end, (1000, None));
    assert_eq!(calls, 1001, "one call per step, and one that logs x(T) and the end");
    assert_eq!(running.episode().step_index(), 1000);
    let outcome = running.finish(Rest::Run).unwrap();
    assert_eq!(outcome.summary.steps, 1000);
    assert_eq!(std::fs::read(&stepped).unwrap(), std::fs::read(&whole).unwrap());

    // Ended by its caller after 250 steps: x(t_250) is the last state, the log is complete.
    let early = dir.path().join("early.mcap");
    let mut running = Prepared::new(&loaded, Keep::Log(&early)).unwrap().start(Vec::new());
    for _ in 0..250 {
        assert_eq!(running.advance().unwrap(), None);
    }
    let x250 = running.episode().plant_state();
    let outcome = running.finish(Rest::EndHere).unwrap();
    assert_eq!(outcome.summary.steps, 250);
    let metrics = outcome.metrics.unwrap();
    assert!(metrics.complete, "{:?}", metrics.error);
    let tables = mjsafe::export::read_tables(&early, &mjsafe::export::table_topics()).unwrap();
    let (_, state) = tables.tables.iter().find(|(t, _)| t.name() == "/state").unwrap();
    let column = |name: &str| match &state.columns.iter().find(|(n, _)| n == name).unwrap().1 {
        mjsafe::export::Values::F64(v) => v.clone(),
        other => panic!("{name}: {other:?}"),
    };
    assert_eq!(*column("time").last().unwrap(), 0.5);
    assert_eq!(*column("x1").last().unwrap(), x250[0]);
    let (_, events) = tables.tables.iter().find(|(t, _)| t.name() == "/event").unwrap();
    let mjsafe::export::Values::Text(messages) = &events.columns.iter().find(|(n, _)| n == "message").unwrap().1 else {
        panic!("messages are text")
    };
    assert_eq!(
        messages.last().unwrap(),
        "stopped by its caller after 250 of 1000 steps"
    );
}

/// A kind registered under a built-in's name is refused (and the built-in stays what a
/// scenario naming it runs) unless the registration says it replaces it; a refused call keeps
/// none of its kinds.
#[test]
fn a_kind_under_a_taken_name_is_refused_unless_it_says_it_replaces() {
    #[derive(serde::Serialize, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Nothing {}
    impl mjsafe::registry::Params for Nothing {}
    let none = |_: &Nothing, ctx: &mjsafe::filter::FilterContext| mjsafe::filter::none::build(&Default::default(), ctx);
    let refused = embed::register(|r| {
        r.add_filter("kept_out_with_gamma_m", none).label("never registered");
        r.add_filter("gamma_m", none).label("not (4.67)");
    })
    .unwrap_err();
    assert_eq!((refused.section, refused.kind.as_str()), ("filter", "gamma_m"));
    assert!(refused.what.contains("built in: γm filter (4.67)"), "{}", refused.what);
    assert!(refused.to_string().contains("replacing()"), "{refused}");
    let registry = embed::registry();
    assert!(!registry.has_kind("filter", "kept_out_with_gamma_m"));
    let params: toml::Table = toml::from_str("l0 = 4.0\nl1 = 4.0\nm = 50.0").unwrap();
    let label = registry.describe_filter("gamma_m", &params).unwrap().label;
    drop(registry);
    assert!(label.starts_with("γm filter (4.67)"), "{label}");
    // Said: replaced (under a name of its own here, to leave the built-in to the other tests).
    embed::register(|r| {
        r.add_filter("replaced_twice", none).label("first");
    })
    .unwrap();
    embed::register(|r| {
        r.replacing().add_filter("replaced_twice", none).label("second");
    })
    .unwrap();
    let described = embed::registry()
        .describe_filter("replaced_twice", &toml::Table::new())
        .unwrap();
    assert_eq!(described.label, "second");
}
