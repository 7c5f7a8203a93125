//! `kind = "route"`: follows a reference path — a polyline, e.g. a CommonRoad route's centre
//! line (docs/commonroad.md) — with the kinematic bicycle (4.78) by pure pursuit at a reference
//! speed. It ignores other road users: keeping clear of them is the safety filter's job.
//!
//! Steering: the point g on the path a look-ahead distance l_d = max(l_min, T_la v) past the
//! path point nearest the rear axle p; α = ∠(g − p) − θ; the arc through g has curvature
//! κ = 2 sin α / l_d, so u1 = tan δ = L κ (θ̇ = v u1 / L), limited to |δ| ≤ δ_max.
//! Speed: u2 = k (v_ref − v), limited to ±a_max.

use serde::{Deserialize, Serialize};

use super::{NominalContext, NominalController};
use crate::params::{ParamError, Params};

/// Most points of a reference path.
pub const MAX_PATH_POINTS: usize = 100_000;

/// The parameters of `route`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RouteParams {
    /// The reference path's points (m), at least 2, in driving order.
    pub path: Vec<[f64; 2]>,
    /// The reference speed v_ref (m/s, > 0).
    pub speed: f64,
    /// l_min, the shortest look-ahead distance (m).
    #[serde(default = "default_min_lookahead")]
    pub min_lookahead: f64,
    /// T_la, the look-ahead time (s): l_d = max(l_min, T_la v).
    #[serde(default = "default_lookahead_time")]
    pub lookahead_time: f64,
    /// k, the speed gain (1/s).
    #[serde(default = "default_speed_gain")]
    pub speed_gain: f64,
    /// a_max, the largest |u2| (m/s²).
    #[serde(default = "default_max_acceleration")]
    pub max_acceleration: f64,
    /// δ_max, the largest steering angle (rad; CommonRoad's vehicle 2: 1.066).
    #[serde(default = "default_max_steering")]
    pub max_steering: f64,
}

fn default_min_lookahead() -> f64 {
    5.0
}
fn default_lookahead_time() -> f64 {
    1.0
}
fn default_speed_gain() -> f64 {
    1.0
}
fn default_max_acceleration() -> f64 {
    3.0
}
fn default_max_steering() -> f64 {
    1.066
}

impl Params for RouteParams {
    fn validate(&self) -> Result<(), ParamError> {
        let n = self.path.len();
        if !(2..=MAX_PATH_POINTS).contains(&n) {
            return Err(ParamError::new(
                "nominal.path",
                format!("expected 2 to {MAX_PATH_POINTS} points, found {n}"),
            ));
        }
        if let Some(k) = self
            .path
            .iter()
            .position(|p| !(p[0].is_finite() && p[1].is_finite() && p[0].abs() <= 1e9 && p[1].abs() <= 1e9))
        {
            return Err(ParamError::new(
                "nominal.path",
                format!("expected finite points within ±1e9 m (point {k} is not)"),
            ));
        }
        for (key, v) in [
            ("speed", self.speed),
            ("min_lookahead", self.min_lookahead),
            ("speed_gain", self.speed_gain),
            ("max_acceleration", self.max_acceleration),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= 1e6) {
                return Err(ParamError::new(
                    format!("nominal.{key}"),
                    format!("expected a positive number, found {v}"),
                ));
            }
        }
        if !(self.lookahead_time.is_finite() && (0.0..=1e3).contains(&self.lookahead_time)) {
            return Err(ParamError::new(
                "nominal.lookahead_time",
                format!("expected a time >= 0 (s), found {}", self.lookahead_time),
            ));
        }
        if !(self.max_steering.is_finite() && self.max_steering > 0.0 && self.max_steering < 1.5) {
            return Err(ParamError::new(
                "nominal.max_steering",
                format!("expected an angle in (0, 1.5) rad, found {}", self.max_steering),
            ));
        }
        Ok(())
    }
}

/// The `route` nominal, built for a model with the kinematic bicycle's state and inputs.
#[derive(Debug, Clone, PartialEq)]
pub struct RouteFollowing {
    params: RouteParams,
    /// Arc length at each path point (m).
    arc: Vec<f64>,
    /// The path's index for nearest-segment searches.
    blocks: crate::planar::Blocks,
    wheelbase: f64,
}

/// Builds `route` (any vehicle whose analytic model is the bicycle (4.78)).
pub fn build(p: &RouteParams, ctx: &NominalContext) -> Result<Box<dyn NominalController>, ParamError> {
    let wheelbase = super::bicycle_wheelbase(ctx, "route")?;
    let mut arc = Vec::with_capacity(p.path.len());
    let mut s = 0.0;
    for (k, q) in p.path.iter().enumerate() {
        if k > 0 {
            s += (q[0] - p.path[k - 1][0]).hypot(q[1] - p.path[k - 1][1]);
        }
        arc.push(s);
    }
    Ok(Box::new(RouteFollowing {
        params: p.clone(),
        arc,
        blocks: crate::planar::Blocks::new(&p.path),
        wheelbase,
    }))
}

impl RouteFollowing {
    /// The arc length of the path point nearest to `p` (projected onto the nearest segment).
    fn nearest_arc(&self, p: [f64; 2]) -> f64 {
        let (k, f, _) = self.blocks.nearest_segment(&self.params.path, p);
        match k + 1 < self.arc.len() {
            true => self.arc[k] + f * (self.arc[k + 1] - self.arc[k]),
            false => 0.0,
        }
    }

    /// The path point at arc length s (past the end: on along the last segment).
    fn point_at(&self, s: f64) -> [f64; 2] {
        let path = &self.params.path;
        let n = path.len();
        let k = self.arc.partition_point(|&a| a <= s).clamp(1, n - 1) - 1;
        let (a, b) = (path[k], path[k + 1]);
        let l = self.arc[k + 1] - self.arc[k];
        let f = if l > 0.0 { (s - self.arc[k]) / l } else { 0.0 };
        [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])]
    }
}

impl NominalController for RouteFollowing {
    fn input_into(&self, _time: f64, x: &[f64], u: &mut [f64]) {
        let &[px, py, heading, speed, ..] = x else {
            return;
        };
        let p = &self.params;
        let lookahead = p.min_lookahead.max(p.lookahead_time * speed.abs());
        let g = self.point_at(self.nearest_arc([px, py]) + lookahead);
        let alpha = (g[1] - py).atan2(g[0] - px) - heading;
        let distance = (g[0] - px).hypot(g[1] - py).max(1e-6);
        let curvature = 2.0 * alpha.sin() / distance;
        let limit = p.max_steering.tan();
        u[0] = (self.wheelbase * curvature).clamp(-limit, limit);
        u[1] = (p.speed_gain * (p.speed - speed)).clamp(-p.max_acceleration, p.max_acceleration);
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::dynamics::{BicycleModel, Dynamics};

    fn follower(path: Vec<[f64; 2]>) -> Box<dyn NominalController> {
        let model: Arc<dyn Dynamics> = Arc::new(BicycleModel::new(2.5789128));
        let channels = model.channel_names().to_vec();
        let ctx = NominalContext {
            model: &model,
            vehicle_kind: "bicycle",
            channels: &channels,
        };
        let params: RouteParams = toml::from_str(&format!("path = {path:?}\nspeed = 10.0")).expect("params");
        params.validate().unwrap();
        build(&params, &ctx).unwrap()
    }

    /// Closed loop on the bicycle (4.78) by RK4: from 1 m beside an L-shaped path, the vehicle
    /// converges onto it, turns the corner and holds the reference speed.
    #[test]
    fn follows_a_path_round_a_corner() {
        let nominal = follower(vec![[0.0, 0.0], [50.0, 0.0], [50.0, 60.0]]);
        let model = BicycleModel::new(2.5789128);
        let (mut x, h) = (vec![0.0, 1.0, 0.0, 8.0], 0.01);
        let mut u = [0.0; 2];
        let mut worst_after_settling: f64 = 0.0;
        for k in 0..1000 {
            nominal.input_into(k as f64 * h, &x, &mut u);
            let f = |x: &[f64]| {
                let mut d = vec![0.0; 4];
                model.dynamics_into(x, &u, &mut d);
                d
            };
            let add = |x: &[f64], k: &[f64], s: f64| x.iter().zip(k).map(|(a, b)| a + s * b).collect::<Vec<_>>();
            let k1 = f(&x);
            let k2 = f(&add(&x, &k1, h / 2.0));
            let k3 = f(&add(&x, &k2, h / 2.0));
            let k4 = f(&add(&x, &k3, h));
            x = (0..4)
                .map(|i| x[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
                .collect();
            if (300..400).contains(&k) {
                worst_after_settling = worst_after_settling.max(x[1].abs());
            }
        }
        assert!(worst_after_settling < 0.1, "cross-track {worst_after_settling}");
        // After 10 s at ~10 m/s: up the second leg, near x = 50.
        assert!((x[0] - 50.0).abs() < 1.0 && x[1] > 20.0, "{x:?}");
        assert!((x[3] - 10.0).abs() < 0.05, "{x:?}");
    }

    #[test]
    fn bad_paths_are_refused_with_the_key() {
        let p: RouteParams = toml::from_str("path = [[0.0, 0.0]]\nspeed = 1.0").unwrap();
        assert_eq!(p.validate().unwrap_err().key, "nominal.path");
        let p: RouteParams = toml::from_str("path = [[0.0, 0.0], [1.0, 1e300]]\nspeed = 1.0").unwrap();
        assert_eq!(p.validate().unwrap_err().key, "nominal.path");
        let p: RouteParams = toml::from_str("path = [[0.0, 0.0], [1.0, 0.0]]\nspeed = -1.0").unwrap();
        assert_eq!(p.validate().unwrap_err().key, "nominal.speed");
    }
}
