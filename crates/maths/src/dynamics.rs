//! The analytic control-affine models ẋ = f(x) + G(x) u that filters and predictors use
//! ([`Dynamics`]): bicycle (4.78), unicycle (2.36), double integrators, linear systems,
//! Example 1 of Ch. 4 (4.52), the strict-feedback system (5.82), the longitudinal car of
//! Ames et al.'s adaptive cruise control (CDC 2014). Pure maths: no MuJoCo.

use nalgebra::{DMatrix, DVector};

/// The analytic control-affine model ẋ = f(x) + G(x) u.
///
/// Models implement the in-place forms (no allocation: predictors and filters call them many
/// times per control tick); the allocating forms are derived from them.
pub trait Dynamics: Send + Sync {
    /// Names of the state components, in order.
    fn state_names(&self) -> &[String];
    /// Names of the input channels, in order.
    fn channel_names(&self) -> &[String];
    /// f ← f(x).
    fn drift_into(&self, x: &[f64], f: &mut [f64]);
    /// ẋ ← ẋ + G(x) u, without forming G.
    fn add_input_term(&self, x: &[f64], u: &[f64], xdot: &mut [f64]);
    /// j ← ∂f/∂x (j arrives zeroed; used for Lie derivatives of relative-degree-2 barriers).
    fn drift_jacobian_into(&self, x: &[f64], j: &mut DMatrix<f64>);
    /// g ← G(x) = [g_1(x), …, g_r(x)] (g arrives zeroed).
    fn input_matrix_into(&self, x: &[f64], g: &mut DMatrix<f64>);
    /// Indices of the planar position (x, y) in the state, if the system moves in a plane.
    fn planar_position(&self) -> Option<[usize; 2]> {
        None
    }
    /// Index of the heading angle in the state, if the system has one.
    fn heading_index(&self) -> Option<usize> {
        None
    }
    /// The model's scalar parameters by name (SI units), e.g. the bicycle's
    /// `wheelbase` (m): what a filter written elsewhere (Python) reads instead of hard-coding.
    fn parameters(&self) -> Vec<(&'static str, f64)> {
        Vec::new()
    }
    /// Index of the position of a vehicle that moves along a line (the 1-D double integrator):
    /// the Foxglove scene draws it along the world x axis.
    fn line_position(&self) -> Option<usize> {
        None
    }

    /// ẋ ← f(x) + G(x) u.
    fn dynamics_into(&self, x: &[f64], u: &[f64], xdot: &mut [f64]) {
        self.drift_into(x, xdot);
        self.add_input_term(x, u, xdot);
    }
    /// f ← f(x), g ← G(x), j ← ∂f/∂x in one call (g and j arrive zeroed), for Lie
    /// derivatives; a model may override it to share work between the three.
    fn lie_terms_into(&self, x: &[f64], f: &mut [f64], g: &mut DMatrix<f64>, j: &mut DMatrix<f64>) {
        self.drift_into(x, f);
        self.input_matrix_into(x, g);
        self.drift_jacobian_into(x, j);
    }
    /// For the squared planar distance d(x) = ‖p − c‖² (p the planar position, c a point):
    /// `[d, L_f d, L_f² d]`, with the rows L_g d into `lg` and L_g L_f d into `lg_lf`, in closed
    /// form; `None` when the model has none (the Lie derivatives are then formed from f, G and
    /// ∂f/∂x). Obstacle barriers (4.81) are d − r².
    fn squared_distance_lie_into(
        &self,
        _x: &[f64],
        _centre: [f64; 2],
        _lg: &mut [f64],
        _lg_lf: &mut [f64],
    ) -> Option<[f64; 3]> {
        None
    }
    /// For a linear function ℓ(x) = c·x (`c` over the leading state components, the rest 0):
    /// `[L_f ℓ, L_f² ℓ]`, with the rows L_g ℓ into `lg` and L_g L_f ℓ into `lg_lf`, in closed
    /// form; `None` when the model has none. Half-space barriers (2.47) are ℓ + d. The sums
    /// are the general path's nonzero terms in its order from 0.0 (so `0.0 + …`: no −0), the
    /// same bits for a finite state.
    fn linear_lie_into(&self, _x: &[f64], _c: &[f64], _lg: &mut [f64], _lg_lf: &mut [f64]) -> Option<[f64; 2]> {
        None
    }
    /// Whether the dynamics commute with rigid motions of the plane acting on the planar
    /// position and the heading (they do not depend on where the vehicle is or which way it
    /// faces): the shared predictor then moves its previous trajectory onto a new
    /// measurement instead of integrating it again.
    fn planar_motion_invariant(&self) -> bool {
        false
    }
    /// x ← the exact solution of ẋ = f(x) + G(x) u after `dt` with u held constant, when the
    /// model has a closed form (the predictors then step with it instead of RK4); returns
    /// false, leaving x untouched, when it has none.
    fn flow_into(&self, _x: &mut [f64], _u: &[f64], _dt: f64) -> bool {
        false
    }
    /// Drift f(x).
    fn drift(&self, x: &DVector<f64>) -> DVector<f64> {
        let mut f = DVector::zeros(x.len());
        self.drift_into(x.as_slice(), f.as_mut_slice());
        f
    }
    /// Jacobian ∂f/∂x.
    fn drift_jacobian(&self, x: &DVector<f64>) -> DMatrix<f64> {
        let mut j = DMatrix::zeros(x.len(), x.len());
        self.drift_jacobian_into(x.as_slice(), &mut j);
        j
    }
    /// Input matrix G(x).
    fn input_matrix(&self, x: &DVector<f64>) -> DMatrix<f64> {
        let mut g = DMatrix::zeros(x.len(), self.input_dim());
        self.input_matrix_into(x.as_slice(), &mut g);
        g
    }
    /// ẋ = f(x) + G(x) u.
    fn dynamics(&self, x: &DVector<f64>, u: &DVector<f64>) -> DVector<f64> {
        let mut xdot = DVector::zeros(x.len());
        self.dynamics_into(x.as_slice(), u.as_slice(), xdot.as_mut_slice());
        xdot
    }
    fn state_dim(&self) -> usize {
        self.state_names().len()
    }
    fn input_dim(&self) -> usize {
        self.channel_names().len()
    }
}

fn names(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

/// Kinematic bicycle (4.78) with wheelbase L.
#[derive(Debug, Clone)]
pub struct BicycleModel {
    pub wheelbase: f64,
    state_names: Vec<String>,
    channel_names: Vec<String>,
}

impl BicycleModel {
    pub fn new(wheelbase: f64) -> BicycleModel {
        BicycleModel {
            wheelbase,
            state_names: names(&["x1", "x2", "heading", "speed"]),
            channel_names: names(&["steering", "acceleration"]),
        }
    }
}

impl Dynamics for BicycleModel {
    fn state_names(&self) -> &[String] {
        &self.state_names
    }
    /// L (m).
    fn parameters(&self) -> Vec<(&'static str, f64)> {
        vec![("wheelbase", self.wheelbase)]
    }
    fn channel_names(&self) -> &[String] {
        &self.channel_names
    }
    fn drift_into(&self, x: &[f64], f: &mut [f64]) {
        bicycle_drift(x, x[2].sin_cos(), f);
    }
    fn add_input_term(&self, x: &[f64], u: &[f64], xdot: &mut [f64]) {
        xdot[2] += x[3] / self.wheelbase * u[0];
        xdot[3] += u[1];
    }
    fn drift_jacobian_into(&self, x: &[f64], j: &mut DMatrix<f64>) {
        bicycle_drift_jacobian(x, x[2].sin_cos(), j);
    }
    fn input_matrix_into(&self, x: &[f64], g: &mut DMatrix<f64>) {
        g[(2, 0)] = x[3] / self.wheelbase;
        g[(3, 1)] = 1.0;
    }
    // One sin/cos of the heading for all terms (the predictors call these in their inner loop).
    fn dynamics_into(&self, x: &[f64], u: &[f64], xdot: &mut [f64]) {
        bicycle_drift(x, x[2].sin_cos(), xdot);
        self.add_input_term(x, u, xdot);
    }
    fn planar_motion_invariant(&self) -> bool {
        true
    }
    // (4.88)–(4.90): L_f d = 2v(Δx cos θ + Δy sin θ), L_f² d = 2v², L_g d = 0,
    // L_g L_f d = (2v²/L (Δy cos θ − Δx sin θ), 2(Δx cos θ + Δy sin θ)).
    fn squared_distance_lie_into(
        &self,
        x: &[f64],
        centre: [f64; 2],
        lg: &mut [f64],
        lg_lf: &mut [f64],
    ) -> Option<[f64; 3]> {
        // Destructured: no bounds checks, no memset (the predictors call it at every step).
        let (&[px, py, heading, v, ..], [lg_0, lg_1], [lg_lf_0, lg_lf_1]) = (x, lg, lg_lf) else {
            return None;
        };
        let (dx, dy) = (px - centre[0], py - centre[1]);
        let (s, c) = heading.sin_cos();
        let along = dx * c + dy * s;
        (*lg_0, *lg_1) = (0.0, 0.0);
        *lg_lf_0 = 2.0 * v * v / self.wheelbase * (dy * c - dx * s);
        *lg_lf_1 = 2.0 * along;
        Some([dx * dx + dy * dy, 2.0 * v * along, 2.0 * v * v])
    }
    // (4.78) with ℓ = c·x: L_f ℓ = v (c_x cos θ + c_y sin θ), L_g ℓ = (c_θ v/L, c_v),
    // ∇L_f ℓ = (0, 0, v (c_y cos θ − c_x sin θ), c_x cos θ + c_y sin θ), so L_f² ℓ = 0 and
    // L_g L_f ℓ = (v/L · v (c_y cos θ − c_x sin θ), c_x cos θ + c_y sin θ).
    fn linear_lie_into(&self, x: &[f64], c: &[f64], lg: &mut [f64], lg_lf: &mut [f64]) -> Option<[f64; 2]> {
        let (&[_, _, heading, v, ..], [lg_0, lg_1], [lg_lf_0, lg_lf_1]) = (x, lg, lg_lf) else {
            return None;
        };
        let k = |i| coefficient(c, i);
        let (s, cos) = heading.sin_cos();
        let steer_gain = v / self.wheelbase;
        // ∂f/∂x's columns 2 and 3 against c.
        let lf_grad_heading = 0.0 + -v * s * k(0) + v * cos * k(1);
        let lf_grad_speed = 0.0 + cos * k(0) + s * k(1);
        (*lg_0, *lg_1) = (0.0 + steer_gain * k(2), 0.0 + k(3));
        (*lg_lf_0, *lg_lf_1) = (0.0 + steer_gain * lf_grad_heading, 0.0 + lf_grad_speed);
        Some([0.0 + k(0) * (v * cos) + k(1) * (v * s), 0.0])
    }
    // Exact with (u_1, u_2) held: v(s) = v_0 + u_2 s, θ advances by u_1/L per metre travelled,
    // so with σ = ∫v (signed distance) (x, y) moves by ∫ (cos, sin)(θ_0 + u_1 σ / L) dσ, a chord.
    fn flow_into(&self, x: &mut [f64], u: &[f64], dt: f64) -> bool {
        let distance = x[3] * dt + 0.5 * u[1] * dt * dt;
        let half_turn = 0.5 * u[0] / self.wheelbase * distance;
        advance_along_arc(x, distance, half_turn);
        x[3] += u[1] * dt;
        true
    }
    fn lie_terms_into(&self, x: &[f64], f: &mut [f64], g: &mut DMatrix<f64>, j: &mut DMatrix<f64>) {
        let heading = x[2].sin_cos();
        bicycle_drift(x, heading, f);
        self.input_matrix_into(x, g);
        bicycle_drift_jacobian(x, heading, j);
    }
    fn planar_position(&self) -> Option<[usize; 2]> {
        Some([0, 1])
    }
    fn heading_index(&self) -> Option<usize> {
        Some(2)
    }
}

/// c_i, 0 past the end of c (the coefficients of ℓ = c·x over the leading components).
#[inline(always)]
fn coefficient(c: &[f64], i: usize) -> f64 {
    c.get(i).copied().unwrap_or(0.0)
}

/// (x, y, θ) ← the end of a circular arc of signed length `distance` turning by 2 `half_turn`:
/// the chord distance · sinc(half_turn) along θ + half_turn.
fn advance_along_arc(x: &mut [f64], distance: f64, half_turn: f64) {
    let (s, c) = (x[2] + half_turn).sin_cos();
    let chord = distance * sinc(half_turn);
    x[0] += chord * c;
    x[1] += chord * s;
    x[2] += 2.0 * half_turn;
}

/// sin(z)/z, by its Taylor series near 0 (truncation < z¹⁰/11! < 3e-18 for |z| < 0.1).
fn sinc(z: f64) -> f64 {
    if z.abs() < 0.1 {
        let z2 = z * z;
        1.0 - z2 / 6.0 * (1.0 - z2 / 20.0 * (1.0 - z2 / 42.0 * (1.0 - z2 / 72.0)))
    } else {
        z.sin() / z
    }
}

/// f(x) of (4.78) given (sin, cos) of the heading.
fn bicycle_drift(x: &[f64], (s, c): (f64, f64), f: &mut [f64]) {
    f.copy_from_slice(&[x[3] * c, x[3] * s, 0.0, 0.0]);
}

/// ∂f/∂x of (4.78) given (sin, cos) of the heading (the other entries stay zero).
fn bicycle_drift_jacobian(x: &[f64], (s, c): (f64, f64), j: &mut DMatrix<f64>) {
    j[(0, 2)] = -x[3] * s;
    j[(0, 3)] = c;
    j[(1, 2)] = x[3] * c;
    j[(1, 3)] = s;
}

/// Nonholonomic unicycle (2.36): ẋ = v cos θ, ẏ = v sin θ, θ̇ = ω.
#[derive(Debug, Clone)]
pub struct UnicycleModel {
    state_names: Vec<String>,
    channel_names: Vec<String>,
}

impl Default for UnicycleModel {
    fn default() -> Self {
        UnicycleModel {
            state_names: names(&["x", "y", "heading"]),
            channel_names: names(&["speed", "turn_rate"]),
        }
    }
}

impl Dynamics for UnicycleModel {
    fn state_names(&self) -> &[String] {
        &self.state_names
    }
    fn channel_names(&self) -> &[String] {
        &self.channel_names
    }
    fn drift_into(&self, _x: &[f64], f: &mut [f64]) {
        f.fill(0.0);
    }
    fn add_input_term(&self, x: &[f64], u: &[f64], xdot: &mut [f64]) {
        let (s, c) = x[2].sin_cos();
        xdot[0] += c * u[0];
        xdot[1] += s * u[0];
        xdot[2] += u[1];
    }
    // (2.36) written out: the predictors' RK4 stages call it in their inner loop (the
    // default zero-fills f first). `0.0 +` keeps the default's bits (no −0).
    fn dynamics_into(&self, x: &[f64], u: &[f64], xdot: &mut [f64]) {
        let (s, c) = x[2].sin_cos();
        xdot[0] = 0.0 + c * u[0];
        xdot[1] = 0.0 + s * u[0];
        xdot[2] = 0.0 + u[1];
    }
    fn drift_jacobian_into(&self, _x: &[f64], _j: &mut DMatrix<f64>) {}
    fn planar_motion_invariant(&self) -> bool {
        true
    }
    // Driftless: L_f d = L_f² d = 0, L_g d = (2(Δx cos θ + Δy sin θ), 0).
    fn squared_distance_lie_into(
        &self,
        x: &[f64],
        centre: [f64; 2],
        lg: &mut [f64],
        lg_lf: &mut [f64],
    ) -> Option<[f64; 3]> {
        let (dx, dy) = (x[0] - centre[0], x[1] - centre[1]);
        let (s, c) = x[2].sin_cos();
        lg[0] = 2.0 * (dx * c + dy * s);
        lg[1] = 0.0;
        lg_lf.fill(0.0);
        Some([dx * dx + dy * dy, 0.0, 0.0])
    }
    // Driftless: L_f ℓ = L_f² ℓ = 0, L_g ℓ = (c_x cos θ + c_y sin θ, c_θ), L_g L_f ℓ = 0.
    fn linear_lie_into(&self, x: &[f64], c: &[f64], lg: &mut [f64], lg_lf: &mut [f64]) -> Option<[f64; 2]> {
        let (&[_, _, heading, ..], [lg_0, lg_1], [lg_lf_0, lg_lf_1]) = (x, lg, lg_lf) else {
            return None;
        };
        let k = |i| coefficient(c, i);
        let (s, cos) = heading.sin_cos();
        (*lg_0, *lg_1) = (0.0 + cos * k(0) + s * k(1), 0.0 + k(2));
        (*lg_lf_0, *lg_lf_1) = (0.0, 0.0);
        Some([0.0, 0.0])
    }
    // Exact with (v, ω) held: an arc of length v dt turning by ω dt.
    fn flow_into(&self, x: &mut [f64], u: &[f64], dt: f64) -> bool {
        advance_along_arc(x, u[0] * dt, 0.5 * u[1] * dt);
        true
    }
    fn input_matrix_into(&self, x: &[f64], g: &mut DMatrix<f64>) {
        let (s, c) = x[2].sin_cos();
        g[(0, 0)] = c;
        g[(1, 0)] = s;
        g[(2, 1)] = 1.0;
    }
    fn planar_position(&self) -> Option<[usize; 2]> {
        Some([0, 1])
    }
    fn heading_index(&self) -> Option<usize> {
        Some(2)
    }
}

/// ẍ = u in `dim` dimensions: x = (positions, velocities).
#[derive(Debug, Clone)]
pub struct DoubleIntegratorModel {
    dim: usize,
    state_names: Vec<String>,
    channel_names: Vec<String>,
}

impl DoubleIntegratorModel {
    pub fn new(dim: usize) -> DoubleIntegratorModel {
        let (state_names, channel_names) = if dim == 1 {
            (names(&["position", "velocity"]), names(&["acceleration"]))
        } else {
            (
                names(&["x", "y", "vx", "vy"]),
                names(&["acceleration_x", "acceleration_y"]),
            )
        };
        DoubleIntegratorModel {
            dim,
            state_names,
            channel_names,
        }
    }
}

impl Dynamics for DoubleIntegratorModel {
    fn state_names(&self) -> &[String] {
        &self.state_names
    }
    fn channel_names(&self) -> &[String] {
        &self.channel_names
    }
    fn drift_into(&self, x: &[f64], f: &mut [f64]) {
        let (positions, velocities) = f.split_at_mut(self.dim);
        positions.copy_from_slice(&x[self.dim..]);
        velocities.fill(0.0);
    }
    fn add_input_term(&self, _x: &[f64], u: &[f64], xdot: &mut [f64]) {
        for (v, u) in xdot[self.dim..].iter_mut().zip(u) {
            *v += u;
        }
    }
    fn drift_jacobian_into(&self, _x: &[f64], j: &mut DMatrix<f64>) {
        for i in 0..self.dim {
            j[(i, self.dim + i)] = 1.0;
        }
    }
    fn input_matrix_into(&self, _x: &[f64], g: &mut DMatrix<f64>) {
        for i in 0..self.dim {
            g[(self.dim + i, i)] = 1.0;
        }
    }
    // ℓ = c·x = c_p·p + c_v·v: L_f ℓ = c_p·v, L_g ℓ = c_v, L_f² ℓ = 0, L_g L_f ℓ = c_p.
    fn linear_lie_into(&self, x: &[f64], c: &[f64], lg: &mut [f64], lg_lf: &mut [f64]) -> Option<[f64; 2]> {
        let d = self.dim;
        let k = |i| coefficient(c, i);
        let mut lf = 0.0;
        for (i, (lg, lg_lf)) in lg.iter_mut().zip(lg_lf.iter_mut()).enumerate() {
            lf += k(i) * x[d + i];
            (*lg, *lg_lf) = (0.0 + k(d + i), 0.0 + k(i));
        }
        Some([lf, 0.0])
    }
    fn planar_position(&self) -> Option<[usize; 2]> {
        (self.dim == 2).then_some([0, 1])
    }
    fn line_position(&self) -> Option<usize> {
        (self.dim == 1).then_some(0)
    }
}

/// ẋ = A x + B u.
#[derive(Debug, Clone)]
pub struct LinearModel {
    pub a: DMatrix<f64>,
    pub b: DMatrix<f64>,
    state_names: Vec<String>,
    channel_names: Vec<String>,
}

impl LinearModel {
    /// A linear model; state components are named x1…xn and channels u1…um.
    pub fn new(a: DMatrix<f64>, b: DMatrix<f64>) -> LinearModel {
        let state_names = (1..=a.nrows()).map(|i| format!("x{i}")).collect();
        let channel_names = (1..=b.ncols()).map(|i| format!("u{i}")).collect();
        LinearModel {
            a,
            b,
            state_names,
            channel_names,
        }
    }
}

impl Dynamics for LinearModel {
    fn state_names(&self) -> &[String] {
        &self.state_names
    }
    fn channel_names(&self) -> &[String] {
        &self.channel_names
    }
    fn drift_into(&self, x: &[f64], f: &mut [f64]) {
        for (i, fi) in f.iter_mut().enumerate() {
            *fi = self.a.row(i).iter().zip(x).map(|(a, x)| a * x).sum();
        }
    }
    fn add_input_term(&self, _x: &[f64], u: &[f64], xdot: &mut [f64]) {
        for (i, v) in xdot.iter_mut().enumerate() {
            *v += self.b.row(i).iter().zip(u).map(|(b, u)| b * u).sum::<f64>();
        }
    }
    fn drift_jacobian_into(&self, _x: &[f64], j: &mut DMatrix<f64>) {
        j.copy_from(&self.a);
    }
    fn input_matrix_into(&self, _x: &[f64], g: &mut DMatrix<f64>) {
        g.copy_from(&self.b);
    }
    /// A system of two states moves in the plane of its state (Ch. 3's (3.34) avoids a disk in
    /// (x1, x2)); with more, x2 is in general not a position (a chain of integrators: a
    /// velocity), so it does not.
    fn planar_position(&self) -> Option<[usize; 2]> {
        (self.a.nrows() == 2).then_some([0, 1])
    }
}

/// Example 1 of Ch. 4 (4.52): ẋ1 = −x1 − x2 + u1, ẋ2 = x1³ + x2 u2.
#[derive(Debug, Clone)]
pub struct NonlinearExample1 {
    state_names: Vec<String>,
    channel_names: Vec<String>,
}

impl Default for NonlinearExample1 {
    fn default() -> Self {
        NonlinearExample1 {
            state_names: names(&["x1", "x2"]),
            channel_names: names(&["u1", "u2"]),
        }
    }
}

impl Dynamics for NonlinearExample1 {
    fn state_names(&self) -> &[String] {
        &self.state_names
    }
    fn channel_names(&self) -> &[String] {
        &self.channel_names
    }
    fn drift_into(&self, x: &[f64], f: &mut [f64]) {
        f.copy_from_slice(&[-x[0] - x[1], x[0].powi(3)]);
    }
    fn add_input_term(&self, x: &[f64], u: &[f64], xdot: &mut [f64]) {
        xdot[0] += u[0];
        xdot[1] += x[1] * u[1];
    }
    fn drift_jacobian_into(&self, x: &[f64], j: &mut DMatrix<f64>) {
        j.copy_from_slice(&[-1.0, 3.0 * x[0] * x[0], -1.0, 0.0]);
    }
    fn input_matrix_into(&self, x: &[f64], g: &mut DMatrix<f64>) {
        g[(0, 0)] = 1.0;
        g[(1, 1)] = x[1];
    }
}

/// The strict-feedback system (5.82): ẋ1 = x1² + x2, ẋ2 = u, output y = x1.
#[derive(Debug, Clone)]
pub struct StrictFeedbackModel {
    state_names: Vec<String>,
    channel_names: Vec<String>,
}

impl Default for StrictFeedbackModel {
    fn default() -> Self {
        StrictFeedbackModel {
            state_names: names(&["x1", "x2"]),
            channel_names: names(&["u"]),
        }
    }
}

impl Dynamics for StrictFeedbackModel {
    fn state_names(&self) -> &[String] {
        &self.state_names
    }
    fn channel_names(&self) -> &[String] {
        &self.channel_names
    }
    fn drift_into(&self, x: &[f64], f: &mut [f64]) {
        f.copy_from_slice(&[x[0] * x[0] + x[1], 0.0]);
    }
    fn add_input_term(&self, _x: &[f64], u: &[f64], xdot: &mut [f64]) {
        xdot[1] += u[0];
    }
    fn drift_jacobian_into(&self, x: &[f64], j: &mut DMatrix<f64>) {
        j[(0, 0)] = 2.0 * x[0];
        j[(0, 1)] = 1.0;
    }
    fn input_matrix_into(&self, _x: &[f64], g: &mut DMatrix<f64>) {
        g[(1, 0)] = 1.0;
    }
}

/// A car on a straight road behind a lead car at constant speed: Ames, Xu, Grizzle, Tabuada,
/// "Control barrier function based quadratic programs with application to adaptive cruise
/// control", CDC 2014, Table 1 (as in ChoiJangho/CBF-CLF-Helper 981e409d, `AccBuiltIn`).
/// x = (p, v, z): ṗ = v, v̇ = (u − F_r(v))/m, ż = v_L − v, with the rolling and air
/// resistance F_r(v) = f0 + f1 v + f2 v² and u the wheel force (N); z is the gap to the lead.
#[derive(Debug, Clone)]
pub struct LongitudinalModel {
    /// Mass m (kg).
    pub mass: f64,
    /// Resistance coefficients (f0 N, f1 N s/m, f2 N s²/m²).
    pub resistance: [f64; 3],
    /// The lead's constant speed v_L (m/s).
    pub lead_speed: f64,
    state_names: Vec<String>,
    channel_names: Vec<String>,
}

impl LongitudinalModel {
    /// The model with mass m, resistance (f0, f1, f2) and lead speed v_L.
    pub fn new(mass: f64, resistance: [f64; 3], lead_speed: f64) -> LongitudinalModel {
        LongitudinalModel {
            mass,
            resistance,
            lead_speed,
            state_names: names(&["position", "speed", "gap"]),
            channel_names: names(&["force"]),
        }
    }

    /// F_r(v) = f0 + f1 v + f2 v².
    pub fn resistance_force(&self, v: f64) -> f64 {
        let [f0, f1, f2] = self.resistance;
        f0 + f1 * v + f2 * v * v
    }
}

impl Dynamics for LongitudinalModel {
    fn state_names(&self) -> &[String] {
        &self.state_names
    }
    /// m (kg), f0 (N), f1 (N s/m), f2 (N s²/m²), v_L (m/s).
    fn parameters(&self) -> Vec<(&'static str, f64)> {
        let [f0, f1, f2] = self.resistance;
        vec![
            ("mass", self.mass),
            ("f0", f0),
            ("f1", f1),
            ("f2", f2),
            ("lead_speed", self.lead_speed),
        ]
    }
    fn channel_names(&self) -> &[String] {
        &self.channel_names
    }
    fn drift_into(&self, x: &[f64], f: &mut [f64]) {
        f.copy_from_slice(&[x[1], -self.resistance_force(x[1]) / self.mass, self.lead_speed - x[1]]);
    }
    fn add_input_term(&self, _x: &[f64], u: &[f64], xdot: &mut [f64]) {
        xdot[1] += u[0] / self.mass;
    }
    // ∂f/∂v = (1, −(f1 + 2 f2 v)/m, −1); f depends on nothing else.
    fn drift_jacobian_into(&self, x: &[f64], j: &mut DMatrix<f64>) {
        let [_, f1, f2] = self.resistance;
        j[(0, 1)] = 1.0;
        j[(1, 1)] = -(f1 + 2.0 * f2 * x[1]) / self.mass;
        j[(2, 1)] = -1.0;
    }
    fn input_matrix_into(&self, _x: &[f64], g: &mut DMatrix<f64>) {
        g[(1, 0)] = 1.0 / self.mass;
    }
    fn line_position(&self) -> Option<usize> {
        Some(0)
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn only_a_two_state_linear_system_moves_in_a_plane() {
        let planar = |n: usize| LinearModel::new(DMatrix::zeros(n, n), DMatrix::zeros(n, 1)).planar_position();
        assert_eq!(planar(2), Some([0, 1]));
        assert_eq!(planar(1), None);
        // A chain of three integrators: x2 is a velocity.
        assert_eq!(planar(3), None);
    }
    use super::*;

    #[test]
    fn bicycle_fused_evaluations_match_the_separate_terms() {
        let model = BicycleModel::new(6.0);
        for k in 0..50 {
            let s = k as f64;
            let x = [s.sin() * 20.0, s.cos() * 5.0, 0.37 * s - 7.0, 3.0 + (1.3 * s).sin()];
            let u = [(0.7 * s).cos() * 0.4, (0.3 * s).sin() * 2.0];
            let (mut f, mut g, mut j) = (vec![0.0; 4], DMatrix::zeros(4, 2), DMatrix::zeros(4, 4));
            model.drift_into(&x, &mut f);
            model.input_matrix_into(&x, &mut g);
            model.drift_jacobian_into(&x, &mut j);
            let mut xdot = vec![0.0; 4];
            model.dynamics_into(&x, &u, &mut xdot);
            let expected = DVector::from_column_slice(&f) + &g * DVector::from_column_slice(&u);
            assert!((DVector::from_column_slice(&xdot) - expected).norm() < 1e-14);
            let (mut f2, mut g2, mut j2) = (vec![0.0; 4], DMatrix::zeros(4, 2), DMatrix::zeros(4, 4));
            model.lie_terms_into(&x, &mut f2, &mut g2, &mut j2);
            assert_eq!((f, g, j), (f2, g2, j2));
        }
    }

    /// RK4 of ẋ = f(x) + G(x) u with u held, on `n` steps over dt.
    fn fine_rk4(model: &dyn Dynamics, x: &[f64], u: &[f64], dt: f64, n: usize) -> Vec<f64> {
        let h = dt / n as f64;
        let mut x = x.to_vec();
        let d = x.len();
        let slope = |x: &[f64]| {
            let mut k = vec![0.0; d];
            model.dynamics_into(x, u, &mut k);
            k
        };
        let shifted = |x: &[f64], k: &[f64], by: f64| x.iter().zip(k).map(|(a, b)| a + b * by).collect::<Vec<_>>();
        for _ in 0..n {
            let k1 = slope(&x);
            let k2 = slope(&shifted(&x, &k1, h / 2.0));
            let k3 = slope(&shifted(&x, &k2, h / 2.0));
            let k4 = slope(&shifted(&x, &k3, h));
            for i in 0..d {
                x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
            }
        }
        x
    }

    #[test]
    fn the_exact_flows_match_a_fine_integration() {
        // Straight lines (no steering), tight turns, reversing through v = 0, long steps.
        let bicycle = BicycleModel::new(2.5);
        let unicycle = UnicycleModel::default();
        let mut worst: f64 = 0.0;
        for k in 0..200 {
            let s = k as f64;
            let steer = if k % 5 == 0 {
                0.0
            } else {
                (0.7 * s).cos() * 0.6 / (1.0 + (k % 7) as f64)
            };
            let dt = [0.002, 0.01, 0.1, 0.5][k % 4];
            let x = [s.sin() * 20.0, s.cos() * 5.0, 0.37 * s - 7.0, 3.0 * (1.3 * s).sin()];
            let u = [steer, (0.3 * s).sin() * 8.0];
            let mut exact = x;
            assert!(bicycle.flow_into(&mut exact, &u, dt));
            let fine = fine_rk4(&bicycle, &x, &u, dt, 2000);
            for (a, b) in exact.iter().zip(&fine) {
                worst = worst.max((a - b).abs() / (1.0 + b.abs()));
            }
            let (x3, u3) = ([x[0], x[1], x[2]], [x[3], steer * 4.0]);
            let mut exact = x3;
            assert!(unicycle.flow_into(&mut exact, &u3, dt));
            let fine = fine_rk4(&unicycle, &x3, &u3, dt, 2000);
            for (a, b) in exact.iter().zip(&fine) {
                worst = worst.max((a - b).abs() / (1.0 + b.abs()));
            }
        }
        // The reference's own round-off over 2000 steps is ~1e-12; a wrong term shows at ≥ 1e-6.
        assert!(worst < 1e-11, "largest relative difference {worst:e}");
        // A model without a closed form leaves the state alone.
        let mut x = [1.0, 2.0];
        assert!(!NonlinearExample1::default().flow_into(&mut x, &[3.0, 1.0], 0.1));
        assert_eq!(x, [1.0, 2.0]);
    }

    #[test]
    fn sinc_is_continuous_where_the_series_hands_over() {
        for z in [0.1 - 1e-12, 0.1, 0.1 + 1e-12, -0.1, 1e-9, 0.0] {
            let direct = if z == 0.0 { 1.0 } else { f64::sin(z) / z };
            assert!(
                (sinc(z) - direct).abs() <= 2.0 * f64::EPSILON,
                "{z}: {:e}",
                sinc(z) - direct
            );
        }
    }
    /// Table 1 of Ames et al. (CDC 2014).
    fn acc_table1() -> LongitudinalModel {
        LongitudinalModel::new(1650.0, [0.1, 5.0, 0.25], 14.0)
    }

    #[test]
    fn acc_speed_is_affine_in_time_without_speed_dependent_resistance() {
        // f1 = f2 = 0, u held: v̇ = (u − f0)/m = a, so v = v0 + a t, p = p0 + v0 t + a t²/2,
        // z = z0 + (v_L − v0) t − a t²/2.
        let model = LongitudinalModel::new(1650.0, [0.1, 0.0, 0.0], 14.0);
        let (x0, u, t) = ([3.0, 20.0, 100.0], [-2000.0], 4.0);
        let a = (u[0] - 0.1) / 1650.0;
        let exact = [
            3.0 + 20.0 * t + 0.5 * a * t * t,
            20.0 + a * t,
            100.0 + (14.0 - 20.0) * t - 0.5 * a * t * t,
        ];
        let integrated = fine_rk4(&model, &x0, &u, t, 400);
        for (e, i) in exact.iter().zip(&integrated) {
            assert!((e - i).abs() < 1e-10, "{exact:?} vs {integrated:?}");
        }
    }

    #[test]
    fn acc_speed_under_air_resistance_matches_the_closed_form() {
        // f0 = f1 = 0, u = 0: m v̇ = −f2 v², so v = v0 / (1 + f2 v0 t / m).
        let model = LongitudinalModel::new(1650.0, [0.0, 0.0, 0.25], 14.0);
        let t = 10.0;
        let v = fine_rk4(&model, &[0.0, 20.0, 100.0], &[0.0], t, 1000)[1];
        let exact = 20.0 / (1.0 + 0.25 * 20.0 * t / 1650.0);
        assert!((v - exact).abs() < 1e-10, "{v} vs {exact}");
    }

    #[test]
    fn acc_drift_jacobian_matches_finite_differences() {
        let model = acc_table1();
        let x = [5.0, 21.3, 60.0];
        let j = model.drift_jacobian(&DVector::from_column_slice(&x));
        for k in 0..3 {
            let (mut up, mut down) = (x, x);
            up[k] += 1e-5;
            down[k] -= 1e-5;
            let column = (model.drift(&DVector::from_column_slice(&up))
                - model.drift(&DVector::from_column_slice(&down)))
                / 2e-5;
            assert!((column - j.column(k)).norm() < 1e-8, "column {k}");
        }
    }

    #[test]
    fn acc_headway_barrier_lie_derivatives_match_hand_and_finite_differences() {
        use crate::barrier::{lie_derivatives, Barrier, Shape};
        // h = z − T v − (v_L − v)²/(2 c_d g) as xᵀQx + cᵀx + d.
        let (t_h, brake, lead, m) = (1.8, 0.3 * 9.81, 14.0, 1650.0);
        let barrier = Barrier {
            name: "headway".into(),
            shape: Shape::Quadratic {
                q: vec![vec![0.0; 3], vec![0.0, -0.5 / brake, 0.0], vec![0.0; 3]],
                c: vec![0.0, -t_h + lead / brake, 1.0],
                d: -lead * lead / (2.0 * brake),
            },
        };
        let h = |x: &[f64]| x[2] - t_h * x[1] - (lead - x[1]).powi(2) / (2.0 * brake);
        let model = acc_table1();
        for x in [[0.0, 20.0, 100.0], [50.0, 14.0, 25.2], [10.0, 9.0, 30.0]] {
            let lie = lie_derivatives(&barrier, &model, &DVector::from_column_slice(&x));
            assert!((lie.h - h(&x)).abs() < 1e-12);
            // By hand: ∂h/∂v = −T + (v_L − v)/(c_d g), ∂h/∂z = 1.
            let dh_dv = -t_h + (lead - x[1]) / brake;
            let resistance = 0.1 + 5.0 * x[1] + 0.25 * x[1] * x[1];
            let lf = dh_dv * (-resistance / m) + (lead - x[1]);
            assert!((lie.lf_h - lf).abs() < 1e-12, "{} vs {lf}", lie.lf_h);
            assert!((lie.lg_h[0] - dh_dv / m).abs() < 1e-15);
            // Central differences of h along f and along g (exact up to rounding for a
            // quadratic h, so with a step of unit length in x).
            let along = |d: &DVector<f64>| {
                let step = 1.0 / d.norm();
                let shifted = |s: f64| h(&[x[0] + s * d[0], x[1] + s * d[1], x[2] + s * d[2]]);
                (shifted(step) - shifted(-step)) / (2.0 * step)
            };
            let xv = DVector::from_column_slice(&x);
            assert!((along(&model.drift(&xv)) - lie.lf_h).abs() < 1e-9);
            assert!((along(&model.input_matrix(&xv).column(0).into_owned()) - lie.lg_h[0]).abs() < 1e-14);
        }
    }
}
