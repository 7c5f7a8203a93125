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
    });
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
