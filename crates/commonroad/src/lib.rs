//! A bounded, pure-Rust reader for CommonRoad XML scenarios (format versions 2020a and 2018b).
//!
//! CommonRoad (<https://commonroad.in.tum.de>, schema `XML_commonRoad_XSD.xsd` in
//! CommonRoad/commonroad-io) describes a road network of lanelets, the obstacles around it (static
//! ones, and dynamic ones with a recorded trajectory of integer time steps of `timeStepSize`
//! seconds) and one or more planning problems (an ego initial state and goal regions).
//!
//! [`read_file`] and [`parse`] turn such a file into a [`CommonRoad`] value and check it on the way:
//! unique ids, resolvable `@ref`s, finite and bounded numbers, trajectories of consecutive time steps,
//! and hard limits on the file size, nesting depth, node count and element counts (`MAX_*`), so that
//! a hostile file costs bounded time and memory. Every error is a [`ReadError`] whose `Display` is one
//! line naming the file and the element (`FILE: lanelet 12 / leftBound / point 3: ...`).
//!
//! What the reader does not use (traffic signs and lights, intersections, phantom and environment
//! obstacles, z coordinates, unknown elements, ...) is counted in [`CommonRoad::ignored`] and
//! summarised by [`CommonRoad::ignored_line`], never dropped silently. Set-valued (interval or shape)
//! state values are reduced to their midpoint or centre and counted in
//! [`CommonRoad::uncertain_states`] (see [`CommonRoad::notes`]).
//!
//! Reading rules follow commonroad-io's Python reader: 2018b files (`<obstacle>` with
//! `<role>static|dynamic</role>`, `<speedLimit>` in lanelets, scenario tags in the root's `tags`
//! attribute) are read alongside 2020a files. One deliberate difference from the 2020a schema's id
//! key: planning-problem ids form their own namespace, because real scenarios (the OpenSCENARIO
//! conversions in commonroad-crime) give the planning problem the id of the ego's dynamic obstacle,
//! and commonroad-io accepts them.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

mod check;
mod error;
mod read;

#[cfg(test)]
mod tests;

pub use error::ReadError;
pub use read::{parse, parse_with, read_file, read_file_with};

/// Largest file [`read_file`] and [`parse`] accept, in bytes (64 MiB).
pub const MAX_FILE_BYTES: u64 = 64 * 1024 * 1024;
/// Most XML nodes (elements, text including whitespace, comments...) the parser builds before giving
/// up: this bounds the DOM's memory. A real 1.2 MB scenario has about 106 k nodes, so the limit admits
/// about 70 MB of typical CommonRoad text (the [`MAX_FILE_BYTES`] cap comes first).
pub const MAX_XML_NODES: u32 = 6_000_000;
/// Deepest element nesting accepted (a CommonRoad document needs about 10 levels).
pub const MAX_DEPTH: usize = 64;
/// Most points in one lanelet bound or polygon.
pub const MAX_BOUND_POINTS: usize = 10_000;
/// Most points read over the whole file (bounds, polygons, centres and positions).
pub const MAX_TOTAL_POINTS: usize = 2_000_000;
/// Most lanelets in a file.
pub const MAX_LANELETS: usize = 20_000;
/// Most obstacles (static and dynamic, including ones only counted as ignored) in a file.
pub const MAX_OBSTACLES: usize = 10_000;
/// Most states (initial state included) of one obstacle.
pub const MAX_STATES: usize = 100_000;
/// Largest magnitude of any coordinate or value (m, m/s, m/s², rad, rad/s, time steps).
pub const MAX_ABS_VALUE: f64 = 1e7;
/// Largest accepted `timeStepSize`, in seconds.
pub const MAX_TIME_STEP: f64 = 10.0;

/// The limits a read enforces. [`Limits::default`] holds the `MAX_*` constants, which [`read_file`]
/// and [`parse`] use; [`read_file_with`] and [`parse_with`] take others (e.g. tighter ones).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest file or text, in bytes ([`MAX_FILE_BYTES`]).
    pub max_file_bytes: u64,
    /// Most XML nodes ([`MAX_XML_NODES`]).
    pub max_xml_nodes: u32,
    /// Deepest element nesting ([`MAX_DEPTH`]).
    pub max_depth: usize,
    /// Most points in one bound or polygon ([`MAX_BOUND_POINTS`]).
    pub max_bound_points: usize,
    /// Most points in the file ([`MAX_TOTAL_POINTS`]).
    pub max_total_points: usize,
    /// Most lanelets ([`MAX_LANELETS`]).
    pub max_lanelets: usize,
    /// Most obstacles ([`MAX_OBSTACLES`]).
    pub max_obstacles: usize,
    /// Most states of one obstacle, initial state included ([`MAX_STATES`]).
    pub max_states: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_file_bytes: MAX_FILE_BYTES,
            max_xml_nodes: MAX_XML_NODES,
            max_depth: MAX_DEPTH,
            max_bound_points: MAX_BOUND_POINTS,
            max_total_points: MAX_TOTAL_POINTS,
            max_lanelets: MAX_LANELETS,
            max_obstacles: MAX_OBSTACLES,
            max_states: MAX_STATES,
        }
    }
}

/// The CommonRoad format version a file declares in `commonRoadVersion`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Version {
    /// The 2018b format (`<obstacle>` with `<role>`, `<speedLimit>` in lanelets).
    V2018b,
    /// The 2020a format (the current schema).
    V2020a,
}

impl Version {
    /// The version as written in the file (`"2018b"` or `"2020a"`).
    pub fn as_str(self) -> &'static str {
        match self {
            Version::V2018b => "2018b",
            Version::V2020a => "2020a",
        }
    }
}

/// One CommonRoad scenario file, read and checked.
#[derive(Debug, Clone, PartialEq)]
pub struct CommonRoad {
    /// The file name the scenario was read from (as given to [`parse`]), used in lookup errors.
    pub file: String,
    /// The declared format version.
    pub version: Version,
    /// `benchmarkID`, e.g. `USA_US101-4_1_T-1` (empty when absent).
    pub benchmark_id: String,
    /// `timeStepSize` in seconds: one trajectory time step lasts this long (0 < dt <= 10).
    pub time_step: f64,
    /// `author` (empty when absent).
    pub author: String,
    /// `affiliation` (empty when absent).
    pub affiliation: String,
    /// `source` (empty when absent).
    pub source: String,
    /// Scenario tags: the element names in `<scenarioTags>` (2020a) or the words of the root's `tags`
    /// attribute (2018b), in file order.
    pub tags: Vec<String>,
    /// The lanelets, in file order.
    pub lanelets: Vec<Lanelet>,
    /// Static and dynamic obstacles with a trajectory, in file order.
    pub obstacles: Vec<Obstacle>,
    /// The planning problems, in file order.
    pub planning_problems: Vec<PlanningProblem>,
    /// Elements the reader did not use, counted by name, sorted by name.
    pub ignored: Vec<Ignored>,
    /// States (obstacle states and planning-problem initial states) with an interval value or a
    /// shape position, read as the interval's midpoint or the shape's centre.
    pub uncertain_states: usize,
    /// Dynamic obstacles of a 2020a file whose initial state is after time step 0 (the schema
    /// says 0; files converted from datasets have them): each exists from its first step, as in
    /// commonroad-io.
    pub late_starts: usize,
    /// Static obstacles of a 2020a file whose initial state is after time step 0: static at every
    /// step, as commonroad-io reads them.
    pub late_static: usize,
    /// Trajectory states repeating their obstacle's initial state at its time step, read once (as
    /// commonroad-io's `state_at_time` reads them).
    pub repeated_initial_states: usize,
}

/// An element the reader skipped, and how often it occurred.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ignored {
    /// The element name, e.g. `trafficLight`; `dynamicObstacle/occupancySet` counts dynamic obstacles
    /// that have an occupancy set instead of a trajectory.
    pub element: String,
    /// How many such elements the file has (where the reader looked: the subtree of an ignored
    /// element is not counted again).
    pub count: usize,
}

/// A lanelet: a lane section between a left and a right bound.
#[derive(Debug, Clone, PartialEq)]
pub struct Lanelet {
    /// The lanelet id.
    pub id: u64,
    /// The left bound, in driving direction.
    pub left: Bound,
    /// The right bound, in driving direction.
    pub right: Bound,
    /// Ids of the lanelets leading into this one.
    pub predecessors: Vec<u64>,
    /// Ids of the lanelets this one leads into.
    pub successors: Vec<u64>,
    /// The neighbour on the left, if any.
    pub adjacent_left: Option<Adjacent>,
    /// The neighbour on the right, if any.
    pub adjacent_right: Option<Adjacent>,
    /// `<laneletType>` values (urban, interstate, highway, ...); empty in 2018b files.
    pub types: Vec<String>,
    /// `<speedLimit>` in m/s (2018b files only; 2020a puts speed limits in traffic signs).
    pub speed_limit: Option<f64>,
}

/// A lanelet bound: a polyline of at least two points.
#[derive(Debug, Clone, PartialEq)]
pub struct Bound {
    /// The points `[x, y]` in metres (a `<z>` is ignored and counted).
    pub points: Vec<[f64; 2]>,
    /// `<lineMarking>` (dashed, solid, ...), if given.
    pub marking: Option<String>,
}

/// A reference to a neighbouring lanelet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Adjacent {
    /// The neighbour's id.
    pub id: u64,
    /// `drivingDir="same"` (true) or `"opposite"` (false).
    pub same_direction: bool,
}

/// A geometric shape, in metres and radians.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A rectangle of `length` along its `orientation` and `width` across, around `center`.
    Rectangle {
        /// Extent along the orientation (> 0).
        length: f64,
        /// Extent across the orientation (> 0).
        width: f64,
        /// Heading of the length axis (0 when absent).
        orientation: f64,
        /// Centre (`[0, 0]` when absent); for a road user's shape with an `<originXShift>` s,
        /// moved by −s along the orientation (its states' positions are then the shifted origin).
        center: [f64; 2],
    },
    /// A circle.
    Circle {
        /// Radius (> 0).
        radius: f64,
        /// Centre (`[0, 0]` when absent).
        center: [f64; 2],
    },
    /// A polygon of at least three vertices.
    Polygon {
        /// The vertices `[x, y]`.
        points: Vec<[f64; 2]>,
    },
}

impl Shape {
    /// The shape's centre: a rectangle's or circle's centre, a polygon's vertex mean.
    pub fn center(&self) -> [f64; 2] {
        match self {
            Shape::Rectangle { center, .. } | Shape::Circle { center, .. } => *center,
            Shape::Polygon { points } => mean(points),
        }
    }
}

/// The mean of points (`[0, 0]` for none).
pub(crate) fn mean(points: &[[f64; 2]]) -> [f64; 2] {
    if points.is_empty() {
        return [0.0, 0.0];
    }
    let n = points.len() as f64;
    let sum = points.iter().fold([0.0, 0.0], |s, p| [s[0] + p[0], s[1] + p[1]]);
    [sum[0] / n, sum[1] / n]
}

/// Whether an obstacle stays put or moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObstacleRole {
    /// A static obstacle: its initial state holds forever.
    Static,
    /// A dynamic obstacle with a recorded trajectory.
    Dynamic,
}

/// An obstacle: a static one, or a dynamic one with its trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Obstacle {
    /// The obstacle id.
    pub id: u64,
    /// Static or dynamic.
    pub role: ObstacleRole,
    /// `<type>`: car, truck, bus, pedestrian, bicycle, parkedVehicle, ... (as written).
    pub kind: String,
    /// The obstacle's outline in its own frame (centred on the state position, heading along +x).
    pub shapes: Vec<Shape>,
    /// The initial state, then the trajectory's states: consecutive integer time steps. A static
    /// obstacle has its initial state only.
    pub states: Vec<State>,
}

impl Obstacle {
    /// The state recorded at `time_step`, if any (no interpolation). A static obstacle returns its
    /// initial state at any step.
    pub fn state_at(&self, time_step: i64) -> Option<&State> {
        let first = self.states.first()?;
        if self.role == ObstacleRole::Static {
            return Some(first);
        }
        let index = usize::try_from(time_step.checked_sub(first.time_step)?).ok()?;
        self.states.get(index)
    }
}

/// One state of an obstacle or an initial state. Interval values are read as their midpoint and a
/// shape position as the shape's centre (see [`CommonRoad::uncertain_states`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct State {
    /// The integer time step (time = `time_step` × [`CommonRoad::time_step`]).
    pub time_step: i64,
    /// Position `[x, y]` in metres (of the obstacle's shape centre).
    pub position: [f64; 2],
    /// Heading in radians.
    pub orientation: f64,
    /// Speed in m/s.
    pub velocity: Option<f64>,
    /// Acceleration in m/s².
    pub acceleration: Option<f64>,
    /// Yaw rate in rad/s.
    pub yaw_rate: Option<f64>,
    /// Slip angle in radians.
    pub slip_angle: Option<f64>,
}

/// A planning problem: where the ego starts and where it should get to.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanningProblem {
    /// The planning problem id.
    pub id: u64,
    /// The ego's initial state.
    pub initial: State,
    /// The goal states (at least one): reaching any of them solves the problem.
    pub goals: Vec<GoalState>,
}

impl PlanningProblem {
    /// Whether the goal states differ in more than their regions (their time windows,
    /// intervals, or whether they have a position): then no one region with one window and one
    /// pair of intervals is the goal, and each goal state must be asked whole.
    pub fn goal_states_differ(&self) -> bool {
        let conditions = |g: &GoalState| (g.time_steps, g.orientation, g.velocity, g.position.is_some());
        self.goals
            .first()
            .is_some_and(|first| self.goals.iter().any(|g| conditions(g) != conditions(first)))
    }
}

/// One goal state: every given constraint must hold at once.
#[derive(Debug, Clone, PartialEq)]
pub struct GoalState {
    /// Inclusive time-step interval `(start, end)`, start <= end.
    pub time_steps: (i64, i64),
    /// Where the ego must be, if constrained.
    pub position: Option<GoalPosition>,
    /// Inclusive orientation interval in radians, if constrained.
    pub orientation: Option<(f64, f64)>,
    /// Inclusive speed interval in m/s, if constrained.
    pub velocity: Option<(f64, f64)>,
}

/// A goal region.
#[derive(Debug, Clone, PartialEq)]
pub enum GoalPosition {
    /// Inside any of these shapes.
    Shapes(Vec<Shape>),
    /// On any of these lanelets (ids).
    Lanelets(Vec<u64>),
}

impl CommonRoad {
    /// The lanelet with this id.
    pub fn lanelet(&self, id: u64) -> Option<&Lanelet> {
        self.lanelets.iter().find(|l| l.id == id)
    }

    /// The obstacle with this id.
    pub fn obstacle(&self, id: u64) -> Option<&Obstacle> {
        self.obstacles.iter().find(|o| o.id == id)
    }

    /// The planning problem with this id, or the first one for `None`. An unknown id (or a file
    /// without planning problems) is an error listing the ids the file has.
    pub fn planning_problem(&self, id: Option<u64>) -> Result<&PlanningProblem, ReadError> {
        let found = match id {
            None => self.planning_problems.first(),
            Some(id) => self.planning_problems.iter().find(|p| p.id == id),
        };
        found.ok_or_else(|| {
            let ids: Vec<String> = self.planning_problems.iter().map(|p| p.id.to_string()).collect();
            let wanted = id.map_or_else(
                || "a planning problem".to_string(),
                |id| format!("planning problem {id}"),
            );
            let has = if ids.is_empty() {
                "none".to_string()
            } else {
                ids.join(", ")
            };
            ReadError::Invalid {
                file: self.file.clone(),
                path: "planningProblem".into(),
                message: format!("expected {wanted}, found planning problem ids: {has}"),
            }
        })
    }

    /// The last recorded time step over all dynamic obstacles (0 if there are none).
    pub fn duration_steps(&self) -> u64 {
        let last = self.obstacles.iter().filter(|o| o.role == ObstacleRole::Dynamic);
        let last = last.filter_map(|o| o.states.last()).map(|s| s.time_step).max();
        last.map_or(0, |t| u64::try_from(t).unwrap_or(0))
    }

    /// The number of ignored elements named `element` (0 if none).
    pub fn ignored_count(&self, element: &str) -> usize {
        self.ignored
            .iter()
            .find(|i| i.element == element)
            .map_or(0, |i| i.count)
    }

    /// One line naming what was ignored, e.g. `ignored: 4 traffic lights, 79 traffic signs`; `None`
    /// when nothing was.
    pub fn ignored_line(&self) -> Option<String> {
        if self.ignored.is_empty() {
            return None;
        }
        let parts: Vec<String> = self.ignored.iter().map(Ignored::describe).collect();
        Some(format!("ignored: {}", parts.join(", ")))
    }

    /// Every line to tell the user about how the file was read: [`CommonRoad::ignored_line`],
    /// then [`CommonRoad::notes`].
    pub fn remarks(&self) -> Vec<String> {
        self.ignored_line().into_iter().chain(self.notes()).collect()
    }

    /// Further remarks on how the file was read (set-valued states reduced to a point, road users
    /// starting late, repeated initial states), one line each; [`CommonRoad::ignored_line`] is separate.
    pub fn notes(&self) -> Vec<String> {
        // (count, singular, plural, the rest of the line)
        let remarks = [
            (
                self.uncertain_states,
                "state",
                "states",
                "with interval values or shape positions read as the interval midpoint / shape centre",
            ),
            (
                self.late_starts,
                "road user starts",
                "road users start",
                "after time step 0 (format 2020a expects 0): each exists from its first recorded step, as commonroad-io reads it",
            ),
            (
                self.late_static,
                "static obstacle starts",
                "static obstacles start",
                "after time step 0 (format 2020a expects 0): static at every step, as commonroad-io reads it",
            ),
            (
                self.repeated_initial_states,
                "trajectory repeats",
                "trajectories repeat",
                "its road user's initial state as its first state: read once, as commonroad-io reads it",
            ),
        ];
        remarks
            .iter()
            .filter(|(n, ..)| *n > 0)
            .map(|&(n, one, many, rest)| format!("{n} {} {rest}", if n == 1 { one } else { many }))
            .collect()
    }
}

impl Ignored {
    /// `count` and a readable name, e.g. `4 traffic lights`, `1 z coordinate`, `2 unknown <foo>`.
    pub fn describe(&self) -> String {
        let (singular, plural) = label(&self.element);
        let name = if self.count == 1 { singular } else { plural };
        format!("{} {name}", self.count)
    }
}

/// Readable singular and plural names of an ignored element.
fn label(element: &str) -> (String, String) {
    let fixed = match element {
        "dynamicObstacle/occupancySet" => Some((
            "dynamic obstacle with an occupancy set only",
            "dynamic obstacles with occupancy sets only",
        )),
        "z" => Some(("z coordinate", "z coordinates")),
        "userOneWay" => Some(("one-way road user entry", "one-way road user entries")),
        "userBidirectional" => Some(("bidirectional road user entry", "bidirectional road user entries")),
        "signalSeries" => Some(("signal series", "signal series")),
        "ref/unresolved" => Some((
            "reference to no element of its kind (in an element not used)",
            "references to no element of their kind (in elements not used)",
        )),
        _ => None,
    };
    if let Some((s, p)) = fixed {
        return (s.to_string(), p.to_string());
    }
    if !SCHEMA_ELEMENTS.split_ascii_whitespace().any(|e| e == element) {
        let name = format!("unknown <{element}>");
        return (name.clone(), name);
    }
    let words = split_camel(element);
    let plural = if words.ends_with('s') {
        words.clone()
    } else {
        format!("{words}s")
    };
    (words, plural)
}

/// `trafficLightRef` → `traffic light ref`.
fn split_camel(name: &str) -> String {
    let mut out = String::with_capacity(name.len() + 4);
    for c in name.chars() {
        if c.is_ascii_uppercase() {
            out.push(' ');
            out.push(c.to_ascii_lowercase());
        } else {
            out.push(c);
        }
    }
    out
}

/// Element names of the 2020a schema plus the 2018b-only `obstacle`, `role` and `speedLimit`, separated by
/// spaces (for [`Ignored::describe`]: anything else is reported as unknown).
const SCHEMA_ELEMENTS: &str = "\
    acceleration active additionalTransformation additionalValue adjacentLeft adjacentRight \
    brakingLights center circle color comfort commonRoad critical crossing crossingLanelet curvature \
    curvatureChange cut_in cycle cycleElement deltaYFront deltaYRear direction duration dynamicObstacle \
    emergency_braking environment environmentObstacle evasive exact flashingBlueLights geoNameId \
    geoReference geoTransformation goalState gpsLatitude gpsLongitude hazardWarningLights highway horn \
    illegal_cutin incoming incomingLanelet indicatorLeft indicatorRight initialSignalState initialState \
    intersection interstate intervalEnd intervalStart isLeftOf jerk jounce lane_change lane_following \
    lanelet laneletType leftBound leftFrontWheelAngularSpeed leftRearWheelAngularSpeed length \
    lineMarking location merging_lanes multi_lane no_oncoming_traffic obstacle occupancy occupancySet \
    oncoming_traffic orientation parallel_lanes phantomObstacle pitchAngle pitchRate planningProblem \
    point polygon position positionZ positionZFront positionZRear predecessor race_track radius \
    rectangle rightBound rightFrontWheelAngularSpeed rightRearWheelAngularSpeed role rollAngle \
    rollAngleFront rollAngleRear rollRate rollRateFront rollRateRear roundabout rural scaling \
    scenarioTags shape signalSeries signalState simulated single_lane slipAngle slip_road speedLimit \
    speed_limit state staticObstacle steeringAngle stopLine successor successorsLeft successorsRight \
    successorsStraight time timeOfDay timeOffset trafficLight trafficLightRef trafficSign trafficSignID \
    trafficSignRef traffic_jam trajectory turn_left turn_right two_lane type underground urban \
    userBidirectional userOneWay velocity velocityY velocityYFront velocityYRear velocityZ \
    velocityZFront velocityZRear virtual weather width x xTranslation y yTranslation yawRate z \
    zRotation";
