//! XML → types: bounded file access, the document, and one reader per CommonRoad element.
//!
//! Every reader walks all child elements of its element: the ones it knows are read (each at most
//! once where the schema allows one), every other one is counted in the ignored list by name.

use std::fs::{File, Metadata};
use std::io::Read;
use std::path::Path;

use roxmltree::{Document, Node, ParsingOptions};

use crate::check::{self, id_attribute, leaf_text, number, positive, time_step, Ctx};
use crate::error::quote;
use crate::{
    mean, Adjacent, Bound, CommonRoad, GoalPosition, GoalState, Ignored, Lanelet, Limits, Obstacle, ObstacleRole,
    PlanningProblem, ReadError, Shape, State, Version, MAX_TIME_STEP,
};

/// Reads and checks a CommonRoad file with the default [`Limits`]. Refuses, before reading, anything
/// that is not a regular file or is larger than [`crate::MAX_FILE_BYTES`] (by its metadata; the read
/// itself is bounded too).
pub fn read_file(path: &Path) -> Result<CommonRoad, ReadError> {
    read_file_with(path, &Limits::default())
}

/// [`read_file`] with other limits.
pub fn read_file_with(path: &Path, limits: &Limits) -> Result<CommonRoad, ReadError> {
    let file = path.display().to_string();
    let io = |source| ReadError::Io {
        file: file.clone(),
        source,
    };
    let max = limits.max_file_bytes;
    regular_and_small(&file, &std::fs::metadata(path).map_err(io)?, max)?;
    let mut handle = File::open(path).map_err(io)?;
    let meta = handle.metadata().map_err(io)?;
    regular_and_small(&file, &meta, max)?;
    let capacity = meta.len().min(max);
    let mut bytes = Vec::with_capacity(usize::try_from(capacity).unwrap_or(0));
    handle
        .by_ref()
        .take(max.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(io)?;
    if bytes.len() as u64 > max {
        return Err(ReadError::TooLarge {
            file,
            size: bytes.len() as u64,
            max,
        });
    }
    let text = String::from_utf8(bytes).map_err(|e| {
        io(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("not UTF-8 text: {e}"),
        ))
    })?;
    parse_with(&text, &file, limits)
}

/// Refuses non-regular files and files over `max` bytes.
fn regular_and_small(file: &str, meta: &Metadata, max: u64) -> Result<(), ReadError> {
    if !meta.is_file() {
        let found = if meta.is_dir() {
            "a directory"
        } else {
            "a special file (device, FIFO or socket)"
        };
        return Err(ReadError::NotRegularFile {
            file: file.to_string(),
            found: found.to_string(),
        });
    }
    if meta.len() > max {
        return Err(ReadError::TooLarge {
            file: file.to_string(),
            size: meta.len(),
            max,
        });
    }
    Ok(())
}

/// Parses and checks CommonRoad XML text with the default [`Limits`]; `file` names the source in
/// errors.
pub fn parse(text: &str, file: &str) -> Result<CommonRoad, ReadError> {
    parse_with(text, file, &Limits::default())
}

/// [`parse`] with other limits.
pub fn parse_with(text: &str, file: &str, limits: &Limits) -> Result<CommonRoad, ReadError> {
    let max = limits.max_file_bytes;
    if text.len() as u64 > max {
        return Err(ReadError::TooLarge {
            file: file.to_string(),
            size: text.len() as u64,
            max,
        });
    }
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let xml = |message: String| ReadError::Xml {
        file: file.to_string(),
        message,
    };
    let depth = limits.max_depth;
    check::nesting_depth(text, depth).map_err(|line| {
        xml(format!(
            "expected elements nested at most {depth} deep, found deeper at line {line}"
        ))
    })?;
    let nodes = limits.max_xml_nodes;
    let options = ParsingOptions {
        allow_dtd: false,
        nodes_limit: nodes,
        ..ParsingOptions::default()
    };
    let doc = Document::parse_with_options(text, options).map_err(|e| match e {
        roxmltree::Error::NodesLimitReached => xml(format!("expected at most {nodes} XML nodes, found more")),
        e @ (roxmltree::Error::UnexpectedEndOfStream | roxmltree::Error::UnclosedRootNode) => {
            xml(format!("{e} at {} (the end of the text)", end_position(text)))
        }
        e => xml(e.to_string().replace(['\n', '\r'], " ")),
    })?;
    read_root(file, doc.root_element(), *limits)
}

/// `line:column` of the end of `text` (1-based).
fn end_position(text: &str) -> String {
    let line = 1 + text.matches('\n').count();
    let column = 1 + text.rsplit('\n').next().map_or(0, |last| last.chars().count());
    format!("{line}:{column}")
}

/// The element children of `node`.
fn elements<'a, 'i>(node: Node<'a, 'i>) -> impl Iterator<Item = Node<'a, 'i>> {
    node.children().filter(Node::is_element)
}

/// The local name of an element.
fn name<'a>(node: Node<'a, '_>) -> &'a str {
    node.tag_name().name()
}

/// An error if `slot` is already filled (a second `<child>` where one is allowed).
fn unique<T>(ctx: &Ctx, child: Node, slot: &Option<T>) -> Result<(), ReadError> {
    if slot.is_some() {
        return Err(ctx.err(child, format!("expected one <{}>, found another", name(child))));
    }
    Ok(())
}

/// The value of a required child, or an error at `node` naming the missing child.
fn required<T>(ctx: &Ctx, node: Node, slot: Option<T>, child: &str) -> Result<T, ReadError> {
    slot.ok_or_else(|| ctx.err(node, format!("expected a <{child}>, found none")))
}

/// The whole document: header, then each top-level element, then the id and reference checks.
fn read_root(file: &str, root: Node, limits: Limits) -> Result<CommonRoad, ReadError> {
    let mut ctx = Ctx::new(file, Version::V2020a, limits);
    if name(root) != "commonRoad" {
        return Err(ctx.err(
            root,
            format!("expected root element <commonRoad>, found <{}>", name(root)),
        ));
    }
    ctx.version = read_version(&ctx, root)?;
    let text = |attribute: &str| root.attribute(attribute).unwrap_or("").to_string();
    let mut cr = CommonRoad {
        file: file.to_string(),
        version: ctx.version,
        benchmark_id: text("benchmarkID"),
        time_step: read_time_step(&ctx, root)?,
        author: text("author"),
        affiliation: text("affiliation"),
        source: text("source"),
        tags: root
            .attribute("tags")
            .unwrap_or("")
            .split_whitespace()
            .map(str::to_string)
            .collect(),
        lanelets: Vec::new(),
        obstacles: Vec::new(),
        planning_problems: Vec::new(),
        ignored: Vec::new(),
        uncertain_states: 0,
        late_starts: 0,
        late_static: 0,
        repeated_initial_states: 0,
    };
    for node in elements(root) {
        read_top(&mut ctx, &mut cr, node)?;
    }
    check::ids_and_refs(&mut ctx, root)?;
    cr.uncertain_states = ctx.uncertain_states;
    (cr.late_starts, cr.late_static) = (ctx.late_starts, ctx.late_static);
    cr.repeated_initial_states = ctx.repeated_initial_states;
    cr.ignored = std::mem::take(&mut ctx.ignored)
        .into_iter()
        .map(|(element, count)| Ignored { element, count })
        .collect();
    Ok(cr)
}

/// `commonRoadVersion`: 2018b or 2020a.
fn read_version(ctx: &Ctx, root: Node) -> Result<Version, ReadError> {
    match root.attribute("commonRoadVersion").map(str::trim) {
        Some("2020a") => Ok(Version::V2020a),
        Some("2018b") => Ok(Version::V2018b),
        Some(other) => Err(ctx.err(
            root,
            format!("expected commonRoadVersion 2018b or 2020a, found {}", quote(other)),
        )),
        None => Err(ctx.err(
            root,
            "expected a commonRoadVersion attribute (2018b or 2020a), found none",
        )),
    }
}

/// `timeStepSize`: seconds, 0 < dt <= [`MAX_TIME_STEP`].
fn read_time_step(ctx: &Ctx, root: Node) -> Result<f64, ReadError> {
    let Some(text) = root.attribute("timeStepSize") else {
        return Err(ctx.err(root, "expected a timeStepSize attribute (seconds), found none"));
    };
    match text.trim().parse::<f64>() {
        Ok(dt) if dt.is_finite() && dt > 0.0 && dt <= MAX_TIME_STEP => Ok(dt),
        _ => Err(ctx.err(
            root,
            format!("expected timeStepSize in (0, 10] seconds, found {}", quote(text)),
        )),
    }
}

/// One top-level element.
fn read_top(ctx: &mut Ctx, cr: &mut CommonRoad, node: Node) -> Result<(), ReadError> {
    let role = match name(node) {
        "lanelet" => {
            ctx.at_most(node, cr.lanelets.len() + 1, ctx.limits.max_lanelets, "lanelets")?;
            cr.lanelets.push(read_lanelet(ctx, node)?);
            return Ok(());
        }
        "planningProblem" => {
            cr.planning_problems.push(read_planning_problem(ctx, node)?);
            return Ok(());
        }
        "scenarioTags" => {
            cr.tags.extend(elements(node).map(|tag| name(tag).to_string()));
            return Ok(());
        }
        "staticObstacle" => Some(ObstacleRole::Static),
        "dynamicObstacle" => Some(ObstacleRole::Dynamic),
        "obstacle" => None,
        other => {
            ctx.ignore(other);
            return Ok(());
        }
    };
    ctx.obstacles += 1;
    ctx.at_most(node, ctx.obstacles, ctx.limits.max_obstacles, "obstacles")?;
    if let Some(obstacle) = read_obstacle(ctx, node, role)? {
        cr.obstacles.push(obstacle);
    }
    Ok(())
}

/// A `<lanelet>`.
fn read_lanelet(ctx: &mut Ctx, node: Node) -> Result<Lanelet, ReadError> {
    let id = id_attribute(ctx, node, "id")?;
    let (mut left, mut right, mut adjacent_left, mut adjacent_right, mut speed_limit) = (None, None, None, None, None);
    let (mut predecessors, mut successors, mut types) = (Vec::new(), Vec::new(), Vec::new());
    for c in elements(node) {
        match name(c) {
            "leftBound" => {
                unique(ctx, c, &left)?;
                left = Some(read_bound(ctx, c)?);
            }
            "rightBound" => {
                unique(ctx, c, &right)?;
                right = Some(read_bound(ctx, c)?);
            }
            "predecessor" => predecessors.push(id_attribute(ctx, c, "ref")?),
            "successor" => successors.push(id_attribute(ctx, c, "ref")?),
            "adjacentLeft" => {
                unique(ctx, c, &adjacent_left)?;
                adjacent_left = Some(read_adjacent(ctx, c)?);
            }
            "adjacentRight" => {
                unique(ctx, c, &adjacent_right)?;
                adjacent_right = Some(read_adjacent(ctx, c)?);
            }
            "laneletType" => types.push(leaf_text(ctx, c).to_string()),
            "speedLimit" => {
                unique(ctx, c, &speed_limit)?;
                speed_limit = Some(number(ctx, c)?);
            }
            other => ctx.ignore(other),
        }
    }
    let left = required(ctx, node, left, "leftBound")?;
    let right = required(ctx, node, right, "rightBound")?;
    Ok(Lanelet {
        id,
        left,
        right,
        predecessors,
        successors,
        adjacent_left,
        adjacent_right,
        types,
        speed_limit,
    })
}

/// A `<leftBound>` or `<rightBound>`: 2..=[`Limits::max_bound_points`] points and an optional line marking.
fn read_bound(ctx: &mut Ctx, node: Node) -> Result<Bound, ReadError> {
    let (mut points, mut marking) = (Vec::new(), None);
    for c in elements(node) {
        match name(c) {
            "point" => push_point(ctx, c, &mut points)?,
            "lineMarking" => {
                unique(ctx, c, &marking)?;
                marking = Some(leaf_text(ctx, c).to_string());
            }
            other => ctx.ignore(other),
        }
    }
    if points.len() < 2 {
        return Err(ctx.err(node, format!("expected at least 2 <point>s, found {}", points.len())));
    }
    Ok(Bound { points, marking })
}

/// `<adjacentLeft>` / `<adjacentRight>`: `ref` and `drivingDir`.
fn read_adjacent(ctx: &Ctx, node: Node) -> Result<Adjacent, ReadError> {
    let id = id_attribute(ctx, node, "ref")?;
    let same_direction = match node.attribute("drivingDir").map(str::trim) {
        Some("same") => true,
        Some("opposite") => false,
        Some(other) => {
            return Err(ctx.err(
                node,
                format!("expected drivingDir same or opposite, found {}", quote(other)),
            ))
        }
        None => return Err(ctx.err(node, "expected a drivingDir attribute (same or opposite), found none")),
    };
    Ok(Adjacent { id, same_direction })
}

/// Reads one more point of a bound or polygon, keeping to [`Limits::max_bound_points`].
fn push_point(ctx: &mut Ctx, node: Node, points: &mut Vec<[f64; 2]>) -> Result<(), ReadError> {
    ctx.at_most(
        node,
        points.len() + 1,
        ctx.limits.max_bound_points,
        "points in a bound or polygon",
    )?;
    points.push(read_point(ctx, node)?);
    Ok(())
}

/// A `<point>` (or `<center>`): `<x>`, `<y>`; a `<z>` is ignored and counted.
fn read_point(ctx: &mut Ctx, node: Node) -> Result<[f64; 2], ReadError> {
    ctx.add_point(node)?;
    let (mut x, mut y) = (None, None);
    for c in elements(node) {
        match name(c) {
            "x" => {
                unique(ctx, c, &x)?;
                x = Some(number(ctx, c)?);
            }
            "y" => {
                unique(ctx, c, &y)?;
                y = Some(number(ctx, c)?);
            }
            other => ctx.ignore(other),
        }
    }
    Ok([required(ctx, node, x, "x")?, required(ctx, node, y, "y")?])
}

/// A `<rectangle>`, `<circle>` or `<polygon>`; `None` for any other element. `obstacle`: the
/// shape of a road user (`<shape>`), whose rectangle may move its origin (`<originXShift>`).
fn read_shape(ctx: &mut Ctx, node: Node, obstacle: bool) -> Result<Option<Shape>, ReadError> {
    Ok(Some(match name(node) {
        "rectangle" => read_rectangle(ctx, node, obstacle)?,
        "circle" => read_circle(ctx, node)?,
        "polygon" => {
            let mut points = Vec::new();
            for c in elements(node) {
                match name(c) {
                    "point" => push_point(ctx, c, &mut points)?,
                    other => ctx.ignore(other),
                }
            }
            if points.len() < 3 {
                return Err(ctx.err(node, format!("expected at least 3 <point>s, found {}", points.len())));
            }
            Shape::Polygon { points }
        }
        _ => return Ok(None),
    }))
}

/// A `<rectangle>`: length and width > 0, orientation 0 and centre (0, 0) unless given. A road
/// user's rectangle may give `<originXShift>` s (commonroad-io 2026's `RectObstacleShape`): its
/// state's position is then s along the length axis from the rectangle's centre (s = −b with the
/// rear axle as origin), so the centre is moved by −s along the orientation; |s| ≤ length / 2,
/// as commonroad-io requires. Elsewhere (a goal's rectangle) commonroad-io reads no
/// `<originXShift>`, and it is counted as ignored.
fn read_rectangle(ctx: &mut Ctx, node: Node, obstacle: bool) -> Result<Shape, ReadError> {
    let (mut length, mut width, mut orientation, mut center) = (None, None, None, None);
    let mut origin_shift = None;
    for c in elements(node) {
        let slot = match name(c) {
            "length" => &mut length,
            "width" => &mut width,
            "orientation" => &mut orientation,
            "center" => {
                unique(ctx, c, &center)?;
                center = Some(read_point(ctx, c)?);
                continue;
            }
            "originXShift" if obstacle => {
                unique(ctx, c, &origin_shift)?;
                origin_shift = Some((number(ctx, c)?, c));
                continue;
            }
            other => {
                ctx.ignore(other);
                continue;
            }
        };
        unique(ctx, c, slot)?;
        *slot = Some(if name(c) == "orientation" {
            number(ctx, c)?
        } else {
            positive(ctx, c)?
        });
    }
    let length = required(ctx, node, length, "length")?;
    let orientation = orientation.unwrap_or(0.0);
    let mut center = center.unwrap_or([0.0, 0.0]);
    if let Some((shift, c)) = origin_shift {
        if shift.abs() > length / 2.0 {
            return Err(ctx.err(
                c,
                format!(
                    "expected |originXShift| <= length / 2 = {}, found {shift}",
                    length / 2.0
                ),
            ));
        }
        let (sin, cos) = orientation.sin_cos();
        center = [center[0] - shift * cos, center[1] - shift * sin];
    }
    Ok(Shape::Rectangle {
        length,
        width: required(ctx, node, width, "width")?,
        orientation,
        center,
    })
}

/// A `<circle>`: radius > 0, centre (0, 0) unless given.
fn read_circle(ctx: &mut Ctx, node: Node) -> Result<Shape, ReadError> {
    let (mut radius, mut center) = (None, None);
    for c in elements(node) {
        match name(c) {
            "radius" => {
                unique(ctx, c, &radius)?;
                radius = Some(positive(ctx, c)?);
            }
            "center" => {
                unique(ctx, c, &center)?;
                center = Some(read_point(ctx, c)?);
            }
            other => ctx.ignore(other),
        }
    }
    let radius = required(ctx, node, radius, "radius")?;
    Ok(Shape::Circle {
        radius,
        center: center.unwrap_or([0.0, 0.0]),
    })
}

/// A `<shape>`: one or more rectangles, circles and polygons.
fn read_shapes(ctx: &mut Ctx, node: Node) -> Result<Vec<Shape>, ReadError> {
    let mut shapes = Vec::new();
    for c in elements(node) {
        match read_shape(ctx, c, true)? {
            Some(shape) => shapes.push(shape),
            None => ctx.ignore(name(c)),
        }
    }
    if shapes.is_empty() {
        return Err(ctx.err(
            node,
            "expected at least one <rectangle>, <circle> or <polygon>, found none",
        ));
    }
    Ok(shapes)
}

/// The parts of an exact-or-interval value.
struct Parts<T> {
    exact: Option<T>,
    start: Option<T>,
    end: Option<T>,
}

/// Reads `<exact>`, `<intervalStart>` and `<intervalEnd>` children with `leaf`.
fn parts<T>(
    ctx: &mut Ctx,
    node: Node,
    leaf: fn(&mut Ctx, Node) -> Result<T, ReadError>,
) -> Result<Parts<T>, ReadError> {
    let mut p = Parts {
        exact: None,
        start: None,
        end: None,
    };
    for c in elements(node) {
        let slot = match name(c) {
            "exact" => &mut p.exact,
            "intervalStart" => &mut p.start,
            "intervalEnd" => &mut p.end,
            other => {
                ctx.ignore(other);
                continue;
            }
        };
        unique(ctx, c, slot)?;
        *slot = Some(leaf(ctx, c)?);
    }
    Ok(p)
}

/// Splits parts into an exact value or an ordered interval.
fn exact_or_interval<T: PartialOrd + Copy + std::fmt::Display>(
    ctx: &Ctx,
    node: Node,
    p: Parts<T>,
) -> Result<Result<T, (T, T)>, ReadError> {
    match (p.exact, p.start, p.end) {
        (Some(v), None, None) => Ok(Ok(v)),
        (None, Some(s), Some(e)) if s <= e => Ok(Err((s, e))),
        (None, Some(s), Some(e)) => {
            Err(ctx.err(node, format!("expected intervalStart <= intervalEnd, found {s} > {e}")))
        }
        _ => {
            let found: Vec<String> = elements(node).map(|c| format!("<{}>", name(c))).collect();
            let found = if found.is_empty() {
                "nothing".to_string()
            } else {
                found.join(" ")
            };
            Err(ctx.err(
                node,
                format!("expected <exact> or <intervalStart> and <intervalEnd>, found {found}"),
            ))
        }
    }
}

/// A state value: `<exact>`, or an interval read as its midpoint (`true` = was an interval).
fn read_value(ctx: &mut Ctx, node: Node) -> Result<(f64, bool), ReadError> {
    let p = parts(ctx, node, number)?;
    Ok(match exact_or_interval(ctx, node, p)? {
        Ok(v) => (v, false),
        Err((s, e)) => (s + (e - s) / 2.0, true),
    })
}

/// A goal interval (an `<exact>` value v reads as (v, v)).
fn read_interval(ctx: &mut Ctx, node: Node) -> Result<(f64, f64), ReadError> {
    let p = parts(ctx, node, number)?;
    Ok(exact_or_interval(ctx, node, p)?.into_pair())
}

/// A state's `<time>`: an exact integer step.
fn read_time(ctx: &mut Ctx, node: Node) -> Result<i64, ReadError> {
    let p = parts(ctx, node, time_step)?;
    match exact_or_interval(ctx, node, p)? {
        Ok(t) => Ok(t),
        Err((s, e)) => Err(ctx.err(
            node,
            format!("expected an <exact> time step, found the interval {s}..{e}"),
        )),
    }
}

/// A goal's `<time>`: an inclusive interval of integer steps (an exact t reads as (t, t)).
fn read_time_interval(ctx: &mut Ctx, node: Node) -> Result<(i64, i64), ReadError> {
    let p = parts(ctx, node, time_step)?;
    Ok(exact_or_interval(ctx, node, p)?.into_pair())
}

/// `(v, v)` from an exact value, the interval as is.
trait IntoPair<T> {
    fn into_pair(self) -> (T, T);
}

impl<T: Copy> IntoPair<T> for Result<T, (T, T)> {
    fn into_pair(self) -> (T, T) {
        match self {
            Ok(v) => (v, v),
            Err(pair) => pair,
        }
    }
}

/// A state's `<position>`: a point, or shapes read as the mean of their centres (`true`).
fn read_position(ctx: &mut Ctx, node: Node) -> Result<([f64; 2], bool), ReadError> {
    let (mut point, mut centres) = (None, Vec::new());
    for c in elements(node) {
        match name(c) {
            "point" => {
                unique(ctx, c, &point)?;
                point = Some(read_point(ctx, c)?);
            }
            "lanelet" => {
                return Err(ctx.err(
                    c,
                    "expected a <point> or shapes, found a lanelet reference (allowed in goals only)",
                ))
            }
            other => match read_shape(ctx, c, false)? {
                Some(shape) => centres.push(shape.center()),
                None => ctx.ignore(other),
            },
        }
    }
    match (point, centres.is_empty()) {
        (Some(p), true) => Ok((p, false)),
        (None, false) => Ok((mean(&centres), true)),
        (Some(_), false) => Err(ctx.err(node, "expected a <point> or shapes, found both")),
        (None, true) => Err(ctx.err(
            node,
            "expected a <point>, <rectangle>, <circle> or <polygon>, found none",
        )),
    }
}

/// The optional values of a state, each with its was-an-interval flag.
#[derive(Default)]
struct StateParts {
    position: Option<([f64; 2], bool)>,
    time: Option<i64>,
    orientation: Option<(f64, bool)>,
    velocity: Option<(f64, bool)>,
    acceleration: Option<(f64, bool)>,
    yaw_rate: Option<(f64, bool)>,
    slip_angle: Option<(f64, bool)>,
}

/// A `<state>` or `<initialState>`: position, orientation and time required; velocity,
/// acceleration, yaw rate and slip angle optional; other state variables ignored and counted.
fn read_state(ctx: &mut Ctx, node: Node) -> Result<State, ReadError> {
    let mut p = StateParts::default();
    for c in elements(node) {
        let slot = match name(c) {
            "position" => {
                unique(ctx, c, &p.position)?;
                p.position = Some(read_position(ctx, c)?);
                continue;
            }
            "time" => {
                unique(ctx, c, &p.time)?;
                p.time = Some(read_time(ctx, c)?);
                continue;
            }
            "orientation" => &mut p.orientation,
            "velocity" => &mut p.velocity,
            "acceleration" => &mut p.acceleration,
            "yawRate" => &mut p.yaw_rate,
            "slipAngle" => &mut p.slip_angle,
            other => {
                ctx.ignore(other);
                continue;
            }
        };
        unique(ctx, c, slot)?;
        *slot = Some(read_value(ctx, c)?);
    }
    let (position, shaped) = required(ctx, node, p.position, "position")?;
    let (orientation, interval) = required(ctx, node, p.orientation, "orientation")?;
    let time_step = required(ctx, node, p.time, "time")?;
    let optional = [p.velocity, p.acceleration, p.yaw_rate, p.slip_angle];
    if shaped || interval || optional.iter().flatten().any(|v| v.1) {
        ctx.uncertain_states += 1;
    }
    let value = |v: Option<(f64, bool)>| v.map(|v| v.0);
    Ok(State {
        time_step,
        position,
        orientation,
        velocity: value(p.velocity),
        acceleration: value(p.acceleration),
        yaw_rate: value(p.yaw_rate),
        slip_angle: value(p.slip_angle),
    })
}

/// The `<time>` child of a state (for error paths), or the state itself.
fn time_node<'a, 'i>(state: Node<'a, 'i>) -> Node<'a, 'i> {
    elements(state).find(|c| name(*c) == "time").unwrap_or(state)
}

/// The children of an obstacle element.
#[derive(Default)]
struct ObstacleParts<'a, 'i> {
    role: Option<ObstacleRole>,
    kind: Option<String>,
    shapes: Option<Vec<Shape>>,
    initial: Option<(State, Node<'a, 'i>)>,
    trajectory: Option<Node<'a, 'i>>,
    occupancy: Option<Node<'a, 'i>>,
}

/// Reads the children of `<staticObstacle>`, `<dynamicObstacle>` or 2018b `<obstacle>` (whose
/// `<role>` is read only when `role_child` is set).
fn obstacle_parts<'a, 'i>(
    ctx: &mut Ctx,
    node: Node<'a, 'i>,
    role_child: bool,
) -> Result<ObstacleParts<'a, 'i>, ReadError> {
    let mut p = ObstacleParts::default();
    for c in elements(node) {
        match name(c) {
            "role" if role_child => {
                unique(ctx, c, &p.role)?;
                p.role = Some(match leaf_text(ctx, c) {
                    "static" => ObstacleRole::Static,
                    "dynamic" => ObstacleRole::Dynamic,
                    other => return Err(ctx.err(c, format!("expected role static or dynamic, found {}", quote(other)))),
                });
            }
            "type" => {
                unique(ctx, c, &p.kind)?;
                p.kind = Some(leaf_text(ctx, c).to_string());
            }
            "shape" => {
                unique(ctx, c, &p.shapes)?;
                p.shapes = Some(read_shapes(ctx, c)?);
            }
            "initialState" => {
                unique(ctx, c, &p.initial)?;
                p.initial = Some((read_state(ctx, c)?, c));
            }
            "trajectory" => {
                unique(ctx, c, &p.trajectory)?;
                p.trajectory = Some(c);
            }
            "occupancySet" => {
                unique(ctx, c, &p.occupancy)?;
                p.occupancy = Some(c);
            }
            other => ctx.ignore(other),
        }
    }
    Ok(p)
}

/// An obstacle; `role` is `None` for a 2018b `<obstacle>` (read from its `<role>`). A dynamic
/// obstacle with an occupancy set but no trajectory is counted as ignored (`Ok(None)`).
fn read_obstacle(ctx: &mut Ctx, node: Node, role: Option<ObstacleRole>) -> Result<Option<Obstacle>, ReadError> {
    let id = id_attribute(ctx, node, "id")?;
    let p = obstacle_parts(ctx, node, role.is_none())?;
    let role = required(ctx, node, role.or(p.role), "role")?;
    let kind = required(ctx, node, p.kind, "type")?;
    if kind.is_empty() {
        return Err(ctx.err(
            node,
            "expected an obstacle <type> (car, truck, ...), found an empty one",
        ));
    }
    let shapes = required(ctx, node, p.shapes, "shape")?;
    let (initial, initial_node) = required(ctx, node, p.initial, "initialState")?;
    check::initial_time_step(ctx, time_node(initial_node), initial.time_step, Some(role))?;
    let mut states = vec![initial];
    match (role, p.trajectory, p.occupancy) {
        (ObstacleRole::Static, trajectory, occupancy) => {
            trajectory.into_iter().for_each(|_| ctx.ignore("trajectory"));
            occupancy.into_iter().for_each(|_| ctx.ignore("occupancySet"));
        }
        (ObstacleRole::Dynamic, Some(trajectory), occupancy) => {
            occupancy.into_iter().for_each(|_| ctx.ignore("occupancySet"));
            read_trajectory(ctx, trajectory, &mut states)?;
        }
        (ObstacleRole::Dynamic, None, Some(_)) => {
            ctx.ignore("dynamicObstacle/occupancySet");
            return Ok(None);
        }
        (ObstacleRole::Dynamic, None, None) => {
            return Err(ctx.err(node, "expected a <trajectory> or an <occupancySet>, found neither"));
        }
    }
    Ok(Some(Obstacle {
        id,
        role,
        kind,
        shapes,
        states,
    }))
}

/// A `<trajectory>`: at least one `<state>`, time steps consecutive after the initial state's.
fn read_trajectory(ctx: &mut Ctx, node: Node, states: &mut Vec<State>) -> Result<(), ReadError> {
    for c in elements(node) {
        if name(c) != "state" {
            ctx.ignore(name(c));
            continue;
        }
        ctx.at_most(c, states.len() + 1, ctx.limits.max_states, "states per obstacle")?;
        let state = read_state(ctx, c)?;
        if let Some(previous) = states.last() {
            // A first state repeating the initial state (its time step included): read once, as
            // commonroad-io's `state_at_time` reads it. One that differs is an error below.
            if states.len() == 1 && state == *previous {
                ctx.repeated_initial_states += 1;
                continue;
            }
            check::next_time_step(ctx, time_node(c), previous.time_step, state.time_step)?;
        }
        states.push(state);
    }
    if states.len() < 2 {
        return Err(ctx.err(
            node,
            "expected at least one <state> after the initial state in the trajectory, found none",
        ));
    }
    Ok(())
}

/// A `<planningProblem>`: an initial state and at least one goal state.
fn read_planning_problem(ctx: &mut Ctx, node: Node) -> Result<PlanningProblem, ReadError> {
    let id = id_attribute(ctx, node, "id")?;
    let (mut initial, mut goals) = (None, Vec::new());
    for c in elements(node) {
        match name(c) {
            "initialState" => {
                unique(ctx, c, &initial)?;
                let state = read_state(ctx, c)?;
                check::initial_time_step(ctx, time_node(c), state.time_step, None)?;
                initial = Some(state);
            }
            "goalState" => goals.push(read_goal(ctx, c)?),
            other => ctx.ignore(other),
        }
    }
    let initial = required(ctx, node, initial, "initialState")?;
    if goals.is_empty() {
        return Err(ctx.err(node, "expected at least one <goalState>, found none"));
    }
    Ok(PlanningProblem { id, initial, goals })
}

/// A `<goalState>`: a time interval, optionally position, orientation and velocity intervals.
fn read_goal(ctx: &mut Ctx, node: Node) -> Result<GoalState, ReadError> {
    let (mut time, mut position, mut orientation, mut velocity) = (None, None, None, None);
    for c in elements(node) {
        match name(c) {
            "time" => {
                unique(ctx, c, &time)?;
                time = Some(read_time_interval(ctx, c)?);
            }
            "position" => {
                unique(ctx, c, &position)?;
                position = Some(read_goal_position(ctx, c)?);
            }
            "orientation" => {
                unique(ctx, c, &orientation)?;
                orientation = Some(read_interval(ctx, c)?);
            }
            "velocity" => {
                unique(ctx, c, &velocity)?;
                velocity = Some(read_interval(ctx, c)?);
            }
            other => ctx.ignore(other),
        }
    }
    let time_steps = required(ctx, node, time, "time")?;
    Ok(GoalState {
        time_steps,
        position,
        orientation,
        velocity,
    })
}

/// A goal `<position>`: shapes, or lanelet references (not both).
fn read_goal_position(ctx: &mut Ctx, node: Node) -> Result<GoalPosition, ReadError> {
    let (mut shapes, mut lanelets) = (Vec::new(), Vec::new());
    for c in elements(node) {
        match name(c) {
            "lanelet" => lanelets.push(id_attribute(ctx, c, "ref")?),
            "point" => return Err(ctx.err(c, "expected a goal region (shapes or lanelets), found a <point>")),
            other => match read_shape(ctx, c, false)? {
                Some(shape) => shapes.push(shape),
                None => ctx.ignore(other),
            },
        }
    }
    match (shapes.is_empty(), lanelets.is_empty()) {
        (false, true) => Ok(GoalPosition::Shapes(shapes)),
        (true, false) => Ok(GoalPosition::Lanelets(lanelets)),
        (false, false) => Err(ctx.err(node, "expected shapes or lanelet references, found both")),
        (true, true) => Err(ctx.err(
            node,
            "expected a <rectangle>, <circle>, <polygon> or <lanelet>, found none",
        )),
    }
}
