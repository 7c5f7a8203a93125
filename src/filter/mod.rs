//! Safety filters. The delay-free CBF-QP (4.6)–(4.11) (= (2.13)–(2.15)) in closed form.

pub mod prescribed_time;
use nalgebra::DVector;

use crate::barrier::Constraint;

/// What the filter did at one control tick.
#[derive(Debug, Clone, PartialEq)]
pub struct FilterOutcome {
    /// u = u0 + ū (4.11).
    pub input: DVector<f64>,
    /// ū ≠ 0: the constraint was active.
    pub active: bool,
    /// μ < 0 but b = 0: no input can satisfy the constraint; u0 is passed through.
    pub infeasible: bool,
    /// μ(x, u0) = a + b u0 (4.10).
    pub mu: f64,
}

/// Below this ‖b‖², the constraint is treated as independent of the input.
const DEGENERATE_B: f64 = 1e-12;

/// Closed-form solution (4.9) of min ‖v‖² s.t. a + b (u0 + v) ≥ 0, applied as (4.11).
pub fn cbf_qp(constraint: &Constraint, nominal: &DVector<f64>) -> FilterOutcome {
    let mu = constraint.value(nominal);
    if mu >= 0.0 {
        return FilterOutcome {
            input: nominal.clone(),
            active: false,
            infeasible: false,
            mu,
        };
    }
    let bb = constraint.b.norm_squared();
    if bb < DEGENERATE_B {
        return FilterOutcome {
            input: nominal.clone(),
            active: false,
            infeasible: true,
            mu,
        };
    }
    FilterOutcome {
        input: nominal - &constraint.b * (mu / bb),
        active: true,
        infeasible: false,
        mu,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn constraint(a: f64, b: &[f64]) -> Constraint {
        Constraint {
            h: 1.0,
            a,
            b: DVector::from_column_slice(b),
        }
    }

    #[test]
    fn inactive_when_the_nominal_is_safe() {
        let out = cbf_qp(&constraint(1.0, &[1.0, 0.0]), &DVector::from_column_slice(&[0.5, 2.0]));
        assert!(!out.active);
        assert_eq!(out.input, DVector::from_column_slice(&[0.5, 2.0]));
    }

    #[test]
    fn active_solution_lands_on_the_constraint_with_minimal_correction() {
        let c = constraint(-3.0, &[1.0, 2.0]);
        let u0 = DVector::from_column_slice(&[0.0, 0.0]);
        let out = cbf_qp(&c, &u0);
        assert!(out.active);
        assert!(c.value(&out.input).abs() < 1e-12);
        // The correction is parallel to b (KKT): v = 3/5 (1, 2).
        assert!((out.input[0] - 0.6).abs() < 1e-12 && (out.input[1] - 1.2).abs() < 1e-12);
    }

    #[test]
    fn zero_b_with_violation_is_reported_infeasible() {
        let out = cbf_qp(&constraint(-1.0, &[0.0]), &DVector::from_column_slice(&[3.0]));
        assert!(out.infeasible && !out.active);
    }
}
