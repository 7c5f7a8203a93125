//! Conformance of every registered filter kind on every registered vehicle kind it accepts
//! (issue 35, part 7), enumerated from the registries, not from a hand list:
//!
//! - (a) the control callback allocates nothing once the episode is warm (a counting global
//!   allocator, this test binary only, counts the allocations made on this thread while the
//!   controller runs inside the plant's step);
//! - (b) a tick at a hostile state (NaN, +1e300, −1e300 in one or every component) through the
//!   predictors, the nominal and the filter never panics: it ends in an error, or every issued
//!   command is finite or the filter flags it (infeasible);
//! - (c) two runs of a pair write byte-identical MCAP logs.
//!
//! A pair is a vehicle setup (each shipped scenario's `[vehicle]` with its delays, nominal and
//! obstacles, and a CommonRoad world's: recorded road users, the route nominal, polyline road
//! edges; a vehicle kind without a shipped scenario gets one made from `models/<kind>.xml`)
//! with a filter kind, whose parameters are the first of its candidate tables (the shipped
//! scenarios' own, then [`EXTRA_TABLES`], then the kind's defaults) the pair accepts. A
//! filter that refuses the vehicle when the episode is assembled is skipped; the test fails
//! if a shipped scenario's own pair, any registered vehicle or any registered filter kind is
//! left out, and prints how many pairs ran.

use std::path::{Path, PathBuf};

use super::Episode;
use crate::mujoco::counting_alloc::{allocations, count_allocations};
use crate::plant::Controller;
use crate::scenario::{self, LoadedScenario};
use crate::vehicle_registry::VehicleBinding;

/// Counts the allocations of the wrapped controller's calls (the body of the control callback).
struct Counted<'a>(&'a mut dyn Controller);

impl Controller for Counted<'_> {
    fn input(&mut self, step: u64, call_in_step: u32, offset: f64, state: &dyn Fn(&mut [f64])) -> &[f64] {
        count_allocations(true);
        let input = self.0.input(step, call_in_step, offset, state);
        count_allocations(false);
        input
    }
}

/// Filter tables for kinds (or variants) no shipped scenario uses as such.
const EXTRA_TABLES: [&str; 3] = [
    "{kind='fixed_channel', l0=4.0, l1=4.0, phi=2}",
    "{kind='cbf_qp', l0=4.0, l1=4.0, compensation='predictor'}",
    "{kind='esf', rate=3.2, horizon=4.0}",
];

/// Simulated seconds of the steady window after warm-up (a), and of the logged runs (c).
const STEADY: f64 = 0.5;
const LOGGED: f64 = 0.2;

/// A vehicle setup: a scenario's text and where it is read from (its model path is relative).
struct Base {
    name: String,
    path: PathBuf,
    text: String,
    /// The scenario's own filter table (inline TOML), when it is a shipped scenario.
    own_filter: Option<String>,
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The inline TOML of a `filter` table.
fn inline(filter: &scenario::KindSpec) -> String {
    toml::Value::try_from(filter).expect("a table").to_string()
}

/// Every shipped scenario (not a sweep) as a base, then one made for each MJCF vehicle kind
/// no shipped scenario uses.
fn bases() -> Vec<Base> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(root().join("scenarios")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.to_string_lossy();
        if name.ends_with(".toml") && !name.ends_with(".sweep.toml") {
            files.push(path);
        }
    }
    files.sort();
    let mut bases: Vec<Base> = files
        .into_iter()
        .map(|path| {
            let loaded = scenario::load(&path, &[]).unwrap();
            Base {
                name: loaded.scenario.name.clone(),
                own_filter: Some(inline(&loaded.scenario.filter)),
                text: loaded.source_text,
                path,
            }
        })
        .collect();
    // A CommonRoad world (docs/commonroad.md): a recorded road user (the pedestrian), the route
    // nominal, polyline road edges, the built-in car model.
    let xml = root().join("data/commonroad/OSC_PedestrianCollision-1_1_T-1.xml");
    let loaded = scenario::load(&xml, &[]).unwrap();
    bases.push(Base {
        name: format!("commonroad {}", loaded.scenario.name),
        own_filter: Some(inline(&loaded.scenario.filter)),
        text: loaded.source_text,
        path: xml,
    });
    let kinds: Vec<String> = crate::vehicle_registry::registry()
        .vehicle_kinds()
        .into_iter()
        .map(String::from)
        .collect();
    for kind in kinds {
        if bases.iter().any(|b| vehicle_kind(b) == kind) {
            continue;
        }
        if let Some(base) = made_base(&kind) {
            bases.push(base);
        }
    }
    bases
}

fn vehicle_kind(base: &Base) -> String {
    // (Parsed as from its path: a CommonRoad world reads its file beside it.)
    scenario::parse(&base.text, &base.path.display().to_string(), &[])
        .unwrap()
        .vehicle
        .kind
}

/// A setup for an MJCF vehicle kind from `models/<kind>.xml`: at rest at the origin, a constant
/// unit input on every channel, the first channel delayed by 0.1 s, an obstacle ahead if the
/// model is planar.
fn made_base(kind: &str) -> Option<Base> {
    let model_path = root().join("models").join(format!("{kind}.xml"));
    let VehicleBinding::Mjcf(bind) = crate::vehicle_registry::registry().vehicle(kind).ok()? else {
        return None;
    };
    let model = crate::mujoco::Model::from_xml_file(&model_path).ok()?;
    let dynamics = bind(&model).ok()?.dynamics();
    let zeros = vec!["0.0"; dynamics.state_dim()].join(", ");
    let ones = vec!["1.0"; dynamics.input_dim()].join(", ");
    let channel = &dynamics.channel_names()[0];
    let obstacle = match dynamics.planar_position() {
        Some(_) => "[[obstacles]]\ncentre = [2.0, 0.2]\nradius = 0.5\n",
        None => "",
    };
    let text = format!(
        "name = \"conformance_{kind}\"\nduration = 2.0\n[vehicle]\nkind = \"{kind}\"\nmodel = \"../models/{kind}.xml\"\ninitial_state = [{zeros}]\n[delays]\n{channel} = 0.1\n[nominal]\nkind = \"constant\"\ninput = [{ones}]\n{obstacle}"
    );
    Some(Base {
        name: format!("conformance_{kind}"),
        path: root().join("scenarios").join(format!("conformance_{kind}.toml")),
        text,
        own_filter: None,
    })
}

fn load(base: &Base, overrides: &[String]) -> Option<LoadedScenario> {
    scenario::from_text(&base.path, base.text.clone(), overrides).ok()
}

/// The filter table of `kind` the base accepts (loads and assembles), if any.
fn accepted_table(base: &Base, kind: &str, shipped: &[String]) -> Option<String> {
    let candidates = base
        .own_filter
        .iter()
        .chain(shipped)
        .cloned()
        .chain(EXTRA_TABLES.iter().map(|t| t.to_string()))
        .chain([format!("{{kind='{kind}'}}")]);
    candidates
        .filter(|table| {
            let value = scenario::override_value(table).unwrap();
            value.get("kind").and_then(toml::Value::as_str) == Some(kind)
        })
        .find(|table| load(base, &[format!("filter={table}")]).is_some_and(|l| Episode::new(&l).is_ok()))
}

/// Runs the episode's control loop as `Episode::run` does (without sinks) and returns the
/// allocations counted in the controller during steps starting at or after `steady_from`,
/// and before it.
fn callback_allocations(loaded: &LoadedScenario, steady_from: f64) -> (u64, u64) {
    let mut episode = Episode::new(loaded).unwrap();
    let h = episode.control.timestep();
    let (mut warm_up, mut steady) = (0, 0);
    let mut realized = Vec::new();
    for k in 0..episode.steps {
        let time = k as f64 * h;
        episode.reveal_obstacles(time);
        let x = episode.plant.state();
        episode.control.realize_into(time, &x, false, &mut realized).unwrap();
        for c in realized.drain(..) {
            episode.control.recycle(c);
        }
        allocations(true);
        episode.plant.step(&mut Counted(&mut episode.control)).unwrap();
        let counted = allocations(false);
        if let Some(e) = episode.control.take_error() {
            println!("  (a) the run stopped at {time} s: {e}");
            break;
        }
        if time >= steady_from {
            steady += counted;
        } else {
            warm_up += counted;
        }
        episode.control.take_tick();
    }
    (warm_up, steady)
}

/// (a): the pair run over its warm-up (the longest delay, the last obstacle's appearance, two
/// control periods) and a steady window (past the prescribed time of a Ch. 5 filter); the
/// allocations in the steady window.
fn steady_allocations(base: &Base, filter: &str) -> u64 {
    let set_filter = format!("filter={filter}");
    let loaded = load(base, std::slice::from_ref(&set_filter)).unwrap();
    let episode = Episode::new(&loaded).unwrap();
    let info = episode.info();
    let appear = loaded
        .scenario
        .obstacles
        .iter()
        .map(|o| o.appear_at + o.appear_jitter)
        .fold(0.0, f64::max);
    let steady_from = info.max_delay.max(appear) + 2.0 * info.control_period;
    let end = (steady_from + STEADY).max(info.prescribed_time.map_or(0.0, |t| t + 0.3));
    let loaded = load(base, &[set_filter, format!("duration={end}")]).unwrap();
    let (warm_up, steady) = callback_allocations(&loaded, steady_from);
    println!("  (a) {warm_up} allocations while warming up, {steady} in [{steady_from:.3}, {end:.3}] s");
    steady
}

/// (b): one tick at each hostile state, at the start of a fresh episode with every obstacle
/// known. Returns what went wrong (a panic, or a non-finite command neither flagged nor an
/// error).
fn hostile_states(base: &Base, filter: &str) -> Vec<String> {
    let loaded = load(base, &[format!("filter={filter}")]).unwrap();
    let x0 = loaded.scenario.vehicle.initial_state.clone();
    let mut problems = Vec::new();
    let (mut errors, mut finite, mut flagged) = (0, 0, 0);
    for value in [f64::NAN, 1e300, -1e300] {
        for every in [false, true] {
            let mut x = x0.clone();
            match every {
                true => x.iter_mut().for_each(|c| *c = value),
                false => x[0] = value,
            }
            let mut episode = Episode::new(&loaded).unwrap();
            episode.reveal_obstacles(f64::INFINITY);
            let tick = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                episode.control.input(0, 0, 0.0, &|state| state.copy_from_slice(&x));
                if episode.control.take_error().is_some() {
                    return Ok("error");
                }
                let Some((tick, _)) = episode.control.take_tick() else {
                    return Ok("error");
                };
                let mut verdict = "finite";
                for (u, outcome) in tick.issued.iter().zip(&tick.outcomes) {
                    verdict = match (u.is_finite(), outcome) {
                        (true, _) => verdict,
                        (false, Some(o)) if o.infeasible => "flagged",
                        (false, _) => return Err(format!("{x:?}: the tick issued {u} unflagged")),
                    };
                }
                Ok(verdict)
            }));
            match tick {
                Ok(Ok("error")) => errors += 1,
                Ok(Ok("finite")) => finite += 1,
                Ok(Ok(_)) => flagged += 1,
                Ok(Err(problem)) => problems.push(problem),
                Err(_) => problems.push(format!("{x:?}: panicked")),
            }
        }
    }
    println!("  (b) hostile states: {errors} errors, {finite} finite, {flagged} flagged infeasible");
    problems
}

/// (c): the pair run twice for [`LOGGED`] seconds into two MCAP logs; whether they are equal.
fn same_bytes_twice(base: &Base, filter: &str, dir: &Path, index: usize) -> bool {
    let loaded = load(base, &[format!("filter={filter}"), format!("duration={LOGGED}")]).unwrap();
    let logs: Vec<Vec<u8>> = (0..2)
        .map(|run| {
            let log = dir.join(format!("pair{index}-{run}.mcap"));
            let mut episode = Episode::new(&loaded).unwrap();
            let mut sink = crate::log::mcap::McapSink::create(&log, episode.info(), &[]).unwrap();
            episode.run(&mut [&mut sink]).unwrap();
            std::fs::read(&log).unwrap()
        })
        .collect();
    println!("  (c) {} bytes, twice", logs[0].len());
    logs[0] == logs[1]
}

#[test]
fn every_filter_on_every_vehicle_it_accepts_conforms() {
    let bases = bases();
    let filter_kinds: Vec<String> = crate::registry::registry()
        .filter_kinds()
        .into_iter()
        .map(String::from)
        .collect();
    let shipped: Vec<String> = bases.iter().filter_map(|b| b.own_filter.clone()).collect();
    let dir = tempfile::tempdir().unwrap();
    let (mut pairs, mut skipped, mut failed) = (Vec::new(), 0, Vec::new());
    for base in &bases {
        for kind in &filter_kinds {
            let Some(table) = accepted_table(base, kind, &shipped) else {
                skipped += 1;
                continue;
            };
            println!("{} × {table}", base.name);
            let allocated = steady_allocations(base, &table);
            if allocated != 0 {
                failed.push(format!(
                    "{} × {table}: {allocated} allocations after warm-up",
                    base.name
                ));
            }
            for problem in hostile_states(base, &table) {
                failed.push(format!("{} × {table}: {problem}", base.name));
            }
            if !same_bytes_twice(base, &table, dir.path(), pairs.len()) {
                failed.push(format!("{} × {table}: two runs, different logs", base.name));
            }
            pairs.push((base.name.clone(), vehicle_kind(base), kind.clone(), table));
        }
    }
    println!(
        "{} pairs ran ({} bases × {} filter kinds, {skipped} refused)",
        pairs.len(),
        bases.len(),
        filter_kinds.len()
    );
    assert!(failed.is_empty(), "{} failures: {failed:#?}", failed.len());
    // Not vacuous: every shipped scenario's own pair, every vehicle and every filter kind ran.
    for base in &bases {
        if let Some(own) = &base.own_filter {
            assert!(
                pairs
                    .iter()
                    .any(|(name, _, _, table)| name == &base.name && table == own),
                "{}'s own filter {own} did not run",
                base.name
            );
        }
    }
    for kind in crate::vehicle_registry::registry().vehicle_kinds() {
        assert!(
            pairs.iter().any(|(_, v, _, _)| v == kind),
            "no filter ran on vehicle {kind}"
        );
    }
    for kind in &filter_kinds {
        assert!(
            pairs.iter().any(|(_, _, f, _)| f == kind),
            "filter {kind} ran on no vehicle"
        );
    }
}

#[test]
fn the_counter_sees_allocations() {
    // The harness itself: an allocating controller is counted.
    struct Allocating(Vec<f64>);
    impl Controller for Allocating {
        fn input(&mut self, _: u64, _: u32, _: f64, _: &dyn Fn(&mut [f64])) -> &[f64] {
            self.0 = vec![0.0; 2];
            &self.0
        }
    }
    let mut inner = Allocating(Vec::new());
    allocations(true);
    Counted(&mut inner).input(0, 0, 0.0, &|_| {});
    assert_eq!(allocations(false), 1);
}

/// The records a step writes — `/barrier`, `/actors`, the scene's road users, the commands —
/// reuse their buffers, as do the MCAP writer's chunks and indexes: over a second of US101-5
/// (25 recorded box road users, the MCAP sink) the stepping thread allocates less than once
/// per five steps once warm (an event allocates; a box road user's scene entity built anew each
/// frame was several allocations per road user and frame, and each trail segment, realised
/// prediction and chunk index allocated: 703 in 500 steps).
#[test]
fn a_warm_step_of_real_traffic_allocates_almost_nothing() {
    let xml = root().join("data/commonroad/USA_US101-5_1_T-1.xml");
    let loaded = scenario::load(&xml, &["duration=5.0".to_string()]).unwrap();
    let mut episode = Episode::new(&loaded).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("u5.mcap");
    let mut sink = crate::log::mcap::McapSink::create(&log, episode.info(), &[]).unwrap();
    // (Past every road user's first trail segment and a few chunks.)
    for _ in 0..1500 {
        episode.advance(&mut [&mut sink]).unwrap();
    }
    let steps = 500;
    allocations(true);
    count_allocations(true);
    for _ in 0..steps {
        episode.advance(&mut [&mut sink]).unwrap();
    }
    count_allocations(false);
    let counted = allocations(true);
    // (34 here: road users entering or leaving (events), buffers growing to a new largest size;
    // a chunk whose buffers the writer thread has not handed back yet takes fresh ones.)
    assert!(counted < steps / 5, "{counted} allocations in {steps} warm steps");
}
