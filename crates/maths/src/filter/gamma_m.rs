//! `kind = "gamma_m"`: the variable-channel γm filter (4.60)–(4.68) at each channel's
//! prediction. Several barriers: QP_k (4.60) with one constraint per barrier ([`ChannelQp`],
//! docs/several-barriers.md).

use nalgebra::DVector;
use serde::{Deserialize, Serialize};

use crate::barrier::BarrierForm;
use crate::filter::several::ChannelQp;
use crate::filter::Params;
use crate::filter::{
    barrier_form, ChannelInput, ChannelOutcome, FilterContext, FilterError, LawInput, ParamError, SafetyFilter,
};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GammaMParams {
    #[serde(default)]
    pub alpha: Option<f64>,
    #[serde(default)]
    pub l0: Option<f64>,
    #[serde(default)]
    pub l1: Option<f64>,
    /// Slack penalty m ≥ 1 (4.60).
    pub m: f64,
    /// γ ≥ 1 of γ_f (4.61); default (m + 1)/m (Remark 4.5).
    #[serde(default)]
    pub gamma: Option<f64>,
}

impl Params for GammaMParams {
    fn label(&self, kind_label: &str) -> String {
        format!("{kind_label}, m = {}", self.m)
    }

    fn validate(&self) -> Result<(), ParamError> {
        barrier_form(self.alpha, self.l0, self.l1)?;
        if !(self.m.is_finite() && self.m >= 1.0) {
            return Err(ParamError::new(
                "filter.m",
                format!("expected m >= 1 (4.60), found {}", self.m),
            ));
        }
        if let Some(gamma) = self.gamma {
            if !(gamma.is_finite() && gamma >= 1.0) {
                return Err(ParamError::new(
                    "filter.gamma",
                    format!("expected gamma >= 1 (4.61), found {gamma}"),
                ));
            }
        }
        Ok(())
    }
}

/// The γm filter (4.67) with its gains.
pub struct GammaM {
    form: BarrierForm,
    m: f64,
    gamma: f64,
    /// ω (4.62), scratch space.
    omega: DVector<f64>,
    /// D_j per channel (constant, non-decreasing).
    delays: Vec<f64>,
    /// QP_k (4.60) with every barrier.
    qp: ChannelQp,
}

/// k (4.68): the last channel with the same delay as channel i.
fn last_of_equal_delay(delays: &[f64], i: usize) -> usize {
    (i..delays.len())
        .take_while(|&j| delays[j] == delays[i])
        .last()
        .unwrap_or(i)
}

/// The filter of a `kind = "gamma_m"` table: constant delays in channel order.
pub fn build(p: &GammaMParams, ctx: &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> {
    let form = barrier_form(p.alpha, p.l0, p.l1)?;
    ctx.ordered_constant_delays()?;
    Ok(Box::new(GammaM {
        form,
        m: p.m,
        gamma: p.gamma.unwrap_or((p.m + 1.0) / p.m),
        omega: DVector::zeros(ctx.queues.len()),
        delays: ctx
            .queues
            .iter()
            .map(|q| q.constant_delay().unwrap_or(f64::NAN))
            .collect(),
        qp: ChannelQp::gamma_m(ctx.queues.len(), ctx.most_rows(form)),
    }))
}

impl SafetyFilter for GammaM {
    fn barrier_form(&self) -> Option<BarrierForm> {
        Some(self.form)
    }
    fn uses_prediction(&self) -> bool {
        true
    }
    fn filter_channel(&mut self, input: &ChannelInput<'_>) -> Result<Option<ChannelOutcome>, FilterError> {
        if input.constraints.is_empty() {
            return Ok(None);
        }
        // k (4.68): the last channel with the same delay as i.
        let i = input.channel;
        let k = last_of_equal_delay(&self.delays, i);
        input.later_commands(k + 1, &mut self.omega)?;
        self.qp.key_rows(input.barriers.rows);
        Ok(Some(self.qp.gamma_m_decision(
            input.constraints,
            input.nominal,
            &self.omega,
            i,
            k,
            self.m,
            self.gamma,
        )))
    }

    /// (4.67) itself at z: u_j = u0_j + ū_j of QP_k (4.62) with ω (4.64) the later channels'
    /// commands in `u` (k (4.68): the channels in `free` share one delay, so one k).
    fn take_planned_inputs(&mut self, largest: &mut [f64]) -> bool {
        self.qp.take_planned(largest);
        true
    }

    fn issued_law(&mut self, input: &LawInput<'_>, u: &mut DVector<f64>) -> Result<(), FilterError> {
        let GammaM {
            m,
            gamma,
            omega,
            delays,
            qp,
            ..
        } = self;
        qp.key_rows(input.barriers.rows);
        input.per_free_channel(u, omega, |constraints, omega, j| {
            let k = last_of_equal_delay(delays, j);
            qp.gamma_m_input(constraints, input.nominal, omega, j, k, *m, *gamma)
        });
        Ok(())
    }
}
