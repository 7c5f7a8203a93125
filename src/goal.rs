//! The `[goal]` table: a region the planar position should enter — a disc or polygons — with
//! the conditions `time_to_goal` asks for at arrival (speed, heading, a time window). The
//! section's spec and its checks at load; the goal metrics read it from the run metadata.

use serde::{Deserialize, Serialize};

use crate::params::ParamError;
use crate::section::{Section, SectionContext};

/// The `[goal]` table: a region the planar position should enter — a disc (`position`,
/// `radius`) or polygons (their union; a CommonRoad goal's rectangles, polygons and lanelets) —
/// optionally within a time window (`after`, `by`); or, without a region, the conditions alone
/// (a CommonRoad goal of a time window, and a speed or heading interval, with no position).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GoalSpec {
    /// Centre of the disc (planar position, m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<[f64; 2]>,
    /// Radius of the disc (m, > 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// The region as polygons instead (each at least 3 points, m; at most
    /// [`MAX_GOAL_POLYGONS`] of at most [`MAX_GOAL_POINTS`] points).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub polygons: Vec<Vec<[f64; 2]>>,
    /// Start of the time window (s, ≥ 0): states before it do not count.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub after: Option<f64>,
    /// The point that must enter the region lies this far ahead of the planar position along
    /// the heading (m; a CommonRoad goal: the car's centre, b ahead of the bicycle's rear axle).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset: Option<f64>,
    /// The speed (the state named `speed`, m/s) must lie in [lo, hi] too, for `time_to_goal`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub speed: Option<[f64; 2]>,
    /// The heading (rad, modulo 2π) must lie in [lo, hi] too, for `time_to_goal`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heading: Option<[f64; 2]>,
    /// Deadline (s, > 0): `distance_to_goal` counts only the states up to it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub by: Option<f64>,
    /// The goal states, any one of which, whole, reaches the goal (a CommonRoad planning
    /// problem's, when they differ in more than their regions): each a region or none with its
    /// own `after`, `by`, `speed` and `heading` (no `offset`, no `states`; the point is the
    /// table's). The table's own region, window and intervals are then their union and hulls:
    /// `distance_to_goal` and the scene use those, `time_to_goal` asks one state whole. At most
    /// [`MAX_GOAL_STATES`].
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub states: Vec<GoalSpec>,
}

/// Most goal states of a goal.
pub const MAX_GOAL_STATES: usize = 64;

/// Most polygons of a goal region, and most points of one.
pub const MAX_GOAL_POLYGONS: usize = 64;
/// Most points of one goal polygon.
pub const MAX_GOAL_POINTS: usize = 10_000;

impl GoalSpec {
    /// The checks of the table when the scenario loads: a disc (finite centre, positive radius)
    /// or 1 to [`MAX_GOAL_POLYGONS`] polygons of 3 to [`MAX_GOAL_POINTS`] points (or no region,
    /// with a time window, a speed or a heading interval), all within
    /// ±`extent` m; an offset, speed and heading intervals, and a window `after` ≤ `by`. Keys
    /// are the scenario's (`goal.radius`). (Planarity is checked with the model.)
    pub fn validate(&self, extent: f64) -> Result<(), ParamError> {
        let goal = self;
        let point_ok = |p: &[f64; 2]| p.iter().all(|v| v.is_finite() && v.abs() <= extent);
        match (goal.position, goal.radius, goal.polygons.is_empty()) {
            (Some(position), Some(radius), true) => {
                if !point_ok(&position) {
                    return Err(ParamError::new(
                        "goal.position",
                        format!("expected two finite coordinates within ±{extent:e} m"),
                    ));
                }
                if !(radius.is_finite() && radius > 0.0) || radius > extent {
                    return Err(ParamError::new(
                        "goal.radius",
                        format!("expected a positive radius (m), found {radius}"),
                    ));
                }
            }
            (None, None, false) => {
                if goal.polygons.len() > MAX_GOAL_POLYGONS {
                    return Err(ParamError::new(
                        "goal.polygons",
                        format!(
                            "expected at most {MAX_GOAL_POLYGONS} polygons, found {}",
                            goal.polygons.len()
                        ),
                    ));
                }
                for (i, polygon) in goal.polygons.iter().enumerate() {
                    if !(3..=MAX_GOAL_POINTS).contains(&polygon.len()) || !polygon.iter().all(point_ok) {
                        return Err(ParamError::new(
                            format!("goal.polygons.{i}"),
                            format!(
                                "expected 3 to {MAX_GOAL_POINTS} points with finite coordinates within ±{extent:e} m"
                            ),
                        ));
                    }
                }
            }
            // A goal of conditions alone (a CommonRoad goal without a position): something
            // must be asked.
            (None, None, true) if goal.speed.is_some() || goal.heading.is_some() || goal.after.is_some() || goal.by.is_some() => {}
            _ => {
                return Err(ParamError::new(
                    "goal",
                    "expected a disc (`position` and `radius`) or `polygons`, one of the two, or without a region a time window (`after`, `by`) or a `speed` or `heading` interval",
                ))
            }
        }
        if let Some(offset) = goal.offset {
            if !(offset.is_finite() && offset.abs() <= extent) {
                return Err(ParamError::new(
                    "goal.offset",
                    format!("expected a distance (m), found {offset}"),
                ));
            }
        }
        for (key, interval) in [("goal.speed", goal.speed), ("goal.heading", goal.heading)] {
            if let Some([lo, hi]) = interval {
                if !(lo.is_finite() && hi.is_finite() && lo <= hi && lo.abs() <= extent && hi.abs() <= extent) {
                    return Err(ParamError::new(
                        key,
                        format!("expected an interval [lo, hi] with lo <= hi, found [{lo}, {hi}]"),
                    ));
                }
            }
        }
        if let Some(after) = goal.after {
            if !(after.is_finite() && after >= 0.0) {
                return Err(ParamError::new(
                    "goal.after",
                    format!("expected a time >= 0 (s), found {after}"),
                ));
            }
        }
        if let Some(by) = goal.by {
            if !(by.is_finite() && by > 0.0) || goal.after.is_some_and(|after| by < after) {
                return Err(ParamError::new(
                    "goal.by",
                    format!("expected a positive time (s), not before `after`, found {by}"),
                ));
            }
        }
        if goal.states.len() > MAX_GOAL_STATES {
            return Err(ParamError::new(
                "goal.states",
                format!(
                    "expected at most {MAX_GOAL_STATES} goal states, found {}",
                    goal.states.len()
                ),
            ));
        }
        for (i, state) in goal.states.iter().enumerate() {
            let key = format!("goal.states.{i}");
            if !state.states.is_empty() || state.offset.is_some() {
                return Err(ParamError::new(
                    key,
                    "expected a region, `after`, `by`, `speed` and `heading` only (the point and its `offset` are the goal's)",
                ));
            }
            state.validate(extent).map_err(|mut e| {
                e.key = e.key.replacen("goal", &key, 1);
                e
            })?;
        }
        Ok(())
    }
}

/// `[goal]`: checked here; the run's description and the progress metrics read it.
impl Section for GoalSpec {
    fn validate(&self, _key: &str, cx: &SectionContext<'_>) -> Result<(), ParamError> {
        GoalSpec::validate(self, cx.extent)
    }
}
