//! The Ch. 5 filters on a chain of integrators z = T(x) (the identity, or (5.83)/(5.84) for
//! the strict-feedback system (5.82)), mapped back by (5.91): `kind = "ptsf"`, the
//! prescribed-time safety filter (5.23)–(5.29) keeping y = z1 < 0 on [0, T), and
//! `kind = "esf"`, the exponential safety filter u = min{u_nom, −k z} (5.89). One input
//! channel, no delay.

use std::sync::Arc;

use nalgebra::{DVector, Vector2};
use serde::{Deserialize, Serialize};

use crate::barrier::BarrierForm;
use crate::filter::Params;
use crate::filter::{
    ChannelInput, ChannelOutcome, FilterContext, FilterError, ParamError, SafetyFilter, TICK_TOLERANCE,
};
use crate::prescribed_time::{
    BlowUp, ChainForms, ContinuityRamp, EsfFilter, PrescribedTimeError, PtsfFilter, StrictFeedbackSystem,
};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PtsfParams {
    /// T: the prescribed time (the filter starts at t0 = 0).
    pub horizon: f64,
    /// Margin added to the lower bounds (5.32)–(5.34) of the gains c_i (computed from x(0)).
    pub margin: f64,
    /// Clip of μ2 (§5.4 uses 1000); none if absent.
    #[serde(default)]
    pub clip: Option<f64>,
    /// Order n of the chain; checked against the model if given.
    #[serde(default)]
    pub order: Option<usize>,
    /// Ramp g (5.28) after T: exponent m, duration T̄, and |y(T)| tolerance for "y(T) = 0".
    #[serde(default = "default_ramp_exponent")]
    pub ramp_exponent: u32,
    #[serde(default = "default_ramp_duration")]
    pub ramp_duration: f64,
    #[serde(default = "default_ramp_tolerance")]
    pub ramp_tolerance: f64,
}

fn default_ramp_exponent() -> u32 {
    2
}
fn default_ramp_duration() -> f64 {
    0.5
}
fn default_ramp_tolerance() -> f64 {
    1e-9
}

fn positive_finite(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

impl Params for PtsfParams {
    fn validate(&self) -> Result<(), ParamError> {
        if !positive_finite(self.horizon) {
            return Err(ParamError::new(
                "filter.horizon",
                format!("expected T > 0, found {}", self.horizon),
            ));
        }
        if !positive_finite(self.margin) {
            return Err(ParamError::new(
                "filter.margin",
                format!("expected a margin > 0, found {}", self.margin),
            ));
        }
        if let Some(clip) = self.clip {
            if !(clip.is_finite() && clip > 1.0) {
                return Err(ParamError::new(
                    "filter.clip",
                    format!("expected a clip > 1 for mu_2, found {clip}"),
                ));
            }
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EsfParams {
    /// ρ.
    pub rate: f64,
    /// T for the prescribed-time metrics (barrier and residuals at T); optional.
    #[serde(default)]
    pub horizon: Option<f64>,
}

impl Params for EsfParams {
    fn validate(&self) -> Result<(), ParamError> {
        if !positive_finite(self.rate) {
            return Err(ParamError::new(
                "filter.rate",
                format!("expected rho > 0, found {}", self.rate),
            ));
        }
        Ok(())
    }
}

/// How the plant's state and input map to a chain of integrators.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ChainTransform {
    /// The plant is the chain.
    Identity,
    /// (5.82) → (5.85) by (5.83)/(5.84), inputs by (5.86)/(5.91).
    StrictFeedback,
}

impl ChainTransform {
    pub fn to_chain(&self, x: &[f64]) -> DVector<f64> {
        let mut z = DVector::zeros(x.len());
        self.to_chain_into(x, &mut z);
        z
    }
    /// z = T(x) into `z` (of the state's dimension).
    pub fn to_chain_into(&self, x: &[f64], z: &mut DVector<f64>) {
        match self {
            ChainTransform::Identity => z.copy_from_slice(x),
            ChainTransform::StrictFeedback => {
                z.copy_from_slice(StrictFeedbackSystem.to_chain(&Vector2::new(x[0], x[1])).as_slice())
            }
        }
    }
    /// The chain input v for plant input u at x ((5.86)).
    pub fn chain_input(&self, x: &[f64], u: f64) -> f64 {
        match self {
            ChainTransform::Identity => u,
            ChainTransform::StrictFeedback => StrictFeedbackSystem.chain_input(&Vector2::new(x[0], x[1]), u),
        }
    }
    /// The plant input u for chain input v at x ((5.91)).
    pub fn plant_input(&self, x: &[f64], v: f64) -> f64 {
        match self {
            ChainTransform::Identity => v,
            ChainTransform::StrictFeedback => StrictFeedbackSystem.plant_input(&Vector2::new(x[0], x[1]), v),
        }
    }
}

/// The checks both chain filters need: one channel without delay, and a model that is a chain
/// of integrators of order n (or the strict-feedback system (5.82), mapped to one).
fn chain_transform(ctx: &FilterContext) -> Result<ChainTransform, ParamError> {
    if ctx.queues.len() != 1 || ctx.queues[0].constant_delay() != Some(0.0) {
        return Err(ParamError::new(
            "filter.kind",
            "the Ch. 5 filters need one input channel without delay",
        ));
    }
    if ctx.vehicle_kind == "strict_feedback" {
        return Ok(ChainTransform::StrictFeedback);
    }
    // ẋ_i = x_{i+1}, ẋ_n = u: check f and G at a generic state.
    let model = ctx.model.as_ref();
    let n = model.state_dim();
    let probe = DVector::from_iterator(n, (0..n).map(|i| 0.37 * (i as f64 + 1.0)));
    let f = model.drift(&probe);
    let g = model.input_matrix(&probe);
    let is_chain = (0..n).all(|i| {
        let expected_f = if i + 1 < n { probe[i + 1] } else { 0.0 };
        let expected_g = if i + 1 == n { 1.0 } else { 0.0 };
        (f[i] - expected_f).abs() < 1e-12 && (g[(i, 0)] - expected_g).abs() < 1e-12
    });
    if !is_chain {
        return Err(ParamError::new(
            "vehicle",
            "the Ch. 5 filters need a chain of integrators (x_i' = x_{i+1}, x_n' = u) or kind = \"strict_feedback\"",
        ));
    }
    Ok(ChainTransform::Identity)
}

fn design_error(e: PrescribedTimeError) -> ParamError {
    ParamError::new("filter", e.to_string())
}

/// Which Ch. 5 filter acts on the chain.
enum ChainLaw {
    Ptsf {
        filter: Arc<PtsfFilter>,
        /// y(t0 + T) = z1 at the prescribed time, once reached (the ramp (5.28) needs it).
        output_at_end: Option<f64>,
        /// The chain (5.24)–(5.26), scratch space.
        chain: Box<ChainForms>,
    },
    Esf(Arc<EsfFilter>),
}

/// u = T⁻¹(filter(t, z, v_nom)) for a scalar-input chain (no delays).
pub struct ChainFilter {
    law: ChainLaw,
    transform: ChainTransform,
    prescribed_time: Option<f64>,
    /// z = T(x), scratch space.
    z: DVector<f64>,
}

/// The filter of a `kind = "ptsf"` table: gains from x(0) (5.32)–(5.34).
pub fn build_ptsf(p: &PtsfParams, ctx: &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> {
    let transform = chain_transform(ctx)?;
    let n = ctx.model.state_dim();
    if let Some(order) = p.order {
        if order != n {
            return Err(ParamError::new(
                "filter.order",
                format!("the model is a chain of order {n}, not {order}"),
            ));
        }
    }
    let mut blow_up = BlowUp::new(0.0, p.horizon).map_err(design_error)?;
    if let Some(clip) = p.clip {
        blow_up = blow_up.with_mu2_clip(clip).map_err(design_error)?;
    }
    let ramp = ContinuityRamp::new(p.ramp_exponent, p.ramp_duration, p.ramp_tolerance).map_err(design_error)?;
    let z0 = transform.to_chain(ctx.initial_state.as_slice());
    let filter = PtsfFilter::from_initial_state(blow_up, &z0, p.margin, ramp).map_err(design_error)?;
    Ok(Box::new(ChainFilter {
        law: ChainLaw::Ptsf {
            chain: Box::new(filter.workspace()),
            filter: Arc::new(filter),
            output_at_end: None,
        },
        transform,
        prescribed_time: Some(p.horizon),
        z: DVector::zeros(n),
    }))
}

/// The filter of a `kind = "esf"` table.
pub fn build_esf(p: &EsfParams, ctx: &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> {
    let transform = chain_transform(ctx)?;
    let filter = EsfFilter::new(ctx.model.state_dim(), p.rate).map_err(design_error)?;
    Ok(Box::new(ChainFilter {
        law: ChainLaw::Esf(Arc::new(filter)),
        transform,
        prescribed_time: p.horizon,
        z: DVector::zeros(ctx.model.state_dim()),
    }))
}

impl SafetyFilter for ChainFilter {
    fn barrier_form(&self) -> Option<BarrierForm> {
        // The chain filters have their own barrier chains ((5.24), (5.15)/(5.16)).
        None
    }
    fn uses_prediction(&self) -> bool {
        false
    }
    fn filter_channel(&mut self, input: &ChannelInput<'_>) -> Result<Option<ChannelOutcome>, FilterError> {
        let (t, x) = (input.time, input.state);
        self.transform.to_chain_into(x, &mut self.z);
        let z = &self.z;
        let v_nom = self.transform.chain_input(x, input.nominal[0]);
        let prescribed = |e: PrescribedTimeError| FilterError::Other(format!("prescribed-time filter: {e}"));
        let decision = match &mut self.law {
            ChainLaw::Ptsf {
                filter,
                output_at_end,
                chain,
            } => {
                if t >= filter.blow_up().end_time() - TICK_TOLERANCE * input.timestep && output_at_end.is_none() {
                    *output_at_end = Some(z[0]);
                }
                filter
                    .control_with(chain, t, z, v_nom, *output_at_end)
                    .map_err(prescribed)?
            }
            ChainLaw::Esf(esf) => esf.control(z, v_nom).map_err(prescribed)?,
        };
        Ok(Some(ChannelOutcome::new(
            self.transform.plant_input(x, decision.input),
            decision.overriding,
            false,
            f64::NAN,
        )))
    }
    fn prescribed_time(&self) -> Option<f64> {
        self.prescribed_time
    }
}
