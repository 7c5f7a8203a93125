//! Every declared metric (`mjsafe::metrics::builtin::METRICS`) reaches every output: the JSON
//! of `analyze` with its unit, the CSV columns, `--compare` with its unit, the aligned table
//! (those declared for it, header with the unit), and docs/metrics.md, whose table is the
//! generated one. A metric added to the declarations and missing from any of them fails here.

mod common;

use common::{mjsafe, root, run_ok, stdout};
use mjsafe::metrics::builtin::METRICS;
use mjsafe::metrics::Shape;

/// Logs that between them have every metric: predictions, obstacles and a planar vehicle
/// ((4.67) on the bicycle), a prescribed time (the red light, Ch. 5), a collision ((4.9)
/// with delays), a stall ((4.9) without delays).
fn logs(dir: &std::path::Path) -> [String; 4] {
    [
        "bicycle_obstacle_gamma_m",
        "red_light",
        "bicycle_obstacle",
        "bicycle_obstacle_nodelay",
    ]
    .map(|name| {
        let log = dir.join(format!("{name}.mcap"));
        run_ok(&root().join(format!("scenarios/{name}.toml")), &log, &[]);
        log.to_str().unwrap().to_string()
    })
}

/// The flat columns a metric declares (a per-channel or per-index group as `<base>.`).
fn declared_columns() -> Vec<(String, &'static str)> {
    let mut columns = Vec::new();
    for m in METRICS {
        let keyed = matches!(m.shape, Shape::PerChannel | Shape::PerBarrier | Shape::Prediction);
        if m.parts.is_empty() {
            columns.push((
                if keyed {
                    format!("{}.", m.name)
                } else {
                    m.name.to_string()
                },
                m.unit,
            ));
        }
        for p in m.parts.iter().filter(|p| !p.column.is_empty()) {
            let keyed = keyed || p.key == "state_residuals";
            columns.push((
                if keyed {
                    format!("{}.", p.column)
                } else {
                    p.column.to_string()
                },
                p.unit,
            ));
        }
    }
    columns
}

#[test]
fn every_declared_metric_reaches_json_csv_compare_table_and_docs() {
    let dir = tempfile::tempdir().unwrap();
    let [a, b, c, d] = logs(dir.path());

    // JSON: every metric under its name, every part's unit under its path.
    for log in [&a, &b, &c, &d] {
        let m = common::analyze_json(std::path::Path::new(log));
        for metric in METRICS {
            assert!(
                m.get(metric.name).is_some(),
                "{} missing from the JSON of {log}",
                metric.name
            );
            let paths: Vec<String> = if metric.parts.is_empty() {
                vec![metric.name.to_string()]
            } else {
                metric
                    .parts
                    .iter()
                    .map(|p| format!("{}.{}", metric.name, p.key))
                    .collect()
            };
            for path in paths {
                assert!(m["units"][&path].is_string(), "no unit for {path}: {}", m["units"]);
            }
        }
    }
    // The runs have values for every metric between them (none is always null).
    let runs = [&a, &b, &c, &d].map(|log| common::analyze_json(std::path::Path::new(log)));
    for metric in METRICS {
        assert!(
            runs.iter().any(|m| !m[metric.name].is_null()),
            "{} is null in every run",
            metric.name
        );
    }

    // CSV: a column (or a group of channel columns) per metric and part.
    let o = mjsafe(&["analyze", "--csv", &a, &b, &c]);
    assert!(o.status.success());
    let csv = stdout(&o);
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let covered = |column: &str, names: &[&str]| {
        names
            .iter()
            .any(|h| *h == column || (column.ends_with('.') && h.starts_with(column)))
    };
    for (column, _) in declared_columns() {
        assert!(
            covered(&column, &header),
            "column {column} missing from analyze --csv: {header:?}"
        );
    }

    // --compare: every column with its declared unit.
    let o = mjsafe(&["analyze", "--compare", "--json", &a, &b]);
    assert!(o.status.success());
    let compare: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let rows = compare["metrics"].as_array().unwrap();
    for (column, unit) in declared_columns() {
        let row = rows
            .iter()
            .find(|r| {
                let name = r["metric"].as_str().unwrap();
                name == column || (column.ends_with('.') && name.starts_with(&column))
            })
            .unwrap_or_else(|| panic!("{column} missing from --compare"));
        assert_eq!(row["unit"], unit, "{column}");
    }

    // The aligned table: the metrics declared for it, each header with its unit.
    let o = mjsafe(&["analyze", &a, &b]);
    let table = stdout(&o);
    let header = table.lines().next().unwrap();
    for metric in METRICS {
        if let Some(name) = metric.table {
            let with_unit = format!("{name} [{}]", metric.unit);
            assert!(
                header.contains(&with_unit) || header.contains(name),
                "{name} missing: {header}"
            );
            if !matches!(metric.unit, "steps" | "ticks") {
                assert!(header.contains(&with_unit), "{with_unit} missing: {header}");
            }
        }
    }

    // docs/metrics.md holds the generated table, and so a row per metric.
    let docs = std::fs::read_to_string(root().join("docs/metrics.md")).unwrap();
    let o = mjsafe(&["metrics", "--markdown"]);
    assert!(o.status.success());
    let generated = stdout(&o);
    assert!(
        docs.contains(&generated),
        "docs/metrics.md is stale: regenerate its table with `mjsafe metrics --markdown`"
    );
    for metric in METRICS {
        assert!(
            generated.contains(&format!("`{}", metric.name)),
            "{} not in the table",
            metric.name
        );
    }
}

#[test]
fn max_input_rate_is_per_channel_and_agrees_with_the_issued_commands() {
    // An independent computation from the log: the largest |Δu|/Δt of each channel.
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    run_ok(&root().join("scenarios/bicycle_obstacle_gamma_m.toml"), &log, &[]);
    let issued = common::read_topic::<mjsafe::log::proto::IssuedCommand>(&log, "/command/issued");
    let mut expected = std::collections::BTreeMap::<String, f64>::new();
    for pair in issued.windows(2) {
        let dt = pair[1].time - pair[0].time;
        if dt <= 0.0 {
            continue;
        }
        for (i, channel) in pair[1].channels.iter().enumerate() {
            let rate = ((pair[1].filtered[i] - pair[0].filtered[i]) / dt).abs();
            let entry = expected.entry(channel.clone()).or_insert(0.0);
            *entry = entry.max(rate);
        }
    }
    let m = common::analyze_json(&log);
    assert_eq!(m["units"]["max_input_rate"], "u-units/s");
    let rates = m["max_input_rate"].as_object().unwrap();
    assert_eq!(rates.len(), 2);
    for (channel, value) in &expected {
        let got = rates[channel].as_f64().unwrap();
        assert!(
            (got - value).abs() <= 1e-12 * value.max(1.0),
            "{channel}: {got} vs {value}"
        );
    }
}

#[test]
fn a_run_held_still_by_its_filter_is_a_stall_and_one_that_passes_is_not() {
    use mjsafe::log::proto;
    let dir = tempfile::tempdir().unwrap();
    // Without delays the CBF-QP stops head-on in front of the obstacle; (4.67) passes it.
    let stalled = dir.path().join("nodelay.mcap");
    run_ok(&root().join("scenarios/bicycle_obstacle_nodelay.toml"), &stalled, &[]);
    let passing = dir.path().join("gamma_m.mcap");
    run_ok(&root().join("scenarios/bicycle_obstacle_gamma_m.toml"), &passing, &[]);

    let m = common::analyze_json(&stalled);
    assert!(m["collision"].is_null(), "safe: {m}");
    let t = m["stall_time"].as_f64().expect("a stall");
    assert_eq!(m["units"]["stall_time"], "s");
    // Independently: the bicycle's own speed state (x4) stays below 0.05 m/s over the next
    // second, the filter overrides the nominal throughout, and the car never passes x1 = 0
    // (the obstacle's centre).
    let states = common::read_topic::<proto::State>(&stalled, "/state");
    let window: Vec<&proto::State> = states.iter().filter(|s| s.time >= t && s.time <= t + 1.0).collect();
    assert!(window.len() > 100);
    assert!(window.iter().all(|s| s.values[3].abs() < 0.05), "stopped from {t} s");
    let filters = common::read_topic::<proto::Filter>(&stalled, "/filter");
    assert!(filters
        .iter()
        .filter(|f| f.time >= t && f.time < t + 1.0)
        .all(|f| f.active));
    assert!(states.iter().all(|s| s.values[0] < 0.0), "never passes the obstacle");

    // `mjsafe run` says so next to "no collision".
    let line = run_ok(
        &root().join("scenarios/bicycle_obstacle_nodelay.toml"),
        &dir.path().join("again.mcap"),
        &[],
    );
    assert!(line.contains("no collision, but STALLED from t = "), "{line}");

    let m = common::analyze_json(&passing);
    assert!(m["stall_time"].is_null(), "{m}");
    let last = common::read_topic::<proto::State>(&passing, "/state").pop().unwrap();
    assert!(last.values[0] > 5.0, "passes the obstacle: x1 = {}", last.values[0]);
}

#[test]
fn barrier_minima_are_per_barrier_and_agree_with_the_log() {
    use mjsafe::log::proto;
    // Two obstacles: the minima of each, from `/barrier` read directly.
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("two.mcap");
    run_ok(&root().join("scenarios/bicycle_two_obstacles.toml"), &log, &[]);
    let mut h = std::collections::BTreeMap::<String, f64>::new();
    let mut clearance = std::collections::BTreeMap::<String, f64>::new();
    for m in common::read_topic::<proto::Barrier>(&log, "/barrier") {
        for b in m.barriers {
            let e = h.entry(b.name.clone()).or_insert(f64::INFINITY);
            *e = e.min(b.h);
            if b.obstacle {
                let e = clearance.entry(b.name).or_insert(f64::INFINITY);
                *e = e.min(b.clearance);
            }
        }
    }
    assert_eq!(h.len(), 2);
    let m = common::analyze_json(&log);
    for (name, value) in &h {
        assert_eq!(m["min_h_by_barrier"][name].as_f64(), Some(*value), "{name}");
    }
    for (name, value) in &clearance {
        assert_eq!(m["min_clearance_by_obstacle"][name].as_f64(), Some(*value), "{name}");
    }
    assert_eq!(m["units"]["min_clearance_by_obstacle"], "m");
    // min_h is the smallest of them.
    assert_eq!(m["min_h"].as_f64(), h.values().copied().reduce(f64::min));
}
