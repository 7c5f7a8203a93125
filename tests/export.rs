//! `mjsafe export`: the tables hold exactly what the log reader reads from the log, as pandas
//! loads them (examples/python/load_log.py), for CSV and Parquet; outputs follow the file rules.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

use common::*;
use mjsafe::log::read::{read_run_file, Message, ReadError, RunVisitor};
use mjsafe::log::{proto, Record};

/// Every message of the table topics, read by mjsafe's one log reader.
#[derive(Default)]
struct Logged {
    states: Vec<proto::State>,
    issued: Vec<proto::IssuedCommand>,
    applied: Vec<proto::AppliedCommand>,
    barriers: Vec<proto::Barrier>,
    filters: Vec<proto::Filter>,
    predictions: Vec<proto::Prediction>,
    events: Vec<proto::Event>,
}

impl RunVisitor for Logged {
    fn metadata(&mut self, _: &str, _: &BTreeMap<String, String>) -> Result<(), ReadError> {
        Ok(())
    }

    fn message(&mut self, message: &Message<'_>) -> Result<(), ReadError> {
        match message.record()? {
            Record::State(m) => self.states.push(m),
            Record::Issued(m) => self.issued.push(m),
            Record::Applied(m) => self.applied.push(m),
            Record::Barrier(m) => self.barriers.push(m),
            Record::Filter(m) => self.filters.push(m),
            Record::Prediction(m) => self.predictions.push(m),
            Record::Event(m) => self.events.push(m),
            _ => {}
        }
        Ok(())
    }
}

/// The export of `log` in `dir` as load_log.py loads it: {topic: {column: values}}.
fn load_with_pandas(dir: &Path, stem: &str) -> serde_json::Value {
    let o = Command::new(python())
        .arg(root().join("examples/python/load_log.py"))
        .args([dir.to_str().unwrap(), "--stem", stem, "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "load_log.py failed: {}", stderr(&o));
    serde_json::from_slice(&o.stdout).expect("load_log.py --json prints JSON")
}

/// A logged double as load_log.py's JSON gives it (NaN as null, infinities as strings).
fn json_of(v: f64) -> serde_json::Value {
    if v.is_nan() {
        serde_json::Value::Null
    } else if v.is_infinite() {
        serde_json::json!(if v > 0.0 { "inf" } else { "-inf" })
    } else {
        serde_json::json!(v)
    }
}

fn column<'a>(tables: &'a serde_json::Value, topic: &str, name: &str) -> &'a Vec<serde_json::Value> {
    tables[topic][name].as_array().unwrap_or_else(|| {
        panic!(
            "no column {name} in {topic}: {:?}",
            tables[topic].as_object().map(|o| o.keys().collect::<Vec<_>>())
        )
    })
}

fn assert_column(tables: &serde_json::Value, topic: &str, name: &str, expected: impl Iterator<Item = f64>) {
    let got = column(tables, topic, name);
    let expected: Vec<serde_json::Value> = expected.map(json_of).collect();
    assert_eq!(got.len(), expected.len(), "{topic} {name}: row count");
    for (i, (g, e)) in got.iter().zip(&expected).enumerate() {
        assert_eq!(g, e, "{topic} {name} row {i}");
    }
}

fn check_tables(tables: &serde_json::Value, logged: &Logged) {
    let s = &logged.states;
    assert_column(tables, "/state", "time", s.iter().map(|m| m.time));
    for (i, name) in s[0].names.iter().enumerate() {
        assert_column(tables, "/state", name, s.iter().map(|m| m.values[i]));
    }
    let steps: Vec<u64> = column(tables, "/state", "step")
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    assert_eq!(steps, s.iter().map(|m| m.step).collect::<Vec<_>>());

    for (i, ch) in logged.issued[0].channels.iter().enumerate() {
        let issued = &logged.issued;
        assert_column(
            tables,
            "/command/issued",
            &format!("{ch}.nominal"),
            issued.iter().map(|m| m.nominal[i]),
        );
        assert_column(
            tables,
            "/command/issued",
            &format!("{ch}.filtered"),
            issued.iter().map(|m| m.filtered[i]),
        );
        let applied = &logged.applied;
        assert_column(tables, "/command/applied", ch, applied.iter().map(|m| m.values[i]));
        assert_column(
            tables,
            "/command/applied",
            &format!("{ch}.issued_at"),
            applied.iter().map(|m| m.issued_at[i]),
        );
        assert_column(
            tables,
            "/filter",
            &format!("{ch}.correction"),
            logged.filters.iter().map(|m| m.correction[i]),
        );
    }
    assert_column(tables, "/filter", "mu", logged.filters.iter().map(|m| m.mu));
    let left_out: Vec<serde_json::Value> = logged.filters.iter().map(|m| serde_json::json!(m.left_out)).collect();
    assert_eq!(column(tables, "/filter", "left_out"), &left_out);
    let b = &logged.barriers;
    assert_column(tables, "/barrier", "time", b.iter().map(|m| m.time));
    for (i, barrier) in b[0].barriers.iter().enumerate() {
        let n = &barrier.name;
        assert_column(tables, "/barrier", &format!("{n}.h"), b.iter().map(|m| m.barriers[i].h));
        assert_column(
            tables,
            "/barrier",
            &format!("{n}.constraint"),
            b.iter().map(|m| m.barriers[i].constraint),
        );
        assert_column(
            tables,
            "/barrier",
            &format!("{n}.clearance"),
            b.iter().map(|m| m.barriers[i].clearance),
        );
        assert_column(
            tables,
            "/barrier",
            &format!("{n}.time_to_collision"),
            b.iter().map(|m| m.barriers[i].time_to_collision),
        );
        let known: Vec<bool> = column(tables, "/barrier", &format!("{n}.known"))
            .iter()
            .map(|v| v.as_bool().unwrap())
            .collect();
        assert_eq!(known, b.iter().map(|m| m.barriers[i].known).collect::<Vec<_>>());
    }
    let p = &logged.predictions;
    assert!(!p.is_empty(), "the scenario uses predictions");
    assert_column(tables, "/prediction", "error", p.iter().map(|m| m.error));
    assert_column(tables, "/prediction", "issued_at", p.iter().map(|m| m.issued_at));
    for (i, name) in s[0].names.iter().enumerate() {
        assert_column(
            tables,
            "/prediction",
            &format!("predicted.{name}"),
            p.iter().map(|m| m.predicted[i]),
        );
        assert_column(
            tables,
            "/prediction",
            &format!("realized.{name}"),
            p.iter().map(|m| m.realized[i]),
        );
    }
    let channels: Vec<&str> = column(tables, "/prediction", "channel")
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(channels, p.iter().map(|m| m.channel.as_str()).collect::<Vec<_>>());
    let kinds: Vec<&str> = column(tables, "/event", "kind")
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert_eq!(kinds, logged.events.iter().map(|m| m.kind.as_str()).collect::<Vec<_>>());
    assert!(kinds.contains(&"obstacle_appeared"), "{kinds:?}");
}

#[test]
fn csv_and_parquet_tables_hold_what_the_log_reader_reads() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    run_ok(
        &scenario("bicycle_obstacle_gamma_m.toml"),
        &log,
        &["--set", "duration=6.0"],
    );
    let mut logged = Logged::default();
    read_run_file(&log, &mut logged).unwrap();

    for format in ["csv", "parquet"] {
        let out = dir.path().join(format);
        let o = mjsafe(&[
            "export",
            log.to_str().unwrap(),
            "--format",
            format,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        // One line per table, with its row count.
        assert!(
            stdout(&o).contains(&format!("/state: {} rows", logged.states.len())),
            "{}",
            stdout(&o)
        );
        let files = listing(&out);
        for table in [
            "state",
            "command_issued",
            "command_applied",
            "barrier",
            "filter",
            "event",
            "prediction",
        ] {
            assert!(files.contains(&format!("run-{table}.{format}")), "{files:?}");
        }
        // No sensor, no actuator dynamics: no tables for the optional topics, no leftovers.
        assert_eq!(files.len(), 7, "{files:?}");
        check_tables(&load_with_pandas(&out, "run"), &logged);
    }

    // A log path: load_log.py exports it itself.
    let o = Command::new(python())
        .arg(root().join("examples/python/load_log.py"))
        .arg(&log)
        .env("MJSAFE", env!("CARGO_BIN_EXE_mjsafe"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    assert!(
        text.contains(&format!(
            "/state: {} rows, columns ['step', 'x1', 'x2', 'heading', 'speed']",
            logged.states.len()
        )),
        "{text}"
    );
}

#[test]
fn topics_select_tables_and_the_optional_topics_are_exported() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("obs.mcap");
    run_ok(
        &scenario("bicycle_obstacle_gamma_m.toml"),
        &log,
        &[
            "--set",
            "duration=1.0",
            "--set",
            "sensing={noise_std=[0.1, 0.1, 0.01, 0.1]}",
            "--set",
            "actuator_dynamics.steering={rate_limit=2.0}",
        ],
    );
    let o = mjsafe(&[
        "export",
        log.to_str().unwrap(),
        "--topics",
        "/state/measured,/command/actuated",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let files = listing(dir.path());
    assert_eq!(
        files,
        ["obs-command_actuated.csv", "obs-state_measured.csv", "obs.mcap"]
    );
    let measured = std::fs::read_to_string(dir.path().join("obs-state_measured.csv")).unwrap();
    assert!(measured.starts_with("time,step,x1,x2,heading,speed\n"), "{measured}");
    let actuated = std::fs::read_to_string(dir.path().join("obs-command_actuated.csv")).unwrap();
    assert!(
        actuated.starts_with("time,steering,steering.issued_at,acceleration,acceleration.issued_at\n"),
        "{actuated}"
    );
    // 1 s at 2 ms: 500 steps, one row each.
    assert_eq!(actuated.lines().count(), 1 + 500);

    // Moving obstacles: the /actors table and the actor columns of /prediction.
    let walker = dir.path().join("walker.mcap");
    run_ok(
        &root().join("tests/data/crossing_walker.toml"),
        &walker,
        &["--set", "duration=2.0"],
    );
    let o = mjsafe(&["export", walker.to_str().unwrap(), "--topics", "/actors,/prediction"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let actors = std::fs::read_to_string(dir.path().join("walker-actors.csv")).unwrap();
    assert!(
        actors.starts_with(
            "time,walker.x,walker.y,walker.vx,walker.vy,walker.ax,walker.ay,walker.heading,walker.absent\n"
        ),
        "{actors}"
    );
    let predictions = std::fs::read_to_string(dir.path().join("walker-prediction.csv")).unwrap();
    let header = predictions.lines().next().unwrap();
    assert!(
        header.ends_with(",walker.predicted_x,walker.predicted_y,walker.realized_x,walker.realized_y,walker.error"),
        "{header}"
    );

    let e = mjsafe(&["export", log.to_str().unwrap(), "--topics", "/scene"]);
    assert!(!e.status.success());
    assert!(
        stderr(&e).contains("/scene is a Foxglove view, not a table"),
        "{}",
        stderr(&e)
    );
}

#[test]
fn outputs_follow_the_file_rules() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    run_ok(&scenario("bicycle_obstacle.toml"), &log, &["--set", "duration=0.5"]);
    let path = |name: &str| dir.path().join(name);
    // A foreign file under a table's name is kept: one error line, nothing written.
    std::fs::write(path("run-state.csv"), "my notes\n").unwrap();
    let o = mjsafe(&["export", log.to_str().unwrap()]);
    assert!(!o.status.success());
    assert_eq!(stderr(&o).lines().count(), 1, "{}", stderr(&o));
    assert!(stderr(&o).contains("run-state.csv"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(path("run-state.csv")).unwrap(), "my notes\n");
    assert_eq!(listing(dir.path()), ["run-state.csv", "run.mcap"]);
    // A user's CSV that merely starts with `time,` is not this table: kept, and nothing written.
    std::fs::write(path("run-state.csv"), "time,speed\n0.0,1.0\n").unwrap();
    let o = mjsafe(&["export", log.to_str().unwrap(), "--topics", "/state,/barrier"]);
    assert!(!o.status.success());
    assert_eq!(stderr(&o).lines().count(), 1, "{}", stderr(&o));
    assert!(
        stderr(&o).contains("run-state.csv") && stderr(&o).contains("not this log's table"),
        "{}",
        stderr(&o)
    );
    assert_eq!(
        std::fs::read_to_string(path("run-state.csv")).unwrap(),
        "time,speed\n0.0,1.0\n"
    );
    assert_eq!(listing(dir.path()), ["run-state.csv", "run.mcap"]);
    // No topic named: an error, not an exit 0 that writes nothing.
    let o = mjsafe(&["export", log.to_str().unwrap(), "--topics", ""]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--topics: no topic named"), "{}", stderr(&o));
    // An earlier export is replaced (CSV: its header is this log's table's).
    std::fs::remove_file(path("run-state.csv")).unwrap();
    for _ in 0..2 {
        let o = mjsafe(&["export", log.to_str().unwrap(), "--topics", "/state"]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    std::fs::remove_file(path("run-state.csv")).unwrap();
    for _ in 0..2 {
        let o = mjsafe(&[
            "export",
            log.to_str().unwrap(),
            "--format",
            "parquet",
            "--topics",
            "/state",
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    assert_eq!(listing(dir.path()), ["run-state.parquet", "run.mcap"]);

    // A damaged log: an error naming it, and no table (no partial file either).
    let bytes = std::fs::read(&log).unwrap();
    let cut = path("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let out = path("cut-export");
    let o = mjsafe(&["export", cut.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("truncated or corrupt MCAP"), "{}", stderr(&o));
    assert!(!out.exists() || listing(&out).is_empty(), "{:?}", listing(&out));
}

/// Peak resident memory (kB) of `mjsafe export FILE --format parquet`, measured by GNU time.
fn export_peak_kb(file: &Path, out: &Path) -> u64 {
    let o = Command::new("/usr/bin/time")
        .args([
            "-f",
            "%M",
            env!("CARGO_BIN_EXE_mjsafe"),
            "export",
            "--format",
            "parquet",
            "--out",
        ])
        .arg(out)
        .arg(file)
        .output()
        .expect("GNU time (/usr/bin/time; scripts/setup.sh --test installs it)");
    assert!(o.status.success(), "{}", stderr(&o));
    stderr(&o).lines().last().unwrap().trim().parse().unwrap()
}

#[test]
fn export_memory_does_not_grow_with_log_length() {
    let dir = tempfile::tempdir().unwrap();
    let (short, long) = (dir.path().join("short.mcap"), dir.path().join("long.mcap"));
    let nodelay = scenario("bicycle_obstacle_nodelay.toml");
    run_ok(&nodelay, &short, &["--set", "duration=150.0"]);
    run_ok(&nodelay, &long, &["--set", "duration=600.0"]);
    let size = |p: &Path| std::fs::metadata(p).unwrap().len();
    let out = dir.path().join("tables");
    let (short_kb, long_kb) = (export_peak_kb(&short, &out), export_peak_kb(&long, &out));
    println!(
        "export --format parquet peak RSS: {short_kb} kB for {} kB of log, {long_kb} kB for {} kB of log",
        size(&short) / 1024,
        size(&long) / 1024
    );
    assert!(size(&long) > 3 * size(&short));
    // 75k vs 300k rows per table, both past the first row groups (16384 rows): the rows are
    // not held; what grows is only the footer metadata Parquet keeps per row group until the
    // file is closed (about 1.6 MB more from 300 s to 900 s, measured). Flat within 4 MB.
    assert!(long_kb < short_kb + 4096, "{short_kb} kB -> {long_kb} kB");
}

/// The tables of one name are one log's: two logs of one stem into one directory are refused
/// before anything is written, and so is an export beside a table of a topic the log lacks (a
/// CSV of another run's predictions would pass for this run's).
#[test]
fn the_tables_of_one_name_are_one_logs() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    let (with_predictions, without) = (a.join("run.mcap"), b.join("run.mcap"));
    run_ok(
        &scenario("bicycle_obstacle_gamma_m.toml"),
        &with_predictions,
        &["--set", "duration=4.0"],
    );
    run_ok(&scenario("bicycle_obstacle.toml"), &without, &["--set", "duration=1.0"]);
    let out = dir.path().join("tables");
    let o = mjsafe(&[
        "export",
        with_predictions.to_str().unwrap(),
        without.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(stderr(&o).contains("both would write run-*.csv"), "{}", stderr(&o));
    assert!(!out.exists(), "nothing written");

    // The γm run's tables, then the other run's under the same name: its export is refused
    // (the γm run's prediction table would pass for its own), and nothing of it is written.
    let export = |log: &Path| mjsafe(&["export", log.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(export(&with_predictions).status.success());
    let before = std::fs::read(out.join("run-state.csv")).unwrap();
    let o = export(&without);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        stderr(&o).contains("run-prediction.csv") && stderr(&o).contains("has no /prediction messages"),
        "{}",
        stderr(&o)
    );
    assert_eq!(
        std::fs::read(out.join("run-state.csv")).unwrap(),
        before,
        "the earlier tables are kept"
    );
    assert!(
        listing(&out).iter().all(|f| !f.contains("partial")),
        "{:?}",
        listing(&out)
    );
    // A log not yet renamed (`run.mcap.partial`) has the tables of `run.mcap`: the same names.
    let partial = dir.path().join("run.mcap.partial");
    std::fs::copy(&without, &partial).unwrap();
    let o = mjsafe(&[
        "export",
        without.to_str().unwrap(),
        partial.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(stderr(&o).contains("both would write run-*.csv"), "{}", stderr(&o));
}

/// A run that did not complete exports what its log holds, with a note saying so; a log still
/// being written (`NAME.mcap.partial`) has the tables of `NAME.mcap`.
#[test]
fn incomplete_runs_and_partial_logs_are_named_as_such() {
    let dir = tempfile::tempdir().unwrap();
    let blowup = write(dir.path(), "blowup.toml", &blowup_scenario());
    let log = dir.path().join("blowup.mcap");
    let o = mjsafe(&["run", blowup.to_str().unwrap(), "--out", log.to_str().unwrap()]);
    assert!(!o.status.success() && log.exists(), "{}", text(&o));
    let o = mjsafe(&["export", log.to_str().unwrap(), "--topics", "/state"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("the run did not complete"), "{}", stderr(&o));

    let complete = dir.path().join("run.mcap");
    run_ok(
        &scenario("bicycle_obstacle.toml"),
        &complete,
        &["--set", "duration=0.5"],
    );
    let partial = dir.path().join("copy.mcap.partial");
    std::fs::copy(&complete, &partial).unwrap();
    let o = mjsafe(&["export", partial.to_str().unwrap(), "--topics", "/state"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("did not complete"), "{}", stderr(&o));
    assert!(dir.path().join("copy-state.csv").exists(), "{:?}", listing(dir.path()));
}

#[test]
fn tables_kept_in_memory_are_the_tables_read_from_the_log() {
    use mjsafe::export::{read_tables, table_topics, TableSink};
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("mem.mcap");
    // Predictions, a sensor and actuator dynamics: every table topic has rows.
    let loaded = mjsafe::embed::load_scenario(
        &scenario("bicycle_obstacle_gamma_m.toml"),
        &[
            "duration=3.0".to_string(),
            "sensing={noise_std=[0.1, 0.1, 0.01, 0.1]}".to_string(),
            "actuator_dynamics.steering={rate_limit=2.0}".to_string(),
        ],
    )
    .unwrap();
    let mut sink = TableSink::new("mem.mcap");
    mjsafe::embed::run_logged(&loaded, &log, &mut [&mut sink]).unwrap();
    let kept = sink.tables();
    let read = read_tables(&log, &table_topics()).unwrap();
    assert!(kept.complete && read.complete);
    assert_eq!(
        kept.tables.keys().map(|t| t.name()).collect::<Vec<_>>(),
        [
            "/state",
            "/command/issued",
            "/command/applied",
            "/barrier",
            "/filter",
            "/event",
            "/prediction",
            "/state/measured",
            "/command/actuated"
        ]
    );
    assert!(kept.tables.values().all(|t| t.rows() > 0));
    // Bit for bit (NaN included): the same values, in the same columns.
    use mjsafe::export::Values;
    let bits = |v: &Values| match v {
        Values::F64(x) => format!("{:?}", x.iter().map(|x| x.to_bits()).collect::<Vec<_>>()),
        other => format!("{other:?}"),
    };
    for (topic, table) in &kept.tables {
        let other = &read.tables[topic];
        assert_eq!(table.rows(), other.rows(), "{topic}");
        let names = |t: &mjsafe::export::MemoryTable| t.columns.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
        assert_eq!(names(table), names(other), "{topic}");
        for ((name, a), (_, b)) in table.columns.iter().zip(&other.columns) {
            assert_eq!(bits(a), bits(b), "{topic} {name}");
        }
    }
}
