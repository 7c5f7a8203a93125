//! Each safety filter per call, at states where its constraint is active (the correction is
//! computed, not skipped), plus the constraint evaluation a(x), b(x) they all start from:
//!
//! - `constraint/relative_degree_2`: Lie derivatives and (4.85)/(4.86) for the obstacle (4.81);
//! - `cbf_qp`, `cbf_qp_in_place`: closed-form delay-free CBF-QP (4.9) (allocating / in place);
//! - `fixed_channel` (4.44)–(4.47) and `gamma_m` (4.60)–(4.68) for the steering channel;
//! - `cbf_qp_multi`: the active-set QP with two obstacles and input limits (bicycle_two_obstacles),
//!   with a fresh workspace and with a kept one;
//! - `clf_cbf_qp/kappa_lb`: Ch. 3 γm CLF-CBF QP (3.27) of linear_distinct_delays.toml;
//! - `ptsf`, `esf`: Ch. 5 filters of red_light.toml (PTSf (5.27), ESf (5.89) with ρ = 0.6).
//!
//! `cargo bench --no-default-features --bench filters`

use std::hint::black_box;
use std::time::Duration;

use criterion::measurement::WallTime;
use criterion::{criterion_group, criterion_main, BenchmarkGroup, Criterion};
use nalgebra::{DMatrix, DVector, Vector2};

use mjsafe::barrier::{self, Barrier, BarrierForm, Constraint, LieWorkspace};
use mjsafe::dynamics::BicycleModel;
use mjsafe::filter::linear_delays::{ConstrainedStabilizer, DiskBarrier, GammaM, LinearSystem, QuadraticClf};
use mjsafe::filter::prescribed_time::{BlowUp, ContinuityRamp, EsfFilter, PtsfFilter, RedLightNominal};
use mjsafe::filter::{self, qp};
use mjsafe::nominal::BicyclePathLqr;

const FORM: BarrierForm = BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.0 };

fn configure<'a>(c: &'a mut Criterion, name: &str) -> BenchmarkGroup<'a, WallTime> {
    let mut group = c.benchmark_group(name);
    group
        .sample_size(30)
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(1));
    group
}

/// The bicycle filters of Ch. 4 (bicycle_obstacle*.toml): obstacle at (-3, 0.5), r = 6.
fn bicycle_filters(c: &mut Criterion) {
    let model = BicycleModel::new(6.0);
    let barrier = Barrier::circular_obstacle("o", [0, 1], [-3.0, 0.5], 6.0);
    let lqr = BicyclePathLqr::new([0.0, 0.0], 0.0, 3.0, 6.0, [1.0, 1.0, 1.0], [1.0, 1.0]).expect("LQR gain");
    // 7 m short of the obstacle's centre at 3 m/s: the constraint is violated by the nominal.
    let x = [-10.0, 0.2, 0.0, 3.0];
    let mut u0 = DVector::zeros(2);
    lqr.input_into(&x, u0.as_mut_slice());
    let mut lie = LieWorkspace::new(&model);
    let mut constraint = Constraint::zeros(2);
    lie.constraint_into(&barrier, FORM, &model, &x, &mut constraint);
    assert!(
        constraint.value(&u0) < 0.0,
        "the benchmark state should make the filters act"
    );
    // ω: the acceleration already issued that reaches the plant together with u_1.
    let omega = DVector::from_column_slice(&[0.0, 0.1]);

    let mut group = configure(c, "filters");
    group.bench_function("constraint/relative_degree_2", |b| {
        b.iter(|| {
            lie.constraint_into(&barrier, FORM, &model, black_box(&x), &mut constraint);
            black_box(&constraint);
        })
    });
    group.bench_function("cbf_qp", |b| {
        b.iter(|| filter::cbf_qp_closed_form(black_box(&constraint), black_box(&u0)))
    });
    let mut input = u0.clone();
    group.bench_function("cbf_qp_in_place", |b| {
        b.iter(|| {
            input.copy_from(black_box(&u0));
            filter::cbf_qp_in_place(black_box(&constraint), &mut input)
        })
    });
    group.bench_function("fixed_channel", |b| {
        b.iter(|| filter::fixed_channel_one_barrier(black_box(&constraint), black_box(&u0), black_box(&omega), 0, 1))
    });
    group.bench_function("gamma_m", |b| {
        b.iter(|| {
            filter::gamma_m_one_barrier(
                black_box(&constraint),
                black_box(&u0),
                black_box(&omega),
                0,
                0,
                50.0,
                51.0 / 50.0,
            )
        })
    });

    // bicycle_two_obstacles.toml: two cones (r = hull 3 + 2), limits [-1, 1] × [-3, 2].
    let cones = [
        Barrier::circular_obstacle("cone_left", [0, 1], [0.0, 1.5], 5.0),
        Barrier::circular_obstacle("cone_right", [0, 1], [16.0, -1.5], 5.0),
    ];
    let x = DVector::from_column_slice(&[-8.0, 0.5, 0.1, 3.0]);
    let constraints: Vec<Constraint> = cones.iter().map(|b| barrier::constraint(b, FORM, &model, &x)).collect();
    let mut u0 = DVector::zeros(2);
    lqr.input_into(x.as_slice(), u0.as_mut_slice());
    let (lower, upper) = ([-1.0, -3.0], [1.0, 2.0]);
    let outcome = qp::cbf_qp_multi(&constraints, &u0, Some((&lower, &upper)));
    assert!(
        outcome.active && !outcome.infeasible,
        "the QP should be active and feasible: {outcome:?}"
    );
    group.bench_function("cbf_qp_multi/2_barriers_limits", |b| {
        b.iter(|| qp::cbf_qp_multi(black_box(&constraints), black_box(&u0), Some((&lower, &upper))))
    });
    // As the filter solves it: one workspace kept across ticks.
    let mut workspace = qp::QpWorkspace::with_capacity(2, 2);
    let mut u = DVector::zeros(2);
    group.bench_function("cbf_qp_multi/2_barriers_limits_workspace", |b| {
        b.iter(|| workspace.solve(black_box(&constraints), black_box(&u0), Some((&lower, &upper)), &mut u))
    });
    group.finish();
}

/// Ch. 3: the design of scenarios/linear_distinct_delays.toml, built as the episode builds it
/// (Table 3.1: P = 0.4 I, Q = 0.144 I, disk (6, 0) radius 5, l0 = 2, η = 8.06, m = 8, γ = 2.25).
fn linear_delays(c: &mut Criterion) {
    let system = LinearSystem::new(
        DMatrix::from_row_slice(2, 2, &[-1.0, 0.5, -0.5, -1.0]),
        DMatrix::identity(2, 2),
    )
    .expect("valid system");
    let clf = QuadraticClf::new(DMatrix::identity(2, 2) * 0.4, DMatrix::identity(2, 2) * 0.144).expect("valid CLF");
    let disk = DiskBarrier::new(DVector::from_column_slice(&[6.0, 0.0]), 5.0).expect("valid disk");
    let stabilizer = ConstrainedStabilizer::new(
        system,
        vec![0.2, 0.8],
        clf,
        disk,
        2.0,
        8.06,
        GammaM::new(8.0, 2.25).expect("valid m, gamma"),
    )
    .expect("valid design");
    // Next to the disk on the way to the origin: both CLF and CBF constraints matter.
    let x = DVector::from_column_slice(&[12.0, 4.5]);

    let mut group = configure(c, "filters");
    group.bench_function("clf_cbf_qp/kappa_lb", |b| b.iter(|| stabilizer.kappa_lb(black_box(&x))));
    group.finish();
}

/// Ch. 5: the filters of scenarios/red_light.toml (T = 4, margin 0.1, μ2 clip 1000, ramp m = 2,
/// T̄ = 0.5, gains from x(0) = (-4, 2)), with the red-light nominal (5.20).
fn prescribed_time(c: &mut Criterion) {
    let blow_up = BlowUp::new(0.0, 4.0)
        .and_then(|b| b.with_mu2_clip(1000.0))
        .expect("valid horizon");
    let ramp = ContinuityRamp::new(2, 0.5, 1e-9).expect("valid ramp");
    let ptsf = PtsfFilter::from_initial_state(blow_up, &DVector::from_column_slice(&[-4.0, 2.0]), 0.1, ramp)
        .expect("gains from x(0)");
    let esf = EsfFilter::new(2, 0.6).expect("valid rate");
    let nominal = RedLightNominal {
        position_gain: 4.0,
        velocity_gain: 4.0,
        amplitude: 1.0,
        offset: 0.8,
        frequency: std::f64::consts::FRAC_PI_2,
    };
    let (t, z) = (2.5, DVector::from_column_slice(&[-0.6, 0.5]));
    let u_nom = nominal.control(t, &Vector2::new(z[0], z[1]));

    let mut group = configure(c, "filters");
    group.bench_function("ptsf", |b| {
        b.iter(|| {
            ptsf.control(black_box(t), black_box(&z), black_box(u_nom), None)
                .expect("inside the horizon")
        })
    });
    group.bench_function("esf", |b| {
        b.iter(|| esf.control(black_box(&z), black_box(u_nom)).expect("order 2"))
    });
    group.finish();
}

criterion_group!(benches, bicycle_filters, linear_delays, prescribed_time);
criterion_main!(benches);
