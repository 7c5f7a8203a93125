//! CommonRoad worlds (docs/commonroad.md): a scenario's `[commonroad]` names a CommonRoad file
//! (read by the `mjsafe-commonroad` crate) and a planning problem, and the file's world fills
//! every key the scenario does not write itself — the ego at the planning problem's start, the
//! recorded road users as obstacles following their recorded states, the route's centre line as
//! the nominal's reference path, delays, the γm filter (4.67) and the recording's duration.

pub mod route;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use mjsafe_commonroad::{CommonRoad, GoalPosition, GoalState, ObstacleRole, PlanningProblem, Shape};
use serde::{Deserialize, Serialize};

/// `[commonroad]`: the CommonRoad file (relative to the scenario file), the planning problem
/// (its id; default the file's first), and the road user that is the ego's own recording (its id,
/// as CommonRoad-CriMe's `ego_id`: left out; one starting exactly at the planning problem's start
/// is left out without it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CommonRoadSpec {
    pub file: PathBuf,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub planning_problem: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ego_obstacle: Option<u64>,
}

/// A vehicle parameter set of CommonRoad (commonroad-vehicle-models): the footprint L × W, the
/// distances a, b from the centre of gravity to the front and rear axles (m), and its limits: the
/// steering lock (rad), the steering rate (rad/s) and the largest acceleration (m/s²).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleParameters {
    pub name: &'static str,
    pub length: f64,
    pub width: f64,
    pub a: f64,
    pub b: f64,
    pub steering_lock: f64,
    pub steering_rate: f64,
    pub max_acceleration: f64,
}

impl VehicleParameters {
    /// The steering lock on the bicycle's steering input u1 = tan δ: tan of the lock angle.
    pub fn steering_input_lock(&self) -> f64 {
        self.steering_lock.tan()
    }
}

/// The ego of a CommonRoad world: CommonRoad's vehicle parameter set 2 (BMW 320i).
pub const VEHICLE: VehicleParameters = VehicleParameters {
    name: "CommonRoad vehicle 2 (BMW 320i)",
    length: 4.508,
    width: 1.61,
    a: 1.1561957064,
    b: 1.4227170936,
    steering_lock: 1.066,
    steering_rate: 0.4,
    max_acceleration: 11.5,
};

/// The `[actuator_dynamics]` tables that put `vehicle`'s limits on a CommonRoad world's car
/// without its filter knowing of them (docs/studies.md, "Real traffic"): the lock on u1 = tan δ,
/// the steering rate as a rate on tan δ (its rate at δ = 0, stricter than the car's at larger
/// angles), |u2| within the largest acceleration.
pub fn limits_toml(vehicle: &VehicleParameters) -> String {
    let lock = vehicle.steering_input_lock();
    format!(
        "[actuator_dynamics.steering]\nmin = {:?}\nmax = {lock:?}\nrate_limit = {:?}\n\n\
         [actuator_dynamics.acceleration]\nmin = {:?}\nmax = {:?}\n",
        -lock, vehicle.steering_rate, -vehicle.max_acceleration, vehicle.max_acceleration
    )
}

/// `vehicle`'s limits as a `[vehicle_limits]` table (declared for the analysis, not enforced):
/// the lock on u1 = tan δ and the largest acceleration.
fn limits(vehicle: &VehicleParameters) -> toml::Value {
    let mut t = toml::Table::new();
    t.insert("steering".into(), toml::Value::Float(vehicle.steering_input_lock()));
    t.insert("acceleration".into(), toml::Value::Float(vehicle.max_acceleration));
    toml::Value::Table(t)
}

/// The default delays (s) of a CommonRoad world: steering, acceleration.
pub const DELAYS: (f64, f64) = (0.2, 0.5);

/// The control period of a CommonRoad world (s).
pub const CONTROL_PERIOD: f64 = 0.01;

/// How often the controller observes the road users (`actor_knowledge.period`, s): when they were
/// recorded, every time step `dt` of the file, so that it knows the recorded states and nothing
/// between them (docs/commonroad.md); a step that is not a whole number of control periods is
/// observed at the largest one below it (at least one period).
pub fn observation_period(dt: f64) -> f64 {
    let ticks = (dt / CONTROL_PERIOD + 1e-9).floor().max(1.0);
    match (ticks * CONTROL_PERIOD - dt).abs() < 1e-12 {
        true => dt,
        false => ticks * CONTROL_PERIOD,
    }
}

/// The model a CommonRoad world's ego runs on (built in: [`crate::models`]).
pub const MODEL: &str = "mjsafe:commonroad_car.xml";

type Cache = Mutex<HashMap<PathBuf, (u64, std::time::SystemTime, Arc<CommonRoad>)>>;

/// Reads a CommonRoad file (once per file and modification: sweeps and falsification read the
/// same file for every run).
pub fn read(path: &Path) -> Result<Arc<CommonRoad>, String> {
    static CACHE: std::sync::OnceLock<Cache> = std::sync::OnceLock::new();
    let meta = std::fs::metadata(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let stamp = (meta.len(), meta.modified().unwrap_or(std::time::UNIX_EPOCH));
    let cache = CACHE.get_or_init(Default::default);
    if let Some((len, modified, cr)) = cache.lock().unwrap_or_else(|e| e.into_inner()).get(path) {
        if (*len, *modified) == stamp {
            return Ok(cr.clone());
        }
    }
    let cr = Arc::new(mjsafe_commonroad::read_file(path).map_err(|e| e.to_string())?);
    let mut cache = cache.lock().unwrap_or_else(|e| e.into_inner());
    if cache.len() >= 64 {
        cache.clear();
    }
    cache.insert(path.to_path_buf(), (stamp.0, stamp.1, cr.clone()));
    Ok(cr)
}

/// The world of `spec` (its file read relative to `dir`): the file as read and the scenario
/// keys of its planning problem; an error is (the key, what was expected).
pub fn defaults(spec: &CommonRoadSpec, dir: &Path) -> Result<(Arc<CommonRoad>, toml::Table), (String, String)> {
    let cr = read(&dir.join(&spec.file)).map_err(|e| ("commonroad.file".to_string(), e))?;
    let problem = cr
        .planning_problem(spec.planning_problem)
        .map_err(|e| ("commonroad.planning_problem".to_string(), e.to_string()))?;
    if let Some(id) = spec.ego_obstacle {
        if cr.obstacle(id).is_none_or(|o| o.role != ObstacleRole::Dynamic) {
            let message = format!("expected the id of a dynamic road user of {}, found {id}", cr.file);
            return Err(("commonroad.ego_obstacle".to_string(), message));
        }
    }
    let defaults = world(&cr, problem, spec.ego_obstacle).map_err(|e| ("commonroad".to_string(), e))?;
    Ok((cr, defaults))
}

/// Fills `table` (a scenario's TOML) with `defaults` where it is silent (key by key); a filter's
/// or nominal's `kind` one of `overrides` sets (`filter.kind=cbf_qp`) replaces that default table
/// whole, as one the scenario writes does.
pub fn fill(table: &mut toml::Table, mut defaults: toml::Table, overrides: &[String]) {
    for spec in overrides {
        let Some((key, _)) = spec.split_once('=') else { continue };
        if let Some(section) = key.trim().strip_suffix(".kind") {
            if ["filter", "nominal"].contains(&section) && table.get(section).and_then(|t| t.get("kind")).is_none() {
                defaults.remove(section);
            }
        }
    }
    merge(table, defaults);
}

/// Puts each key of `defaults` into `table` where it is absent; a table the scenario writes
/// merges key by key, unless it names its own `kind` (a filter, nominal or vehicle of another
/// kind replaces the default whole).
fn merge(table: &mut toml::Table, defaults: toml::Table) {
    for (key, default) in defaults {
        match (table.get_mut(&key), default) {
            (None, default) => {
                table.insert(key, default);
            }
            (Some(toml::Value::Table(own)), toml::Value::Table(default)) => {
                let other_kind = own.get("kind").is_some_and(|k| Some(k) != default.get("kind"));
                if !other_kind {
                    merge(own, default);
                }
            }
            (Some(_), _) => {}
        }
    }
}

/// The world of planning problem `problem` as scenario keys; `ego` the road user that is the ego's
/// own recording, if the scenario names one.
pub fn world(cr: &CommonRoad, problem: &PlanningProblem, ego: Option<u64>) -> Result<toml::Table, String> {
    let dt = cr.time_step;
    let start = problem.initial;
    let speed = start.velocity.unwrap_or(0.0);
    // CommonRoad's position is the vehicle's centre; the bicycle's is its rear axle, b behind.
    let (s, c) = start.orientation.sin_cos();
    let rear = [start.position[0] - VEHICLE.b * c, start.position[1] - VEHICLE.b * s];
    let route = ego_route(cr, problem)?;
    // (route before the road edges below: both follow it.)
    let goal_speed = problem
        .goals
        .iter()
        .find_map(|g| g.velocity)
        .map(|(lo, hi)| 0.5 * (lo + hi));
    let reference_speed = goal_speed.unwrap_or(speed).max(1.0);
    let steps = cr.duration_steps().max(
        problem
            .goals
            .iter()
            .map(|g| g.time_steps.1.max(0) as u64)
            .max()
            .unwrap_or(0),
    );
    let duration = (steps.max(1) as f64) * dt;
    let mut t = toml::Table::new();
    let v = |x: f64| toml::Value::Float(x);
    let point = |p: [f64; 2]| toml::Value::Array(vec![v(p[0]), v(p[1])]);
    t.insert(
        "name".into(),
        toml::Value::String(cr.benchmark_id.replace(['/', '\\'], "_")),
    );
    t.insert(
        "description".into(),
        toml::Value::String(format!(
            "CommonRoad {} ({}), planning problem {}; route over lanelets {}",
            cr.benchmark_id,
            cr.source,
            problem.id,
            route.lanelets.iter().map(u64::to_string).collect::<Vec<_>>().join(", ")
        )),
    );
    t.insert("duration".into(), v(duration));
    t.insert(
        "vehicle".into(),
        toml::Value::Table(vehicle(rear, start.orientation, speed)),
    );
    t.insert(
        "delays".into(),
        table(&[("steering", v(DELAYS.0)), ("acceleration", v(DELAYS.1))]),
    );
    t.insert(
        "initial_input".into(),
        table(&[("steering", v(0.0)), ("acceleration", v(0.0))]),
    );
    t.insert("vehicle_limits".into(), limits(&VEHICLE));
    t.insert("control".into(), table(&[("period", v(CONTROL_PERIOD))]));
    let path: Vec<toml::Value> = route.centre.iter().map(|p| point(*p)).collect();
    t.insert(
        "nominal".into(),
        table(&[
            ("kind", toml::Value::String("route".into())),
            ("speed", v(reference_speed)),
            ("path", toml::Value::Array(path)),
        ]),
    );
    t.insert(
        "filter".into(),
        table(&[
            ("kind", toml::Value::String("gamma_m".into())),
            ("l0", v(4.0)),
            ("l1", v(4.0)),
            ("m", v(50.0)),
        ]),
    );
    t.insert(
        "actor_knowledge".into(),
        table(&[
            ("kind", toml::Value::String("constant_velocity".into())),
            ("period", v(observation_period(dt))),
        ]),
    );
    if let Some(goal) = goal(cr, problem) {
        t.insert("goal".into(), toml::Value::Table(goal));
    }
    let (road, mut omitted) = road(cr, &route, rear, start.orientation);
    // The ego's own recording: listed under the planning problem's id, or (as CommonRoad-CriMe's
    // files do, with its `ego_id`) a road user starting exactly at the planning problem's start.
    let own_recording = |o: &&mjsafe_commonroad::Obstacle| {
        o.id == problem.id
            || Some(o.id) == ego
            || (o.role == ObstacleRole::Dynamic
                && o.states.first().is_some_and(|s| {
                    (s.time_step, s.position, s.orientation) == (start.time_step, start.position, start.orientation)
                }))
    };
    for o in cr.obstacles.iter().filter(own_recording).filter(|o| o.id != problem.id) {
        let why = match Some(o.id) == ego {
            true => "commonroad.ego_obstacle names it",
            false => "it starts at the planning problem's initial state",
        };
        omitted.push(format!("road user {} left out: {why} (the ego's own recording)", o.id));
    }
    if let Some(road) = road {
        t.insert("road".into(), toml::Value::Table(road));
    }
    if !omitted.is_empty() {
        let description = format!(
            "{}; {}",
            t["description"].as_str().unwrap_or_default(),
            omitted.join("; ")
        );
        t.insert("description".into(), toml::Value::String(description));
    }
    let obstacles = (cr.obstacles.iter().filter(|o| !own_recording(o)))
        .filter_map(obstacle)
        .collect::<Result<Vec<_>, String>>()?;
    t.insert("obstacles".into(), toml::Value::Array(obstacles));
    Ok(t)
}

fn table(entries: &[(&str, toml::Value)]) -> toml::Value {
    toml::Value::Table(entries.iter().map(|(k, v)| (k.to_string(), v.clone())).collect())
}

/// `[goal]`: the planning problem's goal region — its rectangles and polygons, its lanelets'
/// polygons, its circles (a single circle as the disc itself, circles among other shapes as
/// inscribed 64-gons) — within its time interval (steps × time step); without a position, its
/// time window, speed and heading alone (a goal of a time alone is reached by lasting into its
/// window). Goal states that differ in more than their regions are `states` too (any one of
/// them, whole, reaches the goal; the table's own region, window and intervals are their union
/// and hulls). None when nothing is asked at all.
fn goal(cr: &CommonRoad, problem: &PlanningProblem) -> Option<toml::Table> {
    let goals: Vec<&GoalState> = problem.goals.iter().collect();
    // CommonRoad's goal is for the car's centre, b ahead of the bicycle's rear axle.
    let offset = goals.iter().any(|g| g.position.is_some()).then_some(VEHICLE.b);
    let mut t = goal_table(cr, &goals, offset);
    if problem.goal_states_differ() {
        let states = goals.iter().map(|g| {
            let mut state = goal_table(cr, &[g], None);
            // (Every state asks something: from its window's start on, 0 included.)
            if !state.contains_key("after") {
                state.insert("after".into(), toml::Value::Float(g.time_steps.0 as f64 * cr.time_step));
            }
            toml::Value::Table(state)
        });
        t.insert("states".into(), toml::Value::Array(states.collect()));
    }
    // A goal of a time alone is reached by lasting into its window, as commonroad-io's
    // `GoalRegion.is_reached` decides it; nothing at all to ask: no goal.
    let asks = ["position", "polygons", "after", "by", "speed", "heading", "states"];
    asks.iter().any(|k| t.contains_key(*k)).then_some(t)
}

/// The `[goal]` keys of these goal states: their region (the union, when every one has a
/// position), `after`, `offset` (if given), their speed and heading intervals' hulls (when every
/// one has one) and `by`.
fn goal_table(cr: &CommonRoad, goals: &[&GoalState], offset: Option<f64>) -> toml::Table {
    let v = toml::Value::Float;
    let point = |p: [f64; 2]| toml::Value::Array(vec![v(p[0]), v(p[1])]);
    let mut t = toml::Table::new();
    let shapes: Vec<&Shape> = (goals.iter())
        .filter_map(|g| match &g.position {
            Some(GoalPosition::Shapes(shapes)) => Some(shapes.iter()),
            _ => None,
        })
        .flatten()
        .collect();
    let mut lanelets: Vec<u64> = Vec::new();
    // (Each lanelet once, in the order the goal states name them: several may share one.)
    for id in goals
        .iter()
        .filter_map(|g| match &g.position {
            Some(GoalPosition::Lanelets(ids)) => Some(ids.iter().copied()),
            _ => None,
        })
        .flatten()
    {
        if !lanelets.contains(&id) {
            lanelets.push(id);
        }
    }
    // (A goal state without a position is met anywhere: then the union has no region.)
    let everywhere = goals.iter().any(|g| g.position.is_none());
    if let ([Shape::Circle { radius, center }], true, false) = (shapes.as_slice(), lanelets.is_empty(), everywhere) {
        t.insert("position".into(), point(*center));
        t.insert("radius".into(), v(*radius));
    } else if !everywhere {
        let mut polygons: Vec<Vec<[f64; 2]>> = shapes.iter().map(|s| shape_polygon(s)).collect();
        polygons.extend(lanelets.iter().filter_map(|id| cr.lanelet(*id)).map(route::polygon));
        if !polygons.is_empty() {
            let polygons = polygons
                .into_iter()
                .map(|p| toml::Value::Array(p.into_iter().map(point).collect()));
            t.insert("polygons".into(), toml::Value::Array(polygons.collect()));
        }
    }
    let (start, end) = (goals.iter())
        .map(|g| g.time_steps)
        .fold((i64::MAX, i64::MIN), |(a, b), (s, e)| (a.min(s), b.max(e)));
    if start > 0 {
        t.insert("after".into(), v(start as f64 * cr.time_step));
    }
    if let Some(offset) = offset {
        t.insert("offset".into(), v(offset));
    }
    // The velocity and orientation intervals, when every goal state has one (their hull).
    let hull = |intervals: Vec<Option<(f64, f64)>>| -> Option<toml::Value> {
        let all: Option<Vec<(f64, f64)>> = intervals.into_iter().collect();
        let (lo, hi) = all?
            .into_iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), (l, h)| {
                (a.min(l), b.max(h))
            });
        Some(toml::Value::Array(vec![v(lo), v(hi)]))
    };
    if let Some(speed) = hull(goals.iter().map(|g| g.velocity).collect()) {
        t.insert("speed".into(), speed);
    }
    if let Some(heading) = hull(goals.iter().map(|g| g.orientation).collect()) {
        t.insert("heading".into(), heading);
    }
    if end > 0 {
        t.insert("by".into(), v(end as f64 * cr.time_step));
    }
    t
}

/// The largest deviation (m) of a road edge's smooth curve from its polyline that a world
/// keeps as a barrier: beyond it the outer bounds do not join up (a merge, a split), and the
/// margin would take the road away.
pub const MAX_EDGE_DEVIATION: f64 = 0.5;

/// `[road]`: the route's road edges ([`route::road_edges`]) as polyline edges, the road on
/// their inner side; an edge whose smooth curve deviates more than [`MAX_EDGE_DEVIATION`]
/// from its polyline, or that the ego's footprint would start beyond, is left out, the reason
/// returned (it goes into the scenario's description).
fn road(cr: &CommonRoad, route: &route::Route, rear: [f64; 2], heading: f64) -> (Option<toml::Table>, Vec<String>) {
    let (left, right) = route::road_edges(cr, &route.lanelets);
    let v = toml::Value::Float;
    let mut edges = Vec::new();
    let mut omitted = Vec::new();
    let footprint = crate::footprint::Rectangle {
        length: VEHICLE.length,
        width: VEHICLE.width,
        circles: None,
        offset: VEHICLE.b,
    };
    for (name, points, side, road_side) in [("road_left", left, -1.0, "right"), ("road_right", right, 1.0, "left")] {
        let Ok(curve) = crate::barrier::curve::SmoothCurve::new(&points) else {
            omitted.push(format!("{name} left out: fewer than 2 distinct points"));
            continue;
        };
        if curve.deviation() > MAX_EDGE_DEVIATION {
            omitted.push(format!(
                "{name} left out: its smooth curve deviates {:.2} m from the lanelet bounds (more than {MAX_EDGE_DEVIATION} m: they do not join up)",
                curve.deviation()
            ));
            continue;
        }
        // Every covering circle of the footprint starts on the road side.
        let clear = footprint.circles().iter().all(|c| {
            let q = crate::footprint::rotate(c.offset, heading);
            let q = [rear[0] + q[0], rear[1] + q[1]];
            side * curve.nearest(q).distance - c.radius - curve.deviation() >= 0.0
        });
        if !clear {
            omitted.push(format!("{name} left out: the ego's footprint starts beyond it"));
            continue;
        }
        let point = |p: &[f64; 2]| toml::Value::Array(vec![v(p[0]), v(p[1])]);
        edges.push(table(&[
            ("kind", toml::Value::String("polyline".into())),
            ("name", toml::Value::String(name.into())),
            ("points", toml::Value::Array(points.iter().map(point).collect())),
            ("road", toml::Value::String(road_side.into())),
        ]));
    }
    if edges.is_empty() {
        return (None, omitted);
    }
    (
        Some(toml::Table::from_iter([(
            "edges".to_string(),
            toml::Value::Array(edges),
        )])),
        omitted,
    )
}

/// A goal shape as a polygon: a rectangle's corners, a polygon's points, a circle's inscribed
/// 64-gon.
fn shape_polygon(shape: &Shape) -> Vec<[f64; 2]> {
    match shape {
        Shape::Rectangle {
            length,
            width,
            orientation,
            center,
        } => {
            let (s, c) = orientation.sin_cos();
            [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
                .iter()
                .map(|(a, b)| {
                    let (x, y) = (0.5 * length * a, 0.5 * width * b);
                    [center[0] + c * x - s * y, center[1] + s * x + c * y]
                })
                .collect()
        }
        Shape::Polygon { points } => points.clone(),
        Shape::Circle { radius, center } => (0..64)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 64.0;
                [center[0] + radius * a.cos(), center[1] + radius * a.sin()]
            })
            .collect(),
    }
}

/// `[vehicle]`: the car-sized bicycle at its rear axle `rear`, heading and speed.
fn vehicle(rear: [f64; 2], heading: f64, speed: f64) -> toml::Table {
    let v = toml::Value::Float;
    let mut t = toml::Table::new();
    t.insert("kind".into(), toml::Value::String("bicycle".into()));
    t.insert("model".into(), toml::Value::String(MODEL.into()));
    t.insert(
        "initial_state".into(),
        toml::Value::Array(vec![v(rear[0]), v(rear[1]), v(heading), v(speed)]),
    );
    let footprint = table(&[
        ("length", v(VEHICLE.length)),
        ("width", v(VEHICLE.width)),
        ("offset", v(VEHICLE.b)),
    ]);
    t.insert("footprint".into(), footprint);
    t
}

/// The ego's route: from the lanelet its start lies in to a goal lanelet (the goal's lanelets,
/// or those its goal shapes' centres lie in), or along successors without a goal position.
pub fn ego_route(cr: &CommonRoad, problem: &PlanningProblem) -> Result<route::Route, String> {
    let start = problem.initial;
    let starts = route::lanelets_at(cr, start.position, start.orientation);
    if starts.is_empty() {
        return Err(format!(
            "planning problem {}: its start ({}, {}) lies in no lanelet driving its way",
            problem.id, start.position[0], start.position[1]
        ));
    }
    let mut goals: Vec<u64> = Vec::new();
    for g in &problem.goals {
        match &g.position {
            Some(GoalPosition::Lanelets(ids)) => goals.extend(ids),
            Some(GoalPosition::Shapes(shapes)) => {
                for shape in shapes {
                    let heading = g.orientation.map_or(start.orientation, |(lo, hi)| 0.5 * (lo + hi));
                    goals.extend(route::lanelets_at(cr, shape.center(), heading));
                }
            }
            None => {}
        }
    }
    // From the best aligned lanelet the start lies in that has a route (overlapping lanelets
    // at a junction: the one leading to the goal).
    let lanelets = starts.iter().find_map(|&first| route::plan(cr, first, &goals)).ok_or_else(|| {
        format!(
            "planning problem {}: no route from lanelet {starts:?} to a goal lanelet ({goals:?}) over successors and same-direction neighbours",
            problem.id
        )
    })?;
    let centre = route::centre_of(cr, &lanelets);
    if centre.len() < 2 {
        return Err(format!(
            "planning problem {}: the route's centre line has fewer than 2 points",
            problem.id
        ));
    }
    Ok(route::Route { lanelets, centre })
}

/// An obstacle entry of a road user: a rectangle as a box at its heading, a circle, a polygon
/// as the box around it along its longest edge (covering it); dynamic ones follow their
/// recording (`recorded`), static ones stand. None for a road user without a shape or state.
fn obstacle(o: &mjsafe_commonroad::Obstacle) -> Option<Result<toml::Value, String>> {
    let (shape, first) = (o.shapes.first()?, o.states.first()?);
    let v = toml::Value::Float;
    let mut t = toml::Table::new();
    t.insert("name".into(), toml::Value::String(format!("cr_{}", o.id)));
    let (s, c) = first.orientation.sin_cos();
    let local = local_centre(shape);
    let centre = [
        first.position[0] + c * local[0] - s * local[1],
        first.position[1] + s * local[0] + c * local[1],
    ];
    t.insert("centre".into(), toml::Value::Array(vec![v(centre[0]), v(centre[1])]));
    let boxed = |length: f64, width: f64, heading: f64| {
        table(&[
            ("kind", toml::Value::String("box".into())),
            ("length", v(length)),
            ("width", v(width)),
            ("heading", v(heading)),
        ])
    };
    match shape {
        Shape::Rectangle {
            length,
            width,
            orientation,
            ..
        } => {
            t.insert("shape".into(), boxed(*length, *width, first.orientation + orientation));
        }
        Shape::Circle { radius, .. } => {
            t.insert("radius".into(), v(*radius));
        }
        Shape::Polygon { points } => {
            let (length, width, heading, _) = bounding_box(points);
            t.insert("shape".into(), boxed(length, width, first.orientation + heading));
        }
    }
    if o.role == ObstacleRole::Dynamic {
        let motion = table(&[
            ("kind", toml::Value::String("recorded".into())),
            ("id", toml::Value::Integer(o.id as i64)),
        ]);
        t.insert("motion".into(), motion);
    }
    Some(Ok(toml::Value::Table(t)))
}

/// The centre of a road user's shape in its own frame (a polygon's: its bounding box's).
fn local_centre(shape: &Shape) -> [f64; 2] {
    match shape {
        Shape::Polygon { points } => bounding_box(points).3,
        _ => shape.center(),
    }
}

/// The rectangle around a polygon along its longest edge: length, width, heading, centre offset.
fn bounding_box(points: &[[f64; 2]]) -> (f64, f64, f64, [f64; 2]) {
    let n = points.len();
    let edge = (0..n)
        .max_by(|&a, &b| {
            let l = |k: usize| {
                let (p, q) = (points[k], points[(k + 1) % n]);
                (q[0] - p[0]).hypot(q[1] - p[1])
            };
            l(a).total_cmp(&l(b))
        })
        .unwrap_or(0);
    let (p, q) = (points[edge], points[(edge + 1) % n]);
    let heading = (q[1] - p[1]).atan2(q[0] - p[0]);
    let (s, c) = heading.sin_cos();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points {
        let local = [c * p[0] + s * p[1], -s * p[0] + c * p[1]];
        for k in 0..2 {
            lo[k] = lo[k].min(local[k]);
            hi[k] = hi[k].max(local[k]);
        }
    }
    let mid = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
    (
        (hi[0] - lo[0]).max(1e-3),
        (hi[1] - lo[1]).max(1e-3),
        heading,
        [c * mid[0] - s * mid[1], s * mid[0] + c * mid[1]],
    )
}

/// `kind = "recorded"`'s parameters (`[obstacles.motion]`): the road user of `[commonroad] file`
/// whose recorded states the obstacle follows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordedParams {
    /// Its `obstacle id` in the file.
    pub id: u64,
}

impl crate::params::Params for RecordedParams {}

/// `kind = "recorded"`: the road user `id` of the scenario's CommonRoad file along its recording
/// (docs/commonroad.md).
pub fn build_recorded(
    p: &RecordedParams,
    ctx: &crate::actor::MotionContext<'_>,
) -> Result<crate::actor::ActorMotion, crate::actor::MotionError> {
    let Some(cr) = ctx.commonroad else {
        return Err(crate::actor::motion_error(
            "id",
            "expected a `[commonroad] file` whose road user it names",
        ));
    };
    let motion = recorded_motion(cr, p.id).map_err(|e| crate::actor::motion_error("id", e))?;
    Ok(crate::actor::ActorMotion::new(Arc::new(motion)))
}

/// The recorded motion of road user `id`: its states at their times (step × time step), the
/// position of its shape's centre.
pub fn recorded_motion(cr: &CommonRoad, id: u64) -> Result<crate::actor::RecordedMotion, String> {
    let Some(o) = cr.obstacle(id).filter(|o| o.role == ObstacleRole::Dynamic) else {
        return Err(format!(
            "expected the id of a dynamic road user of {}, found {id}",
            cr.file
        ));
    };
    let local = o.shapes.first().map_or([0.0; 2], local_centre);
    let states: Vec<crate::actor::RecordedState> = o
        .states
        .iter()
        .map(|s| {
            let (sn, cs) = s.orientation.sin_cos();
            crate::actor::RecordedState {
                time: s.time_step as f64 * cr.time_step,
                position: [
                    s.position[0] + cs * local[0] - sn * local[1],
                    s.position[1] + sn * local[0] + cs * local[1],
                ],
                orientation: s.orientation,
            }
        })
        .collect();
    crate::actor::RecordedMotion::new(&states).map_err(|e| format!("road user {id}: {}", e.message))
}

/// A lanelet bound to draw: its entity id, its points (a dashed one's as pairs, each a dash's
/// ends), whether it is dashed.
pub type DrawnBound = (String, Vec<[f64; 2]>, bool);

/// Most lanelets drawn.
pub const MAX_DRAWN_LANELETS: usize = 2000;

/// The bounds of the lanelets near the points `around` (within 20 m of their
/// bounding box), to draw: `road/lanelet/<id>/left|right` solid, or, for a dashed line marking
/// (`dashed`, `broad_dashed`, `dashed_dashed`), `road/lane/lanelet_<id>_left|right` as dashes of
/// 3 m every 6 m.
pub fn lanelet_lines(cr: &CommonRoad, around: &[[f64; 2]]) -> Vec<DrawnBound> {
    const DRAW_MARGIN: f64 = 20.0;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in around {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k] - DRAW_MARGIN);
            hi[k] = hi[k].max(p[k] + DRAW_MARGIN);
        }
    }
    let near = |points: &[[f64; 2]]| points.iter().any(|p| (0..2).all(|k| (lo[k]..=hi[k]).contains(&p[k])));
    let mut out = Vec::new();
    for l in cr
        .lanelets
        .iter()
        .filter(|l| near(&l.left.points) || near(&l.right.points))
        .take(MAX_DRAWN_LANELETS)
    {
        for (side, bound) in [("left", &l.left), ("right", &l.right)] {
            let dashed = bound.marking.as_deref().is_some_and(|m| m.contains("dashed"));
            out.push(match dashed {
                true => (
                    format!("road/lane/lanelet_{}_{side}", l.id),
                    dashes(&bound.points, 3.0),
                    true,
                ),
                false => (format!("road/lanelet/{}/{side}", l.id), bound.points.clone(), false),
            });
        }
    }
    out
}

/// A polyline as dashes of length `dash` every 2 `dash` along it: point pairs.
fn dashes(points: &[[f64; 2]], dash: f64) -> Vec<[f64; 2]> {
    let mut out = Vec::new();
    let mut s = 0.0; // arc length at the current segment's start
    for w in points.windows(2) {
        let (a, b) = (w[0], w[1]);
        let l = (b[0] - a[0]).hypot(b[1] - a[1]);
        if l <= 0.0 {
            continue;
        }
        let at = |t: f64| {
            let f = ((t - s) / l).clamp(0.0, 1.0);
            [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])]
        };
        // The dashes starting on this segment: at multiples of 2 dash (clipped to the segment).
        let mut start = (s / (2.0 * dash)).ceil() * 2.0 * dash;
        while start < s + l {
            out.push(at(start));
            out.push(at((start + dash).min(s + l)));
            start += 2.0 * dash;
        }
        s += l;
    }
    out
}

/// The text of a scenario that is the world of CommonRoad file `xml` with every default (what
/// `mjsafe run FILE.xml` runs, read as if it were a scenario file beside the XML).
pub fn scenario_text(xml: &Path, planning_problem: Option<u64>) -> String {
    let name = xml
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let mut text = format!("[commonroad]\nfile = {}\n", toml::Value::String(name));
    if let Some(id) = planning_problem {
        text.push_str(&format!("planning_problem = {id}\n"));
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("data/commonroad").join(name)
    }

    /// The road users are observed at the file's own step when it is a whole number of control
    /// periods (0.1, 0.2 and 0.04 s among the committed files), else at the largest such below.
    #[test]
    fn the_road_users_are_observed_when_they_were_recorded() {
        for (dt, period) in [
            (0.1, 0.1),
            (0.2, 0.2),
            (0.04, 0.04),
            (0.025, 0.02),
            (0.005, 0.01),
            (1.0, 1.0),
        ] {
            assert_eq!(observation_period(dt), period, "dt {dt}");
        }
        let cr = read(&data("USA_US101-4_1_T-1.xml")).unwrap();
        let t = world(&cr, cr.planning_problem(None).unwrap(), None).unwrap();
        assert_eq!(t["actor_knowledge"]["period"].as_float(), Some(cr.time_step));
    }

    /// US101-4: the ego starts at the planning problem's centre (0, 0) less b along its
    /// heading; its route reaches the lanelet the goal rectangle's centre lies in.
    #[test]
    fn the_world_of_us101_4() {
        let cr = read(&data("USA_US101-4_1_T-1.xml")).unwrap();
        let problem = cr.planning_problem(None).unwrap();
        let t = world(&cr, problem, None).unwrap();
        let x0 = t["vehicle"]["initial_state"].as_array().unwrap();
        let theta = -0.76501_f64;
        assert!((x0[0].as_float().unwrap() + VEHICLE.b * theta.cos()).abs() < 1e-12);
        assert!((x0[1].as_float().unwrap() + VEHICLE.b * theta.sin()).abs() < 1e-12);
        assert_eq!(t["obstacles"].as_array().unwrap().len(), 22);
        let route = ego_route(&cr, problem).unwrap();
        let goal = route::lanelets_at(&cr, [17.836, -17.2178], -0.72);
        assert!(goal.iter().any(|g| route.lanelets.contains(g)), "{route:?} {goal:?}");
        assert!(
            (t["duration"].as_float().unwrap() - 10.0).abs() < 1e-9,
            "{}",
            t["duration"]
        );
    }

    /// A road user starting exactly at the planning problem's start is the ego's own recording
    /// (CommonRoad-CriMe's files list it, with an `ego_id`): left out, and named. One a
    /// millimetre away stays.
    #[test]
    fn the_egos_own_recording_is_left_out_and_named() {
        let mut cr = (*read(&data("USA_US101-4_1_T-1.xml")).unwrap()).clone();
        let start = cr.planning_problem(None).unwrap().initial;
        let recorded = |cr: &CommonRoad, id: u64| {
            let t = world(cr, cr.planning_problem(None).unwrap(), None).unwrap();
            let name = format!("cr_{id}");
            let listed = (t["obstacles"].as_array().unwrap().iter()).any(|o| o["name"].as_str() == Some(name.as_str()));
            let named = t["description"].as_str().unwrap().contains(&format!(
                "road user {id} left out: it starts at the planning problem's initial state"
            ));
            (listed, named)
        };
        let first = &mut cr.obstacles.iter_mut().find(|o| o.id == 373).unwrap().states[0];
        (first.position, first.orientation) = (start.position, start.orientation);
        assert_eq!(recorded(&cr, 373), (false, true));
        let first = &mut cr.obstacles.iter_mut().find(|o| o.id == 373).unwrap().states[0];
        first.position[0] += 1e-3;
        assert_eq!(recorded(&cr, 373), (true, false));
    }

    /// Every committed file gives a world (a route from its start).
    #[test]
    fn every_committed_file_gives_a_world() {
        for entry in std::fs::read_dir(data("")).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "xml") {
                let cr = read(&path).unwrap();
                let problem = cr.planning_problem(None).unwrap();
                world(&cr, problem, None).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            }
        }
    }

    /// Recorded positions are the file's at every step (the shape's centre at the origin).
    #[test]
    fn recorded_motion_is_the_file_at_every_step() {
        let cr = read(&data("USA_US101-4_1_T-1.xml")).unwrap();
        let o = cr.obstacle(373).unwrap();
        let m = recorded_motion(&cr, 373).unwrap();
        for s in &o.states {
            let at = m.state_at(s.time_step as f64 * cr.time_step);
            assert!((at.position[0] - s.position[0]).abs() < 1e-9 && (at.position[1] - s.position[1]).abs() < 1e-9);
        }
    }

    #[test]
    fn a_polygon_gets_the_box_around_it() {
        let (l, w, heading, mid) = bounding_box(&[[0.0, 0.0], [4.0, 0.0], [4.0, 2.0], [0.0, 2.0]]);
        // Along a long side (either direction), covering the rectangle exactly.
        assert!((l - 4.0).abs() < 1e-12 && (w - 2.0).abs() < 1e-12 && heading.sin().abs() < 1e-12);
        assert!((mid[0] - 2.0).abs() < 1e-12 && (mid[1] - 1.0).abs() < 1e-12, "{mid:?}");
    }
}
