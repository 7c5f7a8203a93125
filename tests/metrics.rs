//! Every declared metric (`mjsafe::metrics::builtin::METRICS`) reaches every output: the JSON
//! of `analyze` with its unit, the CSV columns, `--compare` with its unit, the aligned table
//! (those declared for it, header with the unit), and docs/metrics.md, whose table is the
//! generated one. A metric added to the declarations and missing from any of them fails here.

mod common;

use common::{mjsafe, root, run_ok, stdout};
use mjsafe::log::Record;
use mjsafe::metrics::builtin::METRICS;
use mjsafe::metrics::Shape;

/// Logs that between them have every metric: predictions, obstacles and a planar vehicle
/// ((4.67) on the bicycle), a prescribed time (the red light, Ch. 5), a collision ((4.9)
/// with delays; with declared `[vehicle_limits]`), a stall ((4.9) without delays), a collision
/// with a moving obstacle (a walker the controller assumes static).
fn logs(dir: &std::path::Path) -> [String; 5] {
    let runs: [(&str, &str, &[&str]); 5] = [
        // A requirement (docs/requirements.md) met: the `req` metric.
        (
            "scenarios",
            "bicycle_obstacle_gamma_m",
            &["--require", "clear=always obstacle_0.h >= 0"],
        ),
        ("scenarios", "red_light", &[]),
        // It collides: the requirement is violated (`req_violated_at`). Declared limits:
        // `vehicle_limit_ratio`.
        (
            "scenarios",
            "bicycle_obstacle",
            &[
                "--require",
                "clear=always obstacle_0.h >= 0",
                "--set",
                "vehicle_limits={steering=1.8,acceleration=11.5}",
            ],
        ),
        ("scenarios", "bicycle_obstacle_nodelay", &[]),
        ("tests/data", "crossing_walker", STATIC_WALKER),
    ];
    runs.map(|(folder, name, args)| {
        let log = dir.join(format!("{name}.mcap"));
        run_ok(&root().join(format!("{folder}/{name}.toml")), &log, args);
        log.to_str().unwrap().to_string()
    })
}

/// The crossing walker assumed static over the delays: the vehicle hits it.
const STATIC_WALKER: &[&str] = &["--set", "actor_knowledge.kind=\"static\""];

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
    let [a, b, c, d, e] = logs(dir.path());

    // JSON: every metric under its name, every part's unit under its path.
    for log in [&a, &b, &c, &d, &e] {
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
    // The runs have values for every metric between them (none is always null), with CCRm for
    // the headway metrics (a lead ahead in the path).
    let ccrm = dir.path().join("ncap_ccrm.mcap");
    run_ok(&root().join("scenarios/ncap_ccrm.toml"), &ccrm, &[]);
    let ccrm = ccrm.to_str().unwrap().to_string();
    let runs = [&a, &b, &c, &d, &e, &ccrm].map(|log| common::analyze_json(std::path::Path::new(log)));
    for metric in METRICS {
        assert!(
            runs.iter().any(|m| !m[metric.name].is_null()),
            "{} is null in every run",
            metric.name
        );
    }

    // CSV: a column (or a group of channel columns) per metric and part.
    let o = mjsafe(&["analyze", "--csv", &a, &b, &c, &e]);
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
    // (Two logs per comparison: the prescribed-time run, the violated requirement's, then the
    // moving obstacle's.)
    let mut rows = Vec::new();
    for other in [&b, &c, &e] {
        let o = mjsafe(&["analyze", "--compare", "--json", &a, other]);
        assert!(o.status.success());
        let compare: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
        rows.extend(compare["metrics"].as_array().unwrap().iter().cloned());
    }
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

/// The largest |u| that reached each channel's actuator, against the Python `mcap` reader's
/// decoding of every `/command/applied` (tests/read_log.py): on US101-5 under (4.67), a steering
/// tan δ far past what CommonRoad's vehicle 2 can steer (tan 1.066 = 1.8098) and an acceleration past its
/// 11.5 m/s².
#[test]
fn max_applied_input_agrees_with_an_independent_reader_of_the_applied_commands() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    run_ok(&root().join("data/commonroad/USA_US101-5_1_T-1.xml"), &log, &[]);
    let script = "import sys, json\n\
                  from mcap.reader import make_reader\n\
                  from mcap_protobuf.decoder import DecoderFactory\n\
                  f = open(sys.argv[1], 'rb')\n\
                  reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])\n\
                  channels, largest, count = None, None, 0\n\
                  for _, channel, _, m in reader.iter_decoded_messages(topics=['/command/issued', '/command/applied']):\n\
                  \x20   if channel.topic == '/command/issued' and channels is None: channels = list(m.channels)\n\
                  \x20   if channel.topic == '/command/applied':\n\
                  \x20       count += 1\n\
                  \x20       values = [abs(v) for v in m.values]\n\
                  \x20       largest = values if largest is None else [max(a, b) for a, b in zip(largest, values)]\n\
                  print(json.dumps([channels, largest, count]))";
    let o = std::process::Command::new(common::python())
        .args(["-c", script])
        .arg(&log)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (channels, expected, count): (Vec<String>, Vec<f64>, usize) = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(count, 1000);
    let m = common::analyze_json(&log);
    assert_eq!(m["units"]["max_applied_input"], "u-units");
    let got = m["max_applied_input"].as_object().unwrap();
    assert_eq!(got.len(), channels.len());
    for (channel, value) in channels.iter().zip(&expected) {
        assert_eq!(got[channel].as_f64().unwrap(), *value, "{channel}");
    }
    let at = |channel: &str| expected[channels.iter().position(|c| c == channel).unwrap()];
    assert!(
        at("steering") > 1.066f64.tan() && at("acceleration") > 11.5,
        "{expected:?}"
    );
    // The world declares vehicle 2's limits: the ratio is the reader's largest |u| over them.
    assert_eq!(m["units"]["vehicle_limit_ratio"], "1");
    let ratio = |channel: &str| m["vehicle_limit_ratio"][channel].as_f64().unwrap();
    assert_eq!(ratio("steering"), at("steering") / 1.066f64.tan());
    assert_eq!(ratio("acceleration"), at("acceleration") / 11.5);
}

/// `vehicle_limit_ratio` is there only for a run whose scenario declares `[vehicle_limits]`, and
/// only for the channels it declares; a limit that is not a positive number, or names no input
/// channel, is refused with the key.
#[test]
fn vehicle_limits_are_declared_per_channel_and_checked() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = root().join("scenarios/bicycle_obstacle_gamma_m.toml");
    let plain = dir.path().join("plain.mcap");
    run_ok(&scenario, &plain, &["--set", "duration=1.0"]);
    let m = common::analyze_json(&plain);
    assert!(m["vehicle_limit_ratio"].is_null(), "{m}");
    let declared = dir.path().join("declared.mcap");
    run_ok(
        &scenario,
        &declared,
        &["--set", "duration=1.0", "--set", "vehicle_limits.steering=0.5"],
    );
    let m = common::analyze_json(&declared);
    let ratios = m["vehicle_limit_ratio"].as_object().unwrap();
    assert_eq!(ratios.keys().collect::<Vec<_>>(), ["steering"], "{m}");
    let largest = m["max_applied_input"]["steering"].as_f64().unwrap();
    assert_eq!(ratios["steering"].as_f64().unwrap(), largest / 0.5);
    for (set, expected) in [
        (
            "vehicle_limits.steering=0.0",
            "key `vehicle_limits.steering`: expected the largest |u|",
        ),
        (
            "vehicle_limits.steering=nan",
            "key `vehicle_limits.steering`: expected the largest |u|",
        ),
        (
            "vehicle_limits.brake=1.0",
            "key `vehicle_limits.brake`: unknown input channel",
        ),
    ] {
        let out = dir.path().join("refused.mcap");
        let o = common::mjsafe(&[
            "run",
            scenario.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--set",
            set,
        ]);
        let err = common::stderr(&o);
        assert!(
            !o.status.success() && err.contains(expected) && err.lines().count() == 1,
            "{set}: {err}"
        );
        assert!(!out.exists(), "{set}");
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

/// The per-actor metrics, computed here from the raw `/state`, `/actors`, `/event` and
/// `/prediction` messages: a walker the controller assumes static (a collision) and one it
/// assumes at constant velocity (none).
#[test]
fn per_actor_metrics_agree_with_the_raw_messages() {
    use mjsafe::log::proto;
    let dir = tempfile::tempdir().unwrap();
    let scenario = root().join("tests/data/crossing_walker.toml");
    for (name, args, collides) in [("static", STATIC_WALKER, true), ("cv", &[][..], false)] {
        let log = dir.path().join(format!("{name}.mcap"));
        run_ok(&scenario, &log, args);
        let m = common::analyze_json(&log);
        let states = common::read_topic::<proto::State>(&log, "/state");
        let actors = common::read_topic::<proto::Actors>(&log, "/actors");
        let events = common::read_topic::<proto::Event>(&log, "/event");
        let predictions = common::read_topic::<proto::Prediction>(&log, "/prediction");
        assert_eq!(actors.len(), states.len(), "one /actors per step");
        let walker = |a: &proto::Actors| {
            a.actors
                .iter()
                .find(|v| v.name == "walker")
                .map(|v| (v.x, v.y))
                .unwrap()
        };
        // Backward differences of the logged positions (over the step that ends at state k ≥ 1).
        let velocity = |k: usize| {
            let dt = states[k].time - states[k - 1].time;
            let (p, q) = (&states[k - 1].values, &states[k].values);
            ((q[0] - p[0]) / dt, (q[1] - p[1]) / dt)
        };
        let speed = |k: usize| velocity(k).0.hypot(velocity(k).1);
        let collision = events.iter().find(|e| e.kind == "collision_start").map(|e| e.time);
        assert_eq!(collision.is_some(), collides, "{name}: {collision:?}");
        let k_c = collision.map(|t| states.iter().position(|s| (s.time - t).abs() < 1e-9).unwrap());
        let last = k_c.unwrap_or(states.len() - 1);
        let min_speed = (1..=last).map(speed).fold(f64::INFINITY, f64::min);
        let reduction = speed(1) - k_c.map_or(min_speed, speed);
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * b.abs().max(1.0);
        assert!(close(m["speed_reduction"].as_f64().unwrap(), reduction), "{name}: {m}");
        assert_eq!(
            m["vehicle_stopped"].as_u64(),
            Some(u64::from(min_speed < 0.05)),
            "{name}"
        );
        match k_c {
            Some(k) => {
                let (o0, o1) = (walker(&actors[k - 1]), walker(&actors[k]));
                let dt = actors[k].time - actors[k - 1].time;
                let (vx, vy) = velocity(k);
                let relative = (vx - (o1.0 - o0.0) / dt).hypot(vy - (o1.1 - o0.1) / dt);
                let logged = m["impact_speed_by_actor"]["walker"].as_f64().unwrap();
                assert!(close(logged, relative), "{name}: {logged} vs {relative}");
                assert!(relative > 0.5, "a real impact: {relative} m/s");
            }
            None => {
                assert!(m["impact_speed_by_actor"].is_null(), "{m}");
                assert_eq!(m["missing"]["impact_speed_by_actor"], "no collision");
            }
        }
        // Actor predictions: the assumed and true positions, their distance, the truth as /actors.
        let mut max_error = f64::NEG_INFINITY;
        for p in &predictions {
            assert_eq!(p.actors, ["walker"]);
            let (a, r) = (&p.actor_predicted, &p.actor_realized);
            let error = (a[0] - r[0]).hypot(a[1] - r[1]);
            assert!(close(p.actor_error[0], error) || (error.is_nan() && p.actor_error[0].is_nan()));
            if let Some(at) = actors.iter().find(|s| s.time == p.time) {
                let (x, y) = walker(at);
                assert!(close(r[0], x) && close(r[1], y), "truth at {}", p.time);
            }
            if !error.is_nan() {
                max_error = max_error.max(error);
            }
        }
        let logged = m["max_actor_prediction_error"].as_f64().unwrap();
        assert!(close(logged, max_error), "{name}: {logged} vs {max_error}");
        // Static: assumed where it was at the tick, 1.4 m/s × up to 1.5 s behind the truth.
        if collides {
            assert!(max_error > 1.4 * 1.5 - 0.05, "{max_error}");
        } else {
            assert!(max_error < 1e-6, "constant velocity is exact for a walker: {max_error}");
        }
        // min_ttc_by_barrier: the smallest time_to_collision of the known walker.
        let ttc = common::read_topic::<proto::Barrier>(&log, "/barrier")
            .iter()
            .flat_map(|b| b.barriers.iter().filter(|v| v.known && !v.time_to_collision.is_nan()))
            .map(|v| v.time_to_collision)
            .fold(f64::INFINITY, f64::min);
        assert_eq!(m["min_ttc_by_barrier"]["walker"].as_f64(), Some(ttc), "{name}");
    }
    // Scenarios without moving obstacles: no per-actor values, nothing reported missing for them.
    let log = dir.path().join("gamma.mcap");
    run_ok(&root().join("scenarios/bicycle_obstacle_gamma_m.toml"), &log, &[]);
    let m = common::analyze_json(&log);
    assert!(m["impact_speed_by_actor"].is_null() && m["max_actor_prediction_error"].is_null());
    assert!(m["missing"].is_null(), "{m}");
}

/// A sink that writes to its log what `edit` makes of each record.
struct Edited<F> {
    log: mjsafe::log::mcap::McapSink,
    edit: F,
}

impl<F: FnMut(&Record) -> Vec<Record>> mjsafe::log::Sink for Edited<F> {
    fn record(&mut self, record: &Record) -> Result<(), mjsafe::log::LogError> {
        for r in (self.edit)(record) {
            self.log.record(&r)?;
        }
        Ok(())
    }
    fn finish(&mut self, complete: bool) -> Result<(), mjsafe::log::LogError> {
        self.log.finish(complete)
    }
}

/// The run of tests/data/crossing_walker.toml with the walker assumed static (a collision at
/// 6.074 s; delays 0.2 s and 1.5 s), logged to `log` as `edit` rewrites each record: the log a
/// recorded road user with another life span would have given.
fn static_walker_run_edited(log: &std::path::Path, edit: impl FnMut(&Record) -> Vec<Record>) {
    static_walker_run_edited_with(log, &[], edit)
}

/// The same with more overrides.
fn static_walker_run_edited_with(log: &std::path::Path, sets: &[&str], edit: impl FnMut(&Record) -> Vec<Record>) {
    let sets: Vec<String> = ["actor_knowledge.kind=\"static\""]
        .iter()
        .chain(sets)
        .map(|s| s.to_string())
        .collect();
    let loaded = mjsafe::scenario::load(&root().join("tests/data/crossing_walker.toml"), &sets).unwrap();
    let mut episode = mjsafe::episode::Episode::new(&loaded).unwrap();
    let mut sink = Edited {
        log: mjsafe::log::mcap::McapSink::create(log, episode.info(), &[]).unwrap(),
        edit,
    };
    episode.run(&mut [&mut sink]).unwrap();
}

/// The impact speed is the approach's: a road user whose recording ends at its collision (absent
/// from the next step on, where it was last seen) still has one, the backward difference of
/// its positions before the contact, equal to the run's unedited; one whose recording begins at
/// its collision (absent at every step before it) has none, with that reason, and the run is
/// not said to have had no collision.
#[test]
fn an_impact_speed_is_of_the_step_before_the_collision() {
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain.mcap");
    static_walker_run_edited(&plain, |record| vec![record.clone()]);
    let m = common::analyze_json(&plain);
    let t_c = m["collision"]["time"].as_f64().expect("the static assumption collides");
    let speed = m["impact_speed_by_actor"]["walker"].as_f64().unwrap();
    // Ends at the collision: from the step after it on, absent where it was last seen, as the
    // episode logs a road user past its last recorded state.
    let ends = dir.path().join("ends.mcap");
    let mut last_seen = None;
    static_walker_run_edited(&ends, |record| match record {
        Record::Actors(m) if m.time > t_c + 1e-9 => {
            let mut m = m.clone();
            for a in m.actors.iter_mut().filter(|a| a.name == "walker") {
                let (x, y) = *last_seen.get_or_insert((a.x, a.y));
                (a.x, a.y, a.vx, a.vy, a.absent) = (x, y, 0.0, 0.0, true);
            }
            vec![Record::Actors(m)]
        }
        _ => vec![record.clone()],
    });
    let m = common::analyze_json(&ends);
    assert_eq!(m["impact_speed_by_actor"]["walker"].as_f64(), Some(speed), "{m}");
    // Begins at the collision: absent (parked far away) at every step before it.
    let begins = dir.path().join("begins.mcap");
    static_walker_run_edited(&begins, |record| match record {
        Record::Actors(m) if m.time < t_c - 1e-9 => {
            let mut m = m.clone();
            for a in m.actors.iter_mut().filter(|a| a.name == "walker") {
                (a.x, a.y, a.vx, a.vy, a.absent) = (1e6, 1e6, 0.0, 0.0, true);
            }
            vec![Record::Actors(m)]
        }
        _ => vec![record.clone()],
    });
    let m = common::analyze_json(&begins);
    assert!(m["collision"].is_object(), "{m}");
    assert!(m["impact_speed_by_actor"].is_null(), "{m}");
    assert_eq!(
        m["missing"]["impact_speed_by_actor.walker"],
        "it did not exist at the step before its collision (its first recorded state): no backward difference"
    );
    assert!(m["missing"].get("impact_speed_by_actor").is_none(), "{m}");
}

/// The walker's `road_user_entered` event at `time` (its recording "begins" then).
fn walker_enters(time: f64) -> Record {
    Record::Event(mjsafe::log::proto::Event {
        time,
        kind: "road_user_entered".into(),
        message: "walker enters: its first recorded state".into(),
        participants: vec!["walker".into()],
        depth: 0.0,
    })
}

/// delay_attributed_violation_time counts from a road user's `road_user_entered` when its
/// recording begins after it became known: Δt × the steps with its h < 0 within
/// [entered, entered + max delay), counted here from the raw `/barrier` messages.
#[test]
fn a_violation_within_the_delay_after_a_road_user_enters_is_attributed_to_the_delay() {
    use mjsafe::log::proto;
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("enters.mcap");
    // The walker's recording "begins" at the first step from 5.5 s on.
    let mut entered = None;
    static_walker_run_edited(&log, |record| match record {
        Record::Actors(m) if entered.is_none() && m.time >= 5.5 => {
            entered = Some(m.time);
            vec![walker_enters(m.time), record.clone()]
        }
        _ => vec![record.clone()],
    });
    let entered = entered.unwrap();
    let (max_delay, dt) = (1.5, 0.002);
    let steps = common::read_topic::<proto::Barrier>(&log, "/barrier")
        .iter()
        .filter(|m| m.time >= entered && m.time < entered + max_delay)
        .filter(|m| m.barriers.iter().any(|b| b.name == "walker" && b.h < 0.0))
        .count();
    assert!(steps > 100, "violations after it entered: {steps}");
    let m = common::analyze_json(&log);
    let attributed = m["delay_attributed_violation_time"].as_f64().unwrap();
    assert!(
        (attributed - steps as f64 * dt).abs() < 1e-9,
        "{attributed} vs {steps} steps"
    );
}

/// With a footprint the walker is three barriers of the filter (the car's covering circles
/// against it): the log's one entry `walker` and, with `[log] barrier_pairs`, the pairs
/// `walker/<i>-0` are attributed to the walker's appearance alike (the pairs' names once
/// matched no appearance, and the metric read 0 s).
#[test]
fn a_footprint_s_violations_are_attributed_whether_the_log_lists_the_obstacle_or_its_pairs() {
    use mjsafe::log::proto;
    let dir = tempfile::tempdir().unwrap();
    let mut attributed = Vec::new();
    for pairs in [false, true] {
        let log = dir.path().join(format!("pairs_{pairs}.mcap"));
        let footprint = "vehicle.footprint={length=4.6,width=1.8}";
        let sets = [
            footprint,
            if pairs {
                "log.barrier_pairs=true"
            } else {
                "log.barrier_pairs=false"
            },
        ];
        let mut entered = None;
        // The walker's recording "begins" at its first violation.
        static_walker_run_edited_with(&log, &sets, |record| match record {
            Record::Barrier(m) if entered.is_none() && m.barriers.iter().any(|b| b.h < 0.0) => {
                entered = Some(m.time);
                vec![walker_enters(m.time), record.clone()]
            }
            _ => vec![record.clone()],
        });
        let entered = entered.unwrap();
        let messages = common::read_topic::<proto::Barrier>(&log, "/barrier");
        let names: Vec<&str> = messages[0].barriers.iter().map(|b| b.name.as_str()).collect();
        match pairs {
            true => assert_eq!(names, ["walker/0-0", "walker/1-0", "walker/2-0"]),
            false => assert_eq!(names, ["walker"]),
        }
        let steps = messages
            .iter()
            .filter(|m| m.time >= entered && m.time < entered + 1.5)
            .filter(|m| m.barriers.iter().any(|b| b.h < 0.0))
            .count();
        assert!(steps > 10, "violations after it entered: {steps}");
        let value = common::analyze_json(&log)["delay_attributed_violation_time"]
            .as_f64()
            .unwrap();
        assert!((value - steps as f64 * 0.002).abs() < 1e-9, "{value} vs {steps} steps");
        attributed.push(value);
    }
    assert_eq!(attributed[0], attributed[1]);
}
