//! Safety filters, as pure functions of the constraint data a + b·u ≥ 0 at the state they act
//! on (x(t), or a prediction p_i(t)); the relative-degree-2 form enters through (a, b)
//! ((4.85)/(4.86)).
//!
//! - [`cbf_qp_closed_form()`]: the delay-free CBF-QP (4.6)–(4.11) (= (2.13)–(2.15)) in closed form; applied
//!   per channel at p_i it is the full-consistency filter (4.34)–(4.37).
//! - [`fixed_channel_one_barrier()`]: the fixed-channel robust filter (4.39)–(4.47) for one barrier.
//! - [`gamma_m_one_barrier()`]: the variable-channel γm filter (4.60)–(4.68) for one barrier.
//!
//! The registered kinds are the modules of the same stems ([`cbf_qp`], [`fixed_channel`],
//! [`gamma_m`]: parameters, checks, several barriers), so a function never shares a module's
//! name.
//!
//! Channel indices are positions in delay order (D_1 ≤ … ≤ D_r), 0-based here.

mod api;
pub mod cbf_qp;
pub mod chain;
pub mod clf_cbf_qp;
pub mod fixed_channel;
pub mod gamma_m;
pub mod linear_delays;
pub mod none;
/// Ch. 5 maths, a top-level module of its own (the nominals use it too); kept here by name.
pub use crate::prescribed_time;
pub mod qp;
pub mod several;

pub use api::{
    barrier_form, delay_free_qp, AssumedActor, ChannelInput, FilterContext, FilterError, LawInput, ParamError, Params,
    SafetyFilter, SeenBarriers, TICK_TOLERANCE,
};
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
pub fn cbf_qp_closed_form(constraint: &Constraint, nominal: &DVector<f64>) -> FilterOutcome {
    let mut input = nominal.clone();
    let (active, infeasible, mu) = cbf_qp_in_place(constraint, &mut input);
    FilterOutcome {
        input,
        active,
        infeasible,
        mu,
    }
}

/// [`cbf_qp_closed_form()`] without allocation: `input` holds u0 on entry and u on return. Returns
/// (active, infeasible, μ) as in [`FilterOutcome`].
///
/// On slices (the recursive predictors call it at every step of their window): the same
/// sums in the same order as nalgebra's `dot`/`norm_squared`/`axpy` for fewer than 8 channels.
#[inline]
pub fn cbf_qp_in_place(constraint: &Constraint, input: &mut DVector<f64>) -> (bool, bool, f64) {
    let (b, u) = (constraint.b.as_slice(), input.as_mut_slice());
    // Two channels (the planar vehicles): the same code with the length known, unrolled.
    if let (Ok(b), Ok(u)) = (<&[f64; 2]>::try_from(b), <&mut [f64; 2]>::try_from(&mut *u)) {
        return cbf_qp_on_slices(constraint.a, b, u);
    }
    cbf_qp_on_slices(constraint.a, b, u)
}

/// (4.9)/(4.11) for a + b·(u0 + v) ≥ 0 with u holding u0.
#[inline(always)]
fn cbf_qp_on_slices(a: f64, b: &[f64], u: &mut [f64]) -> (bool, bool, f64) {
    let mu = a + crate::barrier::dot(b, u);
    if mu >= 0.0 {
        return (false, false, mu);
    }
    let bb = crate::barrier::dot(b, b);
    if bb < DEGENERATE_B {
        return (false, true, mu);
    }
    // u ← u0 − μ b / ‖b‖² (4.9), (4.11).
    let scale = -mu / bb;
    for (u, b) in u.iter_mut().zip(b) {
        *u += scale * b;
    }
    (true, false, mu)
}

/// What a per-channel filter decided for channel i.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelOutcome {
    /// u_i = u0_i + ū_i.
    pub input: f64,
    /// The constraint was active (ū ≠ 0 for some channel of the QP).
    pub active: bool,
    /// The constraint was violated but no channel of the QP can act on it.
    pub infeasible: bool,
    /// The constraint value the decision was based on (μ_s (4.47) or ζ_i (4.64)); the
    /// smallest over the barriers when there are several.
    pub mu: f64,
    /// The barrier (index into the constraints) whose condition a + b·u ≥ 0 the decision
    /// leaves furthest from met with the real inputs it plans — an infeasible QP's
    /// least-violation fallback, or a γm constraint met only by its fictitious inputs σ (4.60)
    /// — if any.
    pub unmet: Option<usize>,
    /// By how much (≥ 0, in that barrier's constraint units: those of ḣ + α(h), or of
    /// ḧ + l1 ḣ + l0 h); 0 when every condition is met.
    pub shortfall: f64,
}

impl ChannelOutcome {
    /// A decision that meets every barrier condition it plans for (or a filter that does not
    /// say): `unmet` None, `shortfall` 0.
    pub fn new(input: f64, active: bool, infeasible: bool, mu: f64) -> ChannelOutcome {
        ChannelOutcome {
            input,
            active,
            infeasible,
            mu,
            unmet: None,
            shortfall: 0.0,
        }
    }
}

/// Fixed-channel robust filter (4.44)–(4.47) for channel `i`: the first `s` = max{φ, i+1}
/// channels enforce the barrier; the already-issued inputs ω_j of the later channels (arriving
/// with u_i) enter as known disturbances. `omega[j]` is read for j ≥ s.
pub fn fixed_channel_one_barrier(
    c: &Constraint,
    u0: &DVector<f64>,
    omega: &DVector<f64>,
    i: usize,
    s: usize,
) -> ChannelOutcome {
    let r = u0.len();
    // μ_s (4.47).
    let mu = c.a + (0..s).map(|j| c.b[j] * u0[j]).sum::<f64>() + (s..r).map(|j| c.b[j] * omega[j]).sum::<f64>();
    let b_used: f64 = (0..s).map(|j| c.b[j] * c.b[j]).sum();
    if mu >= 0.0 {
        return ChannelOutcome::new(u0[i], false, false, mu);
    }
    if b_used < DEGENERATE_B {
        return ChannelOutcome::new(u0[i], false, true, mu);
    }
    // ū_i (4.46).
    ChannelOutcome::new(u0[i] - mu * c.b[i] / b_used, true, false, mu)
}

/// The smallest i such that ‖b_{1:i}(x)‖ > 0 at every sample x (the set Φ and φ of (4.40)/
/// (4.41), on a finite sample of the state space), where b(x) is the constraint's input row
/// (L_G h, or L_G L_f h for relative degree 2). Returns r if no strict subset suffices.
pub fn minimal_channels(
    samples: impl Iterator<Item = DVector<f64>>,
    b_at: impl Fn(&DVector<f64>) -> DVector<f64>,
) -> usize {
    let mut smallest_norm: Option<Vec<f64>> = None;
    for x in samples {
        let b = b_at(&x);
        let partial: Vec<f64> = (1..=b.len()).map(|i| b.rows(0, i).norm()).collect();
        smallest_norm = Some(match smallest_norm {
            None => partial,
            Some(prev) => prev.iter().zip(&partial).map(|(p, q)| p.min(*q)).collect(),
        });
    }
    let Some(norms) = smallest_norm else { return 1 };
    let r = norms.len();
    (1..r).find(|&i| norms[i - 1] > DEGENERATE_B.sqrt()).unwrap_or(r)
}

/// The grid of `points` per axis in the box [lower, upper].
pub fn box_grid<'a>(lower: &'a [f64], upper: &'a [f64], points: usize) -> impl Iterator<Item = DVector<f64>> + 'a {
    let n = lower.len();
    // Saturating: callers bound points^n first (`filter.phi_box.points`).
    let total = u32::try_from(n)
        .ok()
        .and_then(|n| points.checked_pow(n))
        .unwrap_or(usize::MAX);
    (0..total).map(move |mut index| {
        let mut x = DVector::zeros(n);
        for d in 0..n {
            let k = index % points;
            index /= points;
            x[d] = lower[d] + (upper[d] - lower[d]) * k as f64 / (points - 1) as f64;
        }
        x
    })
}

/// γ_f (4.61): γ s for s ≤ 0, s otherwise.
pub fn gamma_f(gamma: f64, s: f64) -> f64 {
    if s <= 0.0 {
        gamma * s
    } else {
        s
    }
}

/// ζ (4.64) of QP_k with `used` = k + 1 channels: γ_f(z) + Σ_{j>k} b_j ω_j, z (4.66).
#[inline]
pub(crate) fn gamma_m_zeta(c: &Constraint, u0: &DVector<f64>, omega: &DVector<f64>, used: usize, gamma: f64) -> f64 {
    let (b, u0, omega) = (c.b.as_slice(), u0.as_slice(), omega.as_slice());
    let z = c.a + b[..used].iter().zip(&u0[..used]).map(|(b, u)| b * u).sum::<f64>();
    gamma_f(gamma, z) + b[used..].iter().zip(&omega[used..]).map(|(b, w)| b * w).sum::<f64>()
}

/// ξ (4.65) of QP_k with `used` = k + 1 channels: ‖b_{1:k}‖² + ‖b‖²/m.
pub(crate) fn gamma_m_xi(c: &Constraint, used: usize, m: f64) -> f64 {
    (0..used).map(|j| c.b[j] * c.b[j]).sum::<f64>() + c.b.norm_squared() / m
}

/// Variable-channel γm filter (4.60)–(4.68) for channel `i`: QP_k with k the last channel
/// with the same delay as i (4.68); channels after k enter with their already-issued inputs
/// ω (4.64); slack penalty m ≥ 1, γ ≥ 1 (γ = (m+1)/m by default, Remark 4.5).
pub fn gamma_m_one_barrier(
    c: &Constraint,
    u0: &DVector<f64>,
    omega: &DVector<f64>,
    i: usize,
    k: usize,
    m: f64,
    gamma: f64,
) -> ChannelOutcome {
    let used = k + 1;
    let (zeta, xi) = (gamma_m_zeta(c, u0, omega, used, gamma), gamma_m_xi(c, used, m));
    if zeta >= 0.0 {
        return ChannelOutcome::new(u0[i], false, false, zeta);
    }
    if xi < DEGENERATE_B {
        return ChannelOutcome::new(u0[i], false, true, zeta);
    }
    // ū_i of QP_k (4.62), applied as (4.67).
    ChannelOutcome::new(u0[i] - zeta / xi * c.b[i], true, false, zeta)
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
        let out = cbf_qp_closed_form(&constraint(1.0, &[1.0, 0.0]), &DVector::from_column_slice(&[0.5, 2.0]));
        assert!(!out.active);
        assert_eq!(out.input, DVector::from_column_slice(&[0.5, 2.0]));
    }

    #[test]
    fn active_solution_lands_on_the_constraint_with_minimal_correction() {
        let c = constraint(-3.0, &[1.0, 2.0]);
        let u0 = DVector::from_column_slice(&[0.0, 0.0]);
        let out = cbf_qp_closed_form(&c, &u0);
        assert!(out.active);
        assert!(c.value(&out.input).abs() < 1e-12);
        // The correction is parallel to b (KKT): v = 3/5 (1, 2).
        assert!((out.input[0] - 0.6).abs() < 1e-12 && (out.input[1] - 1.2).abs() < 1e-12);
    }

    #[test]
    fn fixed_channel_with_all_channels_and_no_disturbance_is_the_delay_free_qp() {
        let c = constraint(-3.0, &[1.0, 2.0]);
        let u0 = DVector::from_column_slice(&[0.5, -0.2]);
        let full = cbf_qp_closed_form(&c, &u0);
        for i in 0..2 {
            let out = fixed_channel_one_barrier(&c, &u0, &DVector::zeros(2), i, 2);
            assert!((out.input - full.input[i]).abs() < 1e-12);
        }
    }

    #[test]
    fn fixed_channel_uses_only_the_first_channels_and_counts_issued_inputs() {
        // s = 1: channel 0 alone must make a + b0 u0 + b1 ω ≥ 0.
        let c = constraint(-1.0, &[2.0, 1.0]);
        let u0 = DVector::from_column_slice(&[0.0, 5.0]);
        let omega = DVector::from_column_slice(&[0.0, -3.0]);
        let out = fixed_channel_one_barrier(&c, &u0, &omega, 0, 1);
        // μ_1 = −1 + 0 + (−3) = −4; ū_0 = 4·2/4 = 2.
        assert!((out.mu + 4.0).abs() < 1e-12 && (out.input - 2.0).abs() < 1e-12);
        assert!((c.a + c.b[0] * out.input + c.b[1] * omega[1]).abs() < 1e-12);
    }

    #[test]
    fn gamma_m_matches_the_full_qp_when_all_channels_are_used_and_gamma_is_m_plus_1_over_m() {
        // With i = r and γ = (m+1)/m, ū = −γ z b / (‖b‖² (1 + 1/m)) = −z b/‖b‖²: (4.9).
        let c = constraint(-3.0, &[1.0, 2.0]);
        let u0 = DVector::from_column_slice(&[0.5, -0.2]);
        let full = cbf_qp_closed_form(&c, &u0);
        let m = 50.0;
        for i in 0..2 {
            let out = gamma_m_one_barrier(&c, &u0, &DVector::zeros(2), i, 1, m, (m + 1.0) / m);
            assert!((out.input - full.input[i]).abs() < 1e-12, "{out:?} vs {full:?}");
        }
        // Channel 0 alone (QP_1): constraint uses its own channel plus the issued ω_1.
        let omega = DVector::from_column_slice(&[0.0, 1.0]);
        let out = gamma_m_one_barrier(&c, &u0, &omega, 0, 0, m, (m + 1.0) / m);
        let z = c.a + c.b[0] * u0[0];
        let zeta = (m + 1.0) / m * z + c.b[1] * omega[1];
        let xi = 1.0 + 5.0 / m;
        assert!((out.input - (u0[0] - zeta / xi)).abs() < 1e-12);
    }

    #[test]
    fn cbf_qp_in_place_repeats_the_nalgebra_arithmetic_bit_for_bit() {
        // The slice form (unrolled for two channels) against the nalgebra expressions it replaced.
        for r in 1..=5 {
            for k in 0..300 {
                let s = k as f64 + 0.37 * r as f64;
                let b = DVector::from_fn(r, |i, _| {
                    if k % 7 == 0 {
                        0.0
                    } else {
                        (1.7 * s + i as f64).sin() * 3.0
                    }
                });
                let u0 = DVector::from_fn(r, |i, _| (0.9 * s - 2.0 * i as f64).cos() * 2.0);
                let c = Constraint {
                    h: 0.0,
                    a: (0.3 * s).sin() * 5.0,
                    b,
                };
                let mu = c.a + c.b.dot(&u0);
                let mut expected = u0.clone();
                let bb = c.b.norm_squared();
                let flags = match (mu >= 0.0, bb < DEGENERATE_B) {
                    (true, _) => (false, false),
                    (false, true) => (false, true),
                    (false, false) => {
                        expected.axpy(-mu / bb, &c.b, 1.0);
                        (true, false)
                    }
                };
                let mut u = u0.clone();
                let (active, infeasible, got_mu) = cbf_qp_in_place(&c, &mut u);
                assert_eq!((active, infeasible), flags);
                assert_eq!(got_mu.to_bits(), mu.to_bits());
                assert_eq!(c.value(&u0).to_bits(), mu.to_bits());
                for (u, e) in u.iter().zip(expected.iter()) {
                    assert_eq!(u.to_bits(), e.to_bits(), "r = {r}, k = {k}");
                }
            }
        }
    }

    #[test]
    fn zero_b_with_violation_is_reported_infeasible() {
        let out = cbf_qp_closed_form(&constraint(-1.0, &[0.0]), &DVector::from_column_slice(&[3.0]));
        assert!(out.infeasible && !out.active);
    }
}
