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
    #[error("longest delay τ_r = {delay} must be finite and >= 0 ((3.26))")]
    NegativeLongestDelay { delay: f64 },
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
    let (mut input, mut relaxation) = (DVector::zeros(r), DVector::zeros(r));
    let (case, a1_bar, infeasible) = gamma_m_qp_into(clf, cbf, params, &mut input, &mut relaxation);
    QpOutcome {
        input,
        relaxation,
        case,
        a1_bar,
        infeasible,
    }
}

/// [`gamma_m_qp`] into `input` (v) and `relaxation` (σ), without allocation; returns the case,
/// ā1 and the infeasibility flag of [`QpOutcome`].
pub fn gamma_m_qp_into(
    clf: &AffineConstraint,
    cbf: &AffineConstraint,
    params: &GammaM,
    input: &mut DVector<f64>,
    relaxation: &mut DVector<f64>,
) -> (QpCase, f64, bool) {
    let m = params.m;
    let a1_bar = gamma_f(params.gamma, clf.a);
    let a2 = cbf.a;
    let (b1, b2) = (&clf.b, &cbf.b);
    let (n1, n2) = (b1.norm_squared(), b2.norm_squared());
    // Case B alone (F2 inactive or dropped): (3.30), σ = v/m (stationarity).
    let case_b = |infeasible: bool, input: &mut DVector<f64>, relaxation: &mut DVector<f64>| {
        let scale = -m / (m + 1.0) * a1_bar / n1;
        for i in 0..b1.len() {
            input[i] = b1[i] * scale;
            relaxation[i] = input[i] / m;
        }
        (QpCase::B, a1_bar, infeasible)
    };
    // Case C alone (F1 inactive or dropped): (3.31).
    let case_c = |infeasible: bool, input: &mut DVector<f64>, relaxation: &mut DVector<f64>| {
        let scale = -a2 / n2;
        for i in 0..b2.len() {
            input[i] = b2[i] * scale;
        }
        relaxation.fill(0.0);
        (QpCase::C, a1_bar, infeasible)
    };
    let zero = |infeasible: bool, input: &mut DVector<f64>, relaxation: &mut DVector<f64>| {
        input.fill(0.0);
        relaxation.fill(0.0);
        (QpCase::A, a1_bar, infeasible)
    };

    // Degenerate constraints do not depend on the input: drop them (flagging an impossible one)
    // and solve with the other alone.
    if n1 < DEGENERATE_B || n2 < DEGENERATE_B {
        let clf_infeasible = n1 < DEGENERATE_B && a1_bar > 0.0;
        let cbf_infeasible = n2 < DEGENERATE_B && a2 > 0.0;
        let infeasible = clf_infeasible || cbf_infeasible;
        if n2 >= DEGENERATE_B && a2 > 0.0 {
            return case_c(infeasible, input, relaxation);
        }
        if n1 >= DEGENERATE_B && a1_bar > 0.0 {
            return case_b(infeasible, input, relaxation);
        }
        return zero(infeasible, input, relaxation);
    }

    let b1b2 = b1.dot(b2);
    // Case A (3.29): u = 0 is feasible (Ω1, closed).
    if a1_bar <= 0.0 && a2 <= 0.0 {
        return zero(false, input, relaxation);
    }
    // Case B (3.30) in Ω2.
    if a1_bar > 0.0 && a2 < m / (m + 1.0) * b1b2 / n1 * a1_bar {
        return case_b(false, input, relaxation);
    }
    // Case C (3.31) in Ω3.
    if a2 > 0.0 && a1_bar < b1b2 / n2 * a2 {
        return case_c(false, input, relaxation);
    }
    // Case D (3.32) in Ω4: both active; the denominator is ≥ ‖b1‖²‖b2‖²/m > 0.
    let k = 1.0 + 1.0 / m;
    let denominator = k * n1 * n2 - b1b2 * b1b2;
    let (s1, s2, s3, s4) = (-n2 * a1_bar, b1b2 * a2, b1b2 * a1_bar, k * n1 * a2);
    // Half the multiplier of F1, from the same 2×2 KKT system: σ = −(λ1/2) b1ᵀ/m.
    let half_lambda1 = (n2 * a1_bar - b1b2 * a2) / denominator;
    let sigma = -half_lambda1 / m;
    for i in 0..b1.len() {
        input[i] = (b1[i] * s1 + b1[i] * s2 + b2[i] * s3 - b2[i] * s4) / denominator;
        relaxation[i] = b1[i] * sigma;
    }
    (QpCase::D, a1_bar, false)
}

/// Scratch space of [`ConstrainedStabilizer::kappa_lb_into`]: the constraints (3.8)/(3.9),
/// (3.41)/(3.42), the products they need, and the solution.
#[derive(Debug, Clone, PartialEq)]
pub struct KappaLbWorkspace {
    pub clf: AffineConstraint,
    pub cbf: AffineConstraint,
    /// u = v.
    pub input: DVector<f64>,
    /// δ = σ.
    pub relaxation: DVector<f64>,
    mx: DVector<f64>,
    px: DVector<f64>,
    ax: DVector<f64>,
    gradient: DVector<f64>,
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

    /// AᵀP + PA + Q, the matrix of a1 (3.8).
    fn a1_matrix(&self, system: &LinearSystem) -> DMatrix<f64> {
        let pa = &self.p * &system.a;
        pa.transpose() + pa + &self.q
    }

    /// a1(x) = xᵀ(AᵀP + PA + Q)x (3.8), b1(x) = 2xᵀPB (3.9): the constraint of QP-L (3.10).
    pub fn constraint(&self, system: &LinearSystem, x: &DVector<f64>) -> AffineConstraint {
        let m = self.a1_matrix(system);
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
        check_finite(
            "disk centre",
            &DMatrix::from_column_slice(centre.len(), 1, centre.as_slice()),
        )?;
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
        return Err(LinearDelaysError::NegativeLongestDelay { delay: longest_delay });
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
    /// AᵀP + PA + Q of a1 (3.8).
    clf_matrix: DMatrix<f64>,
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
            clf_matrix: clf.a1_matrix(&system),
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
        let mut workspace = self.workspace();
        let (case, a1_bar, infeasible) = self.kappa_lb_into(x, &mut workspace);
        QpOutcome {
            input: workspace.input,
            relaxation: workspace.relaxation,
            case,
            a1_bar,
            infeasible,
        }
    }

    /// Scratch space for [`ConstrainedStabilizer::kappa_lb_into`].
    pub fn workspace(&self) -> KappaLbWorkspace {
        let (n, r) = (self.system.state_dimension(), self.system.input_count());
        let constraint = || AffineConstraint {
            a: 0.0,
            b: DVector::zeros(r),
        };
        KappaLbWorkspace {
            clf: constraint(),
            cbf: constraint(),
            input: DVector::zeros(r),
            relaxation: DVector::zeros(r),
            mx: DVector::zeros(n),
            px: DVector::zeros(n),
            ax: DVector::zeros(n),
            gradient: DVector::zeros(n),
        }
    }

    /// [`ConstrainedStabilizer::kappa_lb`] without allocation: the constraints and u, σ in
    /// `workspace`; returns the case, ā1 and the infeasibility flag of [`QpOutcome`].
    pub fn kappa_lb_into(&self, x: &DVector<f64>, workspace: &mut KappaLbWorkspace) -> (QpCase, f64, bool) {
        let KappaLbWorkspace {
            clf,
            cbf,
            input,
            relaxation,
            mx,
            px,
            ax,
            gradient,
        } = workspace;
        let (a, b) = (&self.system.a, &self.system.b);
        // (a1, b1) (3.8)/(3.9), as [`QuadraticClf::constraint`].
        self.clf_matrix.mul_to(x, mx);
        clf.a = x.dot(mx);
        self.clf.p.mul_to(x, px);
        b.tr_mul_to(px, &mut clf.b);
        clf.b *= 2.0;
        // (a2, b2) (3.41)/(3.42), as [`barrier_constraint`]: ∇h = 2(x − c).
        gradient.copy_from(x);
        *gradient -= &self.barrier.centre;
        let h = gradient.norm_squared() - self.barrier.radius * self.barrier.radius;
        *gradient *= 2.0;
        a.mul_to(x, ax);
        cbf.a = -gradient.dot(ax) - self.l0 * (h - self.eta);
        b.tr_mul_to(gradient, &mut cbf.b);
        cbf.b.neg_mut();
        gamma_m_qp_into(clf, cbf, &self.qp, input, relaxation)
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
        Ok(predictions
            .iter()
            .enumerate()
            .map(|(i, p)| self.clf_pmn(p).input[i])
            .collect())
    }

    /// u_B,i(t) = κ_pmn,i(a2(p_i), b2(p_i)) (3.19).
    pub fn cbf_inputs(&self, predictions: &[DVector<f64>]) -> Result<Vec<f64>> {
        self.check_predictions(predictions)?;
        Ok(predictions
            .iter()
            .enumerate()
            .map(|(i, p)| self.cbf_pmn(p).input[i])
            .collect())
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn vector(values: &[f64]) -> DVector<f64> {
        DVector::from_column_slice(values)
    }

    fn constraint(a: f64, b: &[f64]) -> AffineConstraint {
        AffineConstraint { a, b: vector(b) }
    }

    /// Deterministic pseudo-random numbers in [−1, 1) (xorshift64*).
    struct Noise(u64);

    impl Noise {
        fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            let bits = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11;
            bits as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        }
    }

    #[test]
    fn gamma_f_scales_only_the_positive_side() {
        assert_eq!(gamma_f(2.25, 2.0), 4.5);
        assert_eq!(gamma_f(2.25, -2.0), -2.0);
        assert_eq!(gamma_f(2.25, 0.0), 0.0);
    }

    #[test]
    fn pmn_is_zero_when_inactive_and_the_minimum_norm_solution_when_active() {
        let inactive = pmn(&constraint(-1.0, &[1.0, 2.0]));
        assert!(!inactive.active && !inactive.infeasible);
        assert_eq!(inactive.input, DVector::zeros(2));

        let c = constraint(5.0, &[1.0, 2.0]);
        let active = pmn(&c);
        assert!(active.active && !active.infeasible);
        // (3.7): −a bᵀ/‖b‖² = −(1, 2).
        assert!((active.input.clone() - vector(&[-1.0, -2.0])).amax() < 1e-12);
        assert!(c.value(&active.input).abs() < 1e-12);
        // No feasible input is shorter.
        let mut noise = Noise(7);
        for _ in 0..1000 {
            let v = vector(&[4.0 * noise.next(), 4.0 * noise.next()]);
            if c.value(&v) <= 0.0 {
                assert!(v.norm() >= active.input.norm() - 1e-12);
            }
        }

        let impossible = pmn(&constraint(1.0, &[0.0, 0.0]));
        assert!(impossible.infeasible && !impossible.active);
    }

    /// QP-LB (3.27) solved by enumerating active sets with a generic KKT solve, in the
    /// variables z = (v, σ): min zᵀWz, W = diag(I, m I), s.t. g_k z + a_k ≤ 0.
    fn brute_force_qp(a1_bar: f64, b1: &DVector<f64>, a2: f64, b2: &DVector<f64>, m: f64) -> DVector<f64> {
        let r = b1.len();
        let mut g = DMatrix::zeros(2, 2 * r);
        for j in 0..r {
            g[(0, j)] = b1[j];
            g[(0, r + j)] = b1[j];
            g[(1, j)] = b2[j];
        }
        let offsets = [a1_bar, a2];
        let weights = DVector::from_fn(2 * r, |k, _| if k < r { 1.0 } else { m });
        let objective = |z: &DVector<f64>| (0..2 * r).map(|k| weights[k] * z[k] * z[k]).sum::<f64>();
        let mut best: Option<DVector<f64>> = None;
        for active in [vec![], vec![0], vec![1], vec![0, 1]] {
            let q = active.len();
            let size = 2 * r + q;
            let mut kkt = DMatrix::zeros(size, size);
            let mut rhs = DVector::zeros(size);
            for k in 0..2 * r {
                kkt[(k, k)] = 2.0 * weights[k];
            }
            for (row, &c) in active.iter().enumerate() {
                for k in 0..2 * r {
                    kkt[(2 * r + row, k)] = g[(c, k)];
                    kkt[(k, 2 * r + row)] = g[(c, k)];
                }
                rhs[2 * r + row] = -offsets[c];
            }
            let Some(solution) = kkt.lu().solve(&rhs) else { continue };
            let z = solution.rows(0, 2 * r).into_owned();
            let multipliers_ok = (0..q).all(|row| solution[2 * r + row] >= -1e-9);
            let feasible = (0..2).all(|c| offsets[c] + (g.row(c) * &z)[0] <= 1e-9 * (1.0 + offsets[c].abs()));
            if multipliers_ok && feasible && best.as_ref().is_none_or(|b| objective(&z) < objective(b) - 1e-12) {
                best = Some(z);
            }
        }
        best.expect("QP-LB is feasible when b1, b2 ≠ 0")
    }

    #[test]
    fn closed_form_cases_a_to_d_match_a_brute_force_qp_solution() {
        let mut noise = Noise(0x9E37_79B9_7F4A_7C15);
        let mut seen: HashMap<QpCase, usize> = HashMap::new();
        for trial in 0..4000 {
            let r = 1 + trial % 3;
            let m = 1.0 + 9.0 * (noise.next() + 1.0) / 2.0;
            let gamma = 1.0 + 3.0 * (noise.next() + 1.0) / 2.0;
            let params = GammaM::new(m, gamma).unwrap();
            let clf = AffineConstraint {
                a: 3.0 * noise.next(),
                b: DVector::from_fn(r, |_, _| noise.next()),
            };
            let mut cbf = AffineConstraint {
                a: 3.0 * noise.next(),
                b: DVector::from_fn(r, |_, _| noise.next()),
            };
            if trial % 5 == 0 {
                // Nearly parallel constraint rows stress Case D.
                cbf.b = &clf.b * (2.0 * noise.next()) + DVector::from_fn(r, |_, _| 1e-3 * noise.next());
            }
            let out = gamma_m_qp(&clf, &cbf, &params);
            assert!(!out.infeasible);
            let a1_bar = gamma_f(gamma, clf.a);
            assert_eq!(out.a1_bar, a1_bar);
            let expected = brute_force_qp(a1_bar, &clf.b, cbf.a, &cbf.b, m);
            let got = DVector::from_iterator(2 * r, out.input.iter().chain(out.relaxation.iter()).copied());
            let scale = 1.0 + expected.amax();
            assert!(
                (&got - &expected).amax() < 1e-7 * scale,
                "trial {trial}, case {}: closed form {got} vs brute force {expected}",
                out.case
            );
            // F1, F2 of (3.27) hold.
            assert!(a1_bar + clf.b.dot(&(&out.input + &out.relaxation)) <= 1e-9 * scale);
            assert!(cbf.value(&out.input) <= 1e-9 * scale);
            *seen.entry(out.case).or_default() += 1;
        }
        println!("QP-LB cases over 4000 random instances: {seen:?}");
        for case in [QpCase::A, QpCase::B, QpCase::C, QpCase::D] {
            assert!(
                seen.get(&case).copied().unwrap_or(0) > 100,
                "case {case} rarely reached: {seen:?}"
            );
        }
    }

    #[test]
    fn hand_picked_instances_land_in_each_case() {
        let params = GammaM::new(8.0, 2.25).unwrap();
        let b = [1.0, 0.0];
        let orthogonal = [0.0, 1.0];
        // A: both satisfied at v = 0.
        let out = gamma_m_qp(&constraint(-1.0, &b), &constraint(-1.0, &orthogonal), &params);
        assert_eq!((out.case, out.input.clone()), (QpCase::A, DVector::zeros(2)));
        // B (3.30): ā1 = 2.25, v = −(8/9)·2.25 b1ᵀ = (−2, 0).
        let out = gamma_m_qp(&constraint(1.0, &b), &constraint(-1.0, &orthogonal), &params);
        assert_eq!(out.case, QpCase::B);
        assert!((out.input.clone() - vector(&[-2.0, 0.0])).amax() < 1e-12);
        // C (3.31): v = −a2 b2ᵀ/‖b2‖² = (0, −3).
        let out = gamma_m_qp(&constraint(-1.0, &b), &constraint(3.0, &orthogonal), &params);
        assert_eq!(out.case, QpCase::C);
        assert!((out.input.clone() - vector(&[0.0, -3.0])).amax() < 1e-12);
        // D (3.32) with orthogonal rows: the two corrections add, (−2, −3).
        let out = gamma_m_qp(&constraint(1.0, &b), &constraint(3.0, &orthogonal), &params);
        assert_eq!(out.case, QpCase::D);
        assert!((out.input.clone() - vector(&[-2.0, -3.0])).amax() < 1e-12);
        assert_eq!(QpCase::D.to_string(), "D (CLF and CBF active)");
    }

    #[test]
    fn degenerate_rows_drop_the_constraint_and_flag_infeasibility() {
        let params = GammaM::new(8.0, 2.25).unwrap();
        // x = 0 for the CLF: b1 = 0, a1 = 0 is satisfied; the CBF alone acts (Case C).
        let out = gamma_m_qp(&constraint(0.0, &[0.0, 0.0]), &constraint(2.0, &[0.0, 1.0]), &params);
        assert_eq!(out.case, QpCase::C);
        assert!(!out.infeasible);
        assert!((out.input.clone() - vector(&[0.0, -2.0])).amax() < 1e-12);
        // x = c for the CBF: b2 = 0 with a2 > 0 cannot be met.
        let out = gamma_m_qp(&constraint(-1.0, &[1.0, 0.0]), &constraint(2.0, &[0.0, 0.0]), &params);
        assert!(out.infeasible);
        assert_eq!(out.case, QpCase::A);
    }

    #[test]
    fn with_gamma_m_over_m_plus_one_equal_to_one_the_qp_is_the_pmn_clf_law() {
        // Theorem 3.3, item 3: F2 inactive and γm/(m+1) = 1 give κ_LB = κ_pmn(a1, b1) (3.7).
        let example = table_3_1();
        let params = GammaM::matching_pmn(example.m).unwrap();
        assert!((params.gamma() * params.m() / (params.m() + 1.0) - 1.0).abs() < 1e-15);
        let mut noise = Noise(3);
        let mut compared = 0;
        for _ in 0..500 {
            let clf = AffineConstraint {
                a: 2.0 * noise.next(),
                b: DVector::from_fn(2, |_, _| noise.next()),
            };
            let cbf = constraint(-100.0, &[noise.next(), noise.next()]);
            let lb = gamma_m_qp(&clf, &cbf, &params);
            assert!(matches!(lb.case, QpCase::A | QpCase::B));
            assert!((lb.input - pmn(&clf).input).amax() < 1e-12);
            compared += 1;
        }
        assert_eq!(compared, 500);
    }

    #[test]
    fn delay_integral_matches_closed_forms() {
        // Scalar: ∫₀^τ e^{aθ} dθ = (e^{aτ} − 1)/a.
        let v = delay_integral(&DMatrix::from_element(1, 1, -1.5), 0.8);
        assert!((v[(0, 0)] - ((-1.5f64 * 0.8).exp() - 1.0) / -1.5).abs() < 1e-13);
        // A = 0: τ I.
        let v = delay_integral(&DMatrix::zeros(2, 2), 0.8);
        assert!((v - DMatrix::identity(2, 2) * 0.8).amax() < 1e-15);
    }

    /// |(e^{λτ} − 1)/λ| (|1 + λ/l0| + 1/l0) ω̄ 2ρ for A ≅ λ = −1 + 0.5i (a scaled rotation, so
    /// every matrix in (3.25) is a complex number and the norms are moduli).
    fn buffer_bound_by_complex_arithmetic(tau: f64, l0: f64, omega_bar: f64, radius: f64) -> f64 {
        let (re, im) = (-1.0f64, -0.5f64);
        let growth = (re * tau).exp();
        let (e_re, e_im) = (growth * (im * tau).cos() - 1.0, growth * (im * tau).sin());
        let v = (e_re * e_re + e_im * e_im).sqrt() / (re * re + im * im).sqrt();
        let shaped = ((1.0 + re / l0).powi(2) + (im / l0).powi(2)).sqrt();
        2.0 * radius * (v * shaped + 1.0 / l0) * omega_bar
    }

    #[test]
    fn robust_buffer_of_table_3_1_is_8_06() {
        let example = table_3_1();
        let bound = example.robust_buffer_bound().unwrap();
        let independent = buffer_bound_by_complex_arithmetic(0.8, example.l0, example.omega_bar, example.radius);
        println!(
            "η bound (3.25) for Table 3.1: {bound:.6} (complex-arithmetic check {independent:.6}); Table 3.1 η = {}",
            example.eta
        );
        assert!((bound - independent).abs() < 1e-12);
        // The text: "(3.25) lead[s] to η ≥ 8.06".
        assert!((bound - 8.06).abs() < 0.005, "η bound {bound}");
        assert_eq!((bound * 100.0).ceil() / 100.0, 8.06);
        let design = example.stabilizer().unwrap();
        assert_eq!(design.check_buffer(&example.b_omega, example.omega_bar), Ok(bound));
        // A larger disturbance bound needs a larger η.
        assert!(matches!(
            design.check_buffer(&example.b_omega, 1.1),
            Err(LinearDelaysError::BufferBelowBound { .. })
        ));
    }

    #[test]
    fn bad_parameters_are_rejected_with_clear_errors() {
        assert_eq!(GammaM::new(0.5, 2.0), Err(LinearDelaysError::WeightBelowOne { m: 0.5 }));
        assert_eq!(
            GammaM::new(8.0, 0.9),
            Err(LinearDelaysError::GammaBelowOne { gamma: 0.9 })
        );
        assert!(GammaM::new(f64::NAN, 2.0).is_err());
        let err = validate_delays(&[0.8, 0.2], 2).unwrap_err();
        assert_eq!(
            err,
            LinearDelaysError::DelaysNotNondecreasing {
                channel: 2,
                delay: 0.2,
                previous_channel: 1,
                previous: 0.8
            }
        );
        println!("{err}");
        assert!(err.to_string().contains("τ_2 = 0.2 < τ_1 = 0.8"));
        assert_eq!(
            validate_delays(&[-0.1, 0.2], 2),
            Err(LinearDelaysError::NegativeDelay {
                channel: 1,
                delay: -0.1
            })
        );
        assert_eq!(
            validate_delays(&[0.1], 2),
            Err(LinearDelaysError::DelayCountMismatch { count: 1, channels: 2 })
        );
        assert!(validate_delays(&[0.2, 0.2, 0.8], 3).is_ok());

        let example = table_3_1();
        let mut bad = example.clone();
        bad.delays = vec![0.8, 0.2];
        assert!(matches!(
            bad.stabilizer(),
            Err(LinearDelaysError::DelaysNotNondecreasing { .. })
        ));
        bad = example.clone();
        bad.m = 0.0;
        assert!(matches!(
            bad.stabilizer(),
            Err(LinearDelaysError::WeightBelowOne { .. })
        ));
        bad = example.clone();
        bad.centre_offset = 4.0;
        assert!(matches!(
            bad.stabilizer(),
            Err(LinearDelaysError::OriginNotAdmissible { .. })
        ));
        bad = example.clone();
        bad.p = -0.4;
        assert_eq!(
            bad.stabilizer(),
            Err(LinearDelaysError::NotPositiveDefinite { which: "P" })
        );
        assert!(QuadraticClf::new(
            DMatrix::from_row_slice(2, 2, &[1.0, 0.5, 0.0, 1.0]),
            DMatrix::identity(2, 2)
        )
        .is_err());
        assert!(matches!(
            LinearSystem::new(DMatrix::zeros(2, 3), DMatrix::identity(2, 2)),
            Err(LinearDelaysError::DimensionMismatch { what: "A", .. })
        ));
        let design = example.stabilizer().unwrap();
        assert_eq!(
            design.lb_inputs(std::slice::from_ref(&example.initial_state)),
            Err(LinearDelaysError::PredictionCountMismatch { count: 1, channels: 2 })
        );
        let err = ConstrainedStabilizer::new(
            example.system().unwrap(),
            example.delays.clone(),
            example.clf().unwrap(),
            example.barrier().unwrap(),
            example.l0,
            -1.0,
            GammaM::new(8.0, 2.25).unwrap(),
        )
        .unwrap_err();
        assert_eq!(err, LinearDelaysError::NegativeBuffer { eta: -1.0 });
    }

    #[test]
    fn example_constraints_follow_3_41_to_3_46() {
        let example = table_3_1();
        let design = example.stabilizer().unwrap();
        let x = vector(&[3.0, -2.0]);
        let c = vector(&[6.0, 0.0]);
        let a = &example.a;
        let h = (&x - &c).norm_squared() - 25.0;
        assert_eq!(design.h(&x), h);
        let cbf = design.cbf_constraint(&x);
        let expected_a2 = -2.0 * (&x - &c).dot(&(a * &x)) - 2.0 * (h - 8.06);
        assert!((cbf.a - expected_a2).abs() < 1e-12);
        assert!((cbf.b.clone() + (&x - &c) * 2.0).amax() < 1e-12);
        let clf = design.clf_constraint(&x);
        // AᵀP + PA = p(A + Aᵀ) = −2p I: a1 = (q − 2p)‖x‖² (3.43)–(3.45 before γ_f).
        assert!((clf.a - (example.q - 2.0 * example.p) * x.norm_squared()).abs() < 1e-12);
        assert!((clf.b.clone() - &x * (2.0 * example.p)).amax() < 1e-12);
    }

    /// The closed loop (3.34), (3.33) at control step Δt: RK4 plant with a zero-order hold per
    /// step, per-channel issued-input buffers, and the recursive predictors (3.3) for the linear
    /// case integrated with the same RK4 and hold (channels j < i in the window of p_i take
    /// κ_LB,j at the predicted state). The predictors do not know the disturbance.
    struct ClosedLoop {
        min_h: f64,
        min_h_time: f64,
        min_buffered_h: f64,
        min_buffered_h_time: f64,
        final_norm: f64,
        /// max ‖x‖ over the last 5 s.
        tail_norm: f64,
        cases: HashMap<QpCase, usize>,
        /// max ‖p_i(t_k) − x(t_k + τ_i)‖ over channels and ticks.
        prediction_error: f64,
        infeasible: usize,
    }

    fn rk4_step(
        system: &LinearSystem,
        b_omega: &DMatrix<f64>,
        x: &DVector<f64>,
        u: &DVector<f64>,
        t: f64,
        dt: f64,
        disturbance: &dyn Fn(f64) -> DVector<f64>,
    ) -> DVector<f64> {
        let f = |s: f64, y: &DVector<f64>| system.a() * y + system.b() * u + b_omega * disturbance(s);
        let k1 = f(t, x);
        let k2 = f(t + dt / 2.0, &(x + &k1 * (dt / 2.0)));
        let k3 = f(t + dt / 2.0, &(x + &k2 * (dt / 2.0)));
        let k4 = f(t + dt, &(x + &k3 * dt));
        x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (dt / 6.0)
    }

    fn no_disturbance(_: f64) -> DVector<f64> {
        DVector::zeros(2)
    }

    /// Which per-channel law the closed loop runs.
    #[derive(Clone, Copy, PartialEq)]
    enum Law {
        /// PMN CLF (3.11).
        Clf,
        /// PMN CBF (3.19).
        Cbf,
        /// γm CLF-CBF QP (3.33).
        Qp,
    }

    fn simulate(
        example: &Example35,
        law_kind: Law,
        disturbance: &dyn Fn(f64) -> DVector<f64>,
        duration: f64,
    ) -> ClosedLoop {
        let design = example.stabilizer().unwrap();
        let system = design.system();
        let r = system.input_count();
        let dt = example.timestep;
        let delay_steps: Vec<usize> = design
            .delays()
            .iter()
            .map(|d| {
                let steps = d / dt;
                assert!((steps - steps.round()).abs() < 1e-9, "delay {d} off the Δt grid");
                steps.round() as usize
            })
            .collect();
        let steps = (duration / dt).round() as usize;
        // issued[j][k]: command of channel j issued at tick k; zero before t = 0 ((3.47)/(3.48)).
        let mut issued: Vec<Vec<f64>> = vec![Vec::with_capacity(steps); r];
        let issued_at = |issued: &Vec<Vec<f64>>, j: usize, tick: isize| -> f64 {
            if tick < 0 {
                0.0
            } else {
                issued[j][tick as usize]
            }
        };
        let mut states = vec![example.initial_state.clone()];
        let mut predictions: Vec<Vec<DVector<f64>>> = Vec::with_capacity(steps);
        let mut run = ClosedLoop {
            min_h: design.h(&example.initial_state),
            min_h_time: 0.0,
            min_buffered_h: design.buffered_h(&example.initial_state),
            min_buffered_h_time: 0.0,
            final_norm: 0.0,
            tail_norm: 0.0,
            cases: HashMap::new(),
            prediction_error: 0.0,
            infeasible: 0,
        };
        let law = |x: &DVector<f64>| match law_kind {
            Law::Clf => design.clf_pmn(x).input,
            Law::Cbf => design.cbf_pmn(x).input,
            Law::Qp => design.kappa_lb(x).input,
        };
        for k in 0..steps {
            let x = states[k].clone();
            // Recursive predictors (3.3): p_i from p_{i−1} over arrivals [k + d_{i−1}, k + d_i).
            let mut p = x.clone();
            let mut reached = 0;
            let mut channel_predictions = Vec::with_capacity(r);
            for i in 0..r {
                for s in (k + reached)..(k + delay_steps[i]) {
                    let at_step_start = if i > 0 { Some(law(&p)) } else { None };
                    let u = DVector::from_fn(r, |j, _| {
                        if j < i {
                            at_step_start.as_ref().unwrap()[j]
                        } else {
                            issued_at(&issued, j, s as isize - delay_steps[j] as isize)
                        }
                    });
                    p = rk4_step(system, &example.b_omega, &p, &u, s as f64 * dt, dt, &no_disturbance);
                }
                reached = delay_steps[i];
                channel_predictions.push(p.clone());
            }
            match law_kind {
                Law::Clf | Law::Cbf => {
                    let inputs = if law_kind == Law::Clf {
                        design.clf_inputs(&channel_predictions)
                    } else {
                        design.cbf_inputs(&channel_predictions)
                    };
                    for (j, input) in inputs.unwrap().into_iter().enumerate() {
                        issued[j].push(input);
                    }
                }
                Law::Qp => {
                    for (j, decision) in design.lb_inputs(&channel_predictions).unwrap().iter().enumerate() {
                        issued[j].push(decision.input);
                        *run.cases.entry(decision.case).or_default() += 1;
                        run.infeasible += usize::from(decision.infeasible);
                    }
                }
            }
            predictions.push(channel_predictions);
            let applied = DVector::from_fn(r, |j, _| issued_at(&issued, j, k as isize - delay_steps[j] as isize));
            let next = rk4_step(system, &example.b_omega, &x, &applied, k as f64 * dt, dt, disturbance);
            let t = (k + 1) as f64 * dt;
            let (h, buffered) = (design.h(&next), design.buffered_h(&next));
            if h < run.min_h {
                (run.min_h, run.min_h_time) = (h, t);
            }
            if buffered < run.min_buffered_h {
                (run.min_buffered_h, run.min_buffered_h_time) = (buffered, t);
            }
            if t > duration - 5.0 {
                run.tail_norm = run.tail_norm.max(next.norm());
            }
            states.push(next);
        }
        run.final_norm = states[steps].norm();
        for (k, channel_predictions) in predictions.iter().enumerate() {
            for (i, p) in channel_predictions.iter().enumerate() {
                if let Some(x) = states.get(k + delay_steps[i]) {
                    run.prediction_error = run.prediction_error.max((p - x).norm());
                }
            }
        }
        run
    }

    /// min h along the uncontrolled drift from x(0): the disk is in the way.
    fn drift_min_h(example: &Example35) -> f64 {
        let design = example.stabilizer().unwrap();
        let mut x = example.initial_state.clone();
        let mut min_h = design.h(&x);
        for k in 0..2000 {
            x = rk4_step(
                design.system(),
                &example.b_omega,
                &x,
                &DVector::zeros(2),
                k as f64 * example.timestep,
                example.timestep,
                &no_disturbance,
            );
            min_h = min_h.min(design.h(&x));
        }
        min_h
    }

    fn report(label: &str, run: &ClosedLoop) {
        println!(
            "{label}: min h = {:.4} (t = {:.3}), min h − η = {:.4} (t = {:.3}), final ‖x‖ = {:.3e}, max ‖x‖ over last 5 s = {:.3e}, max prediction error = {:.3e}, cases (channel-ticks) = {:?}, infeasible = {}",
            run.min_h,
            run.min_h_time,
            run.min_buffered_h,
            run.min_buffered_h_time,
            run.final_norm,
            run.tail_norm,
            run.prediction_error,
            run.cases,
            run.infeasible
        );
    }

    #[test]
    fn example_3_5_without_disturbance_keeps_c_and_c_eta_and_converges() {
        let example = table_3_1();
        let drift = drift_min_h(&example);
        println!("uncontrolled drift from x(0) = (16, 6): min h = {drift:.3}");
        assert!(
            drift < 0.0,
            "the drift alone must cross the disk for the test to mean anything"
        );
        let run = simulate(&example, Law::Qp, &no_disturbance, 20.0);
        report("§3.5 without disturbance", &run);
        // The predictors are exact without disturbance ((3.3): p_i(t) = x(t + τ_i)).
        assert!(run.prediction_error < 1e-9, "prediction error {}", run.prediction_error);
        assert!(
            run.cases.get(&QpCase::C).copied().unwrap_or(0) > 0,
            "the barrier never acted"
        );
        assert_eq!(run.infeasible, 0);
        // Fig. 3.1 top: C_η and C are kept invariant, and the state reaches the origin.
        assert!(run.min_h > 0.0, "entered the disk: min h = {}", run.min_h);
        assert!(
            run.min_buffered_h >= -1e-6,
            "left C_η: min h − η = {}",
            run.min_buffered_h
        );
        assert!(run.final_norm < 1e-4, "final ‖x‖ = {}", run.final_norm);
    }

    #[test]
    fn example_3_5_with_disturbance_3_49_keeps_c_and_reaches_a_neighbourhood_of_the_origin() {
        let example = table_3_1();
        // ‖ω(t)‖ ≤ ω̄ = 1.
        for k in 0..10_000 {
            assert!(disturbance_3_49(k as f64 * 1e-3).norm() <= example.omega_bar + 1e-15);
        }
        assert_eq!(disturbance_3_49(0.0), DVector::zeros(2));
        let run = simulate(&example, Law::Qp, &disturbance_3_49, 20.0);
        report("§3.5 with disturbance (3.49)/(3.50)", &run);
        assert!(
            run.prediction_error > 1e-3,
            "the disturbance should spoil the predictions"
        );
        assert_eq!(run.infeasible, 0);
        // Fig. 3.1 bottom: C is never left.
        assert!(run.min_h > 0.0, "entered the disk: min h = {}", run.min_h);
        // "… even though the buffer is violated": the unknown disturbance spoils the
        // predictions, so C_η is left; η (3.25) absorbs it.
        assert!(
            run.min_buffered_h < 0.0,
            "C_η was never left: min h − η = {}",
            run.min_buffered_h
        );
        // ω does not vanish, so x converges to a neighbourhood of the origin: near 0 the barrier
        // is inactive (h(0) − η > 0) and so is the CLF (a1 < 0 everywhere), so ẋ = A x + ω with
        // A + Aᵀ = −2I gives d‖x‖/dt ≤ −‖x‖ + ω̄: limsup ‖x‖ ≤ ω̄.
        assert!(
            run.tail_norm <= example.omega_bar,
            "max ‖x‖ over the last 5 s = {}",
            run.tail_norm
        );
    }

    #[test]
    fn example_3_5_pmn_laws_alone_clf_crosses_the_disk_cbf_keeps_c() {
        let example = table_3_1();
        // (3.11): a1 = (q − 2p)‖x‖² < 0 everywhere, so the PMN CLF law never acts and the
        // drift carries the state through the disk.
        let clf = simulate(&example, Law::Clf, &no_disturbance, 20.0);
        report("§3.5, PMN CLF (3.11) alone", &clf);
        assert!(clf.min_h < 0.0, "min h = {}", clf.min_h);
        // (3.19): the PMN CBF law keeps C (and C_η) without disturbance.
        let cbf = simulate(&example, Law::Cbf, &no_disturbance, 20.0);
        report("§3.5, PMN CBF (3.19) alone", &cbf);
        assert!(cbf.prediction_error < 1e-9, "prediction error {}", cbf.prediction_error);
        assert!(cbf.min_h > 0.0, "entered the disk: min h = {}", cbf.min_h);
        assert!(
            cbf.min_buffered_h >= -1e-6,
            "left C_η: min h − η = {}",
            cbf.min_buffered_h
        );
        assert!(cbf.final_norm < 1e-4, "final ‖x‖ = {}", cbf.final_norm);
    }
}
