//! Checks: the reading context (error paths, ignored counts, running totals), numbers, limits,
//! nesting depth, unique ids and resolvable references.

use std::collections::{BTreeMap, HashMap};

use roxmltree::Node;

use crate::error::quote;
use crate::{Limits, ObstacleRole, ReadError, Version, MAX_ABS_VALUE};

/// State shared by the element readers: the file name for errors, the version, what was ignored,
/// and running totals checked against the limits.
pub(crate) struct Ctx<'f> {
    /// The file name used in errors.
    pub file: &'f str,
    /// The declared version.
    pub version: Version,
    /// Ignored element names and counts.
    pub ignored: BTreeMap<String, usize>,
    /// The limits in force.
    pub limits: Limits,
    /// Points read so far (checked against [`Limits::max_total_points`]).
    pub total_points: usize,
    /// States with an interval value or shape position.
    pub uncertain_states: usize,
    /// 2020a dynamic obstacles whose initial state is after time step 0.
    pub late_starts: usize,
    /// 2020a static obstacles whose initial state is after time step 0.
    pub late_static: usize,
    /// Trajectory states repeating their obstacle's initial state (read once).
    pub repeated_initial_states: usize,
    /// Obstacle elements read so far (checked against [`Limits::max_obstacles`]).
    pub obstacles: usize,
}

impl<'f> Ctx<'f> {
    /// A fresh context.
    pub fn new(file: &'f str, version: Version, limits: Limits) -> Self {
        Ctx {
            file,
            version,
            limits,
            ignored: BTreeMap::new(),
            total_points: 0,
            uncertain_states: 0,
            late_starts: 0,
            late_static: 0,
            repeated_initial_states: 0,
            obstacles: 0,
        }
    }

    /// An [`ReadError::Invalid`] at `node`.
    pub fn err(&self, node: Node, message: impl Into<String>) -> ReadError {
        ReadError::Invalid {
            file: self.file.to_string(),
            path: element_path(node),
            message: message.into(),
        }
    }

    /// Counts one ignored element.
    pub fn ignore(&mut self, element: &str) {
        if let Some(count) = self.ignored.get_mut(element) {
            *count += 1;
        } else {
            self.ignored.insert(element.to_string(), 1);
        }
    }

    /// Counts one point read at `node` against [`Limits::max_total_points`].
    pub fn add_point(&mut self, node: Node) -> Result<(), ReadError> {
        self.total_points += 1;
        self.at_most(
            node,
            self.total_points,
            self.limits.max_total_points,
            "points in the file",
        )
    }

    /// An error unless `count <= max`; `what` names the counted things (plural).
    pub fn at_most(&self, node: Node, count: usize, max: usize, what: &str) -> Result<(), ReadError> {
        if count > max {
            return Err(self.err(node, format!("expected at most {max} {what}, found more")));
        }
        Ok(())
    }
}

/// The path of `node` below the root, e.g. `lanelet 12 / leftBound / point 3`: elements with an `id`
/// attribute are named by it, repeated elements by their 1-based position among same-named siblings.
pub(crate) fn element_path(node: Node) -> String {
    let mut parts: Vec<String> = Vec::new();
    for n in node.ancestors().filter(Node::is_element) {
        if n.parent().is_none_or(|p| p.is_root()) {
            break;
        }
        parts.push(segment(n));
    }
    if parts.is_empty() {
        return node.tag_name().name().to_string();
    }
    parts.reverse();
    parts.join(" / ")
}

/// One path segment: name, plus id or ordinal.
fn segment(n: Node) -> String {
    let name = n.tag_name().name();
    if let Some(id) = n.attribute("id") {
        return format!("{name} {}", short(id));
    }
    let same = |s: &Node| s.is_element() && s.tag_name().name() == name;
    let before = n.prev_siblings().skip(1).filter(same).count();
    let after = n.next_siblings().skip(1).filter(same).count();
    if before + after == 0 {
        name.to_string()
    } else {
        format!("{name} {}", before + 1)
    }
}

/// An attribute value for a path: as is when short and plain, quoted otherwise.
fn short(value: &str) -> String {
    if value.len() <= 20 && value.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_') {
        value.to_string()
    } else {
        quote(value)
    }
}

/// The text of a leaf element (trimmed); element children are counted as ignored.
pub(crate) fn leaf_text<'a>(ctx: &mut Ctx, node: Node<'a, '_>) -> &'a str {
    for child in node.children().filter(Node::is_element) {
        ctx.ignore(child.tag_name().name());
    }
    node.text().unwrap_or("").trim()
}

/// A finite number with |value| <= [`MAX_ABS_VALUE`] from a leaf element.
pub(crate) fn number(ctx: &mut Ctx, node: Node) -> Result<f64, ReadError> {
    let text = leaf_text(ctx, node);
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() && v.abs() <= MAX_ABS_VALUE => Ok(v),
        _ => Err(ctx.err(
            node,
            format!("expected a finite number with |value| <= 1e7, found {}", quote(text)),
        )),
    }
}

/// A number > 0 (a length, width or radius).
pub(crate) fn positive(ctx: &mut Ctx, node: Node) -> Result<f64, ReadError> {
    let v = number(ctx, node)?;
    if v > 0.0 {
        Ok(v)
    } else {
        Err(ctx.err(node, format!("expected a number > 0, found {v}")))
    }
}

/// A non-negative integer time step <= [`MAX_ABS_VALUE`] from a leaf element.
pub(crate) fn time_step(ctx: &mut Ctx, node: Node) -> Result<i64, ReadError> {
    let text = leaf_text(ctx, node);
    match text.parse::<i64>() {
        Ok(t) if (0..=MAX_ABS_VALUE as i64).contains(&t) => Ok(t),
        _ => Err(ctx.err(
            node,
            format!("expected an integer time step in 0..=10000000, found {}", quote(text)),
        )),
    }
}

/// An unsigned integer attribute (an id or a reference).
pub(crate) fn id_attribute(ctx: &Ctx, node: Node, name: &str) -> Result<u64, ReadError> {
    let Some(text) = node.attribute(name) else {
        return Err(ctx.err(node, format!("expected an integer attribute {name}, found none")));
    };
    text.trim().parse::<u64>().map_err(|_| {
        ctx.err(
            node,
            format!("expected {name} to be a non-negative integer, found {}", quote(text)),
        )
    })
}

/// Checks that a trajectory state's time step follows the previous one by exactly one.
pub(crate) fn next_time_step(ctx: &Ctx, node: Node, previous: i64, time: i64) -> Result<(), ReadError> {
    if time <= previous {
        return Err(ctx.err(
            node,
            format!(
                "expected time step {}, found {time} (not after {previous})",
                previous + 1
            ),
        ));
    }
    if time != previous + 1 {
        return Err(ctx.err(
            node,
            format!(
                "expected time step {}, found {time} (a gap after {previous})",
                previous + 1
            ),
        ));
    }
    Ok(())
}

/// Checks the initial state's time step: any step >= 0 in 2018b; exactly 0 in 2020a for a planning
/// problem (`obstacle` None). An obstacle's may be later, as commonroad-io reads it: a dynamic one
/// (files converted from datasets, e.g. inD, have them) exists from that step, a static one at
/// every step (counted in [`Ctx::late_starts`], [`Ctx::late_static`]).
pub(crate) fn initial_time_step(
    ctx: &mut Ctx,
    node: Node,
    time: i64,
    obstacle: Option<ObstacleRole>,
) -> Result<(), ReadError> {
    if ctx.version == Version::V2020a && time != 0 {
        match obstacle {
            Some(ObstacleRole::Dynamic) => ctx.late_starts += 1,
            Some(ObstacleRole::Static) => ctx.late_static += 1,
            None => {
                return Err(ctx.err(
                    node,
                    format!("expected initial time step 0 (format 2020a), found {time}"),
                ))
            }
        }
    }
    Ok(())
}

/// Scans raw text for element nesting deeper than `max_depth` before the DOM is built (comments,
/// CDATA, processing instructions and quoted attribute values are skipped). Returns the 1-based line
/// of the first too-deep element. Malformed input is left to the XML parser.
pub(crate) fn nesting_depth(text: &str, max_depth: usize) -> Result<(), usize> {
    let b = text.as_bytes();
    let (mut i, mut depth) = (0usize, 0usize);
    while let Some(lt) = find(b, i, b"<") {
        let rest = &b[lt + 1..];
        let end = if rest.starts_with(b"!--") {
            find(b, lt + 4, b"-->")
        } else if rest.starts_with(b"![CDATA[") {
            find(b, lt + 9, b"]]>")
        } else if rest.starts_with(b"?") {
            find(b, lt + 2, b"?>")
        } else if rest.starts_with(b"!") || rest.starts_with(b"/") {
            depth = depth.saturating_sub(usize::from(rest.starts_with(b"/")));
            find(b, lt + 1, b">")
        } else {
            let gt = tag_end(b, lt + 1);
            if gt.is_some_and(|gt| b[gt - 1] != b'/') {
                depth += 1;
                if depth > max_depth {
                    return Err(1 + b[..lt].iter().filter(|&&c| c == b'\n').count());
                }
            }
            gt
        };
        let Some(end) = end else { return Ok(()) };
        i = end + 1;
    }
    Ok(())
}

/// The index of the `>` closing a start tag that begins at `from`, skipping quoted values.
fn tag_end(b: &[u8], from: usize) -> Option<usize> {
    let mut quote_char = None;
    for (k, &c) in b.iter().enumerate().skip(from) {
        match quote_char {
            Some(q) if c == q => quote_char = None,
            Some(_) => {}
            None if c == b'"' || c == b'\'' => quote_char = Some(c),
            None if c == b'>' => return Some(k),
            None => {}
        }
    }
    None
}

/// The index of the first `pattern` at or after `from`.
fn find(b: &[u8], from: usize, pattern: &[u8]) -> Option<usize> {
    let hay = b.get(from..)?;
    if pattern.len() == 1 {
        return hay.iter().position(|&c| c == pattern[0]).map(|k| from + k);
    }
    hay.windows(pattern.len()).position(|w| w == pattern).map(|k| from + k)
}

/// What a top-level `id` names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Lanelet,
    TrafficSign,
    TrafficLight,
    Intersection,
    Incoming,
    Obstacle,
}

impl Kind {
    /// The kind of a top-level element that carries a scenario-wide id.
    fn of(element: &str) -> Option<Kind> {
        Some(match element {
            "lanelet" => Kind::Lanelet,
            "trafficSign" => Kind::TrafficSign,
            "trafficLight" => Kind::TrafficLight,
            "intersection" => Kind::Intersection,
            "staticObstacle" | "dynamicObstacle" | "obstacle" | "phantomObstacle" | "environmentObstacle" => {
                Kind::Obstacle
            }
            _ => return None,
        })
    }

    /// The kind a `ref` attribute on an element named `element` must name (`None`: any).
    fn referenced_by(element: &str) -> Option<Kind> {
        match element {
            "predecessor" | "successor" | "adjacentLeft" | "adjacentRight" | "lanelet" | "incomingLanelet"
            | "successorsRight" | "successorsStraight" | "successorsLeft" | "crossingLanelet" => Some(Kind::Lanelet),
            "trafficSignRef" => Some(Kind::TrafficSign),
            "trafficLightRef" => Some(Kind::TrafficLight),
            "isLeftOf" => Some(Kind::Incoming),
            _ => None,
        }
    }
}

/// The id registry: id → (kind, element name, node).
type Ids<'a, 'i> = HashMap<u64, (Kind, Node<'a, 'i>)>;

/// Checks that ids are unique (lanelets, traffic signs and lights, intersections and their
/// incomings, all obstacles share one namespace; planning problems have their own) and that every
/// `ref` attribute anywhere names an existing element of the right kind (one mjsafe does not follow
/// may not: counted, [`check_ref`]), and that no lanelet is its
/// own successor, predecessor or neighbour (longer cycles, as in roundabouts, are fine).
pub(crate) fn ids_and_refs(ctx: &mut Ctx, root: Node) -> Result<(), ReadError> {
    let mut ids: Ids = HashMap::new();
    let mut problems: HashMap<u64, Node> = HashMap::new();
    for node in root.children().filter(Node::is_element) {
        let name = node.tag_name().name();
        if name == "planningProblem" {
            let id = id_attribute(ctx, node, "id")?;
            if let Some(first) = problems.insert(id, node) {
                return Err(duplicate(ctx, node, id, first));
            }
            continue;
        }
        let Some(kind) = Kind::of(name) else { continue };
        register(ctx, &mut ids, node, kind)?;
        if kind == Kind::Intersection {
            for incoming in node.children().filter(|n| n.has_tag_name("incoming")) {
                register(ctx, &mut ids, incoming, Kind::Incoming)?;
            }
        }
    }
    for node in root.descendants().filter(|n| n.is_element() && n.has_attribute("ref")) {
        check_ref(ctx, &ids, node)?;
    }
    Ok(())
}

/// Adds one id, rejecting duplicates.
fn register<'a, 'i>(ctx: &Ctx, ids: &mut Ids<'a, 'i>, node: Node<'a, 'i>, kind: Kind) -> Result<(), ReadError> {
    let id = id_attribute(ctx, node, "id")?;
    match ids.insert(id, (kind, node)) {
        Some((_, first)) => Err(duplicate(ctx, node, id, first)),
        None => Ok(()),
    }
}

/// The error for an id used twice.
fn duplicate(ctx: &Ctx, node: Node, id: u64, first: Node) -> ReadError {
    let at = first.document().text_pos_at(first.range().start);
    ctx.err(
        node,
        format!(
            "expected a unique id, found id {id} already used by {} at line {}",
            element_path(first),
            at.row
        ),
    )
}

/// Whether mjsafe follows a `ref` on this element: a lanelet's links to its neighbours and a goal's
/// lanelets. The others (traffic signs and lights, stop lines, intersections) sit in elements it
/// does not use.
fn followed(node: Node) -> bool {
    let parent = node.parent().map(|p| p.tag_name().name());
    match node.tag_name().name() {
        "predecessor" | "successor" | "adjacentLeft" | "adjacentRight" => parent == Some("lanelet"),
        "lanelet" => parent == Some("position"),
        _ => false,
    }
}

/// Checks one `ref` attribute. One that mjsafe does not follow ([`followed`]) and that names no
/// element of its kind (some files leave a stop line's sign out, or name a lanelet as an incoming)
/// is counted as ignored instead: commonroad-io reads such files, and the element is not used.
fn check_ref(ctx: &mut Ctx, ids: &Ids, node: Node) -> Result<(), ReadError> {
    let name = node.tag_name().name();
    let target = id_attribute(ctx, node, "ref")?;
    let wanted = Kind::referenced_by(name);
    let wanted_name = wanted.map_or("element", kind_name);
    let resolves = ids
        .get(&target)
        .is_some_and(|(kind, _)| wanted.is_none_or(|w| w == *kind));
    if !resolves && !followed(node) {
        ctx.ignore("ref/unresolved");
        return Ok(());
    }
    match ids.get(&target) {
        None => {
            return Err(ctx.err(
                node,
                format!("expected ref to name an existing {wanted_name}, found ref {target} (no such id)"),
            ))
        }
        Some((kind, found)) if wanted.is_some_and(|w| w != *kind) => {
            let found = element_path(*found);
            let article = if wanted_name.starts_with(['a', 'e', 'i', 'o', 'u']) {
                "an"
            } else {
                "a"
            };
            return Err(ctx.err(
                node,
                format!("expected ref to name {article} {wanted_name}, found ref {target} naming {found}"),
            ));
        }
        Some(_) => {}
    }
    let parent = node
        .parent()
        .filter(|p| p.has_tag_name("lanelet") && p.attribute("id").is_some());
    let own = parent
        .and_then(|p| p.attribute("id"))
        .and_then(|id| id.trim().parse::<u64>().ok());
    let link = matches!(name, "successor" | "predecessor" | "adjacentLeft" | "adjacentRight");
    if link && own == Some(target) {
        return Err(ctx.err(
            node,
            format!("expected a different lanelet, found lanelet {target} as its own {name}"),
        ));
    }
    Ok(())
}

/// A kind's name in messages.
fn kind_name(kind: Kind) -> &'static str {
    match kind {
        Kind::Lanelet => "lanelet",
        Kind::TrafficSign => "traffic sign",
        Kind::TrafficLight => "traffic light",
        Kind::Intersection => "intersection",
        Kind::Incoming => "intersection incoming",
        Kind::Obstacle => "obstacle",
    }
}
