//! One control tick's predictions for the bicycle of scenarios/bicycle_obstacle_gamma_m.toml
//! (D1 = 0.2 s steering, D2 = 1.5 s acceleration, control period 0.01 s, plant step 0.002 s):
//! the recursive predictors (4.23)/(4.24), with the delay-free safe law (LQR path tracking +
//! closed-form CBF-QP on the circular obstacle, as the episode's κ_j) predicting the steering
//! commands not yet issued inside the acceleration channel's window. One entry per predictor
//! RK4 step, so the saving of a coarser step is visible; and one tick that continues the
//! previous tick's chain (`control.chain_tolerance`), at the default step.
//!
//! `cargo bench --no-default-features --bench predictor`

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BatchSize, BenchmarkId, Criterion};
use nalgebra::DVector;

use mjsafe::barrier::{Barrier, BarrierForm, Constraint, LieWorkspace};
use mjsafe::delay::DelayQueue;
use mjsafe::dynamics::{BicycleModel, Dynamics};
use mjsafe::filter;
use mjsafe::nominal::BicyclePathLqr;
use mjsafe::predictor::{self, PredictorContext, PredictorWorkspace};

/// Plant step of models/bicycle.xml.
const TIMESTEP: f64 = 0.002;
const CONTROL_PERIOD: f64 = 0.01;
/// The tick at which the predictions are made.
const TICK: f64 = 2.0;

/// Steering and acceleration queues with 2 s of commands issued every control period.
fn filled_queues() -> Vec<DelayQueue> {
    let mut queues = vec![
        DelayQueue::new("steering", 0.2, 0.0, TIMESTEP).expect("valid delay"),
        DelayQueue::new("acceleration", 1.5, 0.0, TIMESTEP).expect("valid delay"),
    ];
    let ticks = (TICK / CONTROL_PERIOD).round() as usize;
    for k in 0..ticks {
        let t = k as f64 * CONTROL_PERIOD;
        queues[0].push(t, 0.05 * (0.7 * t).sin()).expect("increasing times");
        queues[1].push(t, 0.2 * (0.3 * t).cos()).expect("increasing times");
    }
    queues
}

/// κ: u0 = LQR(z), then the closed-form CBF-QP (4.9) at z (the episode's delay-free law).
fn delay_free_law<'a>(
    model: &'a BicycleModel,
    lqr: &'a BicyclePathLqr,
    barrier: &'a Barrier,
    form: BarrierForm,
) -> impl FnMut(f64, &[f64], &[usize], &mut [f64]) + 'a {
    let mut lie = LieWorkspace::new(model);
    let mut constraint = Constraint::zeros(model.input_dim());
    let mut input = DVector::zeros(model.input_dim());
    move |_t: f64, z: &[f64], _free: &[usize], u: &mut [f64]| {
        lqr.input_into(z, input.as_mut_slice());
        lie.constraint_into(barrier, form, model, z, &mut constraint);
        filter::cbf_qp_in_place(&constraint, &mut input);
        u.copy_from_slice(input.as_slice());
    }
}

fn predictions(c: &mut Criterion) {
    let model = BicycleModel::new(6.0);
    let queues = filled_queues();
    let structure = predictor::structure(&queues, CONTROL_PERIOD).expect("distinct constant delays");
    // The scenario's nominal (path_lqr, reference speed 3, default Q = I, R = I) and filter
    // barrier (4.81): obstacle at (-3, 0.5), r = hull 3 + obstacle 3, l0 = l1 = 4.
    let lqr = BicyclePathLqr::new([0.0, 0.0], 0.0, 3.0, 6.0, [1.0, 1.0, 1.0], [1.0, 1.0]).expect("LQR gain");
    let barrier = Barrier::circular_obstacle("obstacle_0", [0, 1], [-3.0, 0.5], 6.0);
    let form = BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.0 };
    // x(t) at t = 2 s on the way to the obstacle.
    let x = [-14.0, 0.1, 0.02, 3.0];

    let mut group = c.benchmark_group("predictor/recursive_tick");
    group
        .sample_size(30)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    for step in [0.01, 0.02, 0.05, 0.1] {
        let context = PredictorContext {
            model: &model,
            queues: &queues,
            timestep: step,
            control_period: CONTROL_PERIOD,
        };
        let mut workspace = PredictorWorkspace::new(model.state_dim(), model.input_dim());
        let mut out = workspace.predictions();
        let mut law = delay_free_law(&model, &lqr, &barrier, form);
        group.bench_function(BenchmarkId::new("step", step), |b| {
            b.iter(|| {
                context
                    .predict_into(
                        &structure,
                        black_box(TICK),
                        black_box(&x),
                        &mut law,
                        &mut workspace,
                        &mut out,
                    )
                    .expect("history covers the windows");
                black_box(&out);
            })
        });
    }
    group.finish();

    // A tick that continues the chain of the tick one period earlier. The tolerance is
    // infinite so that the reuse path runs whatever the synthetic history (its cost does not
    // depend on the mismatch); each iteration starts from a copy of the earlier tick's
    // workspace (the copy is not timed).
    let context = PredictorContext {
        model: &model,
        queues: &queues,
        timestep: CONTROL_PERIOD,
        control_period: CONTROL_PERIOD,
    };
    let mut previous = PredictorWorkspace::new(model.state_dim(), model.input_dim());
    previous.set_chain_reuse(Some(f64::INFINITY));
    let mut out = previous.predictions();
    let mut law = delay_free_law(&model, &lqr, &barrier, form);
    context
        .predict_into(&structure, TICK - CONTROL_PERIOD, &x, &mut law, &mut previous, &mut out)
        .expect("history covers the windows");
    let mut group = c.benchmark_group("predictor/recursive_tick_reusing_chain");
    group
        .sample_size(30)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    group.bench_function("step/0.01", |b| {
        b.iter_batched_ref(
            || previous.clone(),
            |workspace| {
                context
                    .predict_into(
                        &structure,
                        black_box(TICK),
                        black_box(&x),
                        &mut law,
                        workspace,
                        &mut out,
                    )
                    .expect("history covers the windows");
                assert!(out[1].reused_chain);
                black_box(&out);
            },
            BatchSize::SmallInput,
        )
    });
    group.finish();
}

criterion_group!(benches, predictions);
criterion_main!(benches);
