//! The ego's route through a CommonRoad lanelet network (pure geometry): the lanelet its start
//! lies in, a shortest path over successors (cost: the lanelet's length) and same-direction
//! neighbours (cost: a lane change, [`LANE_CHANGE_COST`]) to a goal lanelet, and the route's
//! centre line, the reference path of the `route` nominal.

use std::collections::{BTreeMap, BinaryHeap};

use mjsafe_commonroad::{CommonRoad, Lanelet};

/// What a lane change costs in the search (m of driving).
pub const LANE_CHANGE_COST: f64 = 30.0;
/// How far the centre line goes on past the goal lanelet along first successors (m): the
/// nominal's look-ahead needs a path beyond the goal.
pub const RUN_OUT: f64 = 100.0;
/// Most lanelets of one route.
pub const MAX_ROUTE: usize = 1000;

/// A route: its lanelets in order and its centre line.
#[derive(Debug, Clone, PartialEq)]
pub struct Route {
    pub lanelets: Vec<u64>,
    pub centre: Vec<[f64; 2]>,
}

/// The centre line of a lanelet: the midpoints of its bounds, both resampled to the larger
/// number of points by arc-length fraction when they differ.
pub fn centre_line(l: &Lanelet) -> Vec<[f64; 2]> {
    let (left, right) = (&l.left.points, &l.right.points);
    if left.len() == right.len() {
        return left.iter().zip(right).map(|(a, b)| mid(*a, *b)).collect();
    }
    let n = left.len().max(right.len());
    let (left, right) = (crate::planar::resample(left, n), crate::planar::resample(right, n));
    left.iter().zip(&right).map(|(a, b)| mid(*a, *b)).collect()
}

fn mid(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])]
}

pub use crate::planar::length;

/// The lanelet's polygon: its left bound, then its right bound reversed.
pub fn polygon(l: &Lanelet) -> Vec<[f64; 2]> {
    l.left
        .points
        .iter()
        .chain(l.right.points.iter().rev())
        .copied()
        .collect()
}

/// Whether `p` lies inside the lanelet's polygon.
pub fn contains(l: &Lanelet, p: [f64; 2]) -> bool {
    crate::planar::polygon_contains(&polygon(l), p)
}

/// The direction (rad) of the lanelet's centre line at its point nearest to `p`.
fn direction_near(l: &Lanelet, p: [f64; 2]) -> f64 {
    let c = centre_line(l);
    let k = (0..c.len() - 1)
        .min_by(|&a, &b| dist2(c[a], p).total_cmp(&dist2(c[b], p)))
        .unwrap_or(0);
    (c[k + 1][1] - c[k][1]).atan2(c[k + 1][0] - c[k][0])
}

fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)
}

/// The lanelets containing `p` whose direction there is within 90° of `heading`, the best
/// aligned first.
pub fn lanelets_at(cr: &CommonRoad, p: [f64; 2], heading: f64) -> Vec<u64> {
    let mut found: Vec<(f64, u64)> = cr
        .lanelets
        .iter()
        .filter(|l| contains(l, p))
        .map(|l| {
            let d = direction_near(l, p) - heading;
            (d.sin().atan2(d.cos()).abs(), l.id)
        })
        .filter(|(misalignment, _)| *misalignment < std::f64::consts::FRAC_PI_2)
        .collect();
    found.sort_by(|a, b| a.0.total_cmp(&b.0));
    found.into_iter().map(|(_, id)| id).collect()
}

/// The lanelets reachable from `lanelet` in one move: successors (cost their length) and
/// same-direction neighbours (a lane change).
fn moves(cr: &CommonRoad, lanelet: &Lanelet) -> Vec<(u64, f64)> {
    let mut out: Vec<(u64, f64)> = lanelet
        .successors
        .iter()
        .filter_map(|id| cr.lanelet(*id))
        .map(|s| (s.id, length(&centre_line(s))))
        .collect();
    for adjacent in [lanelet.adjacent_left, lanelet.adjacent_right].into_iter().flatten() {
        if adjacent.same_direction {
            out.push((adjacent.id, LANE_CHANGE_COST));
        }
    }
    out
}

/// The cheapest route (Dijkstra) from `start` to any of `goals`; with no goals, the start
/// lanelet followed by first successors.
pub fn plan(cr: &CommonRoad, start: u64, goals: &[u64]) -> Option<Vec<u64>> {
    if goals.is_empty() {
        return Some(run_out(cr, vec![start], f64::INFINITY));
    }
    let mut best: BTreeMap<u64, (f64, Option<u64>)> = BTreeMap::from([(start, (0.0, None))]);
    let mut queue = BinaryHeap::from([Entry(0.0, start)]);
    while let Some(Entry(cost, id)) = queue.pop() {
        if goals.contains(&id) {
            let mut route = vec![id];
            while let Some((_, Some(previous))) = best.get(route.last().expect("non-empty")) {
                route.push(*previous);
                if route.len() > MAX_ROUTE {
                    return None;
                }
            }
            route.reverse();
            return Some(route);
        }
        if best.get(&id).is_some_and(|(c, _)| *c < cost) {
            continue;
        }
        let lanelet = cr.lanelet(id)?;
        for (next, step) in moves(cr, lanelet) {
            let total = cost + step;
            if best.get(&next).is_none_or(|(c, _)| total < *c) {
                best.insert(next, (total, Some(id)));
                queue.push(Entry(total, next));
            }
        }
    }
    None
}

/// `route` extended along first successors for `distance` metres more (or, infinite, until a
/// lanelet without a successor or one already on the route), at most [`MAX_ROUTE`] lanelets.
fn run_out(cr: &CommonRoad, mut route: Vec<u64>, distance: f64) -> Vec<u64> {
    let mut walked = 0.0;
    while walked < distance && route.len() < MAX_ROUTE {
        let last = *route.last().expect("non-empty");
        let Some(next) = cr.lanelet(last).and_then(|l| l.successors.first()).copied() else {
            break;
        };
        if route.contains(&next) {
            break;
        }
        walked += cr.lanelet(next).map_or(0.0, |l| length(&centre_line(l)));
        route.push(next);
    }
    route
}

/// The centre line of a route, [`RUN_OUT`] metres past its end: each lanelet's centre line;
/// across a lane change (the next lanelet a neighbour, not a successor), the rest of the
/// neighbour's from the point nearest to where the route is.
pub fn centre_of(cr: &CommonRoad, route: &[u64]) -> Vec<[f64; 2]> {
    let route = run_out(cr, route.to_vec(), RUN_OUT);
    let mut centre: Vec<[f64; 2]> = Vec::new();
    for (k, id) in route.iter().enumerate() {
        let Some(l) = cr.lanelet(*id) else { continue };
        let line = centre_line(l);
        let successor = k > 0 && cr.lanelet(route[k - 1]).is_some_and(|p| p.successors.contains(id));
        let from = match centre.last() {
            Some(&last) if !successor => {
                // A lane change: drop the current lanelet's second half, join the neighbour's
                // centre line ahead of its nearest point.
                let half = centre.len() - line.len().min(centre.len()) / 2;
                centre.truncate(half.max(1));
                let last = *centre.last().unwrap_or(&last);
                (0..line.len())
                    .min_by(|&a, &b| dist2(line[a], last).total_cmp(&dist2(line[b], last)))
                    .unwrap_or(0)
                    + 1
            }
            Some(_) => 1, // a successor starts where its predecessor ends
            None => 0,
        };
        centre.extend(line.iter().skip(from.min(line.len())));
    }
    centre.dedup_by(|a, b| dist2(*a, *b) < 1e-12);
    centre
}

/// The lanelet farthest to one side of `id` over same-direction neighbours (`left`: over
/// `adjacent_left`, else `adjacent_right`), at most [`MAX_ROUTE`] steps.
fn outermost(cr: &CommonRoad, id: u64, left: bool) -> u64 {
    let mut current = id;
    for _ in 0..MAX_ROUTE {
        let next = cr
            .lanelet(current)
            .and_then(|l| if left { l.adjacent_left } else { l.adjacent_right });
        match next {
            Some(a) if a.same_direction && a.id != id => current = a.id,
            _ => break,
        }
    }
    current
}

/// The road's edges along a route (and [`RUN_OUT`] past it): the left bounds of the leftmost and
/// the right bounds of the rightmost same-direction lanelets beside each route lanelet, joined
/// in driving order (each lanelet once); (left edge, right edge).
pub fn road_edges(cr: &CommonRoad, route: &[u64]) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let route = run_out(cr, route.to_vec(), RUN_OUT);
    let mut edges = (Vec::new(), Vec::new());
    for (left, edge) in [(true, &mut edges.0), (false, &mut edges.1)] {
        let mut used: Vec<u64> = Vec::new();
        for id in &route {
            let outer = outermost(cr, *id, left);
            if used.contains(&outer) {
                continue;
            }
            used.push(outer);
            let Some(l) = cr.lanelet(outer) else { continue };
            let bound = if left { &l.left.points } else { &l.right.points };
            for p in bound {
                if edge.last().is_none_or(|q: &[f64; 2]| dist2(*q, *p) > 1e-12) {
                    edge.push(*p);
                }
            }
        }
    }
    edges
}

/// A queue entry ordered by the least cost first (then the id, for a deterministic order).
#[derive(Debug, PartialEq)]
struct Entry(f64, u64);

impl Eq for Entry {}

impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Entry {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        other.0.total_cmp(&self.0).then(other.1.cmp(&self.1))
    }
}
