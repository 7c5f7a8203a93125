//! Roads (scenario `[road]`): edges that are barriers with the vehicle's hull, and lane
//! markings that are only drawn. Pure geometry: each edge is an entire line or an entire
//! circle (a road that changes from straight to curved needs a piecewise edge: not supported).
//!
//! An edge's barrier keeps the hull on the road side:
//! - a line edge, h = n·p − n·q − r_hull ≥ 0 with n the unit normal towards the road (a
//!   half-space (2.47) on the planar position; h in metres: the signed gap between the hull
//!   and the edge);
//! - an arc edge, a ball on the planar position ((2.32) inside, (4.81) outside) of radius
//!   R ∓ r_hull (h in m²: the road inside, h = (R − r_hull)² − ‖p − c‖²).

use serde::{Deserialize, Serialize};

use crate::barrier::{Barrier, Shape};
use crate::params::ParamError;

/// Most edges of a road, and most lane markings.
pub const MAX_ROAD_ITEMS: usize = 64;

/// The scenario's `[road]` section.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoadSpec {
    /// `[[road.edges]]`: each a barrier with the vehicle's hull.
    #[serde(default)]
    pub edges: Vec<Edge>,
    /// `[[road.lanes]]`: lane markings, drawn dashed; not barriers.
    #[serde(default)]
    pub lanes: Vec<Marking>,
}

impl RoadSpec {
    /// The edges' barriers for a vehicle of `model` whose hull has radius `hull_radius`, or
    /// whose footprint's covering circles are `footprint` (offset, radius; one barrier per edge
    /// and circle, named `<edge>/<i>`), each checked to hold at the initial state `x0`; errors
    /// at the key they concern (`road.edges.<i>…`).
    pub fn barriers(
        &self,
        model: &dyn crate::dynamics::Dynamics,
        hull_radius: f64,
        footprint: Option<&[([f64; 2], f64)]>,
        x0: &nalgebra::DVector<f64>,
    ) -> Result<Vec<Barrier>, ParamError> {
        let footprint = footprint.zip(model.heading_index());
        let widest = footprint.map_or(hull_radius, |(circles, _)| {
            circles.iter().map(|c| c.1).fold(0.0, f64::max)
        });
        let what = if footprint.is_some() {
            "footprint's covering circles"
        } else {
            "hull"
        };
        let mut barriers = Vec::with_capacity(self.edges.len());
        for (i, edge) in self.edges.iter().enumerate() {
            let Some(position) = model.planar_position() else {
                return Err(ParamError::new("road.edges", "this vehicle does not move in a plane"));
            };
            if let Edge::Arc {
                radius,
                road: ArcSide::Inside,
                ..
            } = edge
            {
                if radius <= &widest {
                    return Err(ParamError::new(
                        format!("road.edges.{i}.radius"),
                        format!("a road inside a circle of radius {radius} m has no room for the vehicle's {what} of radius {widest} m: expected a radius > {widest}"),
                    ));
                }
            }
            let edge_barriers = match (footprint, edge, model.heading_index()) {
                (Some((circles, heading)), _, _) => edge.body_barriers(&edge.name(i), (position, heading), circles),
                // A polyline edge's barrier reads the heading: the hull as one circle at the
                // reference point.
                (None, Edge::Polyline { .. }, Some(heading)) => {
                    edge.body_barriers(&edge.name(i), (position, heading), &[([0.0, 0.0], hull_radius)])
                }
                (None, Edge::Polyline { .. }, None) => {
                    return Err(ParamError::new(
                        format!("road.edges.{i}"),
                        "a polyline edge needs a vehicle with a heading",
                    ));
                }
                (None, _, _) => edge.barrier(&edge.name(i), position, hull_radius).into_iter().collect(),
            };
            for barrier in edge_barriers {
                if barrier.h(x0) < 0.0 {
                    return Err(ParamError::new(
                        format!("road.edges.{i}"),
                        format!(
                            "the vehicle starts off the road: its {what} (radius {widest} m) at ({}, {}) {} {:.3} m beyond this edge",
                            x0[position[0]],
                            x0[position[1]],
                            if footprint.is_some() { format!("reach ({})", barrier.name) } else { "is".into() },
                            -barrier.clearance(x0)
                        ),
                    ));
                }
                barriers.push(barrier);
            }
        }
        Ok(barriers)
    }

    /// The checks of the section when the scenario loads: at most [`MAX_ROAD_ITEMS`] edges and
    /// lanes; polyline edges of 2 to [`MAX_EDGE_POINTS`] finite points within ±`extent` m that
    /// make a smooth curve; lines and arcs within ±`extent`; unique, non-empty lane names. Keys
    /// are the scenario's (`road.edges.2.points`).
    pub fn validate(&self, extent: f64) -> Result<(), ParamError> {
        let road = self;
        for (section, count) in [("road.edges", road.edges.len()), ("road.lanes", road.lanes.len())] {
            if count > MAX_ROAD_ITEMS {
                return Err(ParamError::new(
                    section,
                    format!("expected at most {MAX_ROAD_ITEMS} entries, found {count}"),
                ));
            }
        }
        for (i, edge) in road.edges.iter().enumerate() {
            if let Edge::Polyline { points, .. } = edge {
                let finite = points
                    .iter()
                    .all(|p| p.iter().all(|v| v.is_finite() && v.abs() <= extent));
                if !(2..=MAX_EDGE_POINTS).contains(&points.len()) || !finite {
                    return Err(ParamError::new(
                        format!("road.edges.{i}.points"),
                        format!(
                            "expected 2 to {} points with finite coordinates within ±{extent:e} m",
                            MAX_EDGE_POINTS
                        ),
                    ));
                }
                crate::barrier::curve::SmoothCurve::new(points)
                    .map_err(|e| ParamError::new(format!("road.edges.{i}.points"), e))?;
            }
        }
        let edges = road.edges.iter().filter_map(|e| match e {
            Edge::Line { point, direction, .. } => Some((Some((*point, *direction)), None)),
            Edge::Arc { centre, radius, .. } => Some((None, Some((*centre, *radius)))),
            Edge::Polyline { .. } => None,
        });
        let lanes = road.lanes.iter().map(|m| match m {
            Marking::Line { point, direction, .. } => (Some((*point, *direction)), None),
            Marking::Arc { centre, radius, .. } => (None, Some((*centre, *radius))),
        });
        let keyed = edges
            .enumerate()
            .map(|(i, g)| (format!("road.edges.{i}"), g))
            .chain(lanes.enumerate().map(|(i, g)| (format!("road.lanes.{i}"), g)));
        for (key, (line, circle)) in keyed {
            if let Some((field, message)) = curve_problem(line, circle, extent) {
                return Err(ParamError::new(format!("{key}.{field}"), message));
            }
        }
        let mut lanes = std::collections::BTreeMap::new();
        for (i, marking) in road.lanes.iter().enumerate() {
            let name = marking.name(i);
            let key = format!("road.lanes.{i}.name");
            if name.trim().is_empty() {
                return Err(ParamError::new(key.clone(), "expected a name that is not empty"));
            }
            if let Some(other) = lanes.insert(name.clone(), i) {
                return Err(ParamError::new(key.clone(),
                format!("`{name}` is already the name of road.lanes.{other}; names must be unique (they key the drawn entities)"),
            ));
            }
        }
        Ok(())
    }
}

/// On which side of a directed line edge the road lies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LineSide {
    Left,
    Right,
}

/// On which side of an arc edge (a whole circle) the road lies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ArcSide {
    Inside,
    Outside,
}

/// One road edge (`[[road.edges]]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Edge {
    /// The whole line through `point` along `direction`; the road on its `road` side.
    Line {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        point: [f64; 2],
        direction: [f64; 2],
        road: LineSide,
    },
    /// The whole circle of `radius` about `centre`; the road `inside` or `outside` it.
    Arc {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        centre: [f64; 2],
        radius: f64,
        road: ArcSide,
    },
    /// A polyline (e.g. a CommonRoad lanelet bound), made smooth for the barrier condition
    /// ([`crate::barrier::curve::SmoothCurve`]: a C² curve, its deviation δ from the polyline
    /// added to the margin); the road on its `road` side, looking along the points. Needs a
    /// vehicle with a heading; at most [`MAX_EDGE_POINTS`] points.
    Polyline {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        points: Vec<[f64; 2]>,
        road: LineSide,
    },
}

/// Most points of a polyline edge.
pub const MAX_EDGE_POINTS: usize = 10_000;

/// One lane marking (`[[road.lanes]]`): a whole line or circle, drawn dashed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Marking {
    Line {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        point: [f64; 2],
        direction: [f64; 2],
    },
    Arc {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        centre: [f64; 2],
        radius: f64,
    },
}

/// A whole line or circle in the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Curve {
    /// Through `point` along the unit vector `direction`.
    Line {
        point: [f64; 2],
        direction: [f64; 2],
    },
    Circle {
        centre: [f64; 2],
        radius: f64,
    },
}

/// `v / ‖v‖` (None for a zero or non-finite vector).
fn unit([x, y]: [f64; 2]) -> Option<[f64; 2]> {
    let norm = x.hypot(y);
    (norm > 0.0 && norm.is_finite()).then(|| [x / norm, y / norm])
}

impl Curve {
    fn line(point: [f64; 2], direction: [f64; 2]) -> Curve {
        Curve::Line {
            point,
            direction: unit(direction).unwrap_or([1.0, 0.0]),
        }
    }
}

impl Edge {
    /// The edge's name: the given one or `road_edge_<index>`.
    pub fn name(&self, index: usize) -> String {
        let (Edge::Line { name, .. } | Edge::Arc { name, .. } | Edge::Polyline { name, .. }) = self;
        name.clone().unwrap_or_else(|| format!("road_edge_{index}"))
    }

    /// The edge's line or circle (a line's direction normalised; validation refuses a zero one);
    /// None for a polyline.
    pub fn curve(&self) -> Option<Curve> {
        match self {
            Edge::Line { point, direction, .. } => Some(Curve::line(*point, *direction)),
            Edge::Arc { centre, radius, .. } => Some(Curve::Circle {
                centre: *centre,
                radius: *radius,
            }),
            Edge::Polyline { .. } => None,
        }
    }

    /// The polyline to draw: a line's stretch near the points `around`, a closed circle, a
    /// polyline edge's own points.
    pub fn drawn(&self, around: &[[f64; 2]]) -> Vec<[f64; 2]> {
        match (self, self.curve()) {
            (Edge::Polyline { points, .. }, _) => points.clone(),
            (_, Some(curve)) => curve.polyline(around),
            (_, None) => Vec::new(),
        }
    }

    /// The barrier keeping a hull of `hull_radius` about the planar position (state indices
    /// `position`) on the road side of this edge (module docs); None for a polyline edge,
    /// whose barrier reads the heading ([`Edge::body_barriers`] with one circle at the
    /// reference point).
    pub fn barrier(&self, name: &str, position: [usize; 2], hull_radius: f64) -> Option<Barrier> {
        let shape = match self {
            Edge::Polyline { .. } => return None,
            Edge::Line {
                point, direction, road, ..
            } => {
                let [dx, dy] = unit(*direction).unwrap_or([1.0, 0.0]);
                // The unit normal towards the road: the left normal (−dy, dx), or its opposite.
                let n = match road {
                    LineSide::Left => [-dy, dx],
                    LineSide::Right => [dy, -dx],
                };
                let mut coefficients = vec![0.0; position[0].max(position[1]) + 1];
                coefficients[position[0]] = n[0];
                coefficients[position[1]] = n[1];
                Shape::HalfSpace {
                    coefficients,
                    offset: -(n[0] * point[0] + n[1] * point[1]) - hull_radius,
                }
            }
            Edge::Arc {
                centre, radius, road, ..
            } => Shape::Ball {
                indices: position.to_vec(),
                centre: centre.to_vec(),
                radius: match road {
                    ArcSide::Inside => radius - hull_radius,
                    ArcSide::Outside => radius + hull_radius,
                },
                inside: *road == ArcSide::Inside,
            },
        };
        Some(Barrier {
            name: name.to_string(),
            shape,
        })
    }

    /// The barriers keeping each covering circle of a footprint (offset along and across the
    /// heading, radius) on the road side of this edge, named `<name>/<i>` (docs/actors.md,
    /// "Footprints"): a line edge h = n·q + d − ρ ([`Shape::BodyHalfSpace`]), an arc edge the
    /// circle about its centre of radius R ∓ ρ, inside or outside ([`Shape::BodyCircle`]);
    /// q = p + R(θ) c the circle's centre, p = (`x[position[0]]`, `x[position[1]]`),
    /// θ = `x[heading]`.
    pub fn body_barriers(
        &self,
        name: &str,
        (position, heading): ([usize; 2], usize),
        circles: &[([f64; 2], f64)],
    ) -> Vec<Barrier> {
        // A polyline's smooth curve, built once for all the circles (validated: it exists).
        let smooth = match self {
            Edge::Polyline { points, .. } => crate::barrier::curve::SmoothCurve::new(points)
                .ok()
                .map(std::sync::Arc::new),
            _ => None,
        };
        circles
            .iter()
            .enumerate()
            .map(|(i, &(offset, rho))| {
                let shape = match self {
                    Edge::Polyline { road, .. } => {
                        let curve = smooth.clone().expect("a validated polyline has a smooth curve");
                        Shape::BodyCurve {
                            position,
                            heading,
                            offset,
                            margin: rho + curve.deviation(),
                            curve,
                            side: match road {
                                LineSide::Left => 1.0,
                                LineSide::Right => -1.0,
                            },
                        }
                    }
                    Edge::Line {
                        point, direction, road, ..
                    } => {
                        let [dx, dy] = unit(*direction).unwrap_or([1.0, 0.0]);
                        let normal = match road {
                            LineSide::Left => [-dy, dx],
                            LineSide::Right => [dy, -dx],
                        };
                        Shape::BodyHalfSpace {
                            position,
                            heading,
                            offset,
                            normal,
                            distance: -(normal[0] * point[0] + normal[1] * point[1]) - rho,
                        }
                    }
                    Edge::Arc {
                        centre, radius, road, ..
                    } => Shape::BodyCircle {
                        position,
                        heading,
                        offset,
                        centre: *centre,
                        radius: match road {
                            ArcSide::Inside => radius - rho,
                            ArcSide::Outside => radius + rho,
                        },
                        inside: *road == ArcSide::Inside,
                    },
                };
                Barrier {
                    name: format!("{name}/{i}"),
                    shape,
                }
            })
            .collect()
    }

    /// Signed distance from the planar point `p` to the edge, positive on the road side (a
    /// polyline's: to its smooth curve).
    pub fn distance(&self, p: [f64; 2]) -> f64 {
        match self {
            Edge::Polyline { points, road, .. } => {
                let e = crate::barrier::curve::SmoothCurve::new(points).map_or(f64::NAN, |c| c.nearest(p).distance);
                match road {
                    LineSide::Left => e,
                    LineSide::Right => -e,
                }
            }
            Edge::Line {
                point, direction, road, ..
            } => {
                let [dx, dy] = unit(*direction).unwrap_or([1.0, 0.0]);
                let left = dx * (p[1] - point[1]) - dy * (p[0] - point[0]);
                match road {
                    LineSide::Left => left,
                    LineSide::Right => -left,
                }
            }
            Edge::Arc {
                centre, radius, road, ..
            } => {
                let d = (p[0] - centre[0]).hypot(p[1] - centre[1]);
                match road {
                    ArcSide::Inside => radius - d,
                    ArcSide::Outside => d - radius,
                }
            }
        }
    }
}

impl Marking {
    /// The marking's name: the given one or `lane_<index>`.
    pub fn name(&self, index: usize) -> String {
        let (Marking::Line { name, .. } | Marking::Arc { name, .. }) = self;
        name.clone().unwrap_or_else(|| format!("lane_{index}"))
    }

    /// The marking's line or circle.
    pub fn curve(&self) -> Curve {
        match self {
            Marking::Line { point, direction, .. } => Curve::line(*point, *direction),
            Marking::Arc { centre, radius, .. } => Curve::Circle {
                centre: *centre,
                radius: *radius,
            },
        }
    }
}

/// What is wrong with a line's point and direction, or a circle's centre and radius, if
/// anything: (the field, the expectation). Coordinates and radii within ±`extent`.
pub fn curve_problem(
    line: Option<([f64; 2], [f64; 2])>,
    circle: Option<([f64; 2], f64)>,
    extent: f64,
) -> Option<(&'static str, String)> {
    let within = |v: &[f64]| v.iter().all(|c| c.is_finite() && c.abs() <= extent);
    if let Some((point, direction)) = line {
        if !within(&point) {
            return Some(("point", format!("expected two finite coordinates within ±{extent:e} m")));
        }
        if !direction.iter().all(|c| c.is_finite()) || unit(direction).is_none() {
            return Some((
                "direction",
                "expected a non-zero vector of two finite numbers (the line's direction)".into(),
            ));
        }
    }
    if let Some((centre, radius)) = circle {
        if !within(&centre) {
            return Some((
                "centre",
                format!("expected two finite coordinates within ±{extent:e} m"),
            ));
        }
        if !(radius.is_finite() && radius > 0.0 && radius <= extent) {
            return Some((
                "radius",
                format!("expected a radius > 0 and at most {extent:e} m, found {radius}"),
            ));
        }
    }
    None
}

/// Points where a whole line is drawn: margin metres beyond the projections of `around` onto it
/// (the start, the reference path, the obstacles), and at least ±`margin` about `point`'s
/// nearest point to the first of them.
const DRAW_MARGIN: f64 = 20.0;
/// Segments of a drawn circle; most dashes of a drawn marking.
const CIRCLE_SEGMENTS: usize = 128;
/// At most this many dashes are drawn per marking.
pub const MAX_DASHES: usize = 400;
/// A marking's dash and gap, metres (at least: longer when [`MAX_DASHES`] would not cover it).
const DASH: f64 = 3.0;

impl Curve {
    /// The line's stretch drawn: (from, to) in metres along it from its point.
    fn span(point: [f64; 2], direction: [f64; 2], around: &[[f64; 2]]) -> (f64, f64) {
        let along = |p: &[f64; 2]| (p[0] - point[0]) * direction[0] + (p[1] - point[1]) * direction[1];
        let (lo, hi) = around
            .iter()
            .map(along)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), s| (lo.min(s), hi.max(s)));
        if lo.is_finite() && hi.is_finite() {
            (lo - DRAW_MARGIN, hi + DRAW_MARGIN)
        } else {
            (-DRAW_MARGIN, DRAW_MARGIN)
        }
    }

    /// The curve as a polyline to draw: a line's stretch near the points `around`, a closed
    /// circle.
    pub fn polyline(&self, around: &[[f64; 2]]) -> Vec<[f64; 2]> {
        match *self {
            Curve::Line { point, direction } => {
                let (from, to) = Curve::span(point, direction, around);
                [from, to]
                    .iter()
                    .map(|s| [point[0] + s * direction[0], point[1] + s * direction[1]])
                    .collect()
            }
            Curve::Circle { centre, radius } => (0..=CIRCLE_SEGMENTS)
                .map(|k| {
                    let a = std::f64::consts::TAU * k as f64 / CIRCLE_SEGMENTS as f64;
                    [centre[0] + radius * a.cos(), centre[1] + radius * a.sin()]
                })
                .collect(),
        }
    }

    /// The curve dashed: pairs of points (each a dash's ends), at most [`MAX_DASHES`].
    pub fn dashes(&self, around: &[[f64; 2]]) -> Vec<[f64; 2]> {
        let (length, at): (f64, Box<dyn Fn(f64) -> [f64; 2]>) = match *self {
            Curve::Line { point, direction } => {
                let (from, to) = Curve::span(point, direction, around);
                (
                    to - from,
                    Box::new(move |s| {
                        [
                            point[0] + (from + s) * direction[0],
                            point[1] + (from + s) * direction[1],
                        ]
                    }),
                )
            }
            Curve::Circle { centre, radius } => (
                std::f64::consts::TAU * radius,
                Box::new(move |s| {
                    let a = s / radius;
                    [centre[0] + radius * a.cos(), centre[1] + radius * a.sin()]
                }),
            ),
        };
        let period = (2.0 * DASH).max(length / MAX_DASHES as f64);
        let count = (length / period).floor() as usize;
        (0..count)
            .flat_map(|k| {
                let s = k as f64 * period;
                [at(s), at(s + period / 2.0)]
            })
            .collect()
    }
}

/// The line h = 0 of a half-space barrier that reads only the planar position (its other
/// coefficients zero): c_i p_i + c_j p_j + d = 0, as a [`Curve::Line`].
pub fn planar_half_space(shape: &Shape, [i, j]: [usize; 2]) -> Option<Curve> {
    let Shape::HalfSpace { coefficients, offset } = shape else {
        return None;
    };
    let only_planar = coefficients
        .iter()
        .enumerate()
        .all(|(k, c)| k == i || k == j || *c == 0.0);
    let c = [
        coefficients.get(i).copied().unwrap_or(0.0),
        coefficients.get(j).copied().unwrap_or(0.0),
    ];
    let norm2 = c[0] * c[0] + c[1] * c[1];
    if !(only_planar && norm2 > 0.0 && norm2.is_finite()) {
        return None;
    }
    let point = [-offset * c[0] / norm2, -offset * c[1] / norm2];
    point
        .iter()
        .all(|v| v.is_finite())
        .then(|| Curve::line(point, [-c[1], c[0]]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DVector;

    /// Distance from p to the line through a and b, signed positive to the left of a → b,
    /// by the cross product (independent of `Edge::distance`).
    fn left_distance(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> f64 {
        let (ux, uy) = (b[0] - a[0], b[1] - a[1]);
        (ux * (p[1] - a[1]) - uy * (p[0] - a[0])) / (ux * ux + uy * uy).sqrt()
    }

    fn state(p: [f64; 2]) -> DVector<f64> {
        // The bicycle's order: x1, x2, heading, speed.
        DVector::from_vec(vec![p[0], p[1], 0.7, 3.0])
    }

    const POINTS: [[f64; 2]; 6] = [
        [0.0, 0.0],
        [-20.0, 3.5],
        [5.0, -12.0],
        [100.0, 40.0],
        [-3.0, 11.0],
        [1e-3, -1e-3],
    ];

    #[test]
    fn a_line_edge_is_the_distance_to_the_line_minus_the_hull() {
        let hull = 3.0;
        for (point, direction) in [
            ([0.0, -10.0], [1.0, 0.0]),
            ([2.0, 1.0], [3.0, -4.0]),
            ([-5.0, 7.0], [0.0, 2.5]),
        ] {
            let b = [point[0] + direction[0], point[1] + direction[1]];
            for (road, sign) in [(LineSide::Left, 1.0), (LineSide::Right, -1.0)] {
                let edge = Edge::Line {
                    name: None,
                    point,
                    direction,
                    road,
                };
                let barrier = edge.barrier("e", [0, 1], hull).unwrap();
                for p in POINTS {
                    let expected = sign * left_distance(point, b, p) - hull;
                    let x = state(p);
                    assert!((barrier.h(&x) - expected).abs() < 1e-9, "{edge:?} {p:?}");
                    assert!((barrier.clearance(&x) - expected).abs() < 1e-9);
                    assert!((edge.distance(p) - hull - expected).abs() < 1e-9);
                    // ∇h: the unit normal towards the road on the position, nothing else.
                    let g = barrier.gradient(&x);
                    assert!((g.norm() - 1.0).abs() < 1e-12 && g[2] == 0.0 && g[3] == 0.0);
                }
            }
        }
    }

    #[test]
    fn an_arc_edge_keeps_the_hull_inside_or_outside_the_circle() {
        let (hull, centre, radius) = (3.0, [4.0, -2.0], 25.0);
        for p in POINTS {
            let d = ((p[0] - centre[0]).powi(2) + (p[1] - centre[1]).powi(2)).sqrt();
            for (road, gap) in [
                (ArcSide::Inside, radius - d - hull),
                (ArcSide::Outside, d - radius - hull),
            ] {
                let edge = Edge::Arc {
                    name: None,
                    centre,
                    radius,
                    road,
                };
                let barrier = edge.barrier("e", [0, 1], hull).unwrap();
                let x = state(p);
                // h ≥ 0 exactly where the hull is on the road; its clearance is the gap (m).
                assert_eq!(barrier.h(&x) >= 0.0, gap >= 0.0, "{road:?} {p:?}");
                assert!((barrier.clearance(&x) - gap).abs() < 1e-9, "{road:?} {p:?}");
                assert!((edge.distance(p) - hull - gap).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn names_default_to_their_index() {
        let edge = Edge::Arc {
            name: None,
            centre: [0.0, 0.0],
            radius: 1.0,
            road: ArcSide::Inside,
        };
        assert_eq!(edge.name(2), "road_edge_2");
        let named = Edge::Line {
            name: Some("kerb".into()),
            point: [0.0, 0.0],
            direction: [1.0, 0.0],
            road: LineSide::Left,
        };
        assert_eq!(named.name(0), "kerb");
    }

    #[test]
    fn bad_geometry_is_named() {
        let e = 1e9;
        assert_eq!(
            curve_problem(Some(([0.0, 0.0], [0.0, 0.0])), None, e).unwrap().0,
            "direction"
        );
        assert_eq!(
            curve_problem(Some(([0.0, 0.0], [f64::NAN, 1.0])), None, e).unwrap().0,
            "direction"
        );
        assert_eq!(
            curve_problem(Some(([2e9, 0.0], [1.0, 0.0])), None, e).unwrap().0,
            "point"
        );
        assert_eq!(curve_problem(None, Some(([0.0, 0.0], -1.0)), e).unwrap().0, "radius");
        assert_eq!(curve_problem(None, Some(([0.0, 0.0], 0.0)), e).unwrap().0, "radius");
        assert_eq!(
            curve_problem(None, Some(([f64::INFINITY, 0.0], 1.0)), e).unwrap().0,
            "centre"
        );
        assert!(curve_problem(Some(([1.0, 2.0], [1e-300, 0.0])), Some(([0.0, 0.0], 5.0)), e).is_none());
    }

    #[test]
    fn drawn_lines_cover_the_scene_and_dashes_are_bounded() {
        let line = Curve::line([0.0, -10.0], [2.0, 0.0]);
        let drawn = line.polyline(&[[-20.0, 0.0], [30.0, 0.0]]);
        assert_eq!(drawn, [[-40.0, -10.0], [50.0, -10.0]]);
        let dashes = line.dashes(&[[-20.0, 0.0], [30.0, 0.0]]);
        assert_eq!(dashes.len(), 2 * 15);
        assert_eq!(dashes[0], [-40.0, -10.0]);
        assert_eq!(dashes[1], [-37.0, -10.0]);
        let huge = Curve::Circle {
            centre: [0.0, 0.0],
            radius: 1e9,
        };
        assert!(huge.dashes(&[]).len() <= 2 * MAX_DASHES);
        assert_eq!(huge.polyline(&[]).len(), CIRCLE_SEGMENTS + 1);
    }

    #[test]
    fn a_planar_half_space_is_drawn_where_h_is_zero() {
        let shape = Shape::HalfSpace {
            coefficients: vec![0.0, -2.0, 0.0, 0.0],
            offset: 8.0,
        };
        let Some(Curve::Line { point, direction }) = planar_half_space(&shape, [0, 1]) else {
            panic!("a line")
        };
        assert_eq!(point, [0.0, 4.0]);
        assert_eq!(direction, [1.0, 0.0]);
        let on_speed = Shape::HalfSpace {
            coefficients: vec![0.0, 1.0, 0.0, 1.0],
            offset: 0.0,
        };
        assert!(planar_half_space(&on_speed, [0, 1]).is_none());
    }
}
