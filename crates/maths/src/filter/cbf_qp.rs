//! `kind = "cbf_qp"`: the delay-free CBF-QP (4.6)–(4.11) over all channels, at x(t) ((2.16))
//! or, with `compensation = "predictor"`, at each channel's prediction p_i(t) ((2.26), and the
//! full-consistency filter (4.34)–(4.37) for distinct delays). With several barriers or input
//! limits it is solved numerically ([`crate::filter::qp`]).

use nalgebra::DVector;
use serde::{Deserialize, Serialize};

use crate::barrier::BarrierForm;
use crate::filter::qp::QpWorkspace;
use crate::filter::several::worst_shortfall;
use crate::filter::Params;
use crate::filter::{
    barrier_form, delay_free_qp, ChannelInput, ChannelOutcome, FilterContext, FilterError, LawInput, ParamError,
    SafetyFilter,
};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CbfQpParams {
    /// Relative degree 1: α(h) = alpha·h in ḣ + α(h) ≥ 0.
    #[serde(default)]
    pub alpha: Option<f64>,
    /// Relative degree 2: gains of ḧ + l1 ḣ + l0 h ≥ 0 (4.82).
    #[serde(default)]
    pub l0: Option<f64>,
    #[serde(default)]
    pub l1: Option<f64>,
    /// `none`: the filter acts on the current state ((2.16)); `predictor`: on the predicted
    /// state of each channel ((2.26), and (4.34) for distinct delays).
    #[serde(default)]
    pub compensation: Compensation,
    /// Actuator limits per channel; with them (or several barriers) the QP is solved
    /// numerically (`filter::qp`).
    #[serde(default)]
    pub input_limits: Option<InputLimits>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputLimits {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Compensation {
    #[default]
    None,
    Predictor,
}

impl Params for CbfQpParams {
    fn validate(&self) -> Result<(), ParamError> {
        barrier_form(self.alpha, self.l0, self.l1).map(|_| ())
    }

    /// At the predictions, the filter is (4.34).
    fn label(&self, kind_label: &str) -> String {
        match self.compensation {
            Compensation::Predictor => "predictor CBF-QP (4.34)".to_string(),
            Compensation::None => kind_label.to_string(),
        }
    }
}

/// The CBF-QP filter; `input` is the QP's solution for all channels and `qp` the numerical
/// QP's workspace (scratch space).
pub struct CbfQp {
    form: BarrierForm,
    predicted: bool,
    limits: Option<(Vec<f64>, Vec<f64>)>,
    input: DVector<f64>,
    qp: QpWorkspace,
    /// Per channel, the largest |u_j| of the QP solutions since the last
    /// [`SafetyFilter::take_planned_inputs`].
    largest_planned: Vec<f64>,
}

/// largest_j ← max(largest_j, |u_j|) (NaN stays NaN: no bound holds).
fn note_planned(largest: &mut [f64], u: &DVector<f64>) {
    for (slot, value) in largest.iter_mut().zip(u.iter()) {
        *slot = if value.is_nan() || slot.is_nan() {
            f64::NAN
        } else {
            slot.max(value.abs())
        };
    }
}

/// The filter of a `kind = "cbf_qp"` table (limits checked against the channels).
pub fn build(p: &CbfQpParams, ctx: &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> {
    let r = ctx.queues.len();
    let limits = match &p.input_limits {
        Some(l) => {
            let ordered = l
                .lower
                .iter()
                .zip(&l.upper)
                .all(|(lo, hi)| !lo.is_nan() && !hi.is_nan() && lo <= hi);
            if l.lower.len() != r || l.upper.len() != r || !ordered {
                return Err(ParamError::new(
                    "filter.input_limits",
                    format!("expected lower <= upper, {r} values each (one per channel)"),
                ));
            }
            Some((l.lower.clone(), l.upper.clone()))
        }
        None => None,
    };
    let form = barrier_form(p.alpha, p.l0, p.l1)?;
    Ok(Box::new(CbfQp {
        form,
        predicted: p.compensation == Compensation::Predictor,
        limits,
        input: DVector::zeros(r),
        qp: QpWorkspace::with_capacity(r, ctx.most_rows(form)),
        largest_planned: vec![0.0; r],
    }))
}

impl SafetyFilter for CbfQp {
    fn barrier_form(&self) -> Option<BarrierForm> {
        Some(self.form)
    }
    fn uses_prediction(&self) -> bool {
        self.predicted
    }
    fn filter_channel(&mut self, input: &ChannelInput<'_>) -> Result<Option<ChannelOutcome>, FilterError> {
        if input.constraints.is_empty() {
            return Ok(None);
        }
        let limits = self.limits.as_ref().map(|(lo, hi)| (lo.as_slice(), hi.as_slice()));
        let (active, infeasible, mu) = delay_free_qp(
            input.constraints,
            input.nominal,
            limits,
            Some(&mut self.qp),
            &mut self.input,
        );
        note_planned(&mut self.largest_planned, &self.input);
        let mut outcome = ChannelOutcome::new(self.input[input.channel], active, infeasible, mu);
        if infeasible {
            (outcome.unmet, outcome.shortfall) = worst_shortfall(input.constraints, &self.input);
        }
        Ok(Some(outcome))
    }
    /// What `filter_channel` issues: component j of the same QP (with its limits) at z.
    fn issued_law(&mut self, input: &LawInput<'_>, u: &mut DVector<f64>) -> Result<(), FilterError> {
        let limits = self.limits.as_ref().map(|(lo, hi)| (lo.as_slice(), hi.as_slice()));
        delay_free_qp(input.constraints, input.nominal, limits, Some(&mut self.qp), u);
        note_planned(&mut self.largest_planned, u);
        Ok(())
    }

    /// The whole input vector of every QP solved (one QP over every channel).
    fn take_planned_inputs(&mut self, largest: &mut [f64]) -> bool {
        for (out, planned) in largest.iter_mut().zip(&mut self.largest_planned) {
            *out = std::mem::take(planned);
        }
        true
    }
}
