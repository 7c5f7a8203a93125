//! The CBF-QP when it has no closed form: several barrier constraints (one per obstacle) and
//! actuator limits, solved with Clarabel (a maintained pure-Rust interior-point solver: no C
//! toolchain, deterministic, infeasibility detection; ≈25–36 µs per solve here).
//!
//! min ‖v‖² + ρ Σ s_k   s.t.  a_k + b_k (u0 + v) + s_k ≥ 0,  s_k ≥ 0,  lower ≤ u0 + v ≤ upper.
//!
//! The slacks s_k with a linear (exact) penalty ρ make the problem always feasible: when the
//! barrier constraints can all be met, the solution is the hard-constrained QP's (ρ exceeds
//! every multiplier); when they cannot, it is the least-violation input within the limits —
//! the documented fallback, reported as `infeasible`.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT};
use nalgebra::DVector;

use crate::barrier::Constraint;

/// Penalty on the slacks (per unit of constraint violation).
const SLACK_PENALTY: f64 = 1e6;
/// A slack above this counts as a violated (infeasible) constraint.
const SLACK_TOLERANCE: f64 = 1e-6;

/// What the QP decided.
#[derive(Debug, Clone, PartialEq)]
pub struct QpOutcome {
    pub input: DVector<f64>,
    /// The correction v is non-zero.
    pub active: bool,
    /// Some barrier constraint could not be met within the limits (least-violation fallback),
    /// or the solver failed (then u0 clamped to the limits is returned).
    pub infeasible: bool,
    /// The smallest constraint value a_k + b_k u0 before correction.
    pub mu: f64,
}

/// Solves the multi-constraint CBF-QP around u0 (see the module docs).
pub fn cbf_qp_multi(constraints: &[Constraint], u0: &DVector<f64>, limits: Option<(&[f64], &[f64])>) -> QpOutcome {
    let r = u0.len();
    let k = constraints.len();
    let mu = constraints.iter().map(|c| c.value(u0)).fold(f64::INFINITY, f64::min);
    let clamp = |u: &DVector<f64>| match limits {
        Some((lo, hi)) => DVector::from_iterator(r, u.iter().enumerate().map(|(i, v)| v.clamp(lo[i], hi[i]))),
        None => u.clone(),
    };
    let within_limits = limits.is_none_or(|(lo, hi)| u0.iter().enumerate().all(|(i, v)| *v >= lo[i] && *v <= hi[i]));
    if mu >= 0.0 && within_limits {
        return QpOutcome {
            input: u0.clone(),
            active: false,
            infeasible: false,
            mu,
        };
    }
    // Variables z = (v, s). Objective ½ zᵀPz + qᵀz with P = diag(2 I_r, 0), q = (0, ρ 1_k).
    let n = r + k;
    let mut p = vec![vec![0.0; n]; n];
    for (i, row) in p.iter_mut().enumerate().take(r) {
        row[i] = 2.0;
    }
    let mut q = vec![0.0; n];
    q[r..].fill(SLACK_PENALTY);
    // Constraints A z ≤ b (Clarabel: A z + s = b, s ≥ 0).
    let mut a_rows: Vec<Vec<f64>> = Vec::new();
    let mut b_rhs: Vec<f64> = Vec::new();
    for (j, c) in constraints.iter().enumerate() {
        let mut row = vec![0.0; n];
        for (entry, b) in row.iter_mut().zip(c.b.iter()) {
            *entry = -b;
        }
        row[r + j] = -1.0;
        a_rows.push(row);
        b_rhs.push(c.value(u0));
    }
    for j in 0..k {
        let mut row = vec![0.0; n];
        row[r + j] = -1.0;
        a_rows.push(row);
        b_rhs.push(0.0);
    }
    if let Some((lo, hi)) = limits {
        for i in 0..r {
            let mut up = vec![0.0; n];
            up[i] = 1.0;
            a_rows.push(up);
            b_rhs.push(hi[i] - u0[i]);
            let mut down = vec![0.0; n];
            down[i] = -1.0;
            a_rows.push(down);
            b_rhs.push(u0[i] - lo[i]);
        }
    }
    let p = CscMatrix::from(&p);
    let a = CscMatrix::from(&a_rows);
    let cones = [SupportedConeT::NonnegativeConeT(b_rhs.len())];
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .build()
        .expect("valid settings");
    let solved = DefaultSolver::new(&p, &q, &a, &b_rhs, &cones, settings)
        .ok()
        .and_then(|mut solver| {
            solver.solve();
            matches!(
                solver.solution.status,
                SolverStatus::Solved | SolverStatus::AlmostSolved
            )
            .then(|| solver.solution.x.clone())
        });
    match solved {
        Some(z) => {
            let v = DVector::from_column_slice(&z[..r]);
            let worst_slack = z[r..].iter().cloned().fold(0.0, f64::max);
            QpOutcome {
                input: u0 + &v,
                active: v.norm() > 1e-12,
                infeasible: worst_slack > SLACK_TOLERANCE,
                mu,
            }
        }
        None => QpOutcome {
            input: clamp(u0),
            active: false,
            infeasible: true,
            mu,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::cbf_qp;

    fn constraint(a: f64, b: &[f64]) -> Constraint {
        Constraint {
            h: 1.0,
            a,
            b: DVector::from_column_slice(b),
        }
    }

    #[test]
    fn one_constraint_without_limits_matches_the_closed_form() {
        let c = constraint(-3.0, &[1.0, 2.0]);
        let u0 = DVector::from_column_slice(&[0.5, -0.2]);
        let qp = cbf_qp_multi(std::slice::from_ref(&c), &u0, None);
        let closed = cbf_qp(&c, &u0);
        assert!((&qp.input - &closed.input).norm() < 1e-6, "{qp:?}");
        assert!(qp.active && !qp.infeasible);
    }

    #[test]
    fn two_constraints_are_both_met_with_the_smallest_correction() {
        // u ≥ 1 and u2 ≥ 2 from u0 = 0: v = (1, 2).
        let cs = [constraint(-1.0, &[1.0, 0.0]), constraint(-2.0, &[0.0, 1.0])];
        let qp = cbf_qp_multi(&cs, &DVector::zeros(2), None);
        assert!(
            (qp.input[0] - 1.0).abs() < 1e-6 && (qp.input[1] - 2.0).abs() < 1e-6,
            "{qp:?}"
        );
        assert!(!qp.infeasible);
    }

    #[test]
    fn limits_are_respected_and_infeasibility_falls_back_to_least_violation() {
        // Needs u ≥ 3 but u ≤ 1: infeasible; the fallback pushes to the limit.
        let c = constraint(-3.0, &[1.0]);
        let qp = cbf_qp_multi(std::slice::from_ref(&c), &DVector::zeros(1), Some((&[-1.0], &[1.0])));
        assert!(qp.infeasible);
        assert!((qp.input[0] - 1.0).abs() < 1e-6, "{qp:?}");
        // A nominal outside the limits is brought inside even when the barrier is satisfied.
        let c = constraint(10.0, &[1.0]);
        let qp = cbf_qp_multi(
            std::slice::from_ref(&c),
            &DVector::from_element(1, 4.0),
            Some((&[-1.0], &[1.0])),
        );
        assert!((qp.input[0] - 1.0).abs() < 1e-6 && !qp.infeasible, "{qp:?}");
    }
}
