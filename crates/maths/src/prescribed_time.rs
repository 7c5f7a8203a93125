//! Prescribed-time safety (PTSf) and exponential safety (ESf) filters of Chapter 5: pure
//! maths on `f64`/`nalgebra` values, no plant and no I/O.
//!
//! Safe set: the output y = x1 must stay negative on [t0, t0 + T) (Theorem 5.1); the barrier
//! functions h_i are kept positive, starting from h1 = −x1 (5.7)/(5.24).
//!
//! The PTSf chain (5.24)–(5.26) is built for any order n by exact recursion. Because the chain
//! (5.23) is linear, every h_i and α_i is a linear form in x whose coefficients depend on t only
//! through the gain profile μ2. Each coefficient is carried as a *jet* (its value and time
//! derivatives at the evaluation time), derived from the jet of μ2 given by (5.5), so
//! d/dt α_{i−1} in (5.26) is computed exactly by the Leibniz rule, never by hand expansion.
//! Clipping μ2 (§5.4) continues it, from the clip on, by its Taylor polynomial of degree
//! n − 2 ([`BlowUp::mu2_jet`]): for n = 2 that is the dissertation's hard clip, and for any n
//! the barriers stay continuous and (5.30)/(5.31) hold with the clipped profile.

use nalgebra::{DVector, Matrix2, RowDVector, Vector2};

/// The clip μ2,max = 1000 used in the dissertation's simulations (§5.4).
pub const DISSERTATION_MU2_CLIP: f64 = 1000.0;

/// What can be wrong with a prescribed-time / exponential safety design or query.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PrescribedTimeError {
    #[error("terminal time T = {terminal_time} must be finite and > 0 (5.2)")]
    NonPositiveTerminalTime { terminal_time: f64 },
    #[error("initial time t0 = {initial_time} must be finite")]
    NonFiniteInitialTime { initial_time: f64 },
    #[error("clip of μ2 is {clip}: it must be > 1, since μ2(t0) = 1 and (5.34) relies on it")]
    ClipNotAboveOne { clip: f64 },
    #[error("unsafe start: y(t0) = x1(t0) = {output}, but the safe set needs y < 0 (Theorem 5.1)")]
    UnsafeStart { output: f64 },
    #[error("state has dimension {actual}, expected {expected}")]
    DimensionMismatch { expected: usize, actual: usize },
    #[error("the chain of integrators needs order n >= 1")]
    ZeroOrder,
    #[error("initial state has a non-finite component: {state:?}")]
    NonFiniteState { state: Vec<f64> },
    #[error("gain margin is {margin}: it must be finite and > 0, since (5.32)/(5.33) are strict")]
    NonPositiveMargin { margin: f64 },
    #[error("ESf decay rate ρ = {rate} must be finite and > 0 (5.16)")]
    NonPositiveRate { rate: f64 },
    #[error("ramp exponent m = {exponent} must be >= 1 (5.28)")]
    RampExponentZero { exponent: u32 },
    #[error("ramp duration T̄ = {duration} must be finite and > 0 (5.28)")]
    NonPositiveRampDuration { duration: f64 },
    #[error("ramp tolerance {tolerance} for \"x1(t0 + T) = 0\" must be finite and >= 0")]
    NegativeRampTolerance { tolerance: f64 },
    #[error("gains {gains:?} from (5.32)–(5.34) are so large that h(t0) = {barriers:?} is not positive in floating point; start farther from the barrier or use a larger margin")]
    IllConditionedGains { gains: Vec<f64>, barriers: Vec<f64> },
    #[error("time t = {time} is before the initial time t0 = {initial_time}")]
    BeforeInitialTime { time: f64, initial_time: f64 },
    #[error("time t = {time} is not before t0 + T = {end_time}: the safe control α_n (5.26) is only defined on [t0, t0 + T)")]
    OutsideHorizon { time: f64, end_time: f64 },
    #[error("time t = {time} is past t0 + T = {end_time}: the ramp (5.28) needs x1(t0 + T), which was not given")]
    MissingTerminalOutput { time: f64, end_time: f64 },
}

type Result<T> = std::result::Result<T, PrescribedTimeError>;

/// Rising factorial m^(k̄) = m (m + 1) ⋯ (m + k − 1) (5.4); 1 for k = 0.
pub fn rising_factorial(m: u32, k: u32) -> f64 {
    (0..k).map(|j| f64::from(m + j)).product()
}

/// The blow-up functions μ_m(t − t0, T) (5.2)/(5.3) of one horizon [t0, t0 + T), with an
/// optional clip of the gain profile μ2 (§5.4: μ2,max = 1000).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlowUp {
    initial_time: f64,
    terminal_time: f64,
    mu2_clip: f64,
}

impl BlowUp {
    /// Unclipped blow-up functions on [t0, t0 + T); T is the prescribed terminal time.
    pub fn new(initial_time: f64, terminal_time: f64) -> Result<Self> {
        if !initial_time.is_finite() {
            return Err(PrescribedTimeError::NonFiniteInitialTime { initial_time });
        }
        if !(terminal_time > 0.0 && terminal_time.is_finite()) {
            return Err(PrescribedTimeError::NonPositiveTerminalTime { terminal_time });
        }
        Ok(Self {
            initial_time,
            terminal_time,
            mu2_clip: f64::INFINITY,
        })
    }

    /// The same horizon with the gain profile μ2 clipped at `clip` (> 1; ∞ means no clip).
    pub fn with_mu2_clip(self, clip: f64) -> Result<Self> {
        if clip.is_nan() || clip <= 1.0 {
            return Err(PrescribedTimeError::ClipNotAboveOne { clip });
        }
        Ok(Self { mu2_clip: clip, ..self })
    }

    /// t0.
    pub fn initial_time(&self) -> f64 {
        self.initial_time
    }

    /// T (a duration, measured from t0).
    pub fn terminal_time(&self) -> f64 {
        self.terminal_time
    }

    /// t0 + T, where μ_m blows up.
    pub fn end_time(&self) -> f64 {
        self.initial_time + self.terminal_time
    }

    /// The clip of μ2 (∞ when unclipped).
    pub fn mu2_clip(&self) -> f64 {
        self.mu2_clip
    }

    /// v(t − t0, T) = (T + t0 − t)/T (5.3): 1 at t0, 0 at t0 + T.
    pub fn decay(&self, time: f64) -> f64 {
        (self.end_time() - time) / self.terminal_time
    }

    /// μ_m(t − t0, T) = 1/v^m (5.2). The formula is used as is before t0; from t0 + T on the
    /// function has blown up and +∞ is returned.
    pub fn mu(&self, m: u32, time: f64) -> f64 {
        let v = self.decay(time);
        if v <= 0.0 {
            return if m == 0 { 1.0 } else { f64::INFINITY };
        }
        v.powi(-(m as i32))
    }

    /// i-th time derivative of μ_m: (m^(ī)/T^i) μ_{m+i} (5.5).
    pub fn mu_derivative(&self, m: u32, order: u32, time: f64) -> f64 {
        let coefficient = rising_factorial(m, order) / self.terminal_time.powi(order as i32);
        if coefficient == 0.0 {
            return 0.0;
        }
        coefficient * self.mu(m + order, time)
    }

    /// First time at which the unclipped μ2 reaches the clip: t0 + T (1 − clip^(−1/2)).
    pub fn clip_time(&self) -> f64 {
        self.initial_time + self.terminal_time * (1.0 - self.mu2_clip.sqrt().recip())
    }

    /// Jet of the gain profile μ̄2 used by the filters: its value and first `length − 1` time
    /// derivatives at `time`. Before the clip time this is μ2 with (5.5). From the clip time t_c
    /// on, μ̄2 is μ2's Taylor polynomial of degree d = max{length, 2} − 2 at t_c, so derivatives
    /// up to order d stay continuous and higher ones are zero. For the PTSf chain of order n
    /// (length = n), h_1 … h_n involve derivatives up to order n − 2 only and stay continuous,
    /// which keeps (5.30)/(5.31) and safety across the clip; only α_n jumps. For n = 2 (d = 0)
    /// this is the dissertation's hard clip min{μ2, clip} (§5.4). A hard clip for n ≥ 3 would
    /// make h_3 … h_n jump (h_3 contains −c1 μ2′ x1) and can lose safety. On [t0, t0 + T) the
    /// continuation stays below clip · (d + 1)(d + 2)/2.
    pub fn mu2_jet(&self, time: f64, length: usize) -> Result<Vec<f64>> {
        let mut jet = vec![0.0; length];
        self.mu2_jet_into(time, &mut jet)?;
        Ok(jet)
    }

    /// [`BlowUp::mu2_jet`] into `jet` (length = `jet.len()`), without allocation.
    pub fn mu2_jet_into(&self, time: f64, jet: &mut [f64]) -> Result<()> {
        let length = jet.len();
        if time < self.initial_time {
            return Err(PrescribedTimeError::BeforeInitialTime {
                time,
                initial_time: self.initial_time,
            });
        }
        let clip_time = self.clip_time();
        if self.mu2_clip.is_finite() && time >= clip_time {
            let degree = length.max(2) - 2;
            let elapsed = time - clip_time;
            // d^j/dt^j Σ_k μ2^(k)(t_c) s^k / k! = Σ_{k ≥ j} μ2^(k)(t_c) s^(k−j) / (k − j)!.
            for (order, value) in jet.iter_mut().enumerate() {
                let mut power_over_factorial = 1.0;
                let mut sum = 0.0;
                for k in order..=degree {
                    sum += self.mu_derivative(2, k as u32, clip_time) * power_over_factorial;
                    power_over_factorial *= elapsed / (k - order + 1) as f64;
                }
                *value = sum;
            }
            return Ok(());
        }
        if time >= self.end_time() {
            return Err(PrescribedTimeError::OutsideHorizon {
                time,
                end_time: self.end_time(),
            });
        }
        for (order, value) in jet.iter_mut().enumerate() {
            *value = self.mu_derivative(2, order as u32, time);
        }
        Ok(())
    }
}

/// Continuity ramp g (5.28) applied to the nominal control after t0 + T.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContinuityRamp {
    exponent: u32,
    duration: f64,
    barrier_tolerance: f64,
}

impl ContinuityRamp {
    /// Ramp 1 − v^m(t − t0 − T, T̄) (5.28). (5.28) engages it only when x1(t0 + T) = 0 exactly;
    /// in floating point it is engaged when |x1(t0 + T)| ≤ `barrier_tolerance`.
    pub fn new(exponent: u32, duration: f64, barrier_tolerance: f64) -> Result<Self> {
        if exponent == 0 {
            return Err(PrescribedTimeError::RampExponentZero { exponent });
        }
        if !(duration > 0.0 && duration.is_finite()) {
            return Err(PrescribedTimeError::NonPositiveRampDuration { duration });
        }
        if !(barrier_tolerance >= 0.0 && barrier_tolerance.is_finite()) {
            return Err(PrescribedTimeError::NegativeRampTolerance {
                tolerance: barrier_tolerance,
            });
        }
        Ok(Self {
            exponent,
            duration,
            barrier_tolerance,
        })
    }

    /// m.
    pub fn exponent(&self) -> u32 {
        self.exponent
    }

    /// T̄.
    pub fn duration(&self) -> f64 {
        self.duration
    }

    /// g (5.28) at `time_after_end` = t − t0 − T ≥ 0, given y(t0 + T) = x1(t0 + T).
    pub fn gain(&self, time_after_end: f64, output_at_end: f64) -> f64 {
        let at_barrier = output_at_end.abs() <= self.barrier_tolerance;
        if at_barrier && (0.0..=self.duration).contains(&time_after_end) {
            let v = (self.duration - time_after_end) / self.duration;
            1.0 - v.powi(self.exponent as i32)
        } else {
            1.0
        }
    }
}

/// Jet of a product by the Leibniz rule, truncated to `out.len()`.
fn jet_product_into(a: &[f64], b: &[f64], out: &mut [f64]) {
    for (k, value) in out.iter_mut().enumerate() {
        let mut binomial = 1.0;
        let mut sum = 0.0;
        for j in 0..=k {
            sum += binomial * a[j] * b[k - j];
            binomial *= (k - j) as f64 / (j + 1) as f64;
        }
        *value = sum;
    }
}

/// a·x summed in order from 0 (as nalgebra's `dot` sums a row by a row).
fn dot(a: &[f64], x: &[f64]) -> f64 {
    a.iter().zip(x).fold(0.0, |sum, (a, x)| sum + a * x)
}

/// The linear forms of the PTSf chain at one time (values, the order-0 coefficients), with the
/// scratch space that builds them: sized for an order n once, then rebuilt without allocation.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainForms {
    order: usize,
    /// How many of h_i (and d/dt α_{i−1}) and α_i the last build produced.
    barriers: usize,
    alphas: usize,
    /// h_i(x, t) = barrier_rows[i − 1] · x (5.24) (row-major, n × n).
    barrier_rows: Vec<f64>,
    /// α_i(x, t) = alpha_rows[i − 1] · x (5.26), for the gains given.
    alpha_rows: Vec<f64>,
    /// d/dt α_{i−1} along (5.23) = alpha_rate_rows[i − 1] · x.
    alpha_rate_rows: Vec<f64>,
    /// μ̄2's jet, and the jets of the coefficients (coefficient j of a form holds the jet of the
    /// factor of x_{j+1}; α_{i−1}: n × (n + 1), the others n × n).
    mu2_jet: Vec<f64>,
    alpha_previous: Vec<f64>,
    rate: Vec<f64>,
    barrier: Vec<f64>,
    product: Vec<f64>,
}

impl ChainForms {
    /// Scratch space for a chain of order n.
    pub fn new(order: usize) -> ChainForms {
        ChainForms {
            order,
            barriers: 0,
            alphas: 0,
            barrier_rows: vec![0.0; order * order],
            alpha_rows: vec![0.0; order * order],
            alpha_rate_rows: vec![0.0; order * order],
            mu2_jet: vec![0.0; order],
            alpha_previous: vec![0.0; order * (order + 1)],
            rate: vec![0.0; order * order],
            barrier: vec![0.0; order * order],
            product: vec![0.0; order],
        }
    }

    /// h_i (5.24) as a row, i = 1 … (built count).
    fn barrier_row(&self, i: usize) -> &[f64] {
        &self.barrier_rows[(i - 1) * self.order..i * self.order]
    }

    fn alpha_row(&self, i: usize) -> &[f64] {
        &self.alpha_rows[(i - 1) * self.order..i * self.order]
    }

    fn alpha_rate_row(&self, i: usize) -> &[f64] {
        &self.alpha_rate_rows[(i - 1) * self.order..i * self.order]
    }

    /// The chain (5.24)–(5.26) with the first `gains.len()` gains from μ̄2's jet in
    /// `self.mu2_jet` (μ̄2 and its first n − 1 derivatives): h_1 … h_{k+1} and α_1 … α_k
    /// (k = gains.len() ≤ n; h_{n+1} does not exist).
    fn build(&mut self, gains: &[f64]) {
        let order = self.order;
        let stride = order + 1;
        // α_0 ≡ 0 (5.25).
        self.alpha_previous.fill(0.0);
        self.barriers = 0;
        self.alphas = 0;
        for i in 1..=(gains.len() + 1).min(order) {
            // α_i is differentiated n − i more times on the way to α_n.
            let length = order - i + 1;
            // d/dt Σ a_j x_j = Σ (ȧ_j x_j + a_j x_{j+1}) along (5.23); α_{i−1} has no x_n term.
            for j in 0..order {
                for k in 0..length {
                    let shifted = if j > 0 {
                        self.alpha_previous[(j - 1) * stride + k]
                    } else {
                        0.0
                    };
                    self.rate[j * order + k] = self.alpha_previous[j * stride + k + 1] + shifted;
                }
            }
            // h_i = −x_i + α_{i−1} (5.24).
            for j in 0..order {
                self.barrier[j * order..j * order + length]
                    .copy_from_slice(&self.alpha_previous[j * stride..j * stride + length]);
                if j == i - 1 {
                    self.barrier[j * order] -= 1.0;
                }
            }
            for j in 0..order {
                self.barrier_rows[(i - 1) * order + j] = self.barrier[j * order];
                self.alpha_rate_rows[(i - 1) * order + j] = self.rate[j * order];
            }
            self.barriers = i;
            if let Some(&gain) = gains.get(i - 1) {
                // α_i = c_i μ2 h_i + d/dt α_{i−1} (5.26).
                for j in 0..order {
                    jet_product_into(
                        &self.mu2_jet,
                        &self.barrier[j * order..j * order + length],
                        &mut self.product[..length],
                    );
                    for k in 0..length {
                        self.alpha_previous[j * stride + k] = gain * self.product[k] + self.rate[j * order + k];
                    }
                    self.alpha_rows[(i - 1) * order + j] = self.alpha_previous[j * stride];
                }
                self.alphas = i;
            }
        }
    }
}

/// The chain for `order` n from μ̄2's jet and the first `gains.len()` gains (allocates its
/// scratch space; the filter keeps one [`ChainForms`]).
fn build_chain(mu2_jet: &[f64], gains: &[f64], order: usize) -> ChainForms {
    let mut chain = ChainForms::new(order);
    chain.mu2_jet.copy_from_slice(mu2_jet);
    chain.build(gains);
    chain
}

fn check_dimension(expected: usize, state: &DVector<f64>) -> Result<()> {
    if state.len() != expected {
        return Err(PrescribedTimeError::DimensionMismatch {
            expected,
            actual: state.len(),
        });
    }
    Ok(())
}

/// Initial gains c_1 … c_n from x(t0) (Theorem 5.1): for i < n, c_i = max{c_{i−1}, c̲_i} + margin
/// with c_0 = 0 and c̲_i from (5.34), which satisfies the strict (5.32); c_n = max{c_{n−1}, margin}
/// satisfies (5.33) and reproduces the dissertation's choice c_2 = c_1 in §5.4 and §5.7.
pub fn initial_gains(blow_up: &BlowUp, initial_state: &DVector<f64>, margin: f64) -> Result<Vec<f64>> {
    let order = initial_state.len();
    if order == 0 {
        return Err(PrescribedTimeError::ZeroOrder);
    }
    if initial_state.iter().any(|value| !value.is_finite()) {
        return Err(PrescribedTimeError::NonFiniteState {
            state: initial_state.iter().copied().collect(),
        });
    }
    if !(margin > 0.0 && margin.is_finite()) {
        return Err(PrescribedTimeError::NonPositiveMargin { margin });
    }
    if initial_state[0] >= 0.0 {
        return Err(PrescribedTimeError::UnsafeStart {
            output: initial_state[0],
        });
    }
    let mu2_jet = blow_up.mu2_jet(blow_up.initial_time(), order)?;
    let mut gains: Vec<f64> = Vec::with_capacity(order);
    let mut previous = 0.0_f64;
    for i in 1..order {
        let chain = build_chain(&mu2_jet, &gains, order);
        // Denominator of (5.34): α_{i−1}(t0) − x_i(t0) = h_i(t0) > 0 by induction (5.50).
        let barrier = dot(chain.barrier_row(i), initial_state.as_slice());
        let alpha_rate = dot(chain.alpha_rate_row(i), initial_state.as_slice());
        let lower_bound = (initial_state[i] - alpha_rate) / barrier; // (5.34)
        let gain = previous.max(lower_bound) + margin; // (5.32)
        gains.push(gain);
        previous = gain;
    }
    gains.push(previous.max(margin)); // (5.33)
                                      // In exact arithmetic h_{i+1}(t0) ≥ margin · h_i(t0) > 0 (5.48)–(5.50). The c̲_i of (5.34)
                                      // grow like products of the earlier gains, so from starts close to the barrier with large
                                      // higher derivatives, h_{i+1}(t0) is a difference of huge terms: check it really is positive.
    let chain = build_chain(&mu2_jet, &gains, order);
    let barriers: Vec<f64> = (1..=chain.barriers)
        .map(|i| dot(chain.barrier_row(i), initial_state.as_slice()))
        .collect();
    if barriers.iter().any(|&value| value.is_nan() || value <= 0.0) {
        return Err(PrescribedTimeError::IllConditionedGains { gains, barriers });
    }
    Ok(gains)
}

/// What a safety filter did at one evaluation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterDecision {
    /// The filtered input u.
    pub input: f64,
    /// u ≠ u_nom because the safe bound (α_n or the ESf law) was below the nominal.
    pub overriding: bool,
    /// Ramp factor g (5.28) multiplying u_nom after t0 + T; 1 otherwise.
    pub ramp: f64,
}

/// PTSf safety filter (5.24)–(5.29) for the n-th order chain of integrators (5.23).
#[derive(Debug, Clone, PartialEq)]
pub struct PtsfFilter {
    blow_up: BlowUp,
    gains: Vec<f64>,
    ramp: ContinuityRamp,
}

impl PtsfFilter {
    /// Filter for the chain of order n = x(t0).len(), gains from [`initial_gains`].
    pub fn from_initial_state(
        blow_up: BlowUp,
        initial_state: &DVector<f64>,
        margin: f64,
        ramp: ContinuityRamp,
    ) -> Result<Self> {
        let gains = initial_gains(&blow_up, initial_state, margin)?;
        Ok(Self { blow_up, gains, ramp })
    }

    /// n.
    pub fn order(&self) -> usize {
        self.gains.len()
    }

    /// c_1 … c_n.
    pub fn gains(&self) -> &[f64] {
        &self.gains
    }

    /// The horizon and gain profile.
    pub fn blow_up(&self) -> &BlowUp {
        &self.blow_up
    }

    /// The continuity ramp used after t0 + T.
    pub fn ramp(&self) -> &ContinuityRamp {
        &self.ramp
    }

    /// Scratch space for [`PtsfFilter::control_with`] (keep one per filter).
    pub fn workspace(&self) -> ChainForms {
        ChainForms::new(self.order())
    }

    /// The chain at t ∈ [t0, t0 + T) into `chain`.
    fn chain_into(&self, time: f64, chain: &mut ChainForms) -> Result<()> {
        if time >= self.blow_up.end_time() {
            return Err(PrescribedTimeError::OutsideHorizon {
                time,
                end_time: self.blow_up.end_time(),
            });
        }
        if chain.order != self.order() {
            *chain = self.workspace();
        }
        self.blow_up.mu2_jet_into(time, &mut chain.mu2_jet)?;
        chain.build(&self.gains);
        Ok(())
    }

    /// Row k(t) with α_n(x, t) = k(t) x (5.26), t ∈ [t0, t0 + T).
    pub fn safe_control_row(&self, time: f64) -> Result<RowDVector<f64>> {
        let mut chain = self.workspace();
        self.chain_into(time, &mut chain)?;
        Ok(RowDVector::from_row_slice(chain.alpha_row(self.order())))
    }

    /// α_n(x, t) (5.26): the largest input keeping d/dt h_n ≥ −c_n μ2 h_n (5.31).
    pub fn safe_control(&self, time: f64, state: &DVector<f64>) -> Result<f64> {
        self.safe_control_with(&mut self.workspace(), time, state)
    }

    /// [`PtsfFilter::safe_control`] in `chain`'s scratch space (no allocation).
    pub fn safe_control_with(&self, chain: &mut ChainForms, time: f64, state: &DVector<f64>) -> Result<f64> {
        check_dimension(self.order(), state)?;
        self.chain_into(time, chain)?;
        Ok(dot(chain.alpha_row(self.order()), state.as_slice()))
    }

    /// Barrier functions h_1 … h_n (5.24) at (t, x); all positive while the design holds.
    pub fn barriers(&self, time: f64, state: &DVector<f64>) -> Result<DVector<f64>> {
        check_dimension(self.order(), state)?;
        let mut chain = self.workspace();
        self.chain_into(time, &mut chain)?;
        Ok(DVector::from_iterator(
            self.order(),
            (1..=self.order()).map(|i| dot(chain.barrier_row(i), state.as_slice())),
        ))
    }

    /// The filter (5.27): min{u_nom, α_n} (the QP (5.29)) on [t0, t0 + T), then u_nom g (5.28).
    /// `output_at_end` = x1(t0 + T) is required from t0 + T on and ignored before.
    pub fn control(
        &self,
        time: f64,
        state: &DVector<f64>,
        nominal: f64,
        output_at_end: Option<f64>,
    ) -> Result<FilterDecision> {
        self.control_with(&mut self.workspace(), time, state, nominal, output_at_end)
    }

    /// [`PtsfFilter::control`] in `chain`'s scratch space (no allocation).
    pub fn control_with(
        &self,
        chain: &mut ChainForms,
        time: f64,
        state: &DVector<f64>,
        nominal: f64,
        output_at_end: Option<f64>,
    ) -> Result<FilterDecision> {
        check_dimension(self.order(), state)?;
        let end_time = self.blow_up.end_time();
        if time < end_time {
            let safe = self.safe_control_with(chain, time, state)?;
            let overriding = safe < nominal;
            return Ok(FilterDecision {
                input: if overriding { safe } else { nominal },
                overriding,
                ramp: 1.0,
            });
        }
        let output_at_end = output_at_end.ok_or(PrescribedTimeError::MissingTerminalOutput { time, end_time })?;
        let ramp = self.ramp.gain(time - end_time, output_at_end);
        Ok(FilterDecision {
            input: nominal * ramp,
            overriding: false,
            ramp,
        })
    }
}

/// Time-invariant ESf filter: u = min{u_nom, −k·x} with closed-loop poles −ρ, −2ρ, …, −nρ.
/// Its barrier chain is h_1 = −x1, h_{i+1} = d/dt h_i + iρ h_i ((5.15)/(5.16) for i = 1), and
/// u ≤ −k·x ⇔ d/dt h_n + nρ h_n ≥ 0. For n = 2, k = (2ρ², 3ρ): the law (5.89), the intended
/// (5.17). It is safe for all time when every h_i(x(t0)) ≥ 0 ((5.18) for n = 2).
#[derive(Debug, Clone, PartialEq)]
pub struct EsfFilter {
    rate: f64,
    feedback: RowDVector<f64>,
}

impl EsfFilter {
    /// ESf filter of order n with decay rate ρ.
    pub fn new(order: usize, rate: f64) -> Result<Self> {
        if order == 0 {
            return Err(PrescribedTimeError::ZeroOrder);
        }
        if !(rate > 0.0 && rate.is_finite()) {
            return Err(PrescribedTimeError::NonPositiveRate { rate });
        }
        // Coefficients of Π_{i=1..n} (s + iρ), lowest power first.
        let mut polynomial = vec![1.0];
        for i in 1..=order {
            let root = i as f64 * rate;
            let mut next = vec![0.0; polynomial.len() + 1];
            for (power, coefficient) in polynomial.iter().enumerate() {
                next[power] += root * coefficient;
                next[power + 1] += coefficient;
            }
            polynomial = next;
        }
        Ok(Self {
            rate,
            feedback: RowDVector::from_column_slice(&polynomial[..order]),
        })
    }

    /// n.
    pub fn order(&self) -> usize {
        self.feedback.len()
    }

    /// ρ.
    pub fn rate(&self) -> f64 {
        self.rate
    }

    /// k with the safe control −k·x: s^n + k_n s^(n−1) + … + k_1 = Π (s + iρ).
    pub fn feedback(&self) -> &RowDVector<f64> {
        &self.feedback
    }

    /// The safe control −k·x ((5.89) for n = 2).
    pub fn safe_control(&self, state: &DVector<f64>) -> Result<f64> {
        check_dimension(self.order(), state)?;
        Ok(-dot(self.feedback.as_slice(), state.as_slice()))
    }

    /// ESf barrier functions h_1 … h_n at x.
    pub fn barriers(&self, state: &DVector<f64>) -> Result<DVector<f64>> {
        check_dimension(self.order(), state)?;
        let order = self.order();
        let mut row = RowDVector::zeros(order);
        row[0] = -1.0;
        let mut values = DVector::zeros(order);
        for i in 0..order {
            values[i] = row.dot(&state.transpose());
            if i + 1 < order {
                // d/dt of a form in x_1 … x_{i+1} shifts it one state up along (5.23).
                let mut next = RowDVector::zeros(order);
                for j in 0..order - 1 {
                    next[j + 1] = row[j];
                }
                row = next + &row * ((i + 1) as f64 * self.rate);
            }
        }
        Ok(values)
    }

    /// u = min{u_nom, −k·x} ((5.89) for n = 2).
    pub fn control(&self, state: &DVector<f64>, nominal: f64) -> Result<FilterDecision> {
        let safe = self.safe_control(state)?;
        let overriding = safe < nominal;
        Ok(FilterDecision {
            input: if overriding { safe } else { nominal },
            overriding,
            ramp: 1.0,
        })
    }
}

/// State-transition matrix of the double integrator under u = −2ρ² x1 − 3ρ x2, as (5.19)
/// with the typo in its (1,1) entry corrected: e^{−ρτ}[[2 − e^{−ρτ}, (1 − e^{−ρτ})/ρ],
/// [2ρ(e^{−ρτ} − 1), 2e^{−ρτ} − 1]], τ = time since the override began.
pub fn esf_double_integrator_transition(rate: f64, elapsed: f64) -> Matrix2<f64> {
    let e = (-rate * elapsed).exp();
    Matrix2::new(2.0 - e, (1.0 - e) / rate, 2.0 * rate * (e - 1.0), 2.0 * e - 1.0) * e
}

/// Red-light nominal controller (5.20)–(5.22) for the double integrator:
/// u = −k1 z1 − k2 z2, z1 = x1 + a sin(ωt) + b, z2 = x2 + aω cos(ωt).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RedLightNominal {
    pub position_gain: f64,
    pub velocity_gain: f64,
    pub amplitude: f64,
    pub offset: f64,
    pub frequency: f64,
}

impl RedLightNominal {
    /// §5.4: k1 = k2 = 4, a = 1, b = 0.8, ω = 2π/T.
    pub fn dissertation(terminal_time: f64) -> Self {
        Self {
            position_gain: 4.0,
            velocity_gain: 4.0,
            amplitude: 1.0,
            offset: 0.8,
            frequency: 2.0 * std::f64::consts::PI / terminal_time,
        }
    }

    /// Tracking errors (z1, z2) (5.21)/(5.22) at absolute time t.
    pub fn tracking_error(&self, time: f64, state: &Vector2<f64>) -> Vector2<f64> {
        let phase = self.frequency * time;
        Vector2::new(
            state[0] + self.amplitude * phase.sin() + self.offset,
            state[1] + self.amplitude * self.frequency * phase.cos(),
        )
    }

    /// u_nom (5.20).
    pub fn control(&self, time: f64, state: &Vector2<f64>) -> f64 {
        let z = self.tracking_error(time, state);
        -self.position_gain * z[0] - self.velocity_gain * z[1]
    }
}

/// The strict-feedback system (5.82): ẋ1 = x1² + x2, ẋ2 = u, y = x1, i.e. ẋ = f(x) + g(x) u.
/// It becomes the double integrator (5.85) in z = (x1, x1² + x2) (5.83)/(5.84).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StrictFeedbackSystem;

impl StrictFeedbackSystem {
    /// f(x) = (x1² + x2, 0).
    pub fn drift(&self, state: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(state[0] * state[0] + state[1], 0.0)
    }

    /// g(x) = (0, 1).
    pub fn input_gain(&self, _state: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(0.0, 1.0)
    }

    /// ẋ = f(x) + g(x) u (5.82).
    pub fn dynamics(&self, state: &Vector2<f64>, input: f64) -> Vector2<f64> {
        self.drift(state) + self.input_gain(state) * input
    }

    /// z = (x1, x1² + x2) (5.83)/(5.84).
    pub fn to_chain(&self, state: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(state[0], state[0] * state[0] + state[1])
    }

    /// x = (z1, z2 − z1²), the inverse of (5.83)/(5.84).
    pub fn from_chain(&self, chain_state: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(chain_state[0], chain_state[1] - chain_state[0] * chain_state[0])
    }

    /// v = 2 z1 z2 + u (5.86): the input of the z-chain (5.85).
    pub fn chain_input(&self, state: &Vector2<f64>, input: f64) -> f64 {
        let z = self.to_chain(state);
        2.0 * z[0] * z[1] + input
    }

    /// u = v − 2 x1 (x1² + x2) (5.91).
    pub fn plant_input(&self, state: &Vector2<f64>, chain_input: f64) -> f64 {
        chain_input - 2.0 * state[0] * (state[0] * state[0] + state[1])
    }
}

/// Prescribed-time stabilising nominal control of the z-chain (5.87)/(5.88):
/// v_nom = −μ2(t) [ω², 2ζω] z, with μ2 (clip included) from `blow_up`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PtsNominal {
    pub natural_frequency: f64,
    pub damping_ratio: f64,
    pub blow_up: BlowUp,
}

impl PtsNominal {
    /// K = [ω², 2ζω] (5.88).
    pub fn gain(&self) -> Vector2<f64> {
        Vector2::new(
            self.natural_frequency * self.natural_frequency,
            2.0 * self.damping_ratio * self.natural_frequency,
        )
    }

    /// v_nom (5.87). Once μ2 reaches the clip it is held there (the hard clip of §5.4); an
    /// unclipped nominal is only defined on [t0, t0 + T).
    pub fn control(&self, time: f64, chain_state: &Vector2<f64>) -> Result<f64> {
        let mut mu2 = [0.0];
        self.blow_up.mu2_jet_into(time, &mut mu2)?;
        let mu2 = mu2[0];
        Ok(-mu2 * self.gain().dot(chain_state))
    }
}

/// Inputs of the strict-feedback system under a filter applied in z-coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StrictFeedbackInput {
    /// u (5.91), applied to (5.82).
    pub plant_input: f64,
    /// Filtered v of the z-chain ((5.89)/(5.90)).
    pub chain_input: f64,
    /// v_nom (5.87).
    pub nominal_chain_input: f64,
    pub decision: FilterDecision,
}

/// PTSf for the strict-feedback system (5.82): the PTSf filter (5.90) on z, the PTS nominal
/// (5.87), and the map back (5.91).
#[derive(Debug, Clone, PartialEq)]
pub struct StrictFeedbackPtsf {
    pub system: StrictFeedbackSystem,
    pub filter: PtsfFilter,
    pub nominal: PtsNominal,
}

impl StrictFeedbackPtsf {
    /// Gains from z(t0) = to_chain(x(t0)) by (5.32)–(5.34); §5.7 gets c1 = c2 = 1 with margin 1.
    pub fn from_initial_state(
        initial_state: &Vector2<f64>,
        blow_up: BlowUp,
        margin: f64,
        ramp: ContinuityRamp,
        nominal: PtsNominal,
    ) -> Result<Self> {
        let system = StrictFeedbackSystem;
        let z0 = system.to_chain(initial_state);
        let filter = PtsfFilter::from_initial_state(blow_up, &DVector::from_column_slice(z0.as_slice()), margin, ramp)?;
        Ok(Self {
            system,
            filter,
            nominal,
        })
    }

    /// u at (t, x); `output_at_end` = x1(t0 + T) = z1(t0 + T) as in [`PtsfFilter::control`].
    pub fn input(&self, time: f64, state: &Vector2<f64>, output_at_end: Option<f64>) -> Result<StrictFeedbackInput> {
        let z = self.system.to_chain(state);
        let nominal_chain_input = self.nominal.control(time, &z)?;
        let decision = self.filter.control(
            time,
            &DVector::from_column_slice(z.as_slice()),
            nominal_chain_input,
            output_at_end,
        )?;
        Ok(StrictFeedbackInput {
            plant_input: self.system.plant_input(state, decision.input),
            chain_input: decision.input,
            nominal_chain_input,
            decision,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vector(values: &[f64]) -> DVector<f64> {
        DVector::from_column_slice(values)
    }

    fn blow_up(initial_time: f64, terminal_time: f64) -> BlowUp {
        BlowUp::new(initial_time, terminal_time).unwrap()
    }

    fn dissertation_ramp() -> ContinuityRamp {
        // §5.4: m = 2, T̄ = 0.5.
        ContinuityRamp::new(2, 0.5, 1e-9).unwrap()
    }

    fn filter_with_gains(blow_up: BlowUp, gains: &[f64]) -> PtsfFilter {
        PtsfFilter {
            blow_up,
            gains: gains.to_vec(),
            ramp: dissertation_ramp(),
        }
    }

    fn chain_dynamics(state: &DVector<f64>, input: f64) -> DVector<f64> {
        let n = state.len();
        DVector::from_fn(n, |i, _| if i + 1 < n { state[i + 1] } else { input })
    }

    fn rk4_step(
        derivative: &dyn Fn(f64, &DVector<f64>) -> DVector<f64>,
        time: f64,
        state: &DVector<f64>,
        step: f64,
    ) -> DVector<f64> {
        let k1 = derivative(time, state);
        let k2 = derivative(time + step / 2.0, &(state + &k1 * (step / 2.0)));
        let k3 = derivative(time + step / 2.0, &(state + &k2 * (step / 2.0)));
        let k4 = derivative(time + step, &(state + &k3 * step));
        state + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (step / 6.0)
    }

    /// What a controller returns: applied input, nominal input, overriding.
    type ControlSample = (f64, f64, bool);

    /// Closed-loop controller: (t, x, x1(t0 + T) once known) ↦ sample.
    type Controller<'a> = dyn Fn(f64, &DVector<f64>, Option<f64>) -> ControlSample + 'a;

    struct Sample {
        time: f64,
        state: DVector<f64>,
        input: f64,
        nominal: f64,
        overriding: bool,
    }

    /// Fixed-step RK4 closed loop. From `latch_time` (t0 + T) on the controller receives
    /// x1(t0 + T): the state at the first step boundary at or after it (the current stage's
    /// x1 until then).
    fn simulate(
        initial_state: DVector<f64>,
        duration: f64,
        step: f64,
        latch_time: f64,
        dynamics: &dyn Fn(&DVector<f64>, f64) -> DVector<f64>,
        controller: &Controller,
    ) -> Vec<Sample> {
        let steps = (duration / step).round() as usize;
        let mut state = initial_state;
        let mut latched: Option<f64> = None;
        let mut samples = Vec::with_capacity(steps + 1);
        for k in 0..=steps {
            let time = k as f64 * step;
            if time >= latch_time && latched.is_none() {
                latched = Some(state[0]);
            }
            let end_output = |t: f64, x: &DVector<f64>| (t >= latch_time).then(|| latched.unwrap_or(x[0]));
            let (input, nominal, overriding) = controller(time, &state, end_output(time, &state));
            samples.push(Sample {
                time,
                state: state.clone(),
                input,
                nominal,
                overriding,
            });
            if k == steps {
                break;
            }
            let derivative = |t: f64, x: &DVector<f64>| dynamics(x, controller(t, x, end_output(t, x)).0);
            state = rk4_step(&derivative, time, &state, step);
        }
        samples
    }

    fn first_override(samples: &[Sample]) -> Option<f64> {
        samples.iter().find(|s| s.overriding).map(|s| s.time)
    }

    /// Peak |du/dt| between consecutive samples that both override the nominal (Fig. 5.2).
    fn peak_jerk_while_overriding(samples: &[Sample]) -> f64 {
        samples
            .windows(2)
            .filter(|pair| pair[0].overriding && pair[1].overriding)
            .map(|pair| ((pair[1].input - pair[0].input) / (pair[1].time - pair[0].time)).abs())
            .fold(0.0, f64::max)
    }

    fn max_output_before(samples: &[Sample], end_time: f64) -> f64 {
        samples
            .iter()
            .filter(|s| s.time < end_time)
            .map(|s| s.state[0])
            .fold(f64::NEG_INFINITY, f64::max)
    }

    // ---------- blow-up function ----------

    #[test]
    fn rising_factorial_matches_its_definition() {
        assert_eq!(rising_factorial(2, 0), 1.0);
        assert_eq!(rising_factorial(2, 3), 2.0 * 3.0 * 4.0);
        assert_eq!(rising_factorial(1, 4), 24.0);
        assert_eq!(rising_factorial(0, 2), 0.0);
    }

    #[test]
    fn blow_up_is_one_at_start_and_grows_like_one_over_v_to_the_m() {
        let b = blow_up(0.5, 4.0);
        assert_eq!(b.decay(0.5), 1.0);
        assert_eq!(b.mu(2, 0.5), 1.0);
        assert!((b.mu(2, 2.5) - 4.0).abs() < 1e-12); // v = 1/2
        assert!((b.mu(3, 4.0) - 512.0).abs() < 1e-9); // v = 1/8
        assert_eq!(b.mu(2, 4.5), f64::INFINITY);
    }

    #[test]
    fn derivatives_5_5_match_finite_differences() {
        let b = blow_up(0.3, 2.0);
        let h = 1e-6;
        for m in 1..=4 {
            for order in 1..=3 {
                for &t in &[0.3, 0.9, 1.7, 2.1] {
                    let numeric =
                        (b.mu_derivative(m, order - 1, t + h) - b.mu_derivative(m, order - 1, t - h)) / (2.0 * h);
                    let exact = b.mu_derivative(m, order, t);
                    assert!(
                        (numeric - exact).abs() <= 1e-6 * exact.abs().max(1.0),
                        "m = {m}, i = {order}, t = {t}: (5.5) {exact} vs finite difference {numeric}"
                    );
                }
            }
        }
    }

    #[test]
    fn lemma_5_2_commutativity_5_35() {
        let terminal = 3.0;
        for m in 0..=4 {
            for &(earlier, later) in &[(0.0, 1.0), (0.5, 0.5), (1.2, 2.9), (2.0, 2.99)] {
                let whole = blow_up(0.0, terminal).mu(m, later);
                let split =
                    blow_up(0.0, terminal).mu(m, earlier) * blow_up(0.0, terminal - earlier).mu(m, later - earlier);
                assert!(
                    (whole - split).abs() <= 1e-12 * whole,
                    "m = {m}, t̄ = {earlier}, t = {later}: {whole} vs {split}"
                );
            }
        }
    }

    #[test]
    fn clipped_gain_profile_follows_5_5_then_its_taylor_polynomial() {
        let b = blow_up(0.0, 4.0).with_mu2_clip(DISSERTATION_MU2_CLIP).unwrap();
        let clip_time = b.clip_time();
        assert!((b.mu(2, clip_time) - 1000.0).abs() < 1e-9);
        let before = clip_time - 1e-3;
        let jet = b.mu2_jet(before, 4).unwrap();
        for (order, value) in jet.iter().enumerate() {
            assert_eq!(*value, b.mu_derivative(2, order as u32, before));
        }
        assert!(jet[0] < 1000.0);
        // n = 2 and the nominal (length 1): the dissertation's hard clip.
        for &t in &[clip_time + 1e-9, 3.99, 4.0, 7.0] {
            let jet = b.mu2_jet(t, 2).unwrap();
            assert!((jet[0] - 1000.0).abs() < 1e-9 && jet[1] == 0.0, "{jet:?}");
            assert!((b.mu2_jet(t, 1).unwrap()[0] - 1000.0).abs() < 1e-9);
        }
        // n = 4: orders 0..=2 continuous across the clip, order 3 zero after it.
        let eps = 1e-9;
        let left = b.mu2_jet(clip_time - eps, 4).unwrap();
        let right = b.mu2_jet(clip_time + eps, 4).unwrap();
        for order in 0..3 {
            assert!(
                (left[order] - right[order]).abs() <= 1e-6 * left[order],
                "order {order}: {} vs {}",
                left[order],
                right[order]
            );
        }
        assert_eq!(right[3], 0.0);
        assert!(left[3] > 1e5);
        // Bounded on the horizon by clip · (d + 1)(d + 2)/2 = 6 · clip for d = 2.
        let at_end = b.mu2_jet(4.0 - 1e-12, 4).unwrap()[0];
        assert!(at_end > 1000.0 && at_end <= 6000.0 * (1.0 + 1e-9), "{at_end}");
        // Unclipped, μ2 is not defined from t0 + T on.
        assert!(matches!(
            blow_up(0.0, 4.0).mu2_jet(4.0, 2),
            Err(PrescribedTimeError::OutsideHorizon { .. })
        ));
    }

    #[test]
    fn barriers_stay_continuous_across_the_clip() {
        let b = blow_up(0.0, 2.0).with_mu2_clip(100.0).unwrap();
        let filter = filter_with_gains(b, &[0.5, 0.8, 1.1, 1.4]);
        let x = vector(&[-0.01, 0.2, -3.0, 40.0]);
        let eps = 1e-10;
        let left = filter.barriers(b.clip_time() - eps, &x).unwrap();
        let right = filter.barriers(b.clip_time() + eps, &x).unwrap();
        assert!((&left - &right).norm() <= 1e-6 * left.norm(), "{left} vs {right}");
    }

    // ---------- barrier chain ----------

    #[test]
    fn second_order_chain_equals_5_10() {
        let b = blow_up(0.25, 4.0);
        let (c1, c2) = (0.7, 1.9);
        let filter = filter_with_gains(b, &[c1, c2]);
        for &t in &[0.25, 1.0, 3.0, 4.1] {
            for x in [vector(&[-4.0, 2.0]), vector(&[-0.3, -1.5]), vector(&[1.0, 0.5])] {
                let mu1 = b.mu(1, t);
                let mu2 = b.mu(2, t);
                let expected = -(c1 + c2) * mu2 * x[1] - c1 * (c2 * mu2 + 2.0 * mu1 / 4.0) * mu2 * x[0];
                let got = filter.safe_control(t, &x).unwrap();
                assert!(
                    (got - expected).abs() <= 1e-12 * expected.abs().max(1.0),
                    "t = {t}: {got} vs (5.10) {expected}"
                );
                // h1 (5.7), h2 (5.8).
                let h = filter.barriers(t, &x).unwrap();
                assert_eq!(h[0], -x[0]);
                assert!((h[1] - (-x[1] - c1 * mu2 * x[0])).abs() < 1e-12 * mu2.max(1.0));
            }
        }
    }

    #[test]
    fn third_order_chain_equals_hand_expansion_of_5_26() {
        let b = blow_up(0.0, 2.0);
        let (c1, c2, c3) = (0.4, 0.9, 1.3);
        let filter = filter_with_gains(b, &[c1, c2, c3]);
        for &t in &[0.0, 0.8, 1.6, 1.95] {
            let m = b.mu(2, t);
            let m1 = b.mu_derivative(2, 1, t);
            let m2 = b.mu_derivative(2, 2, t);
            let x = vector(&[-1.5, 0.7, -0.2]);
            // α1 = −c1 μ2 x1; α2 = −(c1 + c2) μ2 x2 − c1 (c2 μ2² + μ2') x1;
            // α3 = c3 μ2 (−x3 + α2) + d/dt α2.
            let alpha2 = -(c1 + c2) * m * x[1] - c1 * (c2 * m * m + m1) * x[0];
            let alpha2_rate = -(c1 + c2) * (m1 * x[1] + m * x[2])
                - c1 * (2.0 * c2 * m * m1 + m2) * x[0]
                - c1 * (c2 * m * m + m1) * x[1];
            let expected = c3 * m * (-x[2] + alpha2) + alpha2_rate;
            let got = filter.safe_control(t, &x).unwrap();
            assert!(
                (got - expected).abs() <= 1e-11 * expected.abs().max(1.0),
                "t = {t}: {got} vs {expected}"
            );
        }
    }

    #[test]
    fn target_system_5_30_5_31_holds_along_the_closed_loop_for_n_4() {
        let b = blow_up(0.0, 2.0);
        let gains = [0.5, 0.8, 1.1, 1.4];
        let filter = filter_with_gains(b, &gains);
        let derivative = |t: f64, x: &DVector<f64>| chain_dynamics(x, filter.safe_control(t, x).unwrap());
        let x = vector(&[-1.0, 0.4, 0.3, -0.6]);
        for &t in &[0.1, 0.9, 1.5] {
            let h = 1e-4;
            let forward = rk4_step(&derivative, t, &x, h);
            let backward = rk4_step(&derivative, t, &x, -h);
            let barrier_rate =
                (filter.barriers(t + h, &forward).unwrap() - filter.barriers(t - h, &backward).unwrap()) / (2.0 * h);
            let barrier = filter.barriers(t, &x).unwrap();
            let mu2 = b.mu(2, t);
            for i in 0..4 {
                let next = if i < 3 { barrier[i + 1] } else { 0.0 };
                let expected = -gains[i] * mu2 * barrier[i] + next;
                assert!(
                    (barrier_rate[i] - expected).abs() <= 1e-5 * expected.abs().max(1.0),
                    "t = {t}, i = {}: dh/dt {} vs (5.30)/(5.31) {expected}",
                    i + 1,
                    barrier_rate[i]
                );
            }
        }
    }

    #[test]
    fn closed_form_5_13_5_14_holds_with_c2_in_the_exponent_of_5_14() {
        // (5.14) prints c1 in the exponent of h2; (5.11) gives ḣ2 = −c2 μ2 h2, so it is c2.
        let terminal = 1.0;
        let b = blow_up(0.0, terminal);
        let (c1, c2) = (0.5, 1.5);
        let filter = filter_with_gains(b, &[c1, c2]);
        let x0 = vector(&[-1.0, 0.2]);
        let h0 = filter.barriers(0.0, &x0).unwrap();
        let step = 1.0 / 4096.0;
        let samples = simulate(x0, 0.75, step, f64::INFINITY, &chain_dynamics, &|t, x, _| {
            let u = filter.safe_control(t, x).unwrap();
            (u, u, true)
        });
        let exponent = |t: f64| terminal * (b.mu(1, t) - 1.0); // ∫_0^t μ2 = T (μ1 − 1)
        let mut integral = 0.0; // ∫_0^t e^{(c1 − c2) T (μ1 − 1)} dτ by the trapezoid rule
        for pair in samples.windows(2) {
            let integrand = |t: f64| ((c1 - c2) * exponent(t)).exp();
            integral += 0.5 * step * (integrand(pair[0].time) + integrand(pair[1].time));
            let s = &pair[1];
            let h = filter.barriers(s.time, &s.state).unwrap();
            let h2 = (-c2 * exponent(s.time)).exp() * h0[1];
            let h1 = (-c1 * exponent(s.time)).exp() * (h0[0] + h0[1] * integral);
            assert!((h[1] - h2).abs() < 1e-7, "t = {}: h2 {} vs {h2}", s.time, h[1]);
            assert!((h[0] - h1).abs() < 1e-6, "t = {}: h1 {} vs {h1}", s.time, h[0]);
        }
        let with_c1 = (-c1 * exponent(0.75)).exp() * h0[1];
        let last = samples.last().unwrap();
        let h2_final = filter.barriers(last.time, &last.state).unwrap()[1];
        assert!(
            h2_final < 0.1 * with_c1,
            "the printed (5.14) would match too: {h2_final} vs {with_c1}"
        );
    }

    // ---------- initial gains ----------

    #[test]
    fn gains_reproduce_the_dissertation_choices() {
        // §5.4: c1 = c2 = max{0, −x2(0)/x1(0)} + 0.1 = 0.6.
        let gains = initial_gains(&blow_up(0.0, 4.0), &vector(&[-4.0, 2.0]), 0.1).unwrap();
        assert!(
            (gains[0] - 0.6).abs() < 1e-12 && (gains[1] - 0.6).abs() < 1e-12,
            "{gains:?}"
        );
        // §5.7: z(0) = (−1, 0), c1 = c2 = 1.
        let gains = initial_gains(&blow_up(0.0, 1.0), &vector(&[-1.0, 0.0]), 1.0).unwrap();
        assert_eq!(gains, vec![1.0, 1.0]);
    }

    #[test]
    fn gains_make_every_initial_barrier_positive_5_50() {
        let starts: [&[f64]; 7] = [
            &[-1.0],
            &[-4.0, 2.0],
            &[-0.1, 5.0],
            &[-2.0, 1.0, 0.0],
            &[-0.5, 3.0, 4.0],
            &[-1.0, 2.0, -3.0, 5.0],
            &[-1.0, 0.5, 0.3, -0.2, 0.4],
        ];
        for start in starts {
            let x0 = vector(start);
            let b = blow_up(0.5, 2.5).with_mu2_clip(50.0).unwrap();
            let gains = initial_gains(&b, &x0, 0.05).unwrap();
            let n = gains.len();
            for i in 1..n.saturating_sub(1) {
                assert!(gains[i] > gains[i - 1], "(5.32) fails: {gains:?}");
            }
            assert!(gains.iter().all(|&c| c > 0.0), "{gains:?}");
            let filter = PtsfFilter::from_initial_state(b, &x0, 0.05, dissertation_ramp()).unwrap();
            let h = filter.barriers(0.5, &x0).unwrap();
            assert!(h.iter().all(|&value| value > 0.0), "x0 = {start:?}: h(t0) = {h}");
        }
    }

    #[test]
    fn gains_that_lose_positivity_in_floating_point_are_rejected() {
        // Close to the barrier with large higher derivatives, (5.34) asks for
        // c ≈ (7.6, 1.2e3, 2.9e7, 1.1e16): h5(t0) = margin · h4(t0) ≈ 2e-6 is lost to rounding.
        let b = blow_up(0.5, 2.5);
        let error = initial_gains(&b, &vector(&[-0.2, 1.5, 2.0, 3.0, 4.0]), 0.05).unwrap_err();
        let PrescribedTimeError::IllConditionedGains { gains, barriers } = error else {
            panic!("expected IllConditionedGains, got {error}");
        };
        assert!(gains[3] > 1e15, "{gains:?}");
        assert!(
            barriers[..4].iter().all(|&h| h > 0.0) && barriers[4] <= 0.0,
            "{barriers:?}"
        );
    }

    // ---------- errors ----------

    #[test]
    fn invalid_designs_are_rejected_with_clear_errors() {
        assert_eq!(
            BlowUp::new(0.0, 0.0),
            Err(PrescribedTimeError::NonPositiveTerminalTime { terminal_time: 0.0 })
        );
        assert!(BlowUp::new(0.0, -1.0).is_err());
        assert!(BlowUp::new(0.0, f64::NAN).is_err());
        assert_eq!(
            blow_up(0.0, 1.0).with_mu2_clip(1.0),
            Err(PrescribedTimeError::ClipNotAboveOne { clip: 1.0 })
        );
        assert!(blow_up(0.0, 1.0).with_mu2_clip(f64::NAN).is_err());
        let b = blow_up(0.0, 1.0);
        for output in [0.0, 0.5] {
            let error = initial_gains(&b, &vector(&[output, 1.0]), 0.1).unwrap_err();
            assert_eq!(error, PrescribedTimeError::UnsafeStart { output });
            assert!(error.to_string().contains("y < 0"), "{error}");
        }
        assert_eq!(
            initial_gains(&b, &vector(&[]), 0.1),
            Err(PrescribedTimeError::ZeroOrder)
        );
        assert!(matches!(
            initial_gains(&b, &vector(&[-1.0, 0.0]), 0.0),
            Err(PrescribedTimeError::NonPositiveMargin { .. })
        ));
        let filter = PtsfFilter::from_initial_state(b, &vector(&[-1.0, 0.0]), 1.0, dissertation_ramp()).unwrap();
        let mismatch = filter.safe_control(0.1, &vector(&[-1.0, 0.0, 0.0])).unwrap_err();
        assert_eq!(
            mismatch,
            PrescribedTimeError::DimensionMismatch { expected: 2, actual: 3 }
        );
        assert!(mismatch.to_string().contains("dimension 3, expected 2"));
        assert!(matches!(
            filter.control(1.2, &vector(&[-1.0, 0.0]), 0.0, None),
            Err(PrescribedTimeError::MissingTerminalOutput { .. })
        ));
        assert!(matches!(
            filter.safe_control(1.0, &vector(&[-1.0, 0.0])),
            Err(PrescribedTimeError::OutsideHorizon { .. })
        ));
        assert!(matches!(
            filter.safe_control(-0.1, &vector(&[-1.0, 0.0])),
            Err(PrescribedTimeError::BeforeInitialTime { .. })
        ));
        assert!(EsfFilter::new(2, 0.0).is_err());
        assert!(EsfFilter::new(0, 1.0).is_err());
        assert!(ContinuityRamp::new(0, 0.5, 0.0).is_err());
        assert!(ContinuityRamp::new(2, 0.0, 0.0).is_err());
        assert!(ContinuityRamp::new(2, 0.5, -1.0).is_err());
    }

    // ---------- ramp and filter switching ----------

    #[test]
    fn ramp_5_28_rises_from_zero_to_one_only_after_reaching_the_barrier() {
        let ramp = dissertation_ramp();
        assert_eq!(ramp.gain(0.0, 0.0), 0.0);
        assert!((ramp.gain(0.25, 0.0) - 0.75).abs() < 1e-12); // 1 − (1/2)²
        assert_eq!(ramp.gain(0.5, 0.0), 1.0);
        assert_eq!(ramp.gain(3.0, 0.0), 1.0);
        assert_eq!(ramp.gain(0.0, -0.6), 1.0);
        let filter = PtsfFilter::from_initial_state(blow_up(0.0, 1.0), &vector(&[-1.0, 0.0]), 1.0, ramp).unwrap();
        let decision = filter.control(1.25, &vector(&[0.0, 0.0]), 2.0, Some(0.0)).unwrap();
        assert_eq!(decision.input, 1.5);
        assert!(!decision.overriding);
    }

    #[test]
    fn filter_is_the_qp_5_29_solution() {
        let filter =
            PtsfFilter::from_initial_state(blow_up(0.0, 4.0), &vector(&[-4.0, 2.0]), 0.1, dissertation_ramp()).unwrap();
        let x = vector(&[-1.0, 1.5]);
        let alpha = filter.safe_control(2.0, &x).unwrap();
        let below = filter.control(2.0, &x, alpha - 1.0, None).unwrap();
        assert_eq!((below.input, below.overriding), (alpha - 1.0, false));
        let above = filter.control(2.0, &x, alpha + 1.0, None).unwrap();
        assert_eq!((above.input, above.overriding), (alpha, true));
    }

    // ---------- ESf ----------

    #[test]
    fn esf_pole_placement_reduces_to_5_89_for_n_2() {
        let rho = 3.2;
        let esf = EsfFilter::new(2, rho).unwrap();
        assert!((esf.feedback()[0] - 2.0 * rho * rho).abs() < 1e-12);
        assert!((esf.feedback()[1] - 3.0 * rho).abs() < 1e-12);
        let x = vector(&[-0.7, 1.1]);
        let expected = -2.0 * rho * rho * x[0] - 3.0 * rho * x[1];
        assert!((esf.safe_control(&x).unwrap() - expected).abs() < 1e-12);
        // (s + ρ)(s + 2ρ)(s + 3ρ) = s³ + 6ρ s² + 11ρ² s + 6ρ³.
        let third = EsfFilter::new(3, 0.5).unwrap();
        let k = third.feedback();
        assert!((k[0] - 6.0 * 0.125).abs() < 1e-12 && (k[1] - 11.0 * 0.25).abs() < 1e-12 && (k[2] - 3.0).abs() < 1e-12);
    }

    #[test]
    fn esf_barriers_are_5_15_5_16_and_positivity_is_5_18() {
        let esf = EsfFilter::new(2, 0.6).unwrap();
        let x0 = vector(&[-4.0, 2.0]);
        let h = esf.barriers(&x0).unwrap();
        assert_eq!(h[0], 4.0);
        assert!((h[1] - (-2.0 + 0.6 * 4.0)).abs() < 1e-12);
        // ρ below max{0, −x2/x1} = 0.5 violates (5.18) and makes h2(t0) < 0.
        assert!(EsfFilter::new(2, 0.45).unwrap().barriers(&x0).unwrap()[1] < 0.0);
        // n = 3: the last barrier's constraint is exactly u ≤ −k·x.
        let esf3 = EsfFilter::new(3, 0.8).unwrap();
        let x = vector(&[-1.0, 0.3, 0.2]);
        let derivative = |_t: f64, y: &DVector<f64>| chain_dynamics(y, esf3.safe_control(y).unwrap());
        let h = 1e-4;
        let rate = (esf3.barriers(&rk4_step(&derivative, 0.0, &x, h)).unwrap()
            - esf3.barriers(&rk4_step(&derivative, 0.0, &x, -h)).unwrap())
            / (2.0 * h);
        let barriers = esf3.barriers(&x).unwrap();
        for i in 0..3 {
            let next = if i < 2 { barriers[i + 1] } else { 0.0 };
            let lambda = (i + 1) as f64 * 0.8;
            assert!((rate[i] + lambda * barriers[i] - next).abs() < 1e-8, "i = {i}");
        }
    }

    #[test]
    fn esf_closed_loop_matches_corrected_5_19() {
        let rho = 1.7;
        let esf = EsfFilter::new(2, rho).unwrap();
        let x0 = vector(&[-1.0, 0.8]);
        let samples = simulate(
            x0.clone(),
            2.0,
            1.0 / 1024.0,
            f64::INFINITY,
            &chain_dynamics,
            &|_t, x, _| {
                let u = esf.safe_control(x).unwrap();
                (u, u, true)
            },
        );
        let start = Vector2::new(x0[0], x0[1]);
        for s in samples.iter().step_by(128) {
            let expected = esf_double_integrator_transition(rho, s.time) * start;
            assert!((s.state[0] - expected[0]).abs() < 1e-9 && (s.state[1] - expected[1]).abs() < 1e-9);
        }
    }

    // ---------- strict-feedback system ----------

    #[test]
    fn strict_feedback_transform_is_5_83_to_5_86_and_inverts_by_5_91() {
        let system = StrictFeedbackSystem;
        let x = Vector2::new(-1.0, -1.0);
        assert_eq!(system.to_chain(&x), Vector2::new(-1.0, 0.0)); // §5.7
        let x = Vector2::new(0.7, -0.3);
        assert!((system.from_chain(&system.to_chain(&x)) - x).norm() < 1e-15);
        let u = 0.9;
        let v = system.chain_input(&x, u);
        assert!((system.plant_input(&x, v) - u).abs() < 1e-15);
        // ż = (z2, v) along (5.82) (5.85).
        let h = 1e-6;
        let zdot = (system.to_chain(&(x + system.dynamics(&x, u) * h))
            - system.to_chain(&(x - system.dynamics(&x, u) * h)))
            / (2.0 * h);
        let z = system.to_chain(&x);
        assert!(
            (zdot[0] - z[1]).abs() < 1e-8 && (zdot[1] - v).abs() < 1e-6,
            "{zdot} vs ({}, {v})",
            z[1]
        );
        assert_eq!(system.drift(&x), Vector2::new(0.7 * 0.7 - 0.3, 0.0));
        assert_eq!(system.input_gain(&x), Vector2::new(0.0, 1.0));
        let nominal = PtsNominal {
            natural_frequency: 4.0,
            damping_ratio: 0.1,
            blow_up: blow_up(0.0, 1.0),
        };
        assert_eq!(nominal.gain(), Vector2::new(16.0, 0.8));
        assert!((nominal.control(0.5, &Vector2::new(1.0, 1.0)).unwrap() + 4.0 * 16.8).abs() < 1e-12);
    }

    // ---------- closed loops: the dissertation's outcomes ----------

    #[test]
    fn red_light_double_integrator_section_5_4() {
        let terminal = 4.0;
        let step = 1.0 / 8192.0;
        let duration = 6.0;
        let x0 = vector(&[-4.0, 2.0]);
        let nominal = RedLightNominal::dissertation(terminal);
        let nominal_at = |t: f64, x: &DVector<f64>| nominal.control(t, &Vector2::new(x[0], x[1]));
        let b = blow_up(0.0, terminal).with_mu2_clip(DISSERTATION_MU2_CLIP).unwrap();
        let ptsf = PtsfFilter::from_initial_state(b, &x0, 0.1, dissertation_ramp()).unwrap();
        assert!((ptsf.gains()[0] - 0.6).abs() < 1e-12 && (ptsf.gains()[1] - 0.6).abs() < 1e-12);

        let run_nominal = simulate(x0.clone(), duration, step, terminal, &chain_dynamics, &|t, x, _| {
            let u = nominal_at(t, x);
            (u, u, false)
        });
        let run_ptsf = simulate(x0.clone(), duration, step, terminal, &chain_dynamics, &|t, x, end| {
            let u_nom = nominal_at(t, x);
            let d = ptsf.control(t, x, u_nom, end).unwrap();
            (d.input, u_nom, d.overriding)
        });
        let esf_run = |rho: f64| {
            let esf = EsfFilter::new(2, rho).unwrap();
            assert!(
                esf.barriers(&x0).unwrap().iter().all(|&h| h >= 0.0),
                "(5.18) for ρ = {rho}"
            );
            simulate(x0.clone(), duration, step, terminal, &chain_dynamics, &|t, x, _| {
                let u_nom = nominal_at(t, x);
                let d = esf.control(x, u_nom).unwrap();
                (d.input, u_nom, d.overriding)
            })
        };
        let run_esf_slow = esf_run(0.6);
        let run_esf_fast = esf_run(3.2);

        let crossing = run_nominal.iter().find(|s| s.state[0] >= 0.0).map(|s| s.time);
        let ptsf_first = first_override(&run_ptsf).unwrap();
        let slow_first = first_override(&run_esf_slow).unwrap();
        let fast_first = first_override(&run_esf_fast).unwrap();
        let ptsf_jerk = peak_jerk_while_overriding(&run_ptsf);
        let slow_jerk = peak_jerk_while_overriding(&run_esf_slow);
        let fast_jerk = peak_jerk_while_overriding(&run_esf_fast);
        let ptsf_last = run_ptsf
            .iter()
            .filter(|s| s.overriding)
            .map(|s| s.time)
            .fold(0.0, f64::max);
        let at_end = run_ptsf.iter().find(|s| s.time >= terminal).unwrap();
        println!(
            "§5.4 nominal: first y >= 0 at t = {crossing:?}, max y on [0, T) = {:.4}",
            max_output_before(&run_nominal, terminal)
        );
        println!("§5.4 PTSf c = {:?}: overrides on [{ptsf_first:.4}, {ptsf_last:.4}], max y on [0, T) = {:.3e}, peak jerk {ptsf_jerk:.3}, x(T) = ({:.4}, {:.4})",
            ptsf.gains(), max_output_before(&run_ptsf, terminal), at_end.state[0], at_end.state[1]);
        println!(
            "§5.4 ESf ρ = 0.6: first override {slow_first:.4}, max y on [0, T) = {:.4}, peak jerk {slow_jerk:.3}",
            max_output_before(&run_esf_slow, terminal)
        );
        println!("§5.4 ESf ρ = 3.2: first override {fast_first:.4}, max y on [0, T) = {:.4}, peak jerk {fast_jerk:.3} ({:.2} × PTSf)",
            max_output_before(&run_esf_fast, terminal), fast_jerk / ptsf_jerk);

        // The nominal alone runs the red light before T.
        assert!(crossing.is_some_and(|t| t < terminal), "nominal crossing {crossing:?}");
        // PTSf keeps y < 0 on [0, T).
        assert!(max_output_before(&run_ptsf, terminal) < 0.0);
        // ESf ρ = 0.6 overrides much earlier than PTSf; ρ = 3.2 reacts at about the same instant.
        assert!(
            slow_first < ptsf_first - 0.5,
            "ESf 0.6 at {slow_first}, PTSf at {ptsf_first}"
        );
        assert!(
            (fast_first - ptsf_first).abs() < 0.25,
            "ESf 3.2 at {fast_first}, PTSf at {ptsf_first}"
        );
        // Both ESf runs stay safe (for all time, by design).
        assert!(run_esf_slow.iter().chain(&run_esf_fast).all(|s| s.state[0] < 0.0));
        // ESf ρ = 3.2 pays with several times PTSf's peak jerk.
        assert!(
            fast_jerk > 3.0 * ptsf_jerk,
            "ESf 3.2 jerk {fast_jerk}, PTSf {ptsf_jerk}"
        );
        // After T + T̄ the PTSf control is the nominal one.
        for s in run_ptsf.iter().filter(|s| s.time >= terminal + 0.5) {
            assert_eq!(s.input, s.nominal, "t = {}", s.time);
        }
    }

    #[test]
    fn strict_feedback_section_5_7() {
        let terminal = 1.0;
        let step = 1.0 / 8192.0;
        let x0 = Vector2::new(-1.0, -1.0);
        let b = blow_up(0.0, terminal).with_mu2_clip(DISSERTATION_MU2_CLIP).unwrap();
        let nominal = PtsNominal {
            natural_frequency: 4.0,
            damping_ratio: 0.1,
            blow_up: b,
        };
        let design = StrictFeedbackPtsf::from_initial_state(&x0, b, 1.0, dissertation_ramp(), nominal).unwrap();
        assert_eq!(design.filter.gains(), &[1.0, 1.0]);
        let system = StrictFeedbackSystem;
        let plant = |x: &DVector<f64>, u: f64| {
            let dx = system.dynamics(&Vector2::new(x[0], x[1]), u);
            vector(&[dx[0], dx[1]])
        };
        let start = vector(&[x0[0], x0[1]]);
        let run_ptsf = simulate(start.clone(), 1.5, step, terminal, &plant, &|t, x, end| {
            let input = design.input(t, &Vector2::new(x[0], x[1]), end).unwrap();
            let nominal_plant = system.plant_input(&Vector2::new(x[0], x[1]), input.nominal_chain_input);
            (input.plant_input, nominal_plant, input.decision.overriding)
        });
        let run_nominal = simulate(start.clone(), terminal, step, terminal, &plant, &|t, x, _| {
            let state = Vector2::new(x[0], x[1]);
            let u = system.plant_input(&state, nominal.control(t, &system.to_chain(&state)).unwrap());
            (u, u, false)
        });
        let esf_final = |rho: f64| {
            let esf = EsfFilter::new(2, rho).unwrap();
            let run = simulate(start.clone(), terminal, step, terminal, &plant, &|t, x, _| {
                let state = Vector2::new(x[0], x[1]);
                let z = system.to_chain(&state);
                let v = esf
                    .control(&vector(&[z[0], z[1]]), nominal.control(t, &z).unwrap())
                    .unwrap();
                let u = system.plant_input(&state, v.input);
                (u, u, v.overriding)
            });
            (
                max_output_before(&run, terminal + step),
                run.last().unwrap().state.clone(),
            )
        };

        let before_end = run_ptsf.iter().rev().find(|s| s.time < terminal).unwrap();
        let at_end = run_ptsf.iter().find(|s| s.time >= terminal).unwrap();
        let peak_input = run_ptsf
            .iter()
            .filter(|s| s.time < terminal)
            .map(|s| s.input.abs())
            .fold(0.0, f64::max);
        let (slow_max, slow_end) = esf_final(1.2);
        let (fast_max, fast_end) = esf_final(10.0);
        println!(
            "§5.7 nominal PTS: max y on [0, T) = {:.4}",
            max_output_before(&run_nominal, terminal)
        );
        println!("§5.7 PTSf: first override {:?}, max y on [0, T) = {:.3e}, |x(T)| = {:.3e}, |u(T − dt)| = {:.3e}, |u(T)| = {:.3e}, max |u| = {peak_input:.3}",
            first_override(&run_ptsf), max_output_before(&run_ptsf, terminal), at_end.state.norm(), before_end.input.abs(), at_end.input.abs());
        println!("§5.7 ESf ρ = 1.2: max y = {slow_max:.4}, x(T) = ({:.4}, {:.4}); ρ = 10: max y = {fast_max:.3e}, x(T) = ({:.3e}, {:.3e})",
            slow_end[0], slow_end[1], fast_end[0], fast_end[1]);

        assert!(
            max_output_before(&run_nominal, terminal) > 0.0,
            "the nominal PTS controller alone must cross"
        );
        assert!(max_output_before(&run_ptsf, terminal) < 0.0);
        assert!(at_end.state.norm() < 1e-9, "|x(T)| = {}", at_end.state.norm());
        assert!(before_end.input.abs() < 1e-9 && at_end.input.abs() < 1e-9);
        // x1(T) is at the barrier, so the ramp (5.28) engages and the control stays continuous.
        assert!(run_ptsf
            .iter()
            .filter(|s| s.time >= terminal)
            .all(|s| s.input.abs() < 1e-9));
        // ESf: ρ = 1.2 stays far from the boundary at T, ρ = 10 ends close to it.
        assert!(slow_max < 0.0 && fast_max < 0.0);
        assert!(fast_end[0].abs() < 0.01 && slow_end[0].abs() > 0.1);
    }

    /// Peak |u| on [0, T).
    fn peak_input_before(samples: &[Sample], end_time: f64) -> f64 {
        samples
            .iter()
            .filter(|s| s.time < end_time)
            .map(|s| s.input.abs())
            .fold(0.0, f64::max)
    }

    /// n = 3 chain from x(0) = (−2, 1, 0) with T = 3, PTSf margin 0.1, the given clip.
    fn third_order_run(nominal: &dyn Fn(&DVector<f64>) -> f64, clip: f64, step: f64) -> (Vec<f64>, Vec<Sample>) {
        let terminal = 3.0;
        let x0 = vector(&[-2.0, 1.0, 0.0]);
        let b = blow_up(0.0, terminal).with_mu2_clip(clip).unwrap();
        let ptsf = PtsfFilter::from_initial_state(b, &x0, 0.1, dissertation_ramp()).unwrap();
        let run = simulate(x0, terminal + 1.0, step, terminal, &chain_dynamics, &|t, x, end| {
            let u_nom = nominal(x);
            let d = ptsf.control(t, x, u_nom, end).unwrap();
            (d.input, u_nom, d.overriding)
        });
        (ptsf.gains().to_vec(), run)
    }

    #[test]
    fn third_order_chain_stays_safe_under_a_tracking_nominal() {
        let terminal = 3.0;
        let step = 1.0 / 8192.0;
        // Nominal: triple pole at −1 driving x1 to +1, beyond the barrier.
        let nominal = |x: &DVector<f64>| -(x[0] - 1.0) - 3.0 * x[1] - 3.0 * x[2];
        let run_nominal = simulate(
            vector(&[-2.0, 1.0, 0.0]),
            terminal,
            step,
            terminal,
            &chain_dynamics,
            &|_t, x, _| (nominal(x), nominal(x), false),
        );
        let crossing = run_nominal.iter().find(|s| s.state[0] >= 0.0).map(|s| s.time);
        let (gains, run) = third_order_run(&nominal, DISSERTATION_MU2_CLIP, step);
        let overriding: Vec<f64> = run.iter().filter(|s| s.overriding).map(|s| s.time).collect();
        let peak_nominal = run
            .iter()
            .filter(|s| s.time < terminal)
            .map(|s| s.nominal.abs())
            .fold(0.0, f64::max);
        println!(
            "n = 3 tracking nominal: first y >= 0 at {crossing:?}; PTSf gains {gains:?} override on [{:?}, {:?}], max y on [0, T) = {:.3e}, max |u| = {:.4}, max |u_nom| = {peak_nominal:.4}",
            overriding.first(),
            overriding.last(),
            max_output_before(&run, terminal),
            peak_input_before(&run, terminal)
        );
        assert!(crossing.is_some_and(|t| t < terminal), "nominal crossing {crossing:?}");
        assert!(!overriding.is_empty());
        assert!(max_output_before(&run, terminal) < 0.0);
        assert!(peak_input_before(&run, terminal) <= 2.0 * peak_nominal);
    }

    #[test]
    fn hard_clip_of_all_mu2_derivatives_would_break_third_order_safety() {
        // The same closed loop as below with clip 100, once with mu2_jet (Taylor continuation)
        // and once with a hard clip (100, 0, 0) after t_c, which makes h3 jump down by c1 μ2′ |x1|.
        let terminal = 3.0;
        let step = 1.0 / 32768.0;
        let x0 = vector(&[-2.0, 1.0, 0.0]);
        let b = blow_up(0.0, terminal).with_mu2_clip(100.0).unwrap();
        let gains = initial_gains(&b, &x0, 0.1).unwrap();
        let run = |hard: bool| {
            simulate(x0.clone(), terminal, step, terminal, &chain_dynamics, &|t, x, _| {
                let jet = if hard && t >= b.clip_time() {
                    vec![100.0, 0.0, 0.0]
                } else {
                    b.mu2_jet(t, 3).unwrap()
                };
                let alpha = dot(build_chain(&jet, &gains, 3).alpha_row(3), x.as_slice());
                (alpha.min(5.0), 5.0, alpha < 5.0)
            })
        };
        let continued = max_output_before(&run(false), terminal);
        let hard = max_output_before(&run(true), terminal);
        println!("n = 3, clip 100: max y on [0, T) = {continued:.3e} (Taylor continuation), {hard:.3e} (hard clip)");
        assert!(continued < 0.0);
        assert!(hard > 0.0);
    }

    #[test]
    fn third_order_chain_held_until_t_has_bounded_vanishing_control() {
        let terminal = 3.0;
        let step = 1.0 / 32768.0;
        // Nominal: constant jerk 5 towards the barrier; alone, x1 = −2 + t + 5t³/6 crosses at 1.0.
        let nominal = |_x: &DVector<f64>| 5.0;
        let (gains, run) = third_order_run(&nominal, DISSERTATION_MU2_CLIP, step);
        let (_, run_wide) = third_order_run(&nominal, 1e4, step);
        let (_, run_narrow) = third_order_run(&nominal, 100.0, step);
        assert!(max_output_before(&run_narrow, terminal) < 0.0);
        let before_end = |run: &[Sample]| run.iter().rev().find(|s| s.time < terminal).unwrap().input;
        let at_end = run.iter().find(|s| s.time >= terminal).unwrap();
        let peak = peak_input_before(&run, terminal);
        let peak_wide = peak_input_before(&run_wide, terminal);
        println!(
            "n = 3 constant nominal: gains {gains:?}, first override {:?}, max y on [0, T) = {:.3e}, max |u| = {peak:.4} (clip 1e4: {peak_wide:.4}), u(T − dt) = {:.3e} (clip 1e4: {:.3e}), |x(T)| = {:.3e}",
            first_override(&run),
            max_output_before(&run, terminal),
            before_end(&run),
            before_end(&run_wide),
            at_end.state.norm()
        );
        assert!(run.iter().filter(|s| s.time < terminal).all(|s| s.overriding));
        assert!(max_output_before(&run, terminal) < 0.0);
        assert!(max_output_before(&run_wide, terminal) < 0.0);
        // Bounded (Theorem 5.1): ten times more gain growth leaves the peak input unchanged,
        // and the input vanishes at T (Remark 5.1) instead of growing with μ2.
        assert!((peak - peak_wide).abs() <= 0.01 * peak, "{peak} vs {peak_wide}");
        assert!(before_end(&run).abs() < 1e-6 && before_end(&run_wide).abs() < 1e-6);
        assert!(at_end.state.norm() < 1e-6);
    }
}
