//! A user-defined safety filter in one file: a robust CBF-QP with a delay margin, registered
//! as `kind = "robust_cbf"` and run on the Ch. 4 bicycle (`scenarios/bicycle_obstacle.toml`)
//! next to the delay-free CBF-QP (4.9) and the γm filter (4.67).
//!
//! The filter acts on the measured state x(t), without a predictor, and keeps the shrunken
//! set h ≥ ε instead of h ≥ 0: ḧ + l1 ḣ + l0 (h − ε) ≥ 0, i.e. a(x) − l0 ε + b(x) u ≥ 0 in the
//! relative-degree-2 form (4.85)/(4.86). The margin ε grows with the largest input delay D:
//! ε = `margin_rate` · D (units of h per second of delay).
//!
//! Run: `cargo run --example robust_cbf -- OUT_DIR` (prints one line per filter).

use std::path::{Path, PathBuf};

use mjsafe::barrier::{BarrierForm, Constraint};
use mjsafe::embed;
use mjsafe::filter::qp::QpWorkspace;
use mjsafe::filter::{
    delay_free_qp, ChannelInput, ChannelOutcome, FilterContext, FilterError, ParamError, SafetyFilter,
};
use nalgebra::DVector;
use serde::{Deserialize, Serialize};

/// The scenario's `filter` table without `kind`.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RobustCbfParams {
    l0: f64,
    l1: f64,
    /// ε per second of the largest delay (units of h, m² for the obstacle barrier (4.81)).
    margin_rate: f64,
}

impl embed::Params for RobustCbfParams {
    fn validate(&self) -> Result<(), ParamError> {
        if !(self.margin_rate.is_finite() && self.margin_rate >= 0.0) {
            return Err(ParamError::new("filter.margin_rate", "expected a rate >= 0"));
        }
        mjsafe::filter::barrier_form(None, Some(self.l0), Some(self.l1)).map(|_| ())
    }
}

struct RobustCbf {
    form: BarrierForm,
    /// l0 ε: how much the constraint is tightened.
    tightening: f64,
    /// Scratch space: the tightened constraints, the QP's solution and its workspace (no
    /// allocation per tick once every barrier is known).
    tightened: Vec<Constraint>,
    input: DVector<f64>,
    qp: QpWorkspace,
}

fn build(p: &RobustCbfParams, ctx: &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> {
    let largest_delay = ctx
        .queues
        .iter()
        .map(|q| q.constant_delay())
        .try_fold(0.0_f64, |d, q| q.map(|q| d.max(q)))
        .ok_or_else(|| ParamError::new("delays", "robust_cbf needs constant delays"))?;
    let r = ctx.queues.len();
    Ok(Box::new(RobustCbf {
        form: mjsafe::filter::barrier_form(None, Some(p.l0), Some(p.l1))?,
        tightening: p.l0 * p.margin_rate * largest_delay,
        tightened: vec![Constraint::zeros(r); ctx.barriers.len()],
        input: DVector::zeros(r),
        qp: QpWorkspace::with_capacity(r, ctx.barriers.len()),
    }))
}

impl SafetyFilter for RobustCbf {
    fn barrier_form(&self) -> Option<BarrierForm> {
        Some(self.form)
    }
    fn uses_prediction(&self) -> bool {
        false
    }
    fn filter_channel(&mut self, input: &ChannelInput<'_>) -> Result<Option<ChannelOutcome>, FilterError> {
        if input.constraints.is_empty() {
            return Ok(None);
        }
        let count = input.constraints.len();
        for (c, t) in input.constraints.iter().zip(self.tightened.iter_mut()) {
            t.clone_from(c);
            t.a -= self.tightening;
        }
        let (active, infeasible, mu) = delay_free_qp(
            &self.tightened[..count],
            input.nominal,
            None,
            Some(&mut self.qp),
            &mut self.input,
        );
        Ok(Some(ChannelOutcome::new(
            self.input[input.channel],
            active,
            infeasible,
            mu,
        )))
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "robust_cbf_logs".into()));
    std::fs::create_dir_all(&out)?;
    // Its label (legends, `analyze --brief`) and description go into every run's metadata.
    embed::register(|r| {
        r.add_filter("robust_cbf", build)
            .label("robust CBF-QP (margin on h)")
            .description("the CBF-QP at the current state with a constant margin subtracted from h");
    })?;

    let scenarios = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let runs: [(&str, &str, &[&str]); 4] = [
        ("(4.9) delay-free CBF-QP", "bicycle_obstacle.toml", &[]),
        (
            "robust_cbf margin_rate = 20",
            "bicycle_obstacle.toml",
            &["filter={kind='robust_cbf', l0=4.0, l1=4.0, margin_rate=20.0}"],
        ),
        (
            "robust_cbf margin_rate = 60",
            "bicycle_obstacle.toml",
            &["filter={kind='robust_cbf', l0=4.0, l1=4.0, margin_rate=60.0}"],
        ),
        ("(4.67) gamma-m", "bicycle_obstacle_gamma_m.toml", &[]),
    ];
    println!("filter | collision | min h | min clearance (m)");
    for (i, (label, file, overrides)) in runs.iter().enumerate() {
        let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        let loaded = embed::load_scenario(&scenarios.join(file), &overrides)?;
        let outcome = embed::run_logged(&loaded, &out.join(format!("run{i}.mcap")), &mut [])?;
        let m = outcome.metrics.as_ref().expect("a logged run is analysed");
        println!(
            "{label} | {} | {:.2} | {:.3}",
            if m.collision().is_some() { "yes" } else { "no" },
            m.min_h().unwrap_or(f64::NAN),
            m.min_clearance().unwrap_or(f64::NAN),
        );
    }
    Ok(())
}
