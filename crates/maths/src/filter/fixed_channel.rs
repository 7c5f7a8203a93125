//! `kind = "fixed_channel"`: the fixed-channel robust filter (4.39)–(4.47) at each channel's
//! prediction; the first φ channels (4.41) suffice everywhere. Several barriers: (4.42) with
//! one constraint per barrier ([`ChannelQp`], docs/several-barriers.md).

use nalgebra::DVector;
use serde::{Deserialize, Serialize};

use crate::barrier::{self, BarrierForm};
use crate::filter::several::ChannelQp;
use crate::filter::Params;
use crate::filter::{
    barrier_form, box_grid, minimal_channels, ChannelInput, ChannelOutcome, FilterContext, FilterError, LawInput,
    ParamError, SafetyFilter,
};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FixedChannelParams {
    #[serde(default)]
    pub alpha: Option<f64>,
    #[serde(default)]
    pub l0: Option<f64>,
    #[serde(default)]
    pub l1: Option<f64>,
    /// φ (4.41): how many of the shortest-delayed channels suffice everywhere. Declared here
    /// (verified on `phi_box` if given) or, if absent, found on `phi_box`.
    #[serde(default)]
    pub phi: Option<usize>,
    #[serde(default)]
    pub phi_box: Option<StateBox>,
}

/// An axis-aligned box of states, sampled on a grid to verify or find φ (4.40).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateBox {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    /// Grid points per axis (default 9).
    #[serde(default = "default_box_points")]
    pub points: usize,
}

/// Most grid points of `phi_box` (points^n): each evaluates the barrier's input row.
pub const MAX_PHI_BOX_POINTS: usize = 1_000_000;

fn default_box_points() -> usize {
    9
}

impl Params for FixedChannelParams {
    fn validate(&self) -> Result<(), ParamError> {
        barrier_form(self.alpha, self.l0, self.l1)?;
        if self.phi == Some(0) {
            return Err(ParamError::new(
                "filter.phi",
                "expected phi >= 1 (a number of input channels, (4.41))",
            ));
        }
        if self.phi.is_none() && self.phi_box.is_none() {
            return Err(ParamError::new(
                "filter.phi",
                "declare phi (4.41) or give filter.phi_box to find it",
            ));
        }
        if let Some(b) = &self.phi_box {
            let ok = b.lower.len() == b.upper.len()
                && b.points >= 2
                && b.lower
                    .iter()
                    .zip(&b.upper)
                    .all(|(l, u)| l.is_finite() && u.is_finite() && l <= u);
            if !ok {
                return Err(ParamError::new(
                    "filter.phi_box",
                    "expected lower <= upper of equal lengths, finite, and points >= 2",
                ));
            }
            let total = u32::try_from(b.lower.len())
                .ok()
                .and_then(|n| b.points.checked_pow(n))
                .filter(|&total| total <= MAX_PHI_BOX_POINTS);
            if total.is_none() {
                return Err(ParamError::new(
                    "filter.phi_box.points",
                    format!(
                        "{} points per axis over {} axes is more than {MAX_PHI_BOX_POINTS} grid points (expected points^{} <= {MAX_PHI_BOX_POINTS})",
                        b.points,
                        b.lower.len(),
                        b.lower.len()
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// The fixed-channel filter (4.44) with its φ.
pub struct FixedChannel {
    form: BarrierForm,
    phi: usize,
    /// ω (4.45), scratch space.
    omega: DVector<f64>,
    /// (4.42) with every barrier.
    qp: ChannelQp,
}

/// The filter of a `kind = "fixed_channel"` table: φ declared or found on `phi_box`
/// (verified there if both; with several barriers, the largest φ of any of them), constant
/// delays in channel order.
pub fn build(p: &FixedChannelParams, ctx: &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> {
    let form = barrier_form(p.alpha, p.l0, p.l1)?;
    ctx.ordered_constant_delays()?;
    let r = ctx.queues.len();
    let model = ctx.model.as_ref();
    if ctx.barriers.is_empty() {
        return Err(ParamError::new("filter", "a filter needs a barrier or an obstacle"));
    }
    let phi = match (&p.phi_box, p.phi) {
        (Some(b), declared) => {
            if b.lower.len() != model.state_dim() {
                return Err(ParamError::new(
                    "filter.phi_box",
                    format!("expected {} bounds per side", model.state_dim()),
                ));
            }
            let found = ctx
                .barriers
                .iter()
                .map(|barrier| {
                    let b_at = |x: &DVector<f64>| barrier::constraint(barrier, form, model, x).b;
                    minimal_channels(box_grid(&b.lower, &b.upper, b.points), b_at)
                })
                .max()
                .unwrap_or(r);
            match declared {
                Some(phi) if phi < found => {
                    return Err(ParamError::new("filter.phi", format!("phi = {phi} is too small: on phi_box the first {phi} channels cannot act on the barrier everywhere (the box needs {found})")));
                }
                Some(phi) => phi,
                None => found,
            }
        }
        (None, Some(phi)) => phi,
        (None, None) => unreachable!("validated"),
    };
    if phi > r {
        return Err(ParamError::new(
            "filter.phi",
            format!("expected at most {r} channels, found {phi}"),
        ));
    }
    Ok(Box::new(FixedChannel {
        form,
        phi,
        omega: DVector::zeros(r),
        qp: ChannelQp::fixed_channel(r, ctx.most_rows(form)),
    }))
}

impl SafetyFilter for FixedChannel {
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
        let s = self.phi.max(input.channel + 1);
        input.later_commands(s, &mut self.omega)?;
        self.qp.key_rows(input.barriers.rows);
        Ok(Some(self.qp.fixed_channel_decision(
            input.constraints,
            input.nominal,
            &self.omega,
            input.channel,
            s,
        )))
    }

    /// (4.44) itself at z: u_j = u0_j + ū_j (4.46) with s = max{φ, j} (4.43) and ω (4.45) the
    /// later channels' commands in `u`.
    fn take_planned_inputs(&mut self, largest: &mut [f64]) -> bool {
        self.qp.take_planned(largest);
        true
    }

    fn issued_law(&mut self, input: &LawInput<'_>, u: &mut DVector<f64>) -> Result<(), FilterError> {
        let FixedChannel { phi, omega, qp, .. } = self;
        qp.key_rows(input.barriers.rows);
        input.per_free_channel(u, omega, |constraints, omega, j| {
            qp.fixed_channel_input(constraints, input.nominal, omega, j, (*phi).max(j + 1))
        });
        Ok(())
    }
}
