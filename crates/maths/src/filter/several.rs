//! Several barriers in the distinct-delay filters (docs/several-barriers.md): the
//! fixed-channel QP (4.42) and the γm QP_k (4.60) with one constraint per known barrier,
//! solved by the active-set QP of [`crate::filter::qp`]. With one barrier they are the closed
//! forms (4.46) and (4.62) themselves, so one-barrier runs are unchanged.
//!
//! Both report, per decision, how far the barrier conditions fall short with the *real*
//! inputs the decision plans (u0 + ū on the channels it moves, ω on the later ones): the
//! least-violation fallback of an infeasible QP, and the part of a γm constraint met only by
//! the fictitious inputs σ (4.60) or the exaggeration γ_f (4.61), are never hidden.

use nalgebra::DVector;

use crate::barrier::Constraint;
use crate::filter::qp::{QpHint, QpWorkspace};
use crate::filter::{fixed_channel_one_barrier, gamma_m_one_barrier, gamma_m_xi, gamma_m_zeta, ChannelOutcome};

/// The stream of channel i's decisions (`report`: they report their shortfall) or of its law
/// at predicted states, in [`ChannelQp`]'s hints.
fn hint_index(i: usize, report: bool) -> usize {
    2 * i + usize::from(report)
}

/// The hint of channel i's stream, its next solve's `count` rows keyed by `keys` when they are
/// that solve's ([`ChannelQp::key_rows`]; else by position).
fn keyed_hint<'a>(hints: &'a mut [QpHint], keys: &[usize], (i, report): (usize, bool), count: usize) -> &'a mut QpHint {
    let hint = &mut hints[hint_index(i, report)];
    if keys.len() == count {
        hint.key_rows(keys.iter().copied());
    }
    hint
}

/// A shortfall below this fraction of the constraint's terms (|a| + Σ|b_j u_j|) is rounding.
const SHORTFALL_TOLERANCE: f64 = 1e-9;

/// The scratch space of one per-channel filter: sized when the filter is built, so that a
/// decision allocates nothing (the γm QP has 2r variables: v and σ/√m).
#[derive(Debug, Clone)]
pub struct ChannelQp {
    qp: QpWorkspace,
    /// w0 (u0, or 0 for the γm QP's variables) and the solution w0 + w.
    origin: DVector<f64>,
    solution: DVector<f64>,
    /// u0 + ū on the moved channels, ω on the later ones: the inputs the decision plans.
    planned: DVector<f64>,
    /// Where the last QP of each stream ended: per channel, its decisions and the law the
    /// predictors assume ([`hint_index`]), each a sequence of similar problems.
    hints: Vec<QpHint>,
    /// Per channel, the largest |input| the solves since [`ChannelQp::take_planned`] planned,
    /// fictitious ones included (γm's (u0 + v or ω) + σ).
    largest_planned: Vec<f64>,
    /// The rows' keys of the next solves ([`ChannelQp::key_rows`]).
    keys: Vec<usize>,
}

impl ChannelQp {
    /// Scratch space for r channels, `variables` QP variables (r for (4.42), 2r for (4.60)) and
    /// up to `barriers` barriers (more only allocate when they first appear).
    fn new(r: usize, variables: usize, barriers: usize) -> ChannelQp {
        ChannelQp {
            qp: QpWorkspace::with_capacity(variables, barriers),
            origin: DVector::zeros(variables),
            solution: DVector::zeros(variables),
            planned: DVector::zeros(r),
            hints: vec![QpHint::with_capacity(variables, barriers); 2 * r],
            largest_planned: vec![0.0; r],
            keys: Vec::with_capacity(barriers),
        }
    }

    /// The next solves' rows are those of these barriers (`rows`: per row, its barrier's index,
    /// as [`crate::filter::SeenBarriers::rows`]; a mixed-relative-degree barrier's first-order row
    /// after every barrier's own): each row keyed by its barrier and which of its rows it is, so
    /// that a channel's hint holds while other barriers' rows come and go.
    pub fn key_rows(&mut self, rows: &[usize]) {
        self.keys.clear();
        // The first-order rows begin where the barrier indices stop increasing.
        let second = (1..rows.len()).find(|&j| rows[j] <= rows[j - 1]).unwrap_or(rows.len());
        let key = |(j, barrier): (usize, &usize)| 2 * barrier + usize::from(j >= second);
        self.keys.extend(rows.iter().enumerate().map(key));
    }

    /// largest ← per channel, the largest |input| planned since the last call (then reset).
    pub fn take_planned(&mut self, largest: &mut [f64]) {
        for (out, planned) in largest.iter_mut().zip(&mut self.largest_planned) {
            *out = std::mem::take(planned);
        }
    }

    /// Channel j's input `value` was planned (NaN stays NaN: no bound holds).
    fn plan(&mut self, j: usize, value: f64) {
        let slot = &mut self.largest_planned[j];
        *slot = if value.is_nan() {
            f64::NAN
        } else {
            slot.max(value.abs())
        };
    }

    /// For the fixed-channel filter (4.44) on r channels.
    pub fn fixed_channel(r: usize, barriers: usize) -> ChannelQp {
        ChannelQp::new(r, r, barriers)
    }

    /// For the γm filter (4.67) on r channels.
    pub fn gamma_m(r: usize, barriers: usize) -> ChannelQp {
        ChannelQp::new(r, 2 * r, barriers)
    }

    /// (4.42) for channel `i` with every barrier k: min ‖v‖², v ∈ R^s, s.t.
    /// a_k + Σ_{j<s} b_kj (u0_j + v_j) + Σ_{j≥s} b_kj ω_j ≥ 0; u_i = u0_i + v_i (4.44).
    /// One barrier: (4.46) itself. With the shortfall of the planned inputs.
    pub fn fixed_channel_decision(
        &mut self,
        constraints: &[Constraint],
        u0: &DVector<f64>,
        omega: &DVector<f64>,
        i: usize,
        s: usize,
    ) -> ChannelOutcome {
        self.fixed_channel_solve(constraints, u0, omega, i, s, true)
    }

    /// u_i of [`ChannelQp::fixed_channel_decision`] alone (the law the predictors assume: no
    /// shortfall to report).
    pub fn fixed_channel_input(
        &mut self,
        constraints: &[Constraint],
        u0: &DVector<f64>,
        omega: &DVector<f64>,
        i: usize,
        s: usize,
    ) -> f64 {
        self.fixed_channel_solve(constraints, u0, omega, i, s, false).input
    }

    fn fixed_channel_solve(
        &mut self,
        constraints: &[Constraint],
        u0: &DVector<f64>,
        omega: &DVector<f64>,
        i: usize,
        s: usize,
        report: bool,
    ) -> ChannelOutcome {
        let r = u0.len();
        if let [c] = constraints {
            let mut out = fixed_channel_one_barrier(c, u0, omega, i, s);
            // Active: the constraint is met with equality by construction; infeasible: v = 0.
            if out.infeasible {
                (out.unmet, out.shortfall) = (Some(0), -out.mu);
            }
            // ū_j (4.46) on the channels < s.
            let b_used: f64 = (0..s).map(|j| c.b[j] * c.b[j]).sum();
            let scale = if out.active { -out.mu / b_used } else { 0.0 };
            for j in 0..r {
                self.plan(j, if j < s { u0[j] + scale * c.b[j] } else { omega[j] });
            }
            return out;
        }
        let reduced = |k: usize, reduced: &mut Constraint| {
            let c = &constraints[k];
            (reduced.h, reduced.a) = (0.0, c.a + (s..r).map(|j| c.b[j] * omega[j]).sum::<f64>());
            for j in 0..r {
                reduced.b[j] = if j < s { c.b[j] } else { 0.0 };
            }
        };
        let hint = keyed_hint(&mut self.hints, &self.keys, (i, report), constraints.len());
        let (active, infeasible, mu) =
            self.qp
                .solve_hinted_rows(constraints.len(), reduced, u0, None, &mut self.solution, hint);
        let mut out = ChannelOutcome::new(self.solution[i], active, infeasible, mu);
        for j in 0..r {
            self.plan(j, if j < s { self.solution[j] } else { omega[j] });
        }
        if report {
            for j in 0..r {
                self.planned[j] = if j < s { self.solution[j] } else { omega[j] };
            }
            (out.unmet, out.shortfall) = worst_shortfall(constraints, &self.planned);
        }
        out
    }

    /// QP_k (4.60) for channel `i` (k (4.68): the last channel with i's delay) with every
    /// barrier: min ‖v‖² + m‖σ‖², v ∈ R^k, σ ∈ R^r, s.t. for every barrier
    /// γ_f(z_k) + Σ_{j≤k} b_j (v_j + σ_j) + Σ_{j>k} b_j (ω_j + σ_j) ≥ 0 (z (4.66) per barrier);
    /// u_i = u0_i + v_i (4.67). In w = (v, √m σ) it is min ‖w‖² s.t. ζ + (b_{1:k}, b/√m)·w ≥ 0
    /// (ζ (4.64)), whose one-barrier solution is (4.62)–(4.65). One barrier: (4.62) itself.
    /// With the shortfall of the planned inputs.
    #[allow(clippy::too_many_arguments)]
    pub fn gamma_m_decision(
        &mut self,
        constraints: &[Constraint],
        u0: &DVector<f64>,
        omega: &DVector<f64>,
        i: usize,
        k: usize,
        m: f64,
        gamma: f64,
    ) -> ChannelOutcome {
        self.gamma_m_solve(constraints, u0, omega, [i, k], m, gamma, true)
    }

    /// u_i of [`ChannelQp::gamma_m_decision`] alone (the law the predictors assume: no
    /// shortfall to report).
    #[allow(clippy::too_many_arguments)]
    pub fn gamma_m_input(
        &mut self,
        constraints: &[Constraint],
        u0: &DVector<f64>,
        omega: &DVector<f64>,
        i: usize,
        k: usize,
        m: f64,
        gamma: f64,
    ) -> f64 {
        self.gamma_m_solve(constraints, u0, omega, [i, k], m, gamma, false)
            .input
    }

    #[allow(clippy::too_many_arguments)]
    fn gamma_m_solve(
        &mut self,
        constraints: &[Constraint],
        u0: &DVector<f64>,
        omega: &DVector<f64>,
        [i, k]: [usize; 2],
        m: f64,
        gamma: f64,
        report: bool,
    ) -> ChannelOutcome {
        let r = u0.len();
        let used = k + 1;
        if let [c] = constraints {
            let mut out = gamma_m_one_barrier(c, u0, omega, i, k, m, gamma);
            // w = −ζ/ξ β (4.62): v_j = −ζ/ξ b_j on the channels ≤ k, σ_j = −ζ/(ξ m) b_j.
            let scale = if out.active {
                -out.mu / gamma_m_xi(c, used, m)
            } else {
                0.0
            };
            for j in 0..r {
                let real = if j < used { u0[j] + scale * c.b[j] } else { omega[j] };
                self.plan(j, real + scale / m * c.b[j]);
                // (A decision's shortfall is of the real inputs: they are planned too.)
                if report {
                    self.plan(j, real);
                }
            }
            if report && (out.active || out.infeasible) {
                // ū_j = −ζ/ξ b_j (4.62) on the channels ≤ k (0 if infeasible).
                let scale = if out.active {
                    -out.mu / gamma_m_xi(c, used, m)
                } else {
                    0.0
                };
                for j in 0..r {
                    self.planned[j] = if j < used { u0[j] + scale * c.b[j] } else { omega[j] };
                }
                (out.unmet, out.shortfall) = worst_shortfall(constraints, &self.planned);
            }
            return out;
        }
        let root_m = m.sqrt();
        // The rows formed where the QP scales them (one pass).
        let reduced = |k: usize, reduced: &mut Constraint| {
            let c = &constraints[k];
            (reduced.h, reduced.a) = (0.0, gamma_m_zeta(c, u0, omega, used, gamma));
            let (real, slack) = reduced.b.as_mut_slice().split_at_mut(r);
            let b = &c.b.as_slice()[..r];
            for j in 0..r {
                real[j] = if j < used { b[j] } else { 0.0 };
                slack[j] = b[j] / root_m;
            }
        };
        self.origin.fill(0.0);
        let hint = keyed_hint(&mut self.hints, &self.keys, (i, report), constraints.len());
        let (active, infeasible, mu) =
            self.qp
                .solve_hinted_rows(constraints.len(), reduced, &self.origin, None, &mut self.solution, hint);
        let mut out = ChannelOutcome::new(u0[i] + self.solution[i], active, infeasible, mu);
        for j in 0..r {
            let real = if j < used { u0[j] + self.solution[j] } else { omega[j] };
            self.plan(j, real + self.solution[r + j] / root_m);
            if report {
                self.plan(j, real);
            }
        }
        if report {
            for j in 0..r {
                self.planned[j] = if j < used { u0[j] + self.solution[j] } else { omega[j] };
            }
            (out.unmet, out.shortfall) = worst_shortfall(constraints, &self.planned);
        }
        out
    }
}

/// The barrier whose condition a_k + b_k·u falls furthest below 0 with the planned inputs,
/// and by how much (in its own constraint units); (None, 0) if every condition is met.
pub(crate) fn worst_shortfall(constraints: &[Constraint], planned: &DVector<f64>) -> (Option<usize>, f64) {
    let mut worst = (None, 0.0);
    for (k, c) in constraints.iter().enumerate() {
        let terms = c.a.abs() + c.b.iter().zip(planned.iter()).map(|(b, u)| (b * u).abs()).sum::<f64>();
        let shortfall = -c.value(planned);
        if shortfall > SHORTFALL_TOLERANCE * terms && shortfall > worst.1 {
            worst = (Some(k), shortfall);
        }
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;

    fn constraint(a: f64, b: &[f64]) -> Constraint {
        Constraint {
            h: 1.0,
            a,
            b: DVector::from_column_slice(b),
        }
    }

    fn v(x: &[f64]) -> DVector<f64> {
        DVector::from_column_slice(x)
    }

    /// A second barrier that is far from active leaves the one-barrier decision as it was
    /// (the QP's solution equals the closed form up to rounding).
    #[test]
    fn an_inactive_second_barrier_changes_nothing() {
        let c = constraint(-3.0, &[1.0, 2.0, 0.5]);
        let far = constraint(100.0, &[0.3, -1.0, 2.0]);
        let (u0, omega) = (v(&[0.1, -0.2, 0.4]), v(&[0.0, 0.7, -0.3]));
        let mut qp = ChannelQp::fixed_channel(3, 2);
        for (i, s) in [(0, 1), (0, 2), (1, 2), (2, 3)] {
            let one = qp.fixed_channel_decision(std::slice::from_ref(&c), &u0, &omega, i, s);
            let two = qp.fixed_channel_decision(&[c.clone(), far.clone()], &u0, &omega, i, s);
            assert!((one.input - two.input).abs() < 1e-12, "i {i} s {s}: {one:?} vs {two:?}");
            assert_eq!(
                (one.active, one.infeasible, one.unmet),
                (two.active, two.infeasible, two.unmet)
            );
        }
        let mut qp = ChannelQp::gamma_m(3, 2);
        for (i, k) in [(0, 0), (1, 1), (2, 2), (0, 1)] {
            let one = qp.gamma_m_decision(std::slice::from_ref(&c), &u0, &omega, i, k, 50.0, 51.0 / 50.0);
            let two = qp.gamma_m_decision(&[c.clone(), far.clone()], &u0, &omega, i, k, 50.0, 51.0 / 50.0);
            assert!((one.input - two.input).abs() < 1e-12, "i {i} k {k}: {one:?} vs {two:?}");
            assert!((one.shortfall - two.shortfall).abs() < 1e-9, "{one:?} vs {two:?}");
        }
    }

    /// Two active barriers: the (4.42) solution, found by brute force on a fine grid of v,
    /// meets both and has the least ‖v‖.
    #[test]
    fn fixed_channel_with_two_barriers_meets_both_with_the_least_correction() {
        // a1 + v0 ≥ 0 and a2 + v0 + v1 ≥ 0 with u0 = 0: v = (1, 1) for a = (−1, −2).
        let cs = [constraint(-1.0, &[1.0, 0.0]), constraint(-2.0, &[1.0, 1.0])];
        let (u0, omega) = (v(&[0.0, 0.0]), v(&[0.0, 0.0]));
        let mut qp = ChannelQp::fixed_channel(2, 2);
        let d0 = qp.fixed_channel_decision(&cs, &u0, &omega, 0, 2);
        let d1 = qp.fixed_channel_decision(&cs, &u0, &omega, 1, 2);
        // Independent: minimise ‖v‖² on a grid of step 1e-3 subject to both constraints.
        let mut best = (f64::INFINITY, 0.0, 0.0);
        for a in 0..=3000 {
            for b in -1000..=3000 {
                let (x, y) = (a as f64 * 1e-3, b as f64 * 1e-3);
                if -1.0 + x >= 0.0 && -2.0 + x + y >= 0.0 && x * x + y * y < best.0 {
                    best = (x * x + y * y, x, y);
                }
            }
        }
        assert!((d0.input - best.1).abs() < 2e-3 && (d1.input - best.2).abs() < 2e-3);
        assert!(d0.active && !d0.infeasible && d0.unmet.is_none());
    }

    /// Only channel 0 may move (s = 1) and the two barriers want it in opposite directions:
    /// infeasible, and the barrier left unmet is named with its shortfall.
    #[test]
    fn opposing_barriers_on_one_channel_are_reported_with_the_unmet_one() {
        let cs = [constraint(-1.0, &[1.0, 5.0]), constraint(-3.0, &[-1.0, 1.0])];
        let (u0, omega) = (v(&[0.0, 0.0]), v(&[0.0, 0.0]));
        let mut qp = ChannelQp::fixed_channel(2, 2);
        let d = qp.fixed_channel_decision(&cs, &u0, &omega, 0, 1);
        assert!(d.infeasible);
        let planned = v(&[d.input, 0.0]);
        let g: Vec<f64> = cs.iter().map(|c| c.value(&planned)).collect();
        let worst = if g[0] < g[1] { 0 } else { 1 };
        assert_eq!(d.unmet, Some(worst));
        assert!((d.shortfall + g[worst]).abs() < 1e-9, "{d:?} {g:?}");
    }

    /// A γm decision says the real inputs it plans (those its shortfall is of) as well as
    /// the fictitious u + σ (4.60): here σ points against u0 + v, so only the real input is the
    /// larger one. The law the predictors assume says u + σ alone.
    #[test]
    fn a_gamma_m_decision_plans_its_real_inputs_too() {
        // u0 = 3 violates the first condition by 0.5: v is a small correction against it.
        let cs = [constraint(2.55, &[-1.0, 0.5]), constraint(10.0, &[-0.2, 1.0])];
        let (u0, omega) = (v(&[3.0, -0.1]), v(&[0.0, 0.2]));
        let (m, gamma) = (50.0, 51.0 / 50.0);
        let mut qp = ChannelQp::gamma_m(2, 2);
        let mut largest = [0.0; 2];
        qp.gamma_m_decision(&cs, &u0, &omega, 0, 0, m, gamma);
        qp.take_planned(&mut largest);
        let real = u0[0] + qp.solution[0];
        let fictitious = real + qp.solution[2] / m.sqrt();
        assert!(
            fictitious.abs() < real.abs(),
            "σ does not point against u: {real} {fictitious}"
        );
        assert_eq!(largest[0], real.abs());
        qp.gamma_m_input(&cs, &u0, &omega, 0, 0, m, gamma);
        qp.take_planned(&mut largest);
        assert_eq!(largest[0], fictitious.abs());
    }

    /// The γm QP with two barriers, checked against its KKT conditions in w = (v, √m σ):
    /// w = Σ λ_k c_k with λ ≥ 0, each constraint met, complementary slackness.
    #[test]
    fn gamma_m_with_two_barriers_satisfies_the_kkt_conditions() {
        let cs = [constraint(-2.0, &[1.0, 0.5]), constraint(-1.0, &[-0.2, 1.0])];
        let (u0, omega) = (v(&[0.3, -0.1]), v(&[0.0, 0.2]));
        let (m, gamma) = (50.0, 51.0 / 50.0);
        let mut qp = ChannelQp::gamma_m(2, 2);
        // Channel 0 with k = 0: v ∈ R^1, σ ∈ R^2.
        let d = qp.gamma_m_decision(&cs, &u0, &omega, 0, 0, m, gamma);
        let w: Vec<f64> = qp.solution.iter().copied().collect();
        let rows: Vec<(f64, [f64; 4])> = cs
            .iter()
            .map(|c| {
                let zeta = crate::filter::gamma_f(gamma, c.a + c.b[0] * u0[0]) + c.b[1] * omega[1];
                (zeta, [c.b[0], 0.0, c.b[0] / m.sqrt(), c.b[1] / m.sqrt()])
            })
            .collect();
        let g: Vec<f64> = rows
            .iter()
            .map(|(z, row)| z + row.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>())
            .collect();
        assert!(g.iter().all(|g| *g > -1e-9), "{g:?}");
        // Least squares for λ over the active rows.
        let active: Vec<usize> = (0..2).filter(|&k| g[k].abs() < 1e-9).collect();
        assert!(!active.is_empty());
        let (r0, r1) = (&rows[0].1, &rows[1].1);
        let lambda = if active.len() == 2 {
            let dot = |a: &[f64; 4], b: &[f64; 4]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
            let (g00, g01, g11) = (dot(r0, r0), dot(r0, r1), dot(r1, r1));
            let rw0 = r0.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>();
            let rw1 = r1.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>();
            let det = g00 * g11 - g01 * g01;
            [(g11 * rw0 - g01 * rw1) / det, (g00 * rw1 - g01 * rw0) / det]
        } else {
            let row = &rows[active[0]].1;
            let n = row.iter().map(|x| x * x).sum::<f64>();
            let mut l = [0.0; 2];
            l[active[0]] = row.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>() / n;
            l
        };
        assert!(lambda.iter().all(|l| *l >= -1e-9), "{lambda:?}");
        for (j, wj) in w.iter().enumerate() {
            let rebuilt = lambda[0] * r0[j] + lambda[1] * r1[j];
            assert!((wj - rebuilt).abs() < 1e-9, "w {w:?} λ {lambda:?}");
        }
        assert!((d.input - (u0[0] + w[0])).abs() < 1e-15);
    }
}
