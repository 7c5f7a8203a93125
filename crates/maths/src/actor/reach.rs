//! Reach: when a road user's barrier rows cannot matter (pure maths; docs/actors.md, "Out of
//! reach"). A road user out of reach of the ego at an evaluation state costs no barrier row and
//! enters no QP; this module decides it from bounds, without forming the rows.
//!
//! Every row of a pair of circles (an ego point q with the input reaching it, a road user's
//! circle o, their radii summing to r) has, with d = q − o, h = ‖d‖² − r², q̇ = q̇₀ + K u and
//! the input's part of q̈ at relative degree 2 J u (J = ∂q̇₀/∂x G):
//! - relative degree 2 (4.85)/(4.86) with the motion terms of [`super::add_point_motion_terms`]:
//!   a = 2‖q̇₀ − ȯ‖² + 2 d·(q̈₀ − ö) + 2 l1 d·(q̇₀ − ȯ) + l0 h, and
//!   b = 2 (q̇₀ − ȯ)ᵀK + 2 dᵀ(J + λ1 K) (λ1 K only with mixed relative degree);
//! - the first-order row of mixed relative degree, and relative degree 1 (4.7)/(4.8), with
//!   rate c (λ1 or α): a = 2 d·(q̇₀ − ȯ) + c h, b = 2 dᵀK.
//!
//! With D ≤ ‖d‖ − r (a lower bound of the gap between the circles, from the road user's
//! bounding circle), V ≥ ‖q̇₀ − ȯ‖, A ≥ ‖q̈₀ − ö‖, and for a set of admissible inputs (each
//! channel within its bound U_j) W ≥ ‖K u‖ and B ≥ ‖J u‖ (Σ_j ‖K_j‖ U_j, Σ_j ‖J_j‖ U_j with K_j,
//! J_j the columns): h ≥ ‖d‖ D (‖d‖ + r ≥ ‖d‖), so for every admissible u
//! - a + b·u ≥ ‖d‖ (l0 D − 2 (A + |l1| V + B + λ1 W)) − 2 V W, which is ≥ 0 when the bracket is
//!   ≥ 0 and D times it is ≥ 2 V W (‖d‖ ≥ D);
//! - a + b·u ≥ ‖d‖ (c D − 2 (V + W)), ≥ 0 when the bracket is.
//!
//! A road user moving away or alongside gives more: with C ≤ d·(q̇₀ − ȯ) (the closing term,
//! negative only for a pair that may approach), 2 l1 d·(q̇₀ − ȯ) ≥ 2 l1 C (l1 ≥ 0) instead of
//! −2 l1 ‖d‖ V, so
//! - a + b·u ≥ ‖d‖ (l0 D − 2 (A + B + λ1 W)) + 2 l1 C − 2 V W: every row holds when the bracket
//!   is ≥ 0 and D times it plus 2 l1 C is ≥ 2 V W;
//! - a + b·u ≥ ‖d‖ (c D − 2 W) + 2 C: when the bracket is ≥ 0 and D times it plus 2 C is ≥ 0.
//!
//! Either certificate suffices.
//!
//! Every row then holds for every admissible input: leaving it out of a QP whose solution is
//! admissible changes nothing (a relaxation's solution that meets the left-out constraints is
//! the full problem's).

use crate::actor::ActorState;
use crate::barrier::{BarrierForm, Constraint};

/// Bounds of one road user against the ego at one evaluation state (every pair of its circles
/// with the ego's points) and a set of admissible inputs: see the module docs for their
/// meaning. All non-negative except `gap`, which may be negative (the circles may overlap).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ReachBounds {
    /// D (m): the least gap ‖q − o‖ − r over the pairs.
    pub gap: f64,
    /// V (m/s): bounds ‖q̇₀ − ȯ‖.
    pub speed: f64,
    /// A (m/s²): bounds ‖q̈₀ − ö‖.
    pub acceleration: f64,
    /// C (m²/s): at most d·(q̇₀ − ȯ) (negative when a pair may be closing).
    pub closing: f64,
    /// W (m/s): bounds ‖K u‖, how far an admissible input moves an ego point's velocity.
    pub input_speed: f64,
    /// B (m/s²): bounds ‖J u‖, how far an admissible input moves an ego point's acceleration.
    pub input_acceleration: f64,
}

/// Whether every barrier row of a road user with these bounds holds for every admissible
/// input, in `form` (with its mixed-relative-degree first-order rows, when the form has real
/// rates). False for a form whose rates give no margin (l0 ≤ 0, α ≤ 0), and for bounds that
/// are not finite.
pub fn rows_hold(bounds: &ReachBounds, form: BarrierForm) -> bool {
    rows_hold_given(bounds, form, form.real_rates())
}

/// [`rows_hold`] with the form's [`BarrierForm::real_rates`] already computed (`rates`).
#[inline]
pub fn rows_hold_given(bounds: &ReachBounds, form: BarrierForm, rates: Option<(f64, f64)>) -> bool {
    let ReachBounds {
        gap,
        speed,
        acceleration,
        closing,
        input_speed,
        input_acceleration,
    } = *bounds;
    if !(gap > 0.0
        && [speed, acceleration, closing, input_speed, input_acceleration]
            .iter()
            .all(|v| v.is_finite()))
    {
        return false;
    }
    let first_order = |rate: f64| {
        let directional = rate * gap - 2.0 * input_speed;
        rate > 0.0
            && (rate * gap - 2.0 * (speed + input_speed) >= 0.0
                || (directional >= 0.0 && gap * directional + 2.0 * closing >= 0.0))
    };
    match form {
        BarrierForm::RelativeDegree1 { alpha } => first_order(alpha),
        BarrierForm::RelativeDegree2 { l0, l1 } => {
            let lambda1 = rates.map_or(0.0, |(lambda1, _)| lambda1);
            let inputs = input_acceleration + lambda1 * input_speed;
            let bracket = l0 * gap - 2.0 * (acceleration + l1.abs() * speed + inputs);
            let directional = l0 * gap - 2.0 * (acceleration + inputs);
            let second = l0 > 0.0
                && ((bracket >= 0.0 && gap * bracket >= 2.0 * speed * input_speed)
                    || (l1 >= 0.0
                        && directional >= 0.0
                        && gap * directional + 2.0 * l1 * closing >= 2.0 * speed * input_speed));
            // The first-order row ḣ + λ1 h ≥ 0 of a mixed-relative-degree barrier.
            second && rates.is_none_or(|(lambda1, _)| first_order(lambda1))
        }
    }
}

/// What an ego point does at a state (module docs): q, q̇₀, q̈₀, and per input channel
/// K_j = ∂q̇/∂u_j and J_j (the input's part of q̈ at relative degree 2).
#[derive(Debug, Clone, Copy)]
pub struct PointKinematics<'a> {
    pub position: [f64; 2],
    pub velocity: [f64; 2],
    pub acceleration: [f64; 2],
    pub velocity_columns: &'a [[f64; 2]],
    pub acceleration_columns: &'a [[f64; 2]],
}

/// What a pair's rows are made of: d = q − o, w = q̇₀ − ȯ, q̈₀ − ö and h = ‖d‖² − r².
struct Pair {
    d: [f64; 2],
    w: [f64; 2],
    acceleration: [f64; 2],
    h: f64,
}

fn dot(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

impl Pair {
    fn new(point: &PointKinematics<'_>, circle: &ActorState, radius: f64) -> Pair {
        let d = [
            point.position[0] - circle.position[0],
            point.position[1] - circle.position[1],
        ];
        Pair {
            d,
            w: [
                point.velocity[0] - circle.velocity[0],
                point.velocity[1] - circle.velocity[1],
            ],
            acceleration: [
                point.acceleration[0] - circle.acceleration[0],
                point.acceleration[1] - circle.acceleration[1],
            ],
            h: dot(d, d) - radius * radius,
        }
    }

    /// a of the pair's row in `form`.
    fn a(&self, form: BarrierForm) -> f64 {
        let Pair { d, w, acceleration, h } = *self;
        match form {
            BarrierForm::RelativeDegree1 { alpha } => 2.0 * dot(d, w) + alpha * h,
            BarrierForm::RelativeDegree2 { l0, l1 } => {
                2.0 * dot(w, w) + 2.0 * dot(d, acceleration) + 2.0 * l1 * dot(d, w) + l0 * h
            }
        }
    }

    /// b_j of the pair's row in `form`, for the channel's columns K_j and J_j (with the mixed
    /// relative degree's λ1, else 0).
    fn b(&self, form: BarrierForm, lambda1: f64, k: [f64; 2], j: [f64; 2]) -> f64 {
        match form {
            BarrierForm::RelativeDegree1 { .. } => 2.0 * dot(self.d, k),
            BarrierForm::RelativeDegree2 { .. } => {
                2.0 * dot(self.w, k) + 2.0 * dot(self.d, j) + 2.0 * lambda1 * dot(self.d, k)
            }
        }
    }
}

/// a + b·u of the barrier h = ‖q − o‖² − r² between an ego point and a road user's circle
/// (`circle`: its position, velocity and acceleration), in `form` at the input `u`, the motion
/// terms included: the rows of the module docs formed from the point's kinematics (with
/// `mixed_rate` λ1, b gains 2λ1 dᵀK: the mixed-relative-degree condition).
pub fn pair_condition(
    form: BarrierForm,
    mixed_rate: Option<f64>,
    point: &PointKinematics<'_>,
    circle: &ActorState,
    radius: f64,
    u: &[f64],
) -> f64 {
    let pair = Pair::new(point, circle, radius);
    let lambda1 = mixed_rate.unwrap_or(0.0);
    let columns = point.velocity_columns.iter().zip(point.acceleration_columns).zip(u);
    let b_u: f64 = columns.map(|((k, j), u)| pair.b(form, lambda1, *k, *j) * u).sum();
    pair.a(form) + b_u
}

/// The rows of [`pair_condition`] themselves: `row` ← (h, a, b) with a + b·u that condition
/// (b_j for the point's channels; the rest of b left 0), and, for a mixed-relative-degree pair
/// (`mixed_rate` λ1), `first_order` ← ḣ + λ1 h ≥ 0: a = 2 d·(q̇₀ − ȯ) + λ1 h, b = 2 dᵀK. What
/// the Lie path forms for a body circle against a moving circle (with its motion terms), from
/// the point's kinematics instead of f, G and ∂f/∂x.
pub fn pair_rows(
    form: BarrierForm,
    mixed_rate: Option<f64>,
    point: &PointKinematics<'_>,
    circle: &ActorState,
    radius: f64,
    row: &mut Constraint,
    first_order: Option<&mut Constraint>,
) {
    let pair = Pair::new(point, circle, radius);
    let lambda1 = mixed_rate.unwrap_or(0.0);
    (row.h, row.a) = (pair.h, pair.a(form));
    // (Through slices, each entry written once: nalgebra's iterators, and a fill before
    // the writes (a memset call), cost as much as the arithmetic here.)
    let (velocity_columns, acceleration_columns) = (point.velocity_columns, point.acceleration_columns);
    for (i, b) in row.b.as_mut_slice().iter_mut().enumerate() {
        *b = match (velocity_columns.get(i), acceleration_columns.get(i)) {
            (Some(k), Some(j)) => pair.b(form, lambda1, *k, *j),
            _ => 0.0,
        };
    }
    if let (Some(lambda1), Some(out)) = (mixed_rate, first_order) {
        let first = BarrierForm::RelativeDegree1 { alpha: lambda1 };
        (out.h, out.a) = (pair.h, pair.a(first));
        for (i, b) in out.b.as_mut_slice().iter_mut().enumerate() {
            *b = velocity_columns
                .get(i)
                .map_or(0.0, |k| pair.b(first, 0.0, *k, [0.0; 2]));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::SplitMix64;

    /// The rows of one pair, formed from the quantities the bounds bound (module docs).
    #[allow(clippy::too_many_arguments)]
    fn rows(
        form: BarrierForm,
        d: [f64; 2],
        r: f64,
        w: [f64; 2],
        acc: [f64; 2],
        k: [[f64; 2]; 2],
        j: [[f64; 2]; 2],
        u: [f64; 2],
    ) -> Vec<f64> {
        let dot = |a: [f64; 2], b: [f64; 2]| a[0] * b[0] + a[1] * b[1];
        let mul = |m: [[f64; 2]; 2], u: [f64; 2]| [m[0][0] * u[0] + m[0][1] * u[1], m[1][0] * u[0] + m[1][1] * u[1]];
        let h = dot(d, d) - r * r;
        let (ku, ju) = (mul(k, u), mul(j, u));
        match form {
            BarrierForm::RelativeDegree1 { alpha } => vec![2.0 * dot(d, w) + alpha * h + 2.0 * dot(d, ku)],
            BarrierForm::RelativeDegree2 { l0, l1 } => {
                let lambda1 = form.real_rates().map_or(0.0, |(l, _)| l);
                let a = 2.0 * dot(w, w) + 2.0 * dot(d, acc) + 2.0 * l1 * dot(d, w) + l0 * h;
                let b_u = 2.0 * dot(w, ku) + 2.0 * dot(d, ju) + lambda1 * 2.0 * dot(d, ku);
                let mut out = vec![a + b_u];
                if form.real_rates().is_some() {
                    out.push(2.0 * dot(d, w) + lambda1 * h + 2.0 * dot(d, ku));
                }
                out
            }
        }
    }

    /// Random pairs and inputs within the bounds: whenever `rows_hold` says so, every row is
    /// ≥ 0; and far enough away it does say so.
    #[test]
    fn rows_hold_only_where_every_row_is_met() {
        let mut rng = SplitMix64(7);
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
        let forms = [
            BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.0 },
            BarrierForm::RelativeDegree2 { l0: 1.0, l1: 0.5 },
            BarrierForm::RelativeDegree1 { alpha: 2.0 },
        ];
        let (mut certified, mut checked) = (0, 0);
        for _ in 0..20000 {
            let form = forms[(uniform(0.0, 3.0) as usize).min(2)];
            let r = uniform(0.5, 3.0);
            let distance = r + uniform(-1.0, 200.0);
            let angle = uniform(0.0, std::f64::consts::TAU);
            let d = [distance * angle.cos(), distance * angle.sin()];
            let mut vector = |scale: f64| [uniform(-scale, scale), uniform(-scale, scale)];
            let (w, acc) = (vector(20.0), vector(8.0));
            let (k, j) = ([vector(3.0), vector(3.0)], [vector(5.0), vector(5.0)]);
            // Admissible: |u_j| ≤ U_j; the row is checked at a random admissible input.
            let bound = [uniform(0.0, 4.0), uniform(0.0, 4.0)];
            let u = [bound[0] * uniform(-1.0, 1.0), bound[1] * uniform(-1.0, 1.0)];
            let norm = |v: [f64; 2]| v[0].hypot(v[1]);
            let columns = |m: [[f64; 2]; 2]| norm([m[0][0], m[1][0]]) * bound[0] + norm([m[0][1], m[1][1]]) * bound[1];
            let dot = |a: [f64; 2], b: [f64; 2]| a[0] * b[0] + a[1] * b[1];
            let bounds = ReachBounds {
                gap: distance - r,
                speed: norm(w),
                acceleration: norm(acc),
                closing: dot(d, w) - uniform(0.0, 5.0),
                input_speed: columns(k),
                input_acceleration: columns(j),
            };
            if rows_hold(&bounds, form) {
                certified += 1;
                for row in rows(form, d, r, w, acc, k, j, u) {
                    assert!(row >= 0.0, "{bounds:?} {form:?}: a row {row} < 0");
                }
            }
            checked += 1;
        }
        assert!(certified > checked / 4, "only {certified} of {checked} pairs certified");
    }

    #[test]
    fn overlapping_or_marginless_pairs_are_never_out_of_reach() {
        let far = ReachBounds {
            gap: 1e6,
            ..Default::default()
        };
        let form = BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.0 };
        assert!(rows_hold(&far, form));
        assert!(!rows_hold(&far, BarrierForm::RelativeDegree2 { l0: 0.0, l1: 4.0 }));
        assert!(!rows_hold(&far, BarrierForm::RelativeDegree1 { alpha: 0.0 }));
        let unbounded = ReachBounds {
            input_speed: f64::NAN,
            ..far
        };
        assert!(!rows_hold(&unbounded, form));
        let touching = ReachBounds { gap: 0.0, ..far };
        assert!(!rows_hold(&touching, form));
    }
}
