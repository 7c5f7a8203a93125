//! The same log in other valid MCAP layouts (issue 21), written by Python's `mcap` Writer:
//! LZ4, uncompressed and zstd chunks of other sizes, and the run metadata after the messages,
//! read the same as the original by every reader (`analyze`, `info`, the rerun replay); a
//! topic-filtered copy gives the metrics that need the missing topic as absent, naming it.

mod common;
use common::*;

use std::path::{Path, PathBuf};

/// Re-writes `src` into `dst` (tests/rewrite_log.py); `drop`: topics or metadata records left out.
fn rewrite(src: &Path, dst: &Path, compression: &str, chunk_size: &str, metadata: &str, drop: &str) {
    rewrite_in_order(src, dst, (compression, chunk_size, metadata, drop), "file");
}

/// [`rewrite`] with the messages in `order` (tests/rewrite_log.py: `halves`, `by_topic`,
/// `reverse`, `halves-noindex`, or `file`).
fn rewrite_in_order(
    src: &Path,
    dst: &Path,
    (compression, chunk_size, metadata, drop): (&str, &str, &str, &str),
    order: &str,
) {
    let o = std::process::Command::new(python())
        .arg(root().join("tests/rewrite_log.py"))
        .args([src, dst])
        .args([compression, chunk_size, metadata, drop, order])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "rewrite failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// `analyze --json` of a log without the field naming the file.
fn metrics(file: &Path) -> serde_json::Value {
    let mut m = analyze_json(file);
    m.as_object_mut().unwrap().remove("file");
    m
}

/// `info --json` without what depends on the layout (file name and size, chunk count, channel
/// ids): the messages, their times, and per topic the schema, encodings and message count.
fn info(file: &Path) -> serde_json::Value {
    let o = mjsafe(&["info", "--json", file.to_str().unwrap()]);
    assert!(o.status.success(), "info {}: {}", file.display(), stderr(&o));
    let mut info: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let info = info.as_object_mut().unwrap();
    for key in ["file", "bytes", "chunks"] {
        info.remove(key);
    }
    let mut channels: Vec<serde_json::Value> = info["channels"].as_array().unwrap().clone();
    for c in &mut channels {
        c.as_object_mut().unwrap().remove("id");
    }
    channels.sort_by_key(|c| c["topic"].as_str().unwrap().to_string());
    info.insert("channels".into(), channels.into());
    serde_json::Value::Object(info.clone())
}

/// The layouts a copy is written in: compression, chunk size, where the metadata goes.
const LAYOUTS: [(&str, &str, &str); 8] = [
    ("lz4", "1048576", "first"),
    ("none", "65536", "first"),
    ("zstd", "4096", "first"),
    ("lz4", "300000", "first"),
    ("lz4", "1048576", "last"),
    ("none", "65536", "last"),
    ("zstd", "4096", "last"),
    ("lz4", "300000", "last"),
];

/// A run of `scenario` (scenarios/NAME.toml, with `sets`) logged as DIR/NAME/original/run.mcap.
fn original(dir: &Path, name: &str, sets: &[&str]) -> PathBuf {
    let out = dir.join(name).join("original");
    std::fs::create_dir_all(&out).unwrap();
    let log = out.join("run.mcap");
    let mut extra = Vec::new();
    for s in sets {
        extra.extend(["--set", s]);
    }
    run_ok(&scenario(&format!("{name}.toml")), &log, &extra);
    log
}

/// A copy of `log` in a directory of its own, under the same file name (so a replay of it has
/// the recording id of the original's).
fn copy_path(log: &Path, label: &str) -> PathBuf {
    let dir = log.parent().unwrap().parent().unwrap().join(label);
    std::fs::create_dir_all(&dir).unwrap();
    dir.join("run.mcap")
}

#[test]
fn every_layout_of_several_scenarios_reads_the_same() {
    let dir = tempfile::tempdir().unwrap();
    // A planar bicycle (jerk, override, intervention: the metrics issue 21 found wrong), a
    // prescribed-time run (the metrics at T) and a unicycle with a time-varying delay.
    for (name, sets) in [
        ("bicycle_obstacle_gamma_m", &[][..]),
        ("red_light", &[][..]),
        ("unicycle_tv_delay", &["duration=4.0"][..]),
    ] {
        let log = original(dir.path(), name, sets);
        let (expected, expected_info) = (metrics(&log), info(&log));
        for (compression, chunk_size, metadata) in LAYOUTS {
            let layout = format!("{compression}-{chunk_size}-{metadata}");
            let copy = copy_path(&log, &layout);
            rewrite(&log, &copy, compression, chunk_size, metadata, "");
            assert_eq!(metrics(&copy), expected, "{name}: {layout}");
            assert_eq!(info(&copy), expected_info, "{name}: {layout}");
            println!("{name}, {layout}: same metrics and info");
        }
    }
    // A stream is read once: late metadata is an error there, never defaults.
    let late = copy_path(&dir.path().join("red_light/original/run.mcap"), "lz4-1048576-last");
    let o = std::process::Command::new("sh")
        .arg("-c")
        .arg(format!(
            "cat '{}' | '{}' analyze /dev/stdin",
            late.display(),
            env!("CARGO_BIN_EXE_mjsafe")
        ))
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", stdout(&o));
    assert!(stderr(&o).contains("comes after the messages"), "{}", stderr(&o));
}

/// The replay of a copy whose run metadata comes after the messages (and of other layouts)
/// gives the recording of the original log. (Recordings that hold NaN, e.g. an unused
/// constraint value, never compare equal in `rerun rrd compare`, not even with themselves:
/// the scenarios here log none.)
#[cfg(feature = "rerun")]
#[test]
fn the_replay_of_every_layout_is_the_recording_of_the_original() {
    let dir = tempfile::tempdir().unwrap();
    for (name, sets) in [
        ("bicycle_obstacle_gamma_m", &["duration=3.0"][..]),
        ("unicycle_tv_delay", &["duration=3.0"][..]),
    ] {
        let log = original(dir.path(), name, sets);
        let replay = |log: &Path| {
            let rrd = log.with_extension("rrd");
            let o = mjsafe(&["replay", log.to_str().unwrap(), "--rrd", rrd.to_str().unwrap()]);
            assert!(o.status.success(), "replay {}: {}", log.display(), text(&o));
            rrd
        };
        let expected = replay(&log);
        for (compression, chunk_size, metadata) in [LAYOUTS[4], LAYOUTS[2], LAYOUTS[7]] {
            let layout = format!("{compression}-{chunk_size}-{metadata}");
            let copy = copy_path(&log, &layout);
            rewrite(&log, &copy, compression, chunk_size, metadata, "");
            let replayed = replay(&copy);
            let o = rerun(&[
                "rrd",
                "compare",
                "--unordered",
                expected.to_str().unwrap(),
                replayed.to_str().unwrap(),
            ]);
            assert!(o.status.success(), "{name}, {layout}: recordings differ:\n{}", text(&o));
            println!("{name}, {layout}: same recording");
        }
    }
}

/// The tables `export` writes of `log` into `out`: file name → bytes.
fn exported(log: &Path, out: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    let o = mjsafe(&["export", log.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "export {}: {}", log.display(), stderr(&o));
    std::fs::read_dir(out)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect()
}

/// MCAP does not require messages in log-time order. A copy written out of it (halves swapped,
/// topic by topic, reversed, with and without an index or a summary) gives the original's
/// metrics, info and tables, its messages handed on in log-time order; a stream, read once, is an error saying
/// so, never metrics of the file order. (Reversed, the messages of one log time are reversed
/// too: the metrics are the same, and the tables list the two `/prediction` rows of a tick in
/// the other order, since messages of one log time keep their file order.)
#[test]
fn messages_out_of_log_time_order_read_as_the_original() {
    let dir = tempfile::tempdir().unwrap();
    for (name, sets) in [("bicycle_obstacle_gamma_m", &[][..]), ("bicycle_obstacle", &[][..])] {
        let log = original(dir.path(), name, sets);
        let (expected, expected_info) = (metrics(&log), info(&log));
        let tables = exported(&log, &dir.path().join(name).join("tables-original"));
        for order in [
            "halves",
            "by_topic",
            "reverse",
            "halves-noindex",
            "halves-nosummary",
            "file-nosummary",
        ] {
            let copy = copy_path(&log, order);
            rewrite_in_order(&log, &copy, ("zstd", "65536", "first", ""), order);
            assert_eq!(metrics(&copy), expected, "{name}: {order}");
            // Without a statistics record `info` counts the messages.
            assert_eq!(info(&copy), expected_info, "{name}: {order}");
            let copy_tables = exported(&copy, &dir.path().join(name).join(format!("tables-{order}")));
            if order != "reverse" {
                assert!(copy_tables == tables, "{name}: {order}: the exported tables differ");
            }
            println!("{name}, {order}: same metrics and tables");
        }
        let o = std::process::Command::new("sh")
            .arg("-c")
            .arg(format!(
                "cat '{}' | '{}' analyze /dev/stdin",
                copy_path(&log, "halves").display(),
                env!("CARGO_BIN_EXE_mjsafe")
            ))
            .output()
            .unwrap();
        assert!(!o.status.success(), "{}", stdout(&o));
        assert!(stderr(&o).contains("not in log-time order"), "{}", stderr(&o));
        assert!(stderr(&o).contains("a stream is read once"), "{}", stderr(&o));
    }
}

#[test]
fn a_topic_filtered_copy_names_what_is_missing_and_computes_nothing_from_defaults() {
    let dir = tempfile::tempdir().unwrap();
    let log = original(dir.path(), "bicycle_obstacle_gamma_m", &[]);
    let expected = metrics(&log);
    let filtered = |drop: &str| {
        let copy = copy_path(&log, &format!("without{}", drop.replace(['/', ','], "_")));
        rewrite(&log, &copy, "zstd", "1048576", "last", drop);
        copy
    };
    // Each dropped topic: the metrics that need it are null and named with the topic; every
    // other metric is that of the original.
    for (drop, absent) in [
        (
            "/barrier",
            &[
                "min_h",
                "min_h_by_barrier",
                "time_h_negative",
                "min_clearance",
                "min_clearance_by_obstacle",
                "min_time_to_collision",
                "min_ttc_by_barrier",
                "delay_attributed_violation_time",
            ][..],
        ),
        (
            "/filter",
            &[
                "filter_active_fraction",
                "filter_infeasible_ticks",
                "filter_unmet_ticks",
                "max_shortfall_by_barrier",
                "max_correction",
                "first_override_time",
                "override_duration",
                "intervention_integral",
                "max_input_rate_overriding",
                "stall_time",
            ][..],
        ),
        ("/command/issued", &["max_input_rate", "max_input_rate_overriding"][..]),
        (
            "/event",
            &[
                "collision",
                "error",
                "delay_attributed_violation_time",
                "impact_speed_by_actor",
                "speed_reduction",
                "vehicle_stopped",
            ][..],
        ),
        ("/prediction", &["max_actor_prediction_error", "prediction"][..]),
        ("/command/applied", &["max_applied_input"][..]),
    ] {
        let copy = filtered(drop);
        let m = metrics(&copy);
        let missing = m.get("missing").cloned().unwrap_or_default();
        let named: Vec<&String> = missing.as_object().map_or(Vec::new(), |o| o.keys().collect());
        let mut absent_sorted: Vec<&str> = absent.to_vec();
        absent_sorted.sort();
        assert_eq!(named, absent_sorted, "without {drop}: {missing}");
        for metric in absent {
            assert!(m[metric].is_null(), "without {drop}: {metric} = {}", m[metric]);
            let why = missing[metric].as_str().unwrap();
            assert!(why.contains(&format!("no {drop} topic")), "{metric}: {why}");
        }
        for (key, value) in expected.as_object().unwrap() {
            if !absent.contains(&key.as_str()) {
                assert_eq!(&m[key], value, "without {drop}: {key}");
            }
        }
        // The table names them on stderr.
        let o = mjsafe(&["analyze", copy.to_str().unwrap()]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert_eq!(
            stderr(&o).contains("metrics absent"),
            !absent.is_empty(),
            "{}",
            stderr(&o)
        );
        // So does a comparison with the original: the reasons, not a bare `-`.
        let o = mjsafe(&["analyze", "--compare", log.to_str().unwrap(), copy.to_str().unwrap()]);
        assert_eq!(
            stderr(&o).contains("warning: B") && stderr(&o).contains("metrics absent"),
            !absent.is_empty(),
            "{}",
            stderr(&o)
        );
        let o = mjsafe(&[
            "analyze",
            "--compare",
            "--json",
            log.to_str().unwrap(),
            copy.to_str().unwrap(),
        ]);
        let compared: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
        assert_eq!(compared["missing_b"].is_object(), !absent.is_empty(), "{compared}");
        assert!(compared["missing_a"].is_null(), "{compared}");
        println!("without {drop}: {missing}");
    }
    // Without the status record: not known to be complete, and said so.
    let m = metrics(&filtered("mjsafe_status"));
    assert_eq!(m["complete"], false);
    assert!(
        m["missing"]["complete"].as_str().unwrap().contains("mjsafe_status"),
        "{m}"
    );
    // Without the run metadata: an error naming it, from every reader.
    let copy = filtered("mjsafe");
    let o = mjsafe(&["analyze", "--json", copy.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("no mjsafe metadata record"), "{}", stderr(&o));
    let png = dir.path().join("plots");
    let o = mjsafe(&["analyze", "--plot", png.to_str().unwrap(), copy.to_str().unwrap()]);
    assert!(!o.status.success());
    #[cfg(feature = "rerun")]
    {
        let rrd = copy.with_extension("rrd");
        let o = mjsafe(&["replay", copy.to_str().unwrap(), "--rrd", rrd.to_str().unwrap()]);
        assert!(!o.status.success());
        assert!(stderr(&o).contains("no mjsafe metadata record"), "{}", stderr(&o));
        assert!(!rrd.exists());
    }
}

/// A copy that leaves out the empty `/prediction` channel (as a writer that registers a channel
/// with its first message does) of a run that made no predictions lacks nothing: its metrics
/// are the original's. A run that predicted still names the topic as missing.
#[test]
fn a_copy_without_the_empty_prediction_channel_of_a_run_without_predictions_lacks_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let log = original(dir.path(), "bicycle_obstacle", &["duration=1.0"]);
    let copy = copy_path(&log, "no-prediction");
    rewrite(&log, &copy, "zstd", "1048576", "first", "/prediction");
    let m = metrics(&copy);
    assert!(m["missing"].get("prediction").is_none(), "{m}");
    assert_eq!(m, metrics(&log));

    let predicted = original(dir.path(), "bicycle_obstacle_gamma_m", &["duration=1.0"]);
    let copy = copy_path(&predicted, "no-prediction");
    rewrite(&predicted, &copy, "zstd", "1048576", "first", "/prediction");
    let m = metrics(&copy);
    assert_eq!(m["missing"]["prediction"], "no /prediction topic in the log", "{m}");
}
