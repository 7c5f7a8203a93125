//! Constrained stabilization of multi-input linear systems with distinct input delays
//! (Chapter 3): pure maths on `f64`/`nalgebra` values, no plant and no I/O.
//!
//! System (3.1): ẋ = A x + Σ b_i u_i(t − τ_i), 0 ≤ τ_1 ≤ … ≤ τ_r. Every law here is a
//! delay-free feedback κ(x) for (3.2) applied per channel at that channel's prediction,
//! u_i(t) = κ_i(p_i(t)) (3.5); the predictions p_i(t) = x(t + τ_i) ((3.3)/(3.4)) come from
//! [`crate::predictor`] and are passed in.
//!
//! Sign convention of this chapter: constraints read a + b·v ≤ 0 ((3.10), (3.16), (3.27)),
//! the opposite of [`crate::barrier::Constraint`] (a + b·u ≥ 0). Channel indices are 0-based.
//!
//! - [`pmn`]: pointwise min-norm formula (3.7), used for the CLF (3.8)–(3.11) and the
//!   CBF (3.16)–(3.19).
//! - [`gamma_m_qp`]: the CLF-CBF QP-LB (3.27) in closed form, Cases A–D (3.29)–(3.32), with
//!   γ_f (3.28).
//! - [`ConstrainedStabilizer`]: a design (A, B, delays, CLF, disk CBF, l0, η, m, γ) with the
//!   per-channel laws (3.11), (3.19), (3.33).
//! - [`robust_buffer_bound`]: the smallest buffer η allowed by (3.25)/(3.26).
//! - [`table_3_1`], [`disturbance_3_49`]: the example of §3.5 ((3.34), Table 3.1).

use std::fmt;

use nalgebra::{DMatrix, DVector};

/// Below this ‖b‖², a constraint is treated as independent of the input.
const DEGENERATE_B: f64 = 1e-12;

/// Relative tolerance for the symmetry of P and Q.
const SYMMETRY_TOLERANCE: f64 = 1e-9;

/// What can be wrong with a Chapter 3 design or query.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LinearDelaysError {
    #[error("QP weight m = {m} must be finite and >= 1 (QP-LB (3.27), Theorem 3.3: γ, m ≥ 1)")]
    WeightBelowOne { m: f64 },
    #[error("QP gain γ = {gamma} must be finite and >= 1 (γ_f (3.28), Theorem 3.3: γ, m ≥ 1)")]
    GammaBelowOne { gamma: f64 },
    #[error("the system needs at least one state and one input channel, got A {rows}x{cols}, B with {inputs} columns")]
    EmptySystem { rows: usize, cols: usize, inputs: usize },
    #[error("{what} has shape {actual:?}, expected {expected:?}")]
    DimensionMismatch {
        what: &'static str,
        expected: (usize, usize),
        actual: (usize, usize),
    },
    #[error("{what} has a non-finite entry")]
    NonFinite { what: &'static str },
    #[error("{count} delays given for {channels} input channels")]
    DelayCountMismatch { count: usize, channels: usize },
    #[error("delay τ_{channel} = {delay} of channel {channel} must be finite and >= 0 (3.1)")]
    NegativeDelay { channel: usize, delay: f64 },
    #[error("delays must be non-decreasing, 0 ≤ τ_1 ≤ … ≤ τ_r (3.1), but τ_{channel} = {delay} < τ_{previous_channel} = {previous}; order the channels by delay")]
    DelaysNotNondecreasing {
        channel: usize,
        delay: f64,
        previous_channel: usize,
        previous: f64,
    },
    #[error("{which} must be symmetric positive definite (Definition 3.1)")]
    NotPositiveDefinite { which: &'static str },
    #[error("{what} = {value} must be finite and > 0")]
    NotPositive { what: &'static str, value: f64 },
    #[error("buffer η = {eta} must be finite and >= 0 (C_η = {{h > η}} ⊆ C)")]
    NegativeBuffer { eta: f64 },
    #[error("the origin is not admissible: the disk centre is at distance {distance} < radius ρ = {radius} (§3.5 needs σ > ρ)")]
    OriginNotAdmissible { distance: f64, radius: f64 },
    #[error("buffer η = {eta} is below the robustness bound {bound} of (3.25)")]
    BufferBelowBound { eta: f64, bound: f64 },
    #[error("{count} predictions given for {channels} input channels (one p_i per channel, (3.5))")]
    PredictionCountMismatch { count: usize, channels: usize },
}

type Result<T> = std::result::Result<T, LinearDelaysError>;

fn check_finite(what: &'static str, m: &DMatrix<f64>) -> Result<()> {
    if m.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(LinearDelaysError::NonFinite { what })
    }
}

fn check_positive(what: &'static str, value: f64) -> Result<()> {
    if value > 0.0 && value.is_finite() {
        Ok(())
    } else {
        Err(LinearDelaysError::NotPositive { what, value })
    }
}

/// Induced 2-norm (largest singular value), the norm of (3.14) and (3.25).
pub fn spectral_norm(m: &DMatrix<f64>) -> f64 {
    m.clone().svd(false, false).singular_values.max()
}

/// The delay-free system ẋ = A x + B u (3.2); column i of B is b_i (3.1).
#[derive(Debug, Clone, PartialEq)]
pub struct LinearSystem {
    a: DMatrix<f64>,
    b: DMatrix<f64>,
}

impl LinearSystem {
    pub fn new(a: DMatrix<f64>, b: DMatrix<f64>) -> Result<Self> {
        if a.nrows() == 0 || b.ncols() == 0 {
            return Err(LinearDelaysError::EmptySystem {
                rows: a.nrows(),
                cols: a.ncols(),
                inputs: b.ncols(),
            });
        }
        let n = a.nrows();
        if a.ncols() != n {
            return Err(LinearDelaysError::DimensionMismatch {
                what: "A",
                expected: (n, n),
                actual: a.shape(),
            });
        }
        if b.nrows() != n {
            return Err(LinearDelaysError::DimensionMismatch {
                what: "B",
                expected: (n, b.ncols()),
                actual: b.shape(),
            });
        }
        check_finite("A", &a)?;
        check_finite("B", &b)?;
        Ok(LinearSystem { a, b })
    }

    pub fn a(&self) -> &DMatrix<f64> {
        &self.a
    }

    pub fn b(&self) -> &DMatrix<f64> {
        &self.b
    }

    /// n.
    pub fn state_dimension(&self) -> usize {
        self.a.nrows()
    }

    /// r.
    pub fn input_count(&self) -> usize {
        self.b.ncols()
    }
}

/// Checks 0 ≤ τ_1 ≤ … ≤ τ_r (3.1) for `channels` channels.
pub fn validate_delays(delays: &[f64], channels: usize) -> Result<()> {
    if delays.len() != channels {
        return Err(LinearDelaysError::DelayCountMismatch {
            count: delays.len(),
            channels,
        });
    }
    for (i, &delay) in delays.iter().enumerate() {
        if !(delay >= 0.0 && delay.is_finite()) {
            return Err(LinearDelaysError::NegativeDelay { channel: i + 1, delay });
        }
        if i > 0 && delay < delays[i - 1] {
            return Err(LinearDelaysError::DelaysNotNondecreasing {
                channel: i + 1,
                delay,
                previous_channel: i,
                previous: delays[i - 1],
            });
        }
    }
    Ok(())
}

/// A constraint a + b·v ≤ 0 on the input v ∈ ℝ^r ((3.10), (3.16)); `b` holds the row b(x) as a
/// column.
#[derive(Debug, Clone, PartialEq)]
pub struct AffineConstraint {
    pub a: f64,
    pub b: DVector<f64>,
}

impl AffineConstraint {
    /// a + b·v (≤ 0 when satisfied).
    pub fn value(&self, v: &DVector<f64>) -> f64 {
        self.a + self.b.dot(v)
    }
}

/// Result of the pointwise min-norm formula (3.7).
#[derive(Debug, Clone, PartialEq)]
pub struct PmnOutcome {
    pub input: DVector<f64>,
    /// a > 0: the constraint shaped the input.
    pub active: bool,
    /// a > 0 but b = 0: no input satisfies the constraint; 0 is returned.
    pub infeasible: bool,
}

/// κ_pmn(a, b) (3.7): −a bᵀ/‖b‖² if a > 0, else 0; the unique solution of
/// min vᵀv s.t. a + b v ≤ 0 ((3.10), (3.16)).
pub fn pmn(constraint: &AffineConstraint) -> PmnOutcome {
    let r = constraint.b.len();
    if constraint.a <= 0.0 {
        return PmnOutcome {
            input: DVector::zeros(r),
            active: false,
            infeasible: false,
        };
    }
    let bb = constraint.b.norm_squared();
    if bb < DEGENERATE_B {
        return PmnOutcome {
            input: DVector::zeros(r),
            active: false,
            infeasible: true,
        };
    }
    PmnOutcome {
        input: &constraint.b * (-constraint.a / bb),
        active: true,
        infeasible: false,
    }
}

/// γ_f (3.28): γ s for s ≥ 0, s for s < 0. (Chapter 3 form for a1 ≤ 0 constraints; the
/// Chapter 4 γ_f (4.61) in [`crate::filter::gamma_f`] acts on the negative side.)
pub fn gamma_f(gamma: f64, s: f64) -> f64 {
    if s >= 0.0 {
        gamma * s
    } else {
        s
    }
}

/// The design parameters m (relaxation weight) and γ (3.28) of QP-LB (3.27).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GammaM {
    m: f64,
    gamma: f64,
}

impl GammaM {
    /// Theorem 3.3 assumes γ, m ≥ 1.
    pub fn new(m: f64, gamma: f64) -> Result<Self> {
        if !(m >= 1.0 && m.is_finite()) {
            return Err(LinearDelaysError::WeightBelowOne { m });
        }
        if !(gamma >= 1.0 && gamma.is_finite()) {
            return Err(LinearDelaysError::GammaBelowOne { gamma });
        }
        Ok(GammaM { m, gamma })
    }

    /// γ = (m + 1)/m: γm/(m + 1) = 1, where κ_LB equals the PMN law (3.7) while the barrier is
    /// inactive (Theorem 3.3, item 3).
    pub fn matching_pmn(m: f64) -> Result<Self> {
        GammaM::new(m, (m + 1.0) / m)
    }

    pub fn m(&self) -> f64 {
        self.m
    }

    pub fn gamma(&self) -> f64 {
        self.gamma
    }
}

/// Which constraints of QP-LB (3.27) are active at the solution.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum QpCase {
    /// Case A (3.29): none, u = 0.
    A,
    /// Case B (3.30): the CLF constraint F1 only.
    B,
    /// Case C (3.31): the CBF constraint F2 only.
    C,
    /// Case D (3.32): both.
    D,
}

impl fmt::Display for QpCase {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            QpCase::A => "A (none active)",
            QpCase::B => "B (CLF active)",
            QpCase::C => "C (CBF active)",
            QpCase::D => "D (CLF and CBF active)",
        })
    }
}

/// Solution of QP-LB (3.27).
#[derive(Debug, Clone, PartialEq)]
pub struct QpOutcome {
    /// u = v.
    pub input: DVector<f64>,
    /// δ = σ, the relaxation of the CLF constraint.
    pub relaxation: DVector<f64>,
    pub case: QpCase,
    /// ā1 = γ_f(a1) (3.28).
    pub a1_bar: f64,
    /// A constraint had a > 0 but b = 0, so no input meets it; it was dropped (only possible
    /// for the CBF at x = c, or for a CLF constraint with a1 > 0 at a point where b1 = 0).
    pub infeasible: bool,
}

/// QP-LB (3.27): min vᵀv + m σᵀσ s.t. F1 = ā1 + b1(v + σ) ≤ 0, F2 = a2 + b2 v ≤ 0,
/// ā1 = γ_f(a1) (3.28), solved in closed form by Cases A–D (3.29)–(3.32).
pub fn gamma_m_qp(clf: &AffineConstraint, cbf: &AffineConstraint, params: &GammaM) -> QpOutcome {
    let r = clf.b.len();
    let m = params.m;
    let a1_bar = gamma_f(params.gamma, clf.a);
    let a2 = cbf.a;
    let (b1, b2) = (&clf.b, &cbf.b);
    let (n1, n2) = (b1.norm_squared(), b2.norm_squared());
    let outcome = |input: DVector<f64>, relaxation: DVector<f64>, case: QpCase, infeasible: bool| QpOutcome {
        input,
        relaxation,
        case,
        a1_bar,
        infeasible,
    };
    // Case B alone (F2 inactive or dropped): (3.30), σ = v/m (stationarity).
    let case_b = |infeasible: bool| {
        let v = b1 * (-m / (m + 1.0) * a1_bar / n1);
        let sigma = &v / m;
        outcome(v, sigma, QpCase::B, infeasible)
    };
    // Case C alone (F1 inactive or dropped): (3.31).
    let case_c = |infeasible: bool| outcome(b2 * (-a2 / n2), DVector::zeros(r), QpCase::C, infeasible);
    let zero = |infeasible: bool| outcome(DVector::zeros(r), DVector::zeros(r), QpCase::A, infeasible);

    // Degenerate constraints do not depend on the input: drop them (flagging an impossible one)
    // and solve with the other alone.
    if n1 < DEGENERATE_B || n2 < DEGENERATE_B {
        let clf_infeasible = n1 < DEGENERATE_B && a1_bar > 0.0;
        let cbf_infeasible = n2 < DEGENERATE_B && a2 > 0.0;
        let infeasible = clf_infeasible || cbf_infeasible;
        if n2 >= DEGENERATE_B && a2 > 0.0 {
            return case_c(infeasible);
        }
        if n1 >= DEGENERATE_B && a1_bar > 0.0 {
            return case_b(infeasible);
        }
        return zero(infeasible);
    }

    let b1b2 = b1.dot(b2);
    // Case A (3.29): u = 0 is feasible (Ω1, closed).
    if a1_bar <= 0.0 && a2 <= 0.0 {
        return zero(false);
    }
    // Case B (3.30) in Ω2.
    if a1_bar > 0.0 && a2 < m / (m + 1.0) * b1b2 / n1 * a1_bar {
        return case_b(false);
    }
    // Case C (3.31) in Ω3.
    if a2 > 0.0 && a1_bar < b1b2 / n2 * a2 {
        return case_c(false);
    }
    // Case D (3.32) in Ω4: both active; the denominator is ≥ ‖b1‖²‖b2‖²/m > 0.
    let k = 1.0 + 1.0 / m;
    let denominator = k * n1 * n2 - b1b2 * b1b2;
    let input = (b1 * (-n2 * a1_bar) + b1 * (b1b2 * a2) + b2 * (b1b2 * a1_bar) - b2 * (k * n1 * a2)) / denominator;
    // Half the multiplier of F1, from the same 2×2 KKT system: σ = −(λ1/2) b1ᵀ/m.
    let half_lambda1 = (n2 * a1_bar - b1b2 * a2) / denominator;
    let relaxation = b1 * (-half_lambda1 / m);
    outcome(input, relaxation, QpCase::D, false)
}

/// A quadratic CLF V = xᵀPx with decay rate xᵀQx (Definition 3.1).
#[derive(Debug, Clone, PartialEq)]
pub struct QuadraticClf {
    p: DMatrix<f64>,
    q: DMatrix<f64>,
}

fn check_symmetric_positive_definite(which: &'static str, m: &DMatrix<f64>) -> Result<()> {
    check_finite(which, m)?;
    let scale = m.amax().max(1.0);
    let symmetric = m.is_square() && (m - m.transpose()).amax() <= SYMMETRY_TOLERANCE * scale;
    if symmetric && m.clone().cholesky().is_some() {
        Ok(())
    } else {
        Err(LinearDelaysError::NotPositiveDefinite { which })
    }
}

impl QuadraticClf {
    /// P > 0 and Q > 0, both symmetric and of one size. Whether V is a CLF for a system
    /// ((3.6)) is a property of the pair, not checked here.
    pub fn new(p: DMatrix<f64>, q: DMatrix<f64>) -> Result<Self> {
        check_symmetric_positive_definite("P", &p)?;
        check_symmetric_positive_definite("Q", &q)?;
        if q.shape() != p.shape() {
            return Err(LinearDelaysError::DimensionMismatch {
                what: "Q",
                expected: p.shape(),
                actual: q.shape(),
            });
        }
        Ok(QuadraticClf { p, q })
    }

    pub fn p(&self) -> &DMatrix<f64> {
        &self.p
    }

    pub fn q(&self) -> &DMatrix<f64> {
        &self.q
    }

    /// V(x) = xᵀPx.
    pub fn value(&self, x: &DVector<f64>) -> f64 {
        x.dot(&(&self.p * x))
    }

    /// a1(x) = xᵀ(AᵀP + PA + Q)x (3.8), b1(x) = 2xᵀPB (3.9): the constraint of QP-L (3.10).
    pub fn constraint(&self, system: &LinearSystem, x: &DVector<f64>) -> AffineConstraint {
        let pa = &self.p * &system.a;
        let m = pa.transpose() + pa + &self.q;
        AffineConstraint {
            a: x.dot(&(m * x)),
            b: (system.b.transpose() * (&self.p * x)) * 2.0,
        }
    }
}

/// The CBF constraint (3.17)/(3.18) of QP-B (3.16) for the buffered barrier H = h − η with
/// linear α_h(H) = l0 H ((3.40), (3.41)): a2 = −∇hᵀA x − l0 (h − η), b2 = −∇hᵀB.
pub fn barrier_constraint(
    system: &LinearSystem,
    x: &DVector<f64>,
    h: f64,
    gradient: &DVector<f64>,
    l0: f64,
    eta: f64,
) -> AffineConstraint {
    AffineConstraint {
        a: -gradient.dot(&(&system.a * x)) - l0 * (h - eta),
        b: -(system.b.transpose() * gradient),
    }
}

/// The complement of a disk (ball) as admissible set: h(x) = ‖x − c‖² − ρ² ((3.36), (3.37)).
#[derive(Debug, Clone, PartialEq)]
pub struct DiskBarrier {
    centre: DVector<f64>,
    radius: f64,
}

impl DiskBarrier {
    /// The origin must be admissible (‖c‖ > ρ; §3.5: σ > ρ), so that stabilization and
    /// safety are compatible (Theorem 3.3, item 4).
    pub fn new(centre: DVector<f64>, radius: f64) -> Result<Self> {
        check_positive("disk radius ρ", radius)?;
        check_finite("disk centre", &DMatrix::from_column_slice(centre.len(), 1, centre.as_slice()))?;
        let distance = centre.norm();
        if distance <= radius {
            return Err(LinearDelaysError::OriginNotAdmissible { distance, radius });
        }
        Ok(DiskBarrier { centre, radius })
    }

    pub fn centre(&self) -> &DVector<f64> {
        &self.centre
    }

    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// h(x) (3.36).
    pub fn value(&self, x: &DVector<f64>) -> f64 {
        (x - &self.centre).norm_squared() - self.radius * self.radius
    }

    /// ∂h/∂x = 2(x − c)ᵀ ((3.38), (3.39)), as a column.
    pub fn gradient(&self, x: &DVector<f64>) -> DVector<f64> {
        (x - &self.centre) * 2.0
    }

    /// max ‖∂h/∂x‖ on ∂C = {‖x − c‖ = ρ}: 2ρ, the factor of (3.25).
    pub fn max_gradient_norm_on_boundary(&self) -> f64 {
        2.0 * self.radius
    }
}

/// 𝐯 = ∫₀^τ e^{Aθ} dθ (3.26), as the upper-right block of exp([[A, I], [0, 0]] τ).
pub fn delay_integral(a: &DMatrix<f64>, tau: f64) -> DMatrix<f64> {
    let n = a.nrows();
    let mut augmented = DMatrix::zeros(2 * n, 2 * n);
    augmented.view_mut((0, 0), (n, n)).copy_from(a);
    augmented.view_mut((0, n), (n, n)).fill_with_identity();
    (augmented * tau).exp().view((0, n), (n, n)).into_owned()
}

/// Everything the buffer bound (3.25) depends on.
#[derive(Debug, Clone, PartialEq)]
pub struct BufferInputs<'a> {
    /// A of (3.24).
    pub a: &'a DMatrix<f64>,
    /// B_ω of (3.24): how the disturbance enters.
    pub b_omega: &'a DMatrix<f64>,
    /// l0 of α_h(h) = l0 h (3.40).
    pub l0: f64,
    /// ω̄ ≥ ‖ω(t)‖.
    pub omega_bar: f64,
    /// τ_r, the longest delay.
    pub longest_delay: f64,
    /// max ‖∂h/∂x‖ on ∂C.
    pub max_gradient_norm_on_boundary: f64,
}

/// The smallest buffer η allowed by (3.25):
/// ‖∂h/∂x‖ (‖𝐯‖ ‖(I + A/l0) B_ω‖ + ‖B_ω‖/l0) ω̄ with 𝐯 from (3.26), induced 2-norms, and
/// ‖∂h/∂x‖ maximised over ∂C.
pub fn robust_buffer_bound(inputs: &BufferInputs<'_>) -> Result<f64> {
    let BufferInputs {
        a,
        b_omega,
        l0,
        omega_bar,
        longest_delay,
        max_gradient_norm_on_boundary,
    } = *inputs;
    let n = a.nrows();
    if a.ncols() != n {
        return Err(LinearDelaysError::DimensionMismatch {
            what: "A",
            expected: (n, n),
            actual: a.shape(),
        });
    }
    if b_omega.nrows() != n {
        return Err(LinearDelaysError::DimensionMismatch {
            what: "B_ω",
            expected: (n, b_omega.ncols()),
            actual: b_omega.shape(),
        });
    }
    check_finite("A", a)?;
    check_finite("B_ω", b_omega)?;
    check_positive("l0", l0)?;
    if !(omega_bar >= 0.0 && omega_bar.is_finite()) {
        return Err(LinearDelaysError::NotPositive {
            what: "disturbance bound ω̄",
            value: omega_bar,
        });
    }
    if !(longest_delay >= 0.0 && longest_delay.is_finite()) {
        return Err(LinearDelaysError::NegativeDelay {
            channel: 0,
            delay: longest_delay,
        });
    }
    if !(max_gradient_norm_on_boundary >= 0.0 && max_gradient_norm_on_boundary.is_finite()) {
        return Err(LinearDelaysError::NotPositive {
            what: "max ‖∂h/∂x‖ on ∂C",
            value: max_gradient_norm_on_boundary,
        });
    }
    let v = delay_integral(a, longest_delay);
    let shaped = (DMatrix::identity(n, n) + a / l0) * b_omega;
    Ok(max_gradient_norm_on_boundary
        * (spectral_norm(&v) * spectral_norm(&shaped) + spectral_norm(b_omega) / l0)
        * omega_bar)
}

/// What the QP law (3.33) decided for one channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelDecision {
    /// u_i(t) = κ_LB,i(p_i(t)).
    pub input: f64,
    pub case: QpCase,
    pub infeasible: bool,
}

/// A Chapter 3 design: system (3.1), delays, CLF (Definition 3.1), disk CBF with
/// α_h = l0 h (3.40) and buffer η (C_η = {h > η}), QP parameters (m, γ).
#[derive(Debug, Clone, PartialEq)]
pub struct ConstrainedStabilizer {
    system: LinearSystem,
    delays: Vec<f64>,
    clf: QuadraticClf,
    barrier: DiskBarrier,
    l0: f64,
    eta: f64,
    qp: GammaM,
}

impl ConstrainedStabilizer {
    /// Checks dimensions, 0 ≤ τ_1 ≤ … ≤ τ_r, l0 > 0 and η ≥ 0. Whether η meets (3.25) for a
    /// disturbance is a separate question: [`ConstrainedStabilizer::check_buffer`].
    pub fn new(
        system: LinearSystem,
        delays: Vec<f64>,
        clf: QuadraticClf,
        barrier: DiskBarrier,
        l0: f64,
        eta: f64,
        qp: GammaM,
    ) -> Result<Self> {
        let n = system.state_dimension();
        validate_delays(&delays, system.input_count())?;
        if clf.p.nrows() != n {
            return Err(LinearDelaysError::DimensionMismatch {
                what: "P",
                expected: (n, n),
                actual: clf.p.shape(),
            });
        }
        if barrier.centre.len() != n {
            return Err(LinearDelaysError::DimensionMismatch {
                what: "disk centre",
                expected: (n, 1),
                actual: (barrier.centre.len(), 1),
            });
        }
        check_positive("l0", l0)?;
        if !(eta >= 0.0 && eta.is_finite()) {
            return Err(LinearDelaysError::NegativeBuffer { eta });
        }
        Ok(ConstrainedStabilizer {
            system,
            delays,
            clf,
            barrier,
            l0,
            eta,
            qp,
        })
    }

    pub fn system(&self) -> &LinearSystem {
        &self.system
    }

    /// τ_1 ≤ … ≤ τ_r.
    pub fn delays(&self) -> &[f64] {
        &self.delays
    }

    pub fn clf(&self) -> &QuadraticClf {
        &self.clf
    }

    pub fn barrier(&self) -> &DiskBarrier {
        &self.barrier
    }

    pub fn l0(&self) -> f64 {
        self.l0
    }

    pub fn eta(&self) -> f64 {
        self.eta
    }

    pub fn qp(&self) -> &GammaM {
        &self.qp
    }

    /// h(x) (3.36): C = {h ≥ 0}.
    pub fn h(&self, x: &DVector<f64>) -> f64 {
        self.barrier.value(x)
    }

    /// h(x) − η: C_η = {h − η ≥ 0}.
    pub fn buffered_h(&self, x: &DVector<f64>) -> f64 {
        self.barrier.value(x) - self.eta
    }

    /// (a1, b1) (3.8)/(3.9).
    pub fn clf_constraint(&self, x: &DVector<f64>) -> AffineConstraint {
        self.clf.constraint(&self.system, x)
    }

    /// (a2, b2) (3.41)/(3.42), i.e. (3.17)/(3.18) for H = h − η.
    pub fn cbf_constraint(&self, x: &DVector<f64>) -> AffineConstraint {
        barrier_constraint(
            &self.system,
            x,
            self.barrier.value(x),
            &self.barrier.gradient(x),
            self.l0,
            self.eta,
        )
    }

    /// Delay-free PMN CLF law κ_pmn(a1(x), b1(x)) (3.7).
    pub fn clf_pmn(&self, x: &DVector<f64>) -> PmnOutcome {
        pmn(&self.clf_constraint(x))
    }

    /// Delay-free PMN CBF law κ_pmn(a2(x), b2(x)) solving QP-B (3.16).
    pub fn cbf_pmn(&self, x: &DVector<f64>) -> PmnOutcome {
        pmn(&self.cbf_constraint(x))
    }

    /// Delay-free CLF-CBF law κ_LB(x) solving QP-LB (3.27) ((3.29)–(3.32)).
    pub fn kappa_lb(&self, x: &DVector<f64>) -> QpOutcome {
        gamma_m_qp(&self.clf_constraint(x), &self.cbf_constraint(x), &self.qp)
    }

    fn check_predictions(&self, predictions: &[DVector<f64>]) -> Result<()> {
        let r = self.system.input_count();
        if predictions.len() != r {
            return Err(LinearDelaysError::PredictionCountMismatch {
                count: predictions.len(),
                channels: r,
            });
        }
        let n = self.system.state_dimension();
        for p in predictions {
            if p.len() != n {
                return Err(LinearDelaysError::DimensionMismatch {
                    what: "prediction p_i",
                    expected: (n, 1),
                    actual: (p.len(), 1),
                });
            }
        }
        Ok(())
    }

    /// u_L,i(t) = κ_pmn,i(a1(p_i), b1(p_i)) (3.11); `predictions[i]` = p_i(t) = x(t + τ_i).
    pub fn clf_inputs(&self, predictions: &[DVector<f64>]) -> Result<Vec<f64>> {
        self.check_predictions(predictions)?;
        Ok(predictions.iter().enumerate().map(|(i, p)| self.clf_pmn(p).input[i]).collect())
    }

    /// u_B,i(t) = κ_pmn,i(a2(p_i), b2(p_i)) (3.19).
    pub fn cbf_inputs(&self, predictions: &[DVector<f64>]) -> Result<Vec<f64>> {
        self.check_predictions(predictions)?;
        Ok(predictions.iter().enumerate().map(|(i, p)| self.cbf_pmn(p).input[i]).collect())
    }

    /// u_i(t) = κ_LB,i(p_i(t)) (3.33), with the case of QP-LB solved at p_i.
    pub fn lb_inputs(&self, predictions: &[DVector<f64>]) -> Result<Vec<ChannelDecision>> {
        self.check_predictions(predictions)?;
        Ok(predictions
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let outcome = self.kappa_lb(p);
                ChannelDecision {
                    input: outcome.input[i],
                    case: outcome.case,
                    infeasible: outcome.infeasible,
                }
            })
            .collect())
    }

    /// The bound (3.25) on η for a disturbance B_ω ω(t), ‖ω‖ ≤ ω̄ (3.24), with τ_r the longest
    /// delay of this design.
    pub fn robust_buffer_bound(&self, b_omega: &DMatrix<f64>, omega_bar: f64) -> Result<f64> {
        robust_buffer_bound(&BufferInputs {
            a: &self.system.a,
            b_omega,
            l0: self.l0,
            omega_bar,
            longest_delay: self.delays.last().copied().unwrap_or(0.0),
            max_gradient_norm_on_boundary: self.barrier.max_gradient_norm_on_boundary(),
        })
    }

    /// Ok(bound) if this design's η satisfies (3.25) for the disturbance, else
    /// [`LinearDelaysError::BufferBelowBound`].
    pub fn check_buffer(&self, b_omega: &DMatrix<f64>, omega_bar: f64) -> Result<f64> {
        let bound = self.robust_buffer_bound(b_omega, omega_bar)?;
        if self.eta < bound {
            return Err(LinearDelaysError::BufferBelowBound { eta: self.eta, bound });
        }
        Ok(bound)
    }
}

/// The example of §3.5: system (3.34), disk (3.35)–(3.37), CLF (3.43)–(3.46), Table 3.1,
/// initial conditions (3.47)/(3.48) and x(0).
#[derive(Debug, Clone, PartialEq)]
pub struct Example35 {
    /// A of (3.34).
    pub a: DMatrix<f64>,
    /// B of (3.34): u_i enters ẋ_i.
    pub b: DMatrix<f64>,
    /// B_ω of (3.24) for (3.34): ω_i enters ẋ_i.
    pub b_omega: DMatrix<f64>,
    /// (τ_1, τ_2).
    pub delays: Vec<f64>,
    /// ρ.
    pub radius: f64,
    /// σ: the disk is centred at c = (σ, 0) (3.37).
    pub centre_offset: f64,
    pub l0: f64,
    pub omega_bar: f64,
    /// P = diag{p}.
    pub p: f64,
    /// Q = diag{q}, q = 0.9 p².
    pub q: f64,
    /// η of Table 3.1 (the text: (3.25) gives η ≥ 8.06).
    pub eta: f64,
    pub m: f64,
    pub gamma: f64,
    /// Δt: the step of the predictor integrals (and of the control).
    pub timestep: f64,
    /// x(0) = (16, 6).
    pub initial_state: DVector<f64>,
}

/// The parameters of §3.5 as listed in Table 3.1, with (3.34) and x(0) = (16, 6); the inputs
/// start at zero ((3.47)/(3.48)).
pub fn table_3_1() -> Example35 {
    let p = 0.4;
    Example35 {
        a: DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.5, -1.0]),
        b: DMatrix::identity(2, 2),
        b_omega: DMatrix::identity(2, 2),
        delays: vec![0.2, 0.8],
        radius: 5.0,
        centre_offset: 6.0,
        l0: 2.0,
        omega_bar: 1.0,
        p,
        q: 0.9 * p * p,
        eta: 8.06,
        m: 8.0,
        gamma: 2.25,
        timestep: 0.005,
        initial_state: DVector::from_column_slice(&[16.0, 6.0]),
    }
}

impl Example35 {
    pub fn system(&self) -> Result<LinearSystem> {
        LinearSystem::new(self.a.clone(), self.b.clone())
    }

    /// The disk (3.36) centred at c = (σ, 0) (3.37).
    pub fn barrier(&self) -> Result<DiskBarrier> {
        DiskBarrier::new(DVector::from_column_slice(&[self.centre_offset, 0.0]), self.radius)
    }

    /// V = xᵀ diag{p} x, Q = diag{q}.
    pub fn clf(&self) -> Result<QuadraticClf> {
        QuadraticClf::new(DMatrix::identity(2, 2) * self.p, DMatrix::identity(2, 2) * self.q)
    }

    pub fn stabilizer(&self) -> Result<ConstrainedStabilizer> {
        ConstrainedStabilizer::new(
            self.system()?,
            self.delays.clone(),
            self.clf()?,
            self.barrier()?,
            self.l0,
            self.eta,
            GammaM::new(self.m, self.gamma)?,
        )
    }

    /// The bound (3.25) on η for ω̄ (the text: η ≥ 8.06).
    pub fn robust_buffer_bound(&self) -> Result<f64> {
        self.stabilizer()?.robust_buffer_bound(&self.b_omega, self.omega_bar)
    }
}

/// sgn with sgn(0) = 0 (f64::signum(0.0) is 1).
fn sign(s: f64) -> f64 {
    if s > 0.0 {
        1.0
    } else if s < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// ω(t) of §3.5: ω1 = (√2/2) sin(0.4πt) (3.49), ω2 = (√2/2) sgn(ω1(t)) (3.50); ‖ω‖ ≤ 1 = ω̄.
pub fn disturbance_3_49(t: f64) -> DVector<f64> {
    let w1 = std::f64::consts::FRAC_1_SQRT_2 * (0.4 * std::f64::consts::PI * t).sin();
    DVector::from_column_slice(&[w1, std::f64::consts::FRAC_1_SQRT_2 * sign(w1)])
}
