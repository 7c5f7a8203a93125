//! Control barrier functions and their constraint data a(x), b(x) for the CBF-QP
//! (4.6)–(4.8), including the relative-degree-2 form (4.82)–(4.86).

use nalgebra::{DMatrix, DVector};

use crate::vehicle::Vehicle;

/// Circular obstacle (4.81): h(x) = (p1 − c1)² + (p2 − c2)² − r², with p the vehicle's planar
/// position and r the sum of the vehicle's and the obstacle's radii.
#[derive(Debug, Clone, PartialEq)]
pub struct CircularObstacle {
    pub name: String,
    pub centre: [f64; 2],
    /// r in (4.81): vehicle hull radius + obstacle radius.
    pub radius_sum: f64,
    /// Indices of the planar position in the state vector.
    pub position: [usize; 2],
}

impl CircularObstacle {
    pub fn h(&self, x: &DVector<f64>) -> f64 {
        let dx = x[self.position[0]] - self.centre[0];
        let dy = x[self.position[1]] - self.centre[1];
        dx * dx + dy * dy - self.radius_sum * self.radius_sum
    }

    /// Distance between the two circles' boundaries (negative when overlapping).
    pub fn clearance(&self, x: &DVector<f64>) -> f64 {
        let dx = x[self.position[0]] - self.centre[0];
        let dy = x[self.position[1]] - self.centre[1];
        dx.hypot(dy) - self.radius_sum
    }

    /// ∇h(x).
    pub fn gradient(&self, x: &DVector<f64>) -> DVector<f64> {
        let mut g = DVector::zeros(x.len());
        for (axis, &i) in self.position.iter().enumerate() {
            g[i] = 2.0 * (x[i] - self.centre[axis]);
        }
        g
    }

    /// ∇²h(x): 2 on the position block.
    pub fn hessian(&self, n: usize) -> DMatrix<f64> {
        let mut hess = DMatrix::zeros(n, n);
        for &i in &self.position {
            hess[(i, i)] = 2.0;
        }
        hess
    }
}

/// How the barrier condition is imposed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BarrierForm {
    /// ḣ + α h ≥ 0 with linear α(h) = alpha·h: a = L_f h + α h (4.7), b = L_G h (4.8).
    RelativeDegree1 { alpha: f64 },
    /// ḧ + l1 ḣ + l0 h ≥ 0 (4.82): a = L_f²h + l1 L_f h + l0 h (4.85), b = L_G L_f h (4.86).
    RelativeDegree2 { l0: f64, l1: f64 },
}

impl BarrierForm {
    pub fn relative_degree(&self) -> u32 {
        match self {
            BarrierForm::RelativeDegree1 { .. } => 1,
            BarrierForm::RelativeDegree2 { .. } => 2,
        }
    }
}

/// The affine constraint a + b·u ≥ 0 of one barrier at one state.
#[derive(Debug, Clone, PartialEq)]
pub struct Constraint {
    pub h: f64,
    pub a: f64,
    /// Row vector b(x), one entry per input channel.
    pub b: DVector<f64>,
}

impl Constraint {
    /// a + b·u.
    pub fn value(&self, u: &DVector<f64>) -> f64 {
        self.a + self.b.dot(u)
    }
}

/// Lie derivatives of a circular-obstacle barrier along the vehicle's model.
#[derive(Debug, Clone, PartialEq)]
pub struct LieDerivatives {
    pub h: f64,
    pub lf_h: f64,
    pub lg_h: DVector<f64>,
    pub lf2_h: f64,
    pub lg_lf_h: DVector<f64>,
}

pub fn lie_derivatives(
    barrier: &CircularObstacle,
    vehicle: &dyn Vehicle,
    x: &DVector<f64>,
) -> LieDerivatives {
    let f = vehicle.drift(x);
    let g = vehicle.input_matrix(x);
    let grad_h = barrier.gradient(x);
    // ∇(L_f h) = ∇²h f + (∂f/∂x)ᵀ ∇h.
    let grad_lf_h = barrier.hessian(x.len()) * &f + vehicle.drift_jacobian(x).transpose() * &grad_h;
    LieDerivatives {
        h: barrier.h(x),
        lf_h: grad_h.dot(&f),
        lg_h: g.transpose() * &grad_h,
        lf2_h: grad_lf_h.dot(&f),
        lg_lf_h: g.transpose() * grad_lf_h,
    }
}

/// The constraint data (a, b) of `barrier` in `form` at state x.
pub fn constraint(
    barrier: &CircularObstacle,
    form: BarrierForm,
    vehicle: &dyn Vehicle,
    x: &DVector<f64>,
) -> Constraint {
    let lie = lie_derivatives(barrier, vehicle, x);
    match form {
        BarrierForm::RelativeDegree1 { alpha } => Constraint {
            h: lie.h,
            a: lie.lf_h + alpha * lie.h,
            b: lie.lg_h,
        },
        BarrierForm::RelativeDegree2 { l0, l1 } => Constraint {
            h: lie.h,
            a: lie.lf2_h + l1 * lie.lf_h + l0 * lie.h,
            b: lie.lg_lf_h,
        },
    }
}
