//! The MCAP log: read by an independent reader (Python `mcap`, CRCs validated, messages
//! decoded from the embedded schemas), byte-identical for equal inputs, and what `analyze`
//! does with files that are not good mjsafe logs.

mod common;
use common::*;

use std::process::Command;

#[test]
fn python_mcap_reads_and_decodes_the_log() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("run.mcap");
    run_ok(&scenario("bicycle_obstacle.toml"), &log, &[]);
    let d = python_digest(&log);

    for (topic, schema) in [
        ("/state", "mjsafe.State"),
        ("/command/issued", "mjsafe.IssuedCommand"),
        ("/command/applied", "mjsafe.AppliedCommand"),
        ("/barrier", "mjsafe.Barrier"),
        ("/filter", "mjsafe.Filter"),
        ("/event", "mjsafe.Event"),
    ] {
        assert_eq!(d["schemas"][topic], schema, "{topic}");
        assert_eq!(
            d["encodings"][topic],
            serde_json::json!(["protobuf", "protobuf"]),
            "{topic}"
        );
    }
    // 12 s at h = 0.002: 6000 steps, 6001 states; ticks every 0.01 s.
    assert_eq!(d["counts"]["/state"], 6001);
    assert_eq!(d["counts"]["/command/issued"], 1200);
    assert_eq!(d["counts"]["/command/applied"], 6000);
    let first = &d["first_state"];
    assert_eq!(first["names"], serde_json::json!(["x1", "x2", "heading", "speed"]));
    assert_eq!(first["values"], serde_json::json!([-20.0, 0.0, 0.0, 3.0]));
    assert!((d["last_state"]["time"].as_f64().unwrap() - 12.0).abs() < 1e-9);

    // Metadata: scenario text, versions.
    let meta = &d["metadata"]["mjsafe"];
    assert_eq!(meta["mujoco_version"], "2.2.2");
    assert_eq!(meta["mjsafe_version"], env!("CARGO_PKG_VERSION"));
    let text = std::fs::read_to_string(scenario("bicycle_obstacle.toml")).unwrap();
    assert_eq!(meta["scenario"], text.as_str());
    assert_eq!(d["metadata"]["mjsafe_status"]["complete"], "true");

    // Events: the obstacle appears at 2.75 s, then a collision.
    let events = d["events"].as_array().unwrap();
    assert_eq!(events[0]["kind"], "obstacle_appeared");
    assert!((events[0]["time"].as_f64().unwrap() - 2.75).abs() < 1e-9);
    assert!(events.iter().any(|e| e["kind"] == "collision_start"));
    assert_eq!(events.last().unwrap()["kind"], "episode_end");
    // Each event also as a foxglove.Log on /log (Foxglove's Log panel), at the same time:
    // INFO 2, WARNING 3 for a collision's start.
    assert_eq!(d["schemas"]["/log"], "foxglove.Log");
    let logs = d["logs"].as_array().unwrap();
    assert_eq!(logs.len(), events.len());
    for (log, event) in logs.iter().zip(events) {
        let (tl, te) = (log["time"].as_f64().unwrap(), event["time"].as_f64().unwrap());
        assert!((tl - te).abs() < 1e-9, "{log} at {te}");
        let kind = event["kind"].as_str().unwrap();
        assert!(
            log["message"].as_str().unwrap().starts_with(&format!("{kind}: ")),
            "{log}"
        );
        assert_eq!(log["level"], if kind == "collision_start" { 3 } else { 2 }, "{log}");
        assert_eq!(log["name"], "mjsafe");
    }

    // Delays: the acceleration command issued at t arrives at t + 1.5 and steering at t + 0.2;
    // before that the initial input (issued_at = -D) applies.
    let applied = d["applied"].as_array().unwrap();
    let at = |t: f64| {
        applied
            .iter()
            .find(|a| (a["time"].as_f64().unwrap() - t).abs() < 1e-9)
            .unwrap()
    };
    assert_eq!(at(1.0)["issued_at"], serde_json::json!([0.8, -1.5]));
    let a = at(5.0);
    let issued_at: Vec<f64> = a["issued_at"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(
        (issued_at[0] - 4.8).abs() < 1e-9 && (issued_at[1] - 3.5).abs() < 1e-9,
        "{issued_at:?}"
    );
    // The applied values equal the filtered commands issued then.
    let issued = d["issued"].as_array().unwrap();
    let issued_when = |t: f64| {
        issued
            .iter()
            .find(|i| (i["time"].as_f64().unwrap() - t).abs() < 1e-9)
            .unwrap()
    };
    assert_eq!(a["values"][0], issued_when(4.8)["filtered"][0]);
    assert_eq!(a["values"][1], issued_when(3.5)["filtered"][1]);

    // The Foxglove view: well-known schemas, the vehicle, its trail, the obstacle, the path.
    assert_eq!(d["schemas"]["/scene"], "foxglove.SceneUpdate");
    assert_eq!(d["schemas"]["/tf"], "foxglove.FrameTransform");
    assert_eq!(d["counts"]["/tf"], 1201);
    // The trail is published in segments trail/0, trail/1, … (11 points each, joined up).
    let ids: Vec<&str> = d["scene_ids"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    let (trail, others): (Vec<&str>, Vec<&str>) = ids.iter().partition(|id| id.starts_with("trail/"));
    assert_eq!(others, ["goal", "obstacle_0", "reference_path", "vehicle"]);
    // 1201 ticks, a point every 5th: 241 points, 10 intervals per segment.
    assert_eq!(trail.len(), 24, "{trail:?}");

    // Barrier: unknown before 2.75 s, known after.
    let barrier = d["barrier"].as_array().unwrap();
    assert_eq!(barrier[0]["known"], serde_json::json!([false]));
    assert_eq!(barrier.last().unwrap()["known"], serde_json::json!([true]));
}

#[test]
fn same_inputs_give_byte_identical_logs() {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.mcap");
    let b = dir.path().join("b.mcap");
    run_ok(&scenario("bicycle_obstacle.toml"), &a, &[]);
    run_ok(&scenario("bicycle_obstacle.toml"), &b, &[]);
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(), "logs differ");
    // And a different input gives a different log.
    let c = dir.path().join("c.mcap");
    run_ok(
        &scenario("bicycle_obstacle.toml"),
        &c,
        &["--set", "delays.steering=0.4"],
    );
    assert!(std::fs::read(&a).unwrap() != std::fs::read(&c).unwrap());
}

#[test]
fn analyze_reports_good_files_and_names_bad_ones() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.mcap");
    run_ok(&scenario("bicycle_obstacle_nodelay.toml"), &good, &[]);
    let bytes = std::fs::read(&good).unwrap();
    let truncated = write(dir.path(), "truncated.mcap", "");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let not_mcap = write(dir.path(), "notes.mcap", "this is not an MCAP file\n");
    // A valid MCAP that is not an mjsafe log.
    let foreign = dir.path().join("foreign.mcap");
    {
        let mut w = mcap::Writer::new(std::io::BufWriter::new(std::fs::File::create(&foreign).unwrap())).unwrap();
        let ch = w.add_channel(0, "/chatter", "json", &Default::default()).unwrap();
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: 1,
                log_time: 1,
                publish_time: 1,
            },
            b"{}",
        )
        .unwrap();
        w.finish().unwrap();
    }
    let o = mjsafe(&[
        "analyze",
        good.to_str().unwrap(),
        truncated.to_str().unwrap(),
        not_mcap.to_str().unwrap(),
        foreign.to_str().unwrap(),
    ]);
    assert!(!o.status.success(), "bad files must give a non-zero exit");
    let out = stdout(&o);
    let err = stderr(&o);
    assert!(
        out.contains("good.mcap") && out.contains("bicycle_obstacle_nodelay"),
        "good file still reported: {out}"
    );
    assert!(
        err.contains("truncated.mcap") && err.contains("truncated or corrupt"),
        "{err}"
    );
    assert!(
        err.contains("notes.mcap") && err.contains("not a readable MCAP"),
        "{err}"
    );
    assert!(
        err.contains("foreign.mcap") && err.contains("not an mjsafe log"),
        "{err}"
    );
}

/// Peak resident memory (kB) of `mjsafe analyze FILE`, measured by GNU time.
fn analyze_peak_kb(file: &std::path::Path) -> u64 {
    let o = Command::new("/usr/bin/time")
        .args(["-f", "%M", env!("CARGO_BIN_EXE_mjsafe"), "analyze"])
        .arg(file)
        .output()
        .expect("GNU time (/usr/bin/time; scripts/setup.sh --test installs it)");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    err.lines().last().unwrap().trim().parse().unwrap()
}

#[test]
fn analyze_memory_does_not_grow_with_log_length() {
    let dir = tempfile::tempdir().unwrap();
    let short = dir.path().join("short.mcap");
    let long = dir.path().join("long.mcap");
    run_ok(
        &scenario("bicycle_obstacle_nodelay.toml"),
        &short,
        &["--set", "duration=30.0"],
    );
    run_ok(
        &scenario("bicycle_obstacle_nodelay.toml"),
        &long,
        &["--set", "duration=300.0"],
    );
    let size = |p: &std::path::Path| std::fs::metadata(p).unwrap().len();
    let (short_kb, long_kb) = (analyze_peak_kb(&short), analyze_peak_kb(&long));
    println!(
        "analyze peak RSS: {short_kb} kB for {} kB of log, {long_kb} kB for {} kB of log",
        size(&short) / 1024,
        size(&long) / 1024
    );
    // Ten times the steps; the fixed part (schemas, metadata, first chunk) keeps it under 10x.
    assert!(size(&long) > 6 * size(&short));
    // Flat: the ten times longer log costs less than 2 MB more (the short log is ~1.5 MB).
    assert!(long_kb < short_kb + 2048, "{short_kb} kB -> {long_kb} kB");
}

/// Whether Python's `mcap` reader, reading the whole file with every CRC it knows validated
/// (chunk and data section), accepts it.
fn python_accepts(log: &std::path::Path) -> bool {
    let script = "import sys\nfrom mcap.reader import NonSeekingReader\n\
                  r = NonSeekingReader(open(sys.argv[1], 'rb'), validate_crcs=True)\n\
                  for _ in r.iter_messages(): pass\n";
    let o = Command::new(python())
        .args(["-c", script])
        .arg(log)
        .output()
        .expect("python runs");
    o.status.success()
}

/// Start and end of the top-level records of an MCAP file with opcode `op`.
fn top_level_records(bytes: &[u8], op: u8) -> Vec<(usize, usize)> {
    let (mut pos, mut out) = (8, Vec::new());
    while pos + 9 <= bytes.len() - 8 {
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
        if bytes[pos] == op {
            out.push((pos, pos + 9 + len));
        }
        pos += 9 + len;
    }
    out
}

#[test]
fn damaged_logs_are_errors_and_recover_reports_what_was_read() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.mcap");
    run_ok(&scenario("bicycle_obstacle.toml"), &good, &[]);
    let bytes = std::fs::read(&good).unwrap();
    assert!(python_accepts(&good));

    // The case: one bit of the /barrier channel record (data section, outside any
    // chunk: only the data-section CRC covers it) turns the topic into /barries, which hid
    // the collision's h < 0 behind a "complete" status.
    let channel = top_level_records(&bytes, 0x04)
        .into_iter()
        .find(|&(a, b)| bytes[a..b].windows(8).any(|w| w == b"/barrier"))
        .expect("the /barrier channel record");
    let at = channel.0
        + bytes[channel.0..channel.1]
            .windows(8)
            .position(|w| w == b"/barrier")
            .unwrap()
        + 7;
    let mut damaged = bytes.clone();
    damaged[at] ^= 1;
    let barrier = dir.path().join("barrier-flip.mcap");
    std::fs::write(&barrier, &damaged).unwrap();

    // One bit in the middle of the second chunk.
    let chunk = top_level_records(&bytes, 0x06)[1];
    let mut damaged = bytes.clone();
    damaged[(chunk.0 + chunk.1) / 2] ^= 0x10;
    let in_chunk = dir.path().join("chunk-flip.mcap");
    std::fs::write(&in_chunk, &damaged).unwrap();

    for log in [&barrier, &in_chunk] {
        let name = log.file_name().unwrap().to_str().unwrap();
        let path = log.to_str().unwrap();
        assert!(!python_accepts(log), "{name}: Python's reader accepts it");
        for args in [
            &["analyze", path][..],
            &["info", path],
            &["analyze", "--compare", path, path],
        ] {
            let o = mjsafe(args);
            let err = stderr(&o);
            assert!(!o.status.success(), "{args:?} exits 0 on a damaged log: {}", stdout(&o));
            assert!(
                err.contains(&format!("{path}: truncated or corrupt MCAP after")),
                "{args:?}: {err}"
            );
            assert!(!stdout(&o).contains("complete"), "{args:?}: {}", stdout(&o));
        }
        // --recover: the metrics of what was read, marked as not complete, and still a failure.
        let o = mjsafe(&["analyze", "--json", "--recover", path]);
        assert!(!o.status.success());
        let runs: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
        assert_eq!(runs[0]["complete"], false, "{name}");
        assert!(runs[0]["error"].as_str().unwrap().contains("corrupt"), "{name}");
        let o = mjsafe(&["info", "--recover", path]);
        assert!(!o.status.success());
        assert!(stdout(&o).contains("read before the damage"), "{}", stdout(&o));
        assert!(stdout(&o).contains("metadata mjsafe:"), "{}", stdout(&o));
    }
    // The chunk flip: only the chunks before the damaged one count.
    let o = mjsafe(&["analyze", "--json", "--recover", in_chunk.to_str().unwrap()]);
    let runs: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let time = runs[0]["simulated_time"].as_f64().unwrap();
    assert!(time > 1.0 && time < 8.0, "{time}");

    #[cfg(feature = "rerun")]
    {
        // A failed replay leaves no .rrd (nor its .partial); --recover keeps what was read.
        let rrd = dir.path().join("t.rrd");
        let o = mjsafe(&["replay", in_chunk.to_str().unwrap(), "--rrd", rrd.to_str().unwrap()]);
        assert!(!o.status.success());
        assert!(stderr(&o).contains("truncated or corrupt MCAP"), "{}", stderr(&o));
        assert!(!rrd.exists() && !dir.path().join("t.rrd.partial").exists());
        let o = mjsafe(&[
            "replay",
            in_chunk.to_str().unwrap(),
            "--rrd",
            rrd.to_str().unwrap(),
            "--recover",
        ]);
        assert!(!o.status.success());
        assert!(rrd.exists() && !dir.path().join("t.rrd.partial").exists());
    }
}

#[test]
fn devices_are_refused_as_logs_at_once() {
    for command in ["analyze", "info"] {
        let started = std::time::Instant::now();
        let o = mjsafe(&[command, "/dev/zero"]);
        assert!(!o.status.success());
        let err = stderr(&o);
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(
            err.starts_with("error: /dev/zero: ") && err.contains("character device"),
            "{err}"
        );
        assert!(started.elapsed() < std::time::Duration::from_secs(5));
    }
}

#[test]
fn the_scene_shows_predicted_positions_and_one_dimensional_vehicles() {
    let dir = tempfile::tempdir().unwrap();
    // (4.67) predicts each channel's state at t + D_i: one entity per channel.
    let log = dir.path().join("gamma_m.mcap");
    run_ok(
        &scenario("bicycle_obstacle_gamma_m.toml"),
        &log,
        &["--set", "duration=3.0"],
    );
    let d = python_digest(&log);
    let ids: Vec<&str> = d["scene_ids"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    for id in [
        "prediction/steering",
        "prediction/acceleration",
        "vehicle",
        "obstacle_0",
    ] {
        assert!(ids.contains(&id), "{id} not in {ids:?}");
    }
    // The delay-free filter predicts nothing: no prediction entities.
    let log = dir.path().join("delay_free.mcap");
    run_ok(&scenario("bicycle_obstacle.toml"), &log, &["--set", "duration=1.0"]);
    let d = python_digest(&log);
    assert!(!d["scene_ids"]
        .as_array()
        .unwrap()
        .iter()
        .any(|v| v.as_str().unwrap().starts_with("prediction")));
    // A vehicle on a line (the red light's double integrator) is drawn along the x axis.
    let log = dir.path().join("red_light.mcap");
    run_ok(&scenario("red_light.toml"), &log, &["--set", "duration=2.0"]);
    let d = python_digest(&log);
    assert_eq!(d["schemas"]["/tf"], "foxglove.FrameTransform");
    assert!(d["counts"]["/tf"].as_u64().unwrap() > 0, "{}", d["counts"]);
    let ids: Vec<&str> = d["scene_ids"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(ids.contains(&"vehicle"), "{ids:?}");
    // A moving obstacle: drawn every frame, its trail, where each channel's prediction assumes it.
    let log = dir.path().join("walker.mcap");
    run_ok(
        &root().join("tests/data/crossing_walker.toml"),
        &log,
        &["--set", "duration=3.0"],
    );
    let d = python_digest(&log);
    let ids: Vec<&str> = d["scene_ids"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    for id in [
        "walker",
        "actor_trail/walker/0",
        "actor_prediction/walker/steering",
        "actor_prediction/walker/acceleration",
    ] {
        assert!(ids.contains(&id), "{id} not in {ids:?}");
    }
}

#[test]
fn the_road_and_planar_half_spaces_are_drawn_and_are_barriers_with_the_hull() {
    // Read back by the independent Python reader.
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("road.mcap");
    run_ok(
        &scenario("bicycle_road_gamma_m.toml"),
        &log,
        &[
            "--set",
            "duration=1.0",
            "--set",
            "barriers=[{kind='half_space', coefficients=[0.0, 1.0], offset=20.0}]",
        ],
    );
    let d = python_digest(&log);
    let lines = &d["scene_lines"];
    // Edges as line strips (Foxglove LINE_STRIP = 0) along x2 = 5 and x2 = -15, the lane
    // marking as dashes (LINE_LIST = 2) along x2 = -5, the half-space x2 + 20 >= 0 at x2 = -20.
    for (id, kind, y) in [
        ("road/left_edge", 0, 5.0),
        ("road/right_edge", 0, -15.0),
        ("road/lane/centre", 2, -5.0),
        ("barrier/barrier_0", 0, -20.0),
    ] {
        let line = &lines[id][0];
        assert_eq!(line["type"], kind, "{id}: {line}");
        let points = line["points"].as_array().unwrap();
        assert!(points.len() >= 2, "{id}");
        for p in points {
            assert!((p[1].as_f64().unwrap() - y).abs() < 1e-9, "{id}: {p}");
        }
        // Drawn over the stretch the run covers: from behind the start (x1 = -20).
        assert!(points.iter().any(|p| p[0].as_f64().unwrap() < -20.0), "{id}");
    }
    // The goal's rim (radius 2 about (10, 0)) as dashes.
    let goal = &lines["goal"][0];
    assert_eq!(goal["type"], 2, "{goal}");
    let points = goal["points"].as_array().unwrap();
    assert!(points.len() >= 24, "{goal}");
    for p in points {
        let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
        assert!(((x - 10.0).hypot(y) - 2.0).abs() < 1e-9, "{p}");
    }
    // h in metres at x(0) = (-20, 0): 5 - 0 - 3 (hull) and 0 + 15 - 3; after the obstacle and
    // the scenario's half-space (x2 + 20).
    let h0 = &d["barrier"][0]["h"];
    assert_eq!(h0.as_array().unwrap().len(), 4, "{h0}");
    assert_eq!(
        (&h0[1], &h0[2], &h0[3]),
        (
            &serde_json::json!(20.0),
            &serde_json::json!(2.0),
            &serde_json::json!(12.0)
        )
    );
}

#[test]
fn the_scene_draws_every_tick_but_at_most_every_10_ms() {
    // /tf is published with every scene frame. The bicycle ticks every 10 ms: a frame per
    // tick; the unicycle ticks every 2 ms step: a frame every fifth tick, while the data
    // topics keep every tick.
    let dir = tempfile::tempdir().unwrap();
    for (file, duration, ticks, frames) in [
        ("bicycle_obstacle_gamma_m.toml", "1.0", 100, 101),
        ("unicycle_tv_delay.toml", "1.0", 500, 101),
    ] {
        let log = dir.path().join(format!("{file}.mcap"));
        run_ok(&scenario(file), &log, &["--set", &format!("duration={duration}")]);
        let d = python_digest(&log);
        let count = |topic: &str| d["counts"][topic].as_u64().unwrap();
        assert_eq!(count("/tf"), frames, "{file}: {}", d["counts"]);
        assert_eq!(count("/command/issued"), ticks, "{file}: {}", d["counts"]);
    }
}

/// The resolved scenario in the run metadata writes `[vehicle]` in one order whatever the
/// file's (kind, model, the kind's own keys, initial_state, …), with the kind's own keys as its
/// parameter type reads them (integers as floats).
#[test]
fn the_resolved_vehicle_table_keeps_its_order_and_types() {
    let text = std::fs::read_to_string(scenario("linear_distinct_delays.toml"))
        .unwrap()
        .replace(
            "a = [[-1.0, 0.5], [-0.5, -1.0]]\nb = [[1.0, 0.0], [0.0, 1.0]]\ntimestep = 0.005\ninitial_state = [16.0, 6.0]",
            "initial_state = [16.0, 6.0]\ntimestep = 0.005\nb = [[1, 0], [0, 1]]\na = [[-1.0, 0.5], [-0.5, -1.0]]",
        );
    assert!(text.contains("b = [[1, 0]"), "the replacement applies");
    let loaded = mjsafe::scenario::from_text(&scenario("linear_distinct_delays.toml"), text, &[]).unwrap();
    let episode = mjsafe::episode::Episode::new(&loaded).unwrap();
    let resolved = &episode.info().scenario_resolved;
    let vehicle = &resolved[resolved.find("[vehicle]").unwrap()..];
    let vehicle = &vehicle[..vehicle.find("\n\n").unwrap_or(vehicle.len())];
    assert_eq!(
        vehicle,
        "[vehicle]\nkind = \"linear\"\na = [[-1.0, 0.5], [-0.5, -1.0]]\nb = [[1.0, 0.0], [0.0, 1.0]]\ninitial_state = [16.0, 6.0]\ntimestep = 0.005"
    );
}
