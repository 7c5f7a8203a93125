//! `kind = "clf_cbf_qp"`: the Ch. 3 constrained stabiliser for linear systems with distinct
//! input delays: channel i takes component i of the γm CLF-CBF QP (3.27) solved at its
//! recursive prediction p_i(t) ((3.33), predictors (3.3)/(3.4)), with buffer η (3.25) and a
//! disk barrier. It stabilises through its own CLF: the nominal must be zero.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::barrier::{BarrierForm, Shape};
use crate::filter::linear_delays::{self, ConstrainedStabilizer, KappaLbWorkspace, QpCase};
use crate::filter::Params;
use crate::filter::{ChannelInput, ChannelOutcome, FilterContext, FilterError, LawInput, ParamError, SafetyFilter};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClfCbfQpParams {
    /// CLF V = xᵀPx with P = p·I, decay rate Q = q·I (Definition 3.1).
    pub p: f64,
    pub q: f64,
    /// α_h(H) = l0·H (3.40).
    pub l0: f64,
    /// Buffer η: a number, or absent to use the bound (3.25) for `omega_bar`.
    #[serde(default)]
    pub eta: Option<f64>,
    /// ω̄ of (3.24) for the bound (3.25) (default 0: no disturbance).
    #[serde(default)]
    pub omega_bar: f64,
    /// QP-LB penalty m and γ of γ_f (3.28).
    pub m: f64,
    pub gamma: f64,
}

impl Params for ClfCbfQpParams {
    fn validate(&self) -> Result<(), ParamError> {
        if !(self.l0.is_finite() && self.l0 > 0.0) {
            return Err(ParamError::new(
                "filter.l0",
                format!("expected l0 > 0, found {}", self.l0),
            ));
        }
        if !(self.m.is_finite() && self.m >= 1.0) {
            return Err(ParamError::new(
                "filter.m",
                format!("expected m >= 1, found {}", self.m),
            ));
        }
        if !(self.gamma.is_finite() && self.gamma >= 1.0) {
            return Err(ParamError::new(
                "filter.gamma",
                format!("expected gamma >= 1, found {}", self.gamma),
            ));
        }
        Ok(())
    }
}

/// The Ch. 3 constrained stabiliser κ_LB (3.33) at each channel's prediction.
pub struct ClfCbfQp {
    stabilizer: ConstrainedStabilizer,
    /// The evaluation state as a vector and κ_LB's workspace (scratch space).
    state: DVector<f64>,
    kappa: KappaLbWorkspace,
}

/// The design from the scenario: the linear model (A = ∂f/∂x, B = G), the channel delays,
/// V = p xᵀx, the disk barrier (the scenario's only barrier: a ball, outside, over the whole
/// state) and η (given, or the bound (3.25) for ω̄ with B_ω = I).
pub fn build(spec: &ClfCbfQpParams, ctx: &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> {
    if ctx.vehicle_kind != "linear" {
        return Err(ParamError::new(
            "filter.kind",
            "clf_cbf_qp (Ch. 3) needs vehicle.kind = \"linear\"",
        ));
    }
    if !ctx
        .nominal
        .constant_input()
        .is_some_and(|u| u.iter().all(|v| *v == 0.0))
    {
        return Err(ParamError::new(
            "nominal",
            "clf_cbf_qp stabilises through its CLF (3.27): expected a zero constant nominal",
        ));
    }
    let err = |key: &str, e: linear_delays::LinearDelaysError| ParamError::new(key, e.to_string());
    let model = ctx.model.as_ref();
    let n = model.state_dim();
    let origin = DVector::zeros(n);
    let (a, b) = (model.drift_jacobian(&origin), model.input_matrix(&origin));
    let system = linear_delays::LinearSystem::new(a, b).map_err(|e| err("vehicle.a", e))?;
    let delays: Vec<f64> = ctx
        .queues
        .iter()
        .map(|q| q.constant_delay().unwrap_or(f64::NAN))
        .collect();
    let clf = linear_delays::QuadraticClf::new(DMatrix::identity(n, n) * spec.p, DMatrix::identity(n, n) * spec.q)
        .map_err(|e| err("filter.p", e))?;
    let disk = match ctx.barriers {
        [crate::barrier::Barrier {
            shape:
                Shape::Ball {
                    indices,
                    centre,
                    radius,
                    inside: false,
                },
            ..
        }] if indices.iter().copied().eq(0..n) => {
            linear_delays::DiskBarrier::new(DVector::from_column_slice(centre), *radius)
                .map_err(|e| err("barriers[0]", e))?
        }
        _ => {
            return Err(ParamError::new(
                "barriers",
                "clf_cbf_qp needs exactly one barrier: kind = \"ball\", inside = false, over every state index",
            ))
        }
    };
    let qp = linear_delays::GammaM::new(spec.m, spec.gamma).map_err(|e| err("filter.m", e))?;
    let build = |eta: f64| {
        ConstrainedStabilizer::new(
            system.clone(),
            delays.clone(),
            clf.clone(),
            disk.clone(),
            spec.l0,
            eta,
            qp,
        )
        .map_err(|e| err("filter", e))
    };
    let eta = match spec.eta {
        Some(eta) => eta,
        None => build(0.0)?
            .robust_buffer_bound(&DMatrix::identity(n, n), spec.omega_bar)
            .map_err(|e| err("filter.omega_bar", e))?,
    };
    let stabilizer = build(eta)?;
    Ok(Box::new(ClfCbfQp {
        kappa: stabilizer.workspace(),
        stabilizer,
        state: DVector::zeros(n),
    }))
}

impl SafetyFilter for ClfCbfQp {
    fn barrier_form(&self) -> Option<BarrierForm> {
        // Its own disk barrier (3.40), not the scenario's constraint data.
        None
    }
    fn uses_prediction(&self) -> bool {
        true
    }
    fn filter_channel(&mut self, input: &ChannelInput<'_>) -> Result<Option<ChannelOutcome>, FilterError> {
        // (3.33): channel i takes component i of QP-LB solved at p_i(t).
        self.state.copy_from_slice(input.state);
        let (case, _, infeasible) = self.stabilizer.kappa_lb_into(&self.state, &mut self.kappa);
        Ok(Some(ChannelOutcome::new(
            self.kappa.input[input.channel],
            case != QpCase::A,
            infeasible,
            f64::NAN,
        )))
    }
    /// What `filter_channel` issues: component j of QP-LB (3.33) at z.
    fn issued_law(&mut self, input: &LawInput<'_>, u: &mut DVector<f64>) -> Result<(), FilterError> {
        self.state.copy_from_slice(input.state);
        self.stabilizer.kappa_lb_into(&self.state, &mut self.kappa);
        u.copy_from(&self.kappa.input);
        Ok(())
    }
}
