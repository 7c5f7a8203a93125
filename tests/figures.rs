//! Figures: `analyze --brief --plot DIR A B C` on the three Ch. 4 filters (the comparison
//! scripts/run.sh prints, the overlays scripts/figures.sh copies into docs/figures), and
//! `plot-sweep`.

mod common;

use std::path::Path;
use std::process::Command;

use common::*;

/// Pixels of each colour (r, g, b) in a PNG, counted by Pillow.
fn colour_counts(png: &Path, colours: &[(u8, u8, u8)]) -> (u32, u32, Vec<u64>) {
    let script = "import sys, json\nfrom PIL import Image\n\
                  im = Image.open(sys.argv[1]).convert('RGB')\n\
                  want = [tuple(c) for c in json.loads(sys.argv[2])]\n\
                  counts = dict.fromkeys(want, 0)\n\
                  for c in im.getdata():\n    if c in counts: counts[c] += 1\n\
                  print(json.dumps([im.width, im.height, [counts[c] for c in want]]))";
    let want: Vec<[u8; 3]> = colours.iter().map(|&(r, g, b)| [r, g, b]).collect();
    let o = Command::new(python())
        .args(["-c", script])
        .arg(png)
        .arg(serde_json::to_string(&want).unwrap())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    serde_json::from_slice(&o.stdout).unwrap()
}

const BLUE: (u8, u8, u8) = (31, 119, 180);
const RED: (u8, u8, u8) = (214, 39, 40);
const GREEN: (u8, u8, u8) = (44, 160, 44);

#[test]
fn three_filters_compared_and_overlaid() {
    let dir = tempfile::tempdir().unwrap();
    let bicycle = scenario("bicycle_obstacle.toml");
    let runs = [
        ("delay_free", None),
        (
            "predictor",
            Some("filter={kind='cbf_qp', l0=4.0, l1=4.0, compensation='predictor'}"),
        ),
        ("gamma_m", Some("filter={kind='gamma_m', l0=4.0, l1=4.0, m=50.0}")),
    ];
    let mut logs = Vec::new();
    for (name, set) in runs {
        let log = dir.path().join(format!("{name}.mcap"));
        let mut extra = vec!["--set", "duration=6.0"];
        if let Some(set) = set {
            extra.extend(["--set", set]);
        }
        run_ok(&bicycle, &log, &extra);
        logs.push(log.to_str().unwrap().to_string());
    }
    let plots = dir.path().join("plots");
    let mut args = vec!["analyze", "--brief", "--plot", plots.to_str().unwrap()];
    args.extend(logs.iter().map(String::as_str));
    let o = mjsafe(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let table = stdout(&o);
    println!("{table}");
    let lines: Vec<&str> = table.lines().collect();
    assert!(
        lines[0].starts_with("filter") && lines[0].contains("min_clearance_m"),
        "{table}"
    );
    // Named by equation number; only (4.67) avoids the obstacle.
    assert!(
        lines[1].starts_with("delay-free CBF-QP (4.9)–(4.11)") && lines[1].contains("YES at t="),
        "{table}"
    );
    assert!(
        lines[2].starts_with("predictor CBF-QP (4.34)") && lines[2].contains("YES at t="),
        "{table}"
    );
    assert!(
        lines[3].starts_with("γm filter (4.67), m = 50") && lines[3].contains(" no "),
        "{table}"
    );

    let files = listing(&plots);
    for f in ["overlay-trajectory.png", "overlay-barriers.png", "overlay-inputs.png"] {
        assert!(files.contains(&f.to_string()), "{files:?}");
    }
    // Every run is drawn (its colour present) in each overlay.
    for f in ["overlay-trajectory.png", "overlay-barriers.png", "overlay-inputs.png"] {
        let (w, h, counts) = colour_counts(&plots.join(f), &[BLUE, RED, GREEN]);
        assert!(w == 1200 && h >= 600, "{f}: {w}x{h}");
        assert!(counts.iter().all(|&n| n > 200), "{f}: {counts:?}");
    }
    // The same overlays as SVG, read back independently (tests/figure_check.py): each run's
    // curve with its legend label, the axes' labels with units, and a y axis (symlog) that
    // covers the lowest h of the three runs, where the curves reach it.
    let svg = dir.path().join("svg");
    let mut args = vec![
        "analyze",
        "--brief",
        "--plot",
        svg.to_str().unwrap(),
        "--plot-format",
        "svg",
    ];
    args.extend(logs.iter().map(String::as_str));
    let o = mjsafe(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut json = vec!["analyze", "--json"];
    json.extend(logs.iter().map(String::as_str));
    let metrics: serde_json::Value = serde_json::from_str(&stdout(&mjsafe(&json))).unwrap();
    let lowest = (metrics.as_array().unwrap().iter())
        .map(|m| m["min_h"].as_f64().unwrap())
        .fold(f64::INFINITY, f64::min);
    assert!(lowest < -1.0, "{lowest}");
    let check = |file: &str, extra: &[&str]| {
        let o = Command::new(python())
            .arg(root().join("tests/figure_check.py"))
            .arg(svg.join(file))
            .args([
                "--legend",
                "delay-free CBF-QP (4.9)–(4.11)",
                "--legend",
                "predictor CBF-QP (4.34)",
                "--legend",
                "γm filter (4.67), m = 50",
                "--axis",
                "t [s]",
            ])
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{file}: {}", text(&o));
    };
    check(
        "overlay-barriers.svg",
        &["--axis", "[m²]", "--axis", "symlog", "--covers", &lowest.to_string()],
    );
    check("overlay-inputs.svg", &["--axis", "[m/s²]", "--axis", "tan δ"]);
    assert!(std::fs::read(svg.join("overlay-trajectory.svg"))
        .unwrap()
        .starts_with(b"<svg"));
    // Two logs of one run: told apart by their file stems in the legend (no error).
    let o = mjsafe(&[
        "analyze",
        "--brief",
        "--plot",
        plots.to_str().unwrap(),
        &logs[0],
        &logs[0],
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn a_sweep_metric_is_plotted_against_a_swept_key() {
    let dir = tempfile::tempdir().unwrap();
    let sweep = dir.path().join("sweep");
    let o = mjsafe(&[
        "sweep",
        "scenarios/bicycle_obstacle_gamma_m.toml",
        "--out",
        sweep.to_str().unwrap(),
        "--threads",
        "2",
        "--set",
        "duration=6.0",
        "--grid",
        "delays.acceleration=0.5,1.0,1.5",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = mjsafe(&["plot-sweep", sweep.to_str().unwrap(), "--x", "delays.acceleration"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let png = sweep.join("min_h-vs-delays.acceleration.png");
    let (w, h, counts) = colour_counts(&png, &[BLUE]);
    assert_eq!((w, h), (1000, 560));
    assert!(counts[0] > 100, "the line and its points: {counts:?}");

    let o = mjsafe(&["plot-sweep", sweep.to_str().unwrap(), "--x", "delays.steering"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("`delays.steering` is not a swept key (swept: delays.acceleration)"),
        "{}",
        stderr(&o)
    );
    let plot_y = |metric: &str| {
        mjsafe(&[
            "plot-sweep",
            sweep.to_str().unwrap(),
            "--x",
            "delays.acceleration",
            "--y",
            metric,
        ])
    };
    let o = plot_y("nope");
    assert!(!o.status.success());
    assert!(stderr(&o).contains("no metric `nope`"), "{}", stderr(&o));
    // The list of numeric metrics names per-channel ones and no text column.
    assert!(stderr(&o).contains("max_correction.steering"), "{}", stderr(&o));
    assert!(!stderr(&o).contains(", error"), "{}", stderr(&o));
    // A per-channel metric plots like any other.
    let o = plot_y("max_correction.steering");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(sweep
        .join("max_correction.steering-vs-delays.acceleration.png")
        .exists());
    // The plot is PNG or SVG, by its extension: another is refused; a missing directory is made.
    let plot_to = |out: &Path| {
        mjsafe(&[
            "plot-sweep",
            sweep.to_str().unwrap(),
            "--x",
            "delays.acceleration",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let o = plot_to(&sweep.join("plot.jpg"));
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("expected a .png or .svg file name"),
        "{}",
        stderr(&o)
    );
    assert!(!sweep.join("plot.jpg").exists());
    let o = plot_to(&sweep.join("plot.svg"));
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read(sweep.join("plot.svg")).unwrap().starts_with(b"<svg"));
    let nested = sweep.join("plots/min_h/delays.png");
    let o = plot_to(&nested);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(nested.exists());
}

/// Plots are named by their log's file name: logs of one name, or a log named like the
/// overlays, are refused before anything is drawn (they overwrote each other's plots); a log
/// that cannot be plotted does not take the metrics table with it.
#[test]
fn plots_of_logs_of_one_name_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    for d in [&a, &b] {
        std::fs::create_dir_all(d).unwrap();
        run_ok(
            &scenario("scalar_tv_delay.toml"),
            &d.join("run.mcap"),
            &["--set", "duration=1.0"],
        );
    }
    let plots = dir.path().join("plots");
    let (first, second) = (a.join("run.mcap"), b.join("run.mcap"));
    let o = mjsafe(&[
        "analyze",
        "--plot",
        plots.to_str().unwrap(),
        first.to_str().unwrap(),
        second.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(stderr(&o).contains("both would write run-*.png"), "{}", stderr(&o));
    assert!(!plots.exists(), "nothing drawn");
    let overlay = dir.path().join("overlay.mcap");
    std::fs::copy(&first, &overlay).unwrap();
    let o = mjsafe(&[
        "analyze",
        "--plot",
        plots.to_str().unwrap(),
        overlay.to_str().unwrap(),
        second.to_str().unwrap(),
    ]);
    assert!(stderr(&o).contains("named like the overlays"), "{}", stderr(&o));

    // A damaged log has no plots (no plot of part of a run), and the metrics table is still
    // printed; the command fails.
    let bytes = std::fs::read(&first).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let o = mjsafe(&[
        "analyze",
        "--plot",
        plots.to_str().unwrap(),
        cut.to_str().unwrap(),
        second.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(stdout(&o).contains("run.mcap"), "the intact log's row: {}", stdout(&o));
    assert!(stderr(&o).contains("cut.mcap"), "{}", stderr(&o));
}

/// A log with road users gets the scene at the closest approach (`-closest.png`: the vehicle in
/// blue, the road users in red, 800 × 800); a log without none.
#[test]
fn the_closest_approach_is_drawn_for_logs_with_road_users() {
    let dir = tempfile::tempdir().unwrap();
    let plots = dir.path().join("plots");
    let (actors, plain) = (dir.path().join("ccrb.mcap"), dir.path().join("scalar.mcap"));
    run_ok(
        &scenario("ncap_ccrb.toml"),
        &actors,
        &["--set", "filter={kind=\"none\"}"],
    );
    run_ok(&scenario("scalar_tv_delay.toml"), &plain, &["--set", "duration=1.0"]);
    for log in [&actors, &plain] {
        let o = mjsafe(&["analyze", "--plot", plots.to_str().unwrap(), log.to_str().unwrap()]);
        assert!(o.status.success(), "{}", text(&o));
    }
    let closest = plots.join("ccrb-closest.png");
    let (width, height, counts) = colour_counts(&closest, &[BLUE, RED]);
    assert_eq!((width, height), (800, 800));
    assert!(
        counts[0] > 100 && counts[1] > 100,
        "vehicle and road user drawn: {counts:?}"
    );
    assert!(!plots.join("scalar-closest.png").exists());
}

/// A CommonRoad run (25 recorded cars, a road edge: 28 barriers) reads as a figure: h(t) of the eight
/// barriers that came closest, the closest obstacle among them, each in its own colour, the
/// title saying so, in m² (all obstacles); no appearance marked for road users there from the
/// start (before: 28 legend entries in six colours, cut off at the figure's foot, and 25
/// overprinted "appears" labels at t = 0); the trajectory with the vehicle's path and the road
/// users' paths under one entry (before: 25 entries over the plot, the vehicle's path unnamed in
/// the blue of four road users). Read back by tests/figure_check.py.
#[test]
fn a_commonroad_run_is_plotted_readably() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("us5.mcap");
    let world = root().join("data/commonroad/USA_US101-5_1_T-1.xml");
    run_ok(&world, &log, &["--set", "duration=3.0"]);
    let svg = dir.path().join("svg");
    let o = mjsafe(&[
        "analyze",
        "--plot",
        svg.to_str().unwrap(),
        "--plot-format",
        "svg",
        log.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let o = mjsafe(&["analyze", "--json", log.to_str().unwrap()]);
    let metrics: serde_json::Value = serde_json::from_str(&stdout(&o)).unwrap();
    let by_obstacle = metrics[0]["min_clearance_by_obstacle"].as_object().unwrap();
    assert_eq!(by_obstacle.len(), 25, "{by_obstacle:?}");
    let (closest, _) = (by_obstacle.iter())
        .filter_map(|(name, c)| Some((name, c.as_f64()?)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap();
    let check = |file: &str, args: &[&str]| {
        let o = Command::new(python())
            .arg(root().join("tests/figure_check.py"))
            .arg(svg.join(file))
            .args(args)
            .output()
            .unwrap();
        assert!(o.status.success(), "{file}: {}", text(&o));
    };
    let closest_line = format!("h {closest}");
    check(
        "us5-barriers.svg",
        &[
            "--legend",
            &closest_line,
            "--legends-at-most",
            "8",
            "--distinct",
            "--axis",
            "the 8 of 28 that came closest",
            "--axis",
            "[m²]",
        ],
    );
    check(
        "us5-trajectory.svg",
        &[
            "--legend",
            "vehicle's path",
            "--legend",
            "road users' paths (25)",
            "--legends-at-most",
            "2",
            "--axis",
            "x [m]",
        ],
    );
    for file in ["us5-barriers.svg", "us5-inputs.svg"] {
        let drawn = std::fs::read_to_string(svg.join(file)).unwrap();
        assert!(!drawn.contains("appears"), "{file} marks appearances at the start");
    }
}

/// The Foxglove layout (docs/foxglove-layout.json) follows the figures' rules: every panel the
/// layout places has its configuration, every plotted path is a topic of the log format, and a
/// plot of h zooms about the boundary so that the 0.024 m² margin of (4.67) reads apart from 0
/// and from a violation.
#[test]
fn the_foxglove_layout_shows_h_near_its_boundary() {
    let layout: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root().join("docs/foxglove-layout.json")).unwrap()).unwrap();
    let configs = layout["configById"].as_object().unwrap();
    fn panels(node: &serde_json::Value, out: &mut Vec<String>) {
        match node {
            serde_json::Value::String(id) => out.push(id.clone()),
            serde_json::Value::Object(o) => {
                for key in ["first", "second"] {
                    if let Some(child) = o.get(key) {
                        panels(child, out);
                    }
                }
            }
            _ => {}
        }
    }
    let mut placed = Vec::new();
    panels(&layout["layout"], &mut placed);
    assert!(placed.len() >= 5, "{placed:?}");
    for id in &placed {
        assert!(configs.contains_key(id), "{id} is placed but has no configuration");
    }
    let topics = ["/barrier", "/command/issued", "/command/applied", "/prediction"];
    let mut zoomed = false;
    for (id, config) in configs.iter().filter(|(id, _)| id.starts_with("Plot!")) {
        for path in config["paths"].as_array().unwrap() {
            let value = path["value"].as_str().unwrap();
            assert!(
                topics.iter().any(|t| value.starts_with(&format!("{t}."))),
                "{id}: {value} is not a topic of the log format"
            );
        }
        let (lo, hi) = (config["minYValue"].as_f64(), config["maxYValue"].as_f64());
        if let (Some(lo), Some(hi)) = (lo, hi) {
            let plots_h = config["paths"][0]["value"].as_str().unwrap().ends_with(".h");
            // 0.024 m² at least a twentieth of the height above 0, a violation visible below.
            zoomed |= plots_h && lo < 0.0 && hi > 0.0 && 0.024 / (hi - lo) >= 0.02;
        }
    }
    assert!(zoomed, "no plot of h zoomed about 0");
}
