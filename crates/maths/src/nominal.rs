//! Nominal (safety-agnostic) controllers u0(x), the input the safety filter corrects.

pub mod route;

use std::sync::Arc;

use nalgebra::{DMatrix, DVector, Vector2};
use serde::{Deserialize, Serialize};

use crate::dynamics::Dynamics;
use crate::params::{ParamError, Params};
use crate::prescribed_time::{BlowUp, PtsNominal, RedLightNominal, StrictFeedbackSystem};

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum NominalError {
    #[error("the Riccati solve did not converge (is (A, B) stabilisable and Q >= 0, R > 0?)")]
    RiccatiNotConverged,
    #[error("R is not invertible")]
    SingularR,
}

/// Stabilising solution P of the continuous algebraic Riccati equation
/// AᵀP + PA − PBR⁻¹BᵀP + Q = 0, by the matrix sign function of the Hamiltonian
/// H = [[A, −BR⁻¹Bᵀ], [−Q, −Aᵀ]] (Newton iteration with determinant scaling).
pub fn solve_care(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<DMatrix<f64>, NominalError> {
    let n = a.nrows();
    let r_inv = r.clone().try_inverse().ok_or(NominalError::SingularR)?;
    let mut z = DMatrix::zeros(2 * n, 2 * n);
    z.view_mut((0, 0), (n, n)).copy_from(a);
    z.view_mut((0, n), (n, n)).copy_from(&(-(b * &r_inv * b.transpose())));
    z.view_mut((n, 0), (n, n)).copy_from(&(-q));
    z.view_mut((n, n), (n, n)).copy_from(&(-a.transpose()));
    let mut converged = false;
    for _ in 0..100 {
        let det = z.determinant().abs();
        let inv = z.clone().try_inverse().ok_or(NominalError::RiccatiNotConverged)?;
        let scale = if det > 0.0 && det.is_finite() {
            det.powf(-1.0 / (2.0 * n as f64))
        } else {
            1.0
        };
        let next = (&z * scale + inv / scale) * 0.5;
        let change = (&next - &z).norm() / next.norm();
        z = next;
        if change < 1e-13 {
            converged = true;
            break;
        }
    }
    if !converged {
        return Err(NominalError::RiccatiNotConverged);
    }
    // The stable subspace [I; P] satisfies (W + I)[I; P] = 0, with W = sign(H).
    let w11 = z.view((0, 0), (n, n));
    let w12 = z.view((0, n), (n, n));
    let w21 = z.view((n, 0), (n, n));
    let w22 = z.view((n, n), (n, n));
    let mut lhs = DMatrix::zeros(2 * n, n);
    lhs.view_mut((0, 0), (n, n)).copy_from(&w12);
    lhs.view_mut((n, 0), (n, n)).copy_from(&(w22 + DMatrix::identity(n, n)));
    let mut rhs = DMatrix::zeros(2 * n, n);
    rhs.view_mut((0, 0), (n, n))
        .copy_from(&(-(w11 + DMatrix::identity(n, n))));
    rhs.view_mut((n, 0), (n, n)).copy_from(&(-w21));
    let p = lhs
        .svd(true, true)
        .solve(&rhs, 1e-14)
        .map_err(|_| NominalError::RiccatiNotConverged)?;
    let p = (&p + p.transpose()) * 0.5;
    if p.iter().any(|v| !v.is_finite()) {
        return Err(NominalError::RiccatiNotConverged);
    }
    Ok(p)
}

/// LQR gain K = R⁻¹BᵀP for u = −K e.
pub fn lqr_gain(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    q: &DMatrix<f64>,
    r: &DMatrix<f64>,
) -> Result<DMatrix<f64>, NominalError> {
    let p = solve_care(a, b, q, r)?;
    let r_inv = r.clone().try_inverse().ok_or(NominalError::SingularR)?;
    Ok(r_inv * b.transpose() * p)
}

/// Tracks a straight path at a reference speed with the kinematic bicycle (4.78), by LQR on
/// the linearisation about the path: e = (cross-track error, heading error, speed error),
/// ė = A e + B u with A = [[0, v̄, 0], [0, 0, 0], [0, 0, 0]], B = [[0, 0], [v̄/L, 0], [0, 1]].
#[derive(Debug, Clone, PartialEq)]
pub struct BicyclePathLqr {
    pub path_point: [f64; 2],
    pub path_heading: f64,
    pub reference_speed: f64,
    /// 2×3 gain K (u = −K e).
    pub gain: [[f64; 3]; 2],
    /// (sin, cos) of the path heading.
    path_direction: (f64, f64),
}

impl BicyclePathLqr {
    pub fn new(
        path_point: [f64; 2],
        path_heading: f64,
        reference_speed: f64,
        wheelbase: f64,
        q_diag: [f64; 3],
        r_diag: [f64; 2],
    ) -> Result<BicyclePathLqr, NominalError> {
        let v = reference_speed;
        let a = DMatrix::from_row_slice(3, 3, &[0.0, v, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let b = DMatrix::from_row_slice(3, 2, &[0.0, 0.0, v / wheelbase, 0.0, 0.0, 1.0]);
        let q = DMatrix::from_diagonal(&DVector::from_column_slice(&q_diag));
        let r = DMatrix::from_diagonal(&DVector::from_column_slice(&r_diag));
        Ok(BicyclePathLqr {
            path_point,
            path_heading,
            reference_speed,
            gain: {
                let k = lqr_gain(&a, &b, &q, &r)?;
                std::array::from_fn(|i| std::array::from_fn(|j| k[(i, j)]))
            },
            path_direction: path_heading.sin_cos(),
        })
    }

    /// Tracking error of state x = (x1, x2, heading, speed).
    #[inline]
    pub fn error(&self, x: &[f64]) -> [f64; 3] {
        let &[px, py, heading, speed, ..] = x else {
            panic!("a bicycle state has 4 components, found {}", x.len());
        };
        let (s, c) = self.path_direction;
        let cross_track = -s * (px - self.path_point[0]) + c * (py - self.path_point[1]);
        let heading_error = wrap_angle(heading - self.path_heading);
        [cross_track, heading_error, speed - self.reference_speed]
    }

    /// u ← −K e(x).
    #[inline]
    pub fn input_into(&self, x: &[f64], u: &mut [f64]) {
        let error = self.error(x);
        for (u, k) in u.iter_mut().zip(&self.gain) {
            *u = -(k[0] * error[0] + k[1] * error[1] + k[2] * error[2]);
        }
    }
}

/// Angle in (−π, π].
#[inline]
pub fn wrap_angle(angle: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    // rem_euclid's fmod returns |angle| < 2π unchanged (exactly): skip the call there.
    let mut a = if angle.abs() < two_pi {
        if angle < 0.0 {
            angle + two_pi
        } else {
            angle
        }
    } else {
        angle.rem_euclid(two_pi)
    };
    if a > std::f64::consts::PI {
        a -= two_pi;
    }
    a
}

/// The stabilising time-varying predictor-feedback controller of Example 2 of \[9\] for the
/// unicycle (2.40)–(2.43), evaluated at the prediction p = (p_x, p_y, p_θ) and the prediction
/// time φ⁻¹(t).
pub fn unicycle_stabilizer(prediction_time: f64, p: &[f64]) -> [f64; 2] {
    let (px, py, ptheta) = (p[0], p[1], p[2]);
    let (s, c) = ptheta.sin_cos();
    let a = px * c + py * s; // (2.42)
    let b = px * s - py * c; // (2.43)
    let (s3, c3) = (3.0 * prediction_time).sin_cos();
    let turn_rate = -5.0 * a * a * c3 - a * b * (1.0 + 25.0 * c3 * c3) - ptheta; // (2.40)
    let speed = -a + 5.0 * b * s3 - 5.0 * b * c3 + b * turn_rate; // (2.41)
    [speed, turn_rate]
}

/// (4.58): u0 = −(L_f V + ‖x‖²) L_g Vᵀ / ‖L_g V‖² (0 where L_g V = 0), V = x1⁴/4 + x2²/2 (4.57),
/// which gives V̇ ≤ −‖x‖² (4.59).
/// For a two-state, two-input system (checked when the scenario is built).
pub fn quartic_clf(model: &dyn crate::dynamics::Dynamics, x: &[f64]) -> [f64; 2] {
    let grad_v = [x[0].powi(3), x[1]];
    let dot = |a: &[f64; 2], b: &[f64; 2]| a[0] * b[0] + a[1] * b[1];
    let mut f = [0.0; 2];
    model.drift_into(x, &mut f);
    let lf_v = dot(&grad_v, &f);
    // L_g V component j = ∇V · g_j, with g_j = G e_j.
    let mut lg_v = [0.0; 2];
    for (j, lg_v_j) in lg_v.iter_mut().enumerate() {
        let mut g_j = [0.0; 2];
        let mut e_j = [0.0; 2];
        e_j[j] = 1.0;
        model.add_input_term(x, &e_j, &mut g_j);
        *lg_v_j = dot(&grad_v, &g_j);
    }
    let norm2 = dot(&lg_v, &lg_v);
    if norm2 < 1e-14 {
        return [0.0; 2];
    }
    let scale = -(lf_v + x[0] * x[0] + x[1] * x[1]) / norm2;
    [lg_v[0] * scale, lg_v[1] * scale]
}

/// A nominal (safety-agnostic) controller u0: the extension point a scenario's
/// `nominal.kind` names (see `mjsafe::registry`). Called inside the control callback and the
/// predictors: it must not panic or allocate.
pub trait NominalController: Send {
    /// u ← u0 at time `time` and state x (one value per channel).
    fn input_into(&self, time: f64, x: &[f64], u: &mut [f64]);

    /// Whether u0 reads the moving road users the controller knows (a lead to follow):
    /// then [`NominalController::input_with_actors_into`] is called instead of `input_into`.
    fn reads_actors(&self) -> bool {
        false
    }

    /// u ← u0 at time `time` and state x, with each moving road user the controller knows
    /// where it assumes it at `time` (`[actor_knowledge]`), in the order of the scenario's
    /// moving obstacles (docs/actors.md). Default: [`NominalController::input_into`].
    fn input_with_actors_into(&self, time: f64, x: &[f64], actors: &[SeenActor], u: &mut [f64]) {
        let _ = actors;
        self.input_into(time, x, u)
    }

    /// [`NominalController::input_with_actors_into`] for a controller that can fail (one
    /// written in another language): the control loop calls this one, and an error stops the
    /// run with an error event carrying the message. Default: never fails.
    fn try_input_into(&self, time: f64, x: &[f64], actors: &[SeenActor], u: &mut [f64]) -> Result<(), String> {
        self.input_with_actors_into(time, x, actors, u);
        Ok(())
    }

    /// Whether the controller is itself a predictor-feedback law, evaluated at the prediction
    /// p(t) and its time φ⁻¹(t) even when the safety filter is not delay-compensated (§2.4.2).
    fn uses_prediction(&self) -> bool {
        false
    }

    /// u0 when it does not depend on time or state (filters that stabilise through their own
    /// CLF check it is zero).
    fn constant_input(&self) -> Option<&[f64]> {
        None
    }

    /// The straight path the controller tracks, drawn in the 3D scene.
    fn reference_path(&self) -> Option<ReferencePath> {
        None
    }

    /// The values of a nominal commanded from outside the loop (`kind = "external"`: a
    /// learning agent's action, set between steps by `Episode::set_external_input`);
    /// `None` for a controller that computes its own.
    fn external_input_mut(&mut self) -> Option<&mut [f64]> {
        None
    }
}

/// A moving road user as a nominal controller sees it: its state where the controller assumes
/// it, and the gap (m) between it and the vehicle at the state u0 is evaluated at (the
/// clearance of its barrier: for a lead to follow, D = lead's rear − vehicle's front).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SeenActor {
    pub state: crate::actor::ActorState,
    pub gap: f64,
    /// A lead on the line (`[obstacles.following]`).
    pub lead: bool,
}

/// A straight reference path: a point, its heading (rad) and the reference speed (m/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferencePath {
    pub point: [f64; 2],
    pub heading: f64,
    pub speed: f64,
}

/// What a nominal controller is built from.
pub struct NominalContext<'a> {
    /// The analytic model the controller assumes.
    pub model: &'a Arc<dyn Dynamics>,
    /// The scenario's `vehicle.kind`.
    pub vehicle_kind: &'a str,
    /// The vehicle's input channels, in order.
    pub channels: &'a [String],
}

fn positive_finite(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

/// `kind = "path_lqr"`: LQR tracking of a straight path with the bicycle ([`BicyclePathLqr`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathLqrParams {
    pub reference_speed: f64,
    /// A point of the straight path.
    #[serde(default)]
    pub path_point: [f64; 2],
    /// Direction of the path (radians).
    #[serde(default)]
    pub path_heading: f64,
    /// Diagonal of Q for (cross-track, heading, speed) errors.
    #[serde(default = "default_q")]
    pub q: [f64; 3],
    /// Diagonal of R for (steering, acceleration).
    #[serde(default = "default_r")]
    pub r: [f64; 2],
}

fn default_q() -> [f64; 3] {
    [1.0, 1.0, 1.0]
}
fn default_r() -> [f64; 2] {
    [1.0, 1.0]
}

impl Params for PathLqrParams {
    fn validate(&self) -> Result<(), ParamError> {
        if !positive_finite(self.reference_speed) {
            return Err(ParamError::new(
                "nominal.reference_speed",
                format!("expected a positive speed, found {}", self.reference_speed),
            ));
        }
        if self.q.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return Err(ParamError::new("nominal.q", "expected three weights >= 0"));
        }
        if self.r.iter().any(|v| !positive_finite(*v)) {
            return Err(ParamError::new("nominal.r", "expected two weights > 0"));
        }
        Ok(())
    }
}

pub fn build_path_lqr(p: &PathLqrParams, ctx: &NominalContext) -> Result<Box<dyn NominalController>, ParamError> {
    let wheelbase = bicycle_wheelbase(ctx, "path_lqr")?;
    let lqr = BicyclePathLqr::new(p.path_point, p.path_heading, p.reference_speed, wheelbase, p.q, p.r)
        .map_err(|e| ParamError::new("nominal", e.to_string()))?;
    Ok(Box::new(lqr))
}

/// The wheelbase L of a vehicle whose analytic model is the kinematic bicycle (4.78) (`bicycle`,
/// `car`, a user's), or the error of nominal `kind` that needs one.
pub(crate) fn bicycle_wheelbase(ctx: &NominalContext, kind: &str) -> Result<f64, ParamError> {
    let bicycle = crate::dynamics::BicycleModel::new(1.0);
    if ctx.model.state_names() != bicycle.state_names() || ctx.model.channel_names() != bicycle.channel_names() {
        return Err(ParamError::new(
            "nominal.kind",
            format!(
                "{kind} needs a vehicle with the kinematic bicycle model (4.78) (state {}; inputs {}), e.g. vehicle.kind = \"bicycle\" or \"car\"",
                bicycle.state_names().join(", "),
                bicycle.channel_names().join(", ")
            ),
        ));
    }
    // (4.78): G[2, 0] = v tan'(0)/L at v = 1.
    let n = ctx.model.state_dim();
    Ok(ctx.model.input_matrix(&DVector::from_element(n, 1.0))[(2, 0)].recip())
}

impl NominalController for BicyclePathLqr {
    fn input_into(&self, _: f64, x: &[f64], u: &mut [f64]) {
        BicyclePathLqr::input_into(self, x, u)
    }
    fn reference_path(&self) -> Option<ReferencePath> {
        Some(ReferencePath {
            point: self.path_point,
            heading: self.path_heading,
            speed: self.reference_speed,
        })
    }
}

/// `kind = "car_following"`: Molnar, Kiss, Ames, Orosz's nominal behind a lead (arXiv 2112.08445;
/// their `truck.m`): u0 = A (min(κ (D − D_st), v_max) − v) + B (min(v_L, v_max) − v), with D the
/// gap to the first lead (`[obstacles.following]`) and v_L its speed where the controller
/// assumes it; without a known lead, D = ∞ (cruise at v_max).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CarFollowingParams {
    /// A (1/s): the gain on the headway's speed error.
    #[serde(default = "default_gap_gain")]
    pub gap_gain: f64,
    /// B (1/s): the gain on the lead's speed.
    #[serde(default = "default_speed_gain")]
    pub speed_gain: f64,
    /// D_st (m): the standstill gap.
    #[serde(default = "default_standstill")]
    pub standstill: f64,
    /// κ (1/s): the range policy's slope.
    #[serde(default = "default_kappa")]
    pub kappa: f64,
    /// v_max (m/s).
    #[serde(default = "default_max_speed")]
    pub max_speed: f64,
}

fn default_gap_gain() -> f64 {
    0.4
}
fn default_speed_gain() -> f64 {
    0.5
}
fn default_standstill() -> f64 {
    5.0
}
fn default_kappa() -> f64 {
    0.5
}
fn default_max_speed() -> f64 {
    20.0
}

impl Params for CarFollowingParams {
    fn validate(&self) -> Result<(), ParamError> {
        for (key, v) in [
            ("nominal.gap_gain", self.gap_gain),
            ("nominal.speed_gain", self.speed_gain),
            ("nominal.kappa", self.kappa),
            ("nominal.max_speed", self.max_speed),
        ] {
            if !positive_finite(v) {
                return Err(ParamError::new(key, format!("expected a positive number, found {v}")));
            }
        }
        if !(self.standstill.is_finite() && self.standstill >= 0.0) {
            return Err(ParamError::new(
                "nominal.standstill",
                format!("expected a gap >= 0 (m), found {}", self.standstill),
            ));
        }
        Ok(())
    }
}

/// Molnar et al.'s car-following law ([`CarFollowingParams`]) for a vehicle on a line whose
/// one input is its acceleration.
pub struct CarFollowing {
    params: CarFollowingParams,
    speed: usize,
}

pub fn build_car_following(
    p: &CarFollowingParams,
    ctx: &NominalContext,
) -> Result<Box<dyn NominalController>, ParamError> {
    let model = ctx.model.as_ref();
    let refuse = || {
        ParamError::new(
            "nominal.kind",
            "car_following needs a vehicle on a line whose one input is its acceleration (e.g. vehicle.kind = \"double_integrator_1d\")",
        )
    };
    let position = model.line_position().ok_or_else(refuse)?;
    let n = model.state_dim();
    if ctx.channels.len() != 1 {
        return Err(refuse());
    }
    // The speed: the state the position's derivative is; its derivative the input itself.
    let x = DVector::zeros(n);
    let jacobian = model.drift_jacobian(&x);
    let row = jacobian.row(position);
    let speed = (0..n)
        .find(|&s| row[s] == 1.0 && row.iter().enumerate().all(|(j, v)| j == s || *v == 0.0))
        .ok_or_else(refuse)?;
    if model.input_matrix(&x)[(speed, 0)] != 1.0 || model.drift(&x)[speed] != 0.0 {
        return Err(refuse());
    }
    Ok(Box::new(CarFollowing {
        params: p.clone(),
        speed,
    }))
}

impl NominalController for CarFollowing {
    fn input_into(&self, time: f64, x: &[f64], u: &mut [f64]) {
        self.input_with_actors_into(time, x, &[], u)
    }
    fn reads_actors(&self) -> bool {
        true
    }
    fn input_with_actors_into(&self, _: f64, x: &[f64], actors: &[SeenActor], u: &mut [f64]) {
        let p = &self.params;
        let v = x[self.speed];
        let (gap, lead_speed) = actors
            .iter()
            .find(|a| a.lead)
            .map_or((f64::INFINITY, p.max_speed), |a| (a.gap, a.state.velocity[0]));
        u[0] = p.gap_gain * ((p.kappa * (gap - p.standstill)).min(p.max_speed) - v)
            + p.speed_gain * (lead_speed.min(p.max_speed) - v);
    }
}

/// `kind = "constant"`: one value per channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConstantParams {
    pub input: Vec<f64>,
}

impl Params for ConstantParams {
    fn validate(&self) -> Result<(), ParamError> {
        if self.input.iter().any(|v| !v.is_finite()) {
            return Err(ParamError::new("nominal.input", "expected finite numbers"));
        }
        Ok(())
    }
}

/// A constant input.
pub struct ConstantInput(pub Vec<f64>);

pub fn build_constant(p: &ConstantParams, ctx: &NominalContext) -> Result<Box<dyn NominalController>, ParamError> {
    if p.input.len() != ctx.channels.len() {
        return Err(ParamError::new(
            "nominal.input",
            format!("expected {} values ({})", ctx.channels.len(), ctx.channels.join(", ")),
        ));
    }
    Ok(Box::new(ConstantInput(p.input.clone())))
}

impl NominalController for ConstantInput {
    fn input_into(&self, _: f64, _: &[f64], u: &mut [f64]) {
        u.copy_from_slice(&self.0);
    }
    fn constant_input(&self) -> Option<&[f64]> {
        Some(&self.0)
    }
}

/// `kind = "external"`: u0 is set from outside the loop between steps (`mjsafe.Env`'s
/// action, `Episode::set_external_input`); `initial` until then (default 0).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExternalParams {
    #[serde(default)]
    pub initial: Option<Vec<f64>>,
}

impl Params for ExternalParams {
    fn validate(&self) -> Result<(), ParamError> {
        if self.initial.iter().flatten().any(|v| !v.is_finite()) {
            return Err(ParamError::new("nominal.initial", "expected finite numbers"));
        }
        Ok(())
    }
}

/// A nominal set from outside: the last values set, held (zero-order hold). The predictors
/// assume it held over their window, the best guess without a model of what sets it.
pub struct ExternalInput(Vec<f64>);

pub fn build_external(p: &ExternalParams, ctx: &NominalContext) -> Result<Box<dyn NominalController>, ParamError> {
    let initial = p.initial.clone().unwrap_or_else(|| vec![0.0; ctx.channels.len()]);
    if initial.len() != ctx.channels.len() {
        return Err(ParamError::new(
            "nominal.initial",
            format!("expected {} values ({})", ctx.channels.len(), ctx.channels.join(", ")),
        ));
    }
    Ok(Box::new(ExternalInput(initial)))
}

impl NominalController for ExternalInput {
    fn input_into(&self, _: f64, _: &[f64], u: &mut [f64]) {
        u.copy_from_slice(&self.0);
    }
    fn external_input_mut(&mut self) -> Option<&mut [f64]> {
        Some(&mut self.0)
    }
}

/// A kind without parameters.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoParams {}

impl Params for NoParams {}

/// `kind = "unicycle_stabilizer"`: (2.40)–(2.43) at the prediction and φ⁻¹(t).
pub struct UnicycleStabilizer;

pub fn build_unicycle_stabilizer(_: &NoParams, ctx: &NominalContext) -> Result<Box<dyn NominalController>, ParamError> {
    if ctx.vehicle_kind != "unicycle" {
        return Err(ParamError::new(
            "nominal.kind",
            "unicycle_stabilizer needs vehicle.kind = \"unicycle\"",
        ));
    }
    Ok(Box::new(UnicycleStabilizer))
}

impl NominalController for UnicycleStabilizer {
    fn input_into(&self, time: f64, x: &[f64], u: &mut [f64]) {
        u.copy_from_slice(&unicycle_stabilizer(time, x));
    }
    fn uses_prediction(&self) -> bool {
        true
    }
}

/// `kind = "quartic_clf"`: (4.58) for V = x1⁴/4 + x2²/2 (4.57).
pub struct QuarticClf(Arc<dyn Dynamics>);

pub fn build_quartic_clf(_: &NoParams, ctx: &NominalContext) -> Result<Box<dyn NominalController>, ParamError> {
    if ctx.model.state_dim() != 2 || ctx.channels.len() != 2 {
        return Err(ParamError::new(
            "nominal.kind",
            "quartic_clf (4.57)/(4.58) needs a two-state system",
        ));
    }
    Ok(Box::new(QuarticClf(ctx.model.clone())))
}

impl NominalController for QuarticClf {
    fn input_into(&self, _: f64, x: &[f64], u: &mut [f64]) {
        u.copy_from_slice(&quartic_clf(self.0.as_ref(), x));
    }
}

/// `kind = "red_light"`: (5.20)–(5.22), u = −k1 z1 − k2 z2, z1 = x1 + a sin(ωt) + b,
/// z2 = x2 + aω cos(ωt).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RedLightParams {
    pub k1: f64,
    pub k2: f64,
    pub a: f64,
    pub b: f64,
    pub omega: f64,
}

impl Params for RedLightParams {}

pub fn build_red_light(p: &RedLightParams, ctx: &NominalContext) -> Result<Box<dyn NominalController>, ParamError> {
    if ctx.vehicle_kind != "double_integrator_1d" && ctx.model.state_dim() != 2 {
        return Err(ParamError::new(
            "nominal.kind",
            "red_light (5.20) needs a double integrator",
        ));
    }
    Ok(Box::new(RedLightNominal {
        position_gain: p.k1,
        velocity_gain: p.k2,
        amplitude: p.a,
        offset: p.b,
        frequency: p.omega,
    }))
}

impl NominalController for RedLightNominal {
    fn input_into(&self, time: f64, x: &[f64], u: &mut [f64]) {
        u[0] = self.control(time, &Vector2::new(x[0], x[1]));
    }
}

/// `kind = "pts"`: the prescribed-time stabiliser (5.87)/(5.88) of (5.82),
/// v = −μ2(t)[ω², 2ζω] z on [0, T), in z-coordinates and mapped back by (5.91).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PtsParams {
    pub omega: f64,
    pub zeta: f64,
    pub horizon: f64,
    /// Clip of μ2 (required: (5.87) blows up at T).
    #[serde(default)]
    pub clip: Option<f64>,
}

impl Params for PtsParams {}

pub fn build_pts(p: &PtsParams, ctx: &NominalContext) -> Result<Box<dyn NominalController>, ParamError> {
    if ctx.vehicle_kind != "strict_feedback" {
        return Err(ParamError::new(
            "nominal.kind",
            "pts (5.87) needs vehicle.kind = \"strict_feedback\"",
        ));
    }
    let clip = p.clip.ok_or_else(|| {
        ParamError::new(
            "nominal.clip",
            "the nominal (5.87) blows up at T: expected a clip of mu_2 (e.g. 1000)",
        )
    })?;
    let blow_up = BlowUp::new(0.0, p.horizon)
        .and_then(|b| b.with_mu2_clip(clip))
        .map_err(|e| ParamError::new("nominal", e.to_string()))?;
    Ok(Box::new(PtsNominal {
        natural_frequency: p.omega,
        damping_ratio: p.zeta,
        blow_up,
    }))
}

impl NominalController for PtsNominal {
    fn input_into(&self, time: f64, x: &[f64], u: &mut [f64]) {
        let state = Vector2::new(x[0], x[1]);
        let z = StrictFeedbackSystem.to_chain(&state);
        // With the clip required when built, μ2 is defined for all t; NaN would stop the
        // episode with an error rather than pass silently.
        let v = self.control(time, &z).unwrap_or(f64::NAN);
        u[0] = StrictFeedbackSystem.plant_input(&state, v);
    }
}

/// Largest state a [`SpeedTracking`] nominal evaluates f and G for on the stack.
const SPEED_TRACKING_MAX_STATES: usize = 8;

/// `kind = "speed_tracking"`: drives the state named `speed` to `target_speed` as the first-order
/// lag v̇ = gain (v_d − v), by feedback linearisation of the model's speed row,
/// u0 = (gain (v_d − v) − f_v(x)) / g_v(x), for a single-input model. For the longitudinal car
/// this is u0 = m · gain (v_d − v) + F_r(v), the speed-tracking law (without its CLF) of Ames et
/// al., CDC 2014.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpeedTrackingParams {
    /// The speed to track, v_d (m/s, finite).
    pub target_speed: f64,
    /// The rate of the speed error's decay (1/s, > 0).
    pub gain: f64,
}

impl Params for SpeedTrackingParams {
    fn validate(&self) -> Result<(), ParamError> {
        if !self.target_speed.is_finite() {
            return Err(ParamError::new("nominal.target_speed", "expected a finite speed (m/s)"));
        }
        if !positive_finite(self.gain) {
            return Err(ParamError::new("nominal.gain", "expected a finite rate > 0 (1/s)"));
        }
        Ok(())
    }
}

/// The nominal of [`SpeedTrackingParams`].
pub struct SpeedTracking {
    model: Arc<dyn Dynamics>,
    speed: usize,
    target_speed: f64,
    gain: f64,
}

pub fn build_speed_tracking(
    p: &SpeedTrackingParams,
    ctx: &NominalContext,
) -> Result<Box<dyn NominalController>, ParamError> {
    let model = ctx.model;
    let speed = model.state_names().iter().position(|n| n == "speed");
    match speed {
        Some(speed) if model.input_dim() == 1 && model.state_dim() <= SPEED_TRACKING_MAX_STATES => {
            Ok(Box::new(SpeedTracking {
                model: model.clone(),
                speed,
                target_speed: p.target_speed,
                gain: p.gain,
            }))
        }
        _ => Err(ParamError::new(
            "nominal.kind",
            format!(
                "speed_tracking needs a single-input vehicle with a state named `speed` and at most {SPEED_TRACKING_MAX_STATES} states (state {}; inputs {}), e.g. vehicle.kind = \"longitudinal\"",
                model.state_names().join(", "),
                model.channel_names().join(", ")
            ),
        )),
    }
}

impl NominalController for SpeedTracking {
    fn input_into(&self, _: f64, x: &[f64], u: &mut [f64]) {
        // f(x) and the column g(x) = G(x)·1 on the stack (no allocation in the callback).
        let n = x.len().min(SPEED_TRACKING_MAX_STATES);
        let (mut f, mut g) = ([0.0; SPEED_TRACKING_MAX_STATES], [0.0; SPEED_TRACKING_MAX_STATES]);
        self.model.drift_into(&x[..n], &mut f[..n]);
        self.model.add_input_term(&x[..n], &[1.0], &mut g[..n]);
        let v = x[self.speed];
        // g_v = 0 gives a non-finite input, which stops the episode with an error.
        u[0] = (self.gain * (self.target_speed - v) - f[self.speed]) / g[self.speed];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn riccati_solution_satisfies_the_equation_and_stabilises() {
        let v = 3.0;
        let a = DMatrix::from_row_slice(3, 3, &[0.0, v, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let b = DMatrix::from_row_slice(3, 2, &[0.0, 0.0, v / 6.0, 0.0, 0.0, 1.0]);
        let q = DMatrix::identity(3, 3);
        let r = DMatrix::identity(2, 2);
        let p = solve_care(&a, &b, &q, &r).unwrap();
        let residual = a.transpose() * &p + &p * &a - &p * &b * b.transpose() * &p + &q;
        assert!(residual.norm() < 1e-9, "CARE residual {}", residual.norm());
        let k = lqr_gain(&a, &b, &q, &r).unwrap();
        let closed = &a - &b * &k;
        for ev in closed.complex_eigenvalues().iter() {
            assert!(ev.re < 0.0, "closed-loop eigenvalue {ev}");
        }
    }

    #[test]
    fn scalar_riccati_matches_the_closed_form() {
        // ẋ = a x + u, q, r = 1: P = a + sqrt(a² + q).
        let (a, q) = (0.7, 2.0);
        let p = solve_care(
            &DMatrix::from_element(1, 1, a),
            &DMatrix::from_element(1, 1, 1.0),
            &DMatrix::from_element(1, 1, q),
            &DMatrix::from_element(1, 1, 1.0),
        )
        .unwrap();
        assert!((p[(0, 0)] - (a + (a * a + q).sqrt())).abs() < 1e-10);
    }

    #[test]
    fn wrap_angle_without_fmod_is_the_rem_euclid_form() {
        let reference = |angle: f64| {
            let a = angle.rem_euclid(std::f64::consts::TAU);
            if a > std::f64::consts::PI {
                a - std::f64::consts::TAU
            } else {
                a
            }
        };
        let tau = std::f64::consts::TAU;
        let mut angles = vec![0.0, -0.0, 1e-300, -1e-300, 7.0 * tau, -7.0 * tau + 0.1, 1e6, -1e6];
        for edge in [tau, std::f64::consts::PI] {
            for sign in [1.0, -1.0] {
                let e = sign * edge;
                angles.extend([
                    e,
                    e.next_up(),
                    e.next_down(),
                    e.next_up().next_up(),
                    e.next_down().next_down(),
                ]);
            }
        }
        angles.extend((-2000..2000).map(|k| k as f64 * 0.00731));
        for angle in angles {
            assert_eq!(wrap_angle(angle).to_bits(), reference(angle).to_bits(), "{angle:e}");
        }
    }

    #[test]
    fn wrap_angle_stays_in_range() {
        assert!((wrap_angle(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
        assert!((wrap_angle(-0.5) + 0.5).abs() < 1e-12);
    }
    #[test]
    fn acc_speed_tracking_is_mass_times_gain_times_error_plus_resistance() {
        let model: Arc<dyn Dynamics> =
            Arc::new(crate::dynamics::LongitudinalModel::new(1650.0, [0.1, 5.0, 0.25], 14.0));
        let channels = model.channel_names().to_vec();
        let ctx = NominalContext {
            model: &model,
            vehicle_kind: "longitudinal",
            channels: &channels,
        };
        let nominal = build_speed_tracking(
            &SpeedTrackingParams {
                target_speed: 24.0,
                gain: 0.5,
            },
            &ctx,
        )
        .unwrap();
        let mut u = [0.0];
        nominal.input_into(0.0, &[0.0, 20.0, 100.0], &mut u);
        // m k (v_d − v) + f0 + f1 v + f2 v² = 1650·0.5·4 + 0.1 + 100 + 100.
        assert!((u[0] - 3500.1).abs() < 1e-9, "{}", u[0]);
    }
}
