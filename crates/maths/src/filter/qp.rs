//! The CBF-QP when it has no closed form: several barrier constraints (one per obstacle) and
//! actuator limits.
//!
//! min ‖v‖² + ρ Σ s_k   s.t.  a_k + b_k (u0 + v) + s_k ≥ 0,  s_k ≥ 0,  lower ≤ u0 + v ≤ upper,
//!
//! with each row scaled to ‖b_k‖ = 1 first (the same set, any units): s_k is a distance in
//! input space, so ρ exceeds the multipliers whatever the barrier's units.
//!
//! The slacks s_k with a linear (exact) penalty ρ make the problem always feasible: when the
//! barrier constraints can all be met, the solution is the hard-constrained QP's (ρ exceeds
//! every multiplier); when they cannot, it is the least-violation input within the limits —
//! the documented fallback, reported as `infeasible`.
//!
//! Solved by a dense primal active-set method on v alone ([`QpWorkspace`]): eliminating
//! s_k = max{0, −g_k(v)}, g_k(v) = a_k + b_k (u0 + v), leaves the strictly convex piecewise
//! quadratic ‖v‖² + ρ Σ max{0, −g_k(v)} over the box. A barrier is *hard* (g_k ≥ 0 kept),
//! *soft* (g_k ≤ 0, contributing −ρ b_k to the gradient) or in the working set at g_k = 0 with
//! a multiplier in [0, ρ] (the ℓ1-penalty active set, e.g. Fletcher's Sℓ1QP); the equality
//! subproblems have Hessian 2I, so each step is one ≤ r×r Cholesky solve. The iteration looks
//! only at the barriers near the start (within twice its largest violation); the others are
//! checked at each optimum over those and join when violated, so most rows of a large problem
//! are read twice, not at every iteration (`QpWorkspace::screen`). It allocates nothing
//! once its buffers fit the problem, and is exact up to rounding. Clarabel (the crate's former
//! solver, a maintained interior-point method) remains the fallback if the active set fails to
//! converge, and the reference of the tests: a warm Clarabel solve (data updated in place)
//! still allocates once per call in its internal timers and takes ≈25 µs (docs/performance.md).

use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT};
use nalgebra::{DVector, DVectorView};

use crate::barrier::Constraint;

/// Penalty on the slacks (per unit of constraint violation).
const SLACK_PENALTY: f64 = 1e6;
/// A slack above this counts as a violated (infeasible) constraint.
const SLACK_TOLERANCE: f64 = 1e-6;
/// Input limits at or beyond this magnitude are no limits (as Clarabel's presolve treats them).
const INFINITE_BOUND: f64 = 1e20;
/// Active-set iterations before giving up on a problem (then Clarabel solves it): 200, or four
/// per row for a larger one. An infeasible problem of many rows crosses one kink of the penalty
/// per iteration (a row turns penalised or met): Flensburg's delay-free CBF-QP, 400–550 rows,
/// took up to 750 (docs/performance.md, "Stop 79").
const MAX_ITERATIONS: usize = 200;
const ITERATIONS_PER_ROW: usize = 4;
/// Multipliers within this fraction of the gradient's size of a bound count as on it.
const MULTIPLIER_TOLERANCE: f64 = 1e-12;

/// What the QP decided.
#[derive(Debug, Clone, PartialEq)]
pub struct QpOutcome {
    pub input: DVector<f64>,
    /// The correction v is non-zero.
    pub active: bool,
    /// Some barrier constraint could not be met within the limits (least-violation fallback),
    /// or the solver failed (then u0 clamped to the limits is returned).
    pub infeasible: bool,
    /// The smallest constraint value a_k + b_k u0 before correction.
    pub mu: f64,
}

/// Solves the multi-constraint CBF-QP around u0 (see the module docs) with a fresh workspace
/// (allocates; a filter keeps a [`QpWorkspace`] instead).
pub fn cbf_qp_multi(constraints: &[Constraint], u0: &DVector<f64>, limits: Option<(&[f64], &[f64])>) -> QpOutcome {
    let mut input = DVector::zeros(u0.len());
    let (active, infeasible, mu) = QpWorkspace::default().solve(constraints, u0, limits, &mut input);
    QpOutcome {
        input,
        active,
        infeasible,
        mu,
    }
}

/// A constraint of the active set, in the form n·v ≥ β (ordered: the working set's canonical
/// order, [`QpWorkspace::settle`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Bound {
    /// g_k(v) = c_k + b_k·v ≥ 0 (n = b_k).
    Barrier(usize),
    /// v_i ≤ upper_i − u0_i (n = −e_i).
    Upper(usize),
    /// v_i ≥ lower_i − u0_i (n = e_i).
    Lower(usize),
}

impl Bound {
    /// Component i of the bound's normal n.
    fn normal(self, constraints: &[Constraint], i: usize) -> f64 {
        match self {
            Bound::Barrier(k) => constraints[k].b[i],
            Bound::Upper(j) => -f64::from(u8::from(i == j)),
            Bound::Lower(j) => f64::from(u8::from(i == j)),
        }
    }
}

/// Where the last solve of one stream of similar problems ended (a channel's decisions, say):
/// its working set and which barriers paid the penalty. [`QpWorkspace::solve_hinted`] tries
/// it first and keeps it only if it passes every optimality condition, so a hint changes how
/// fast the solution is found, never which solution (the problem is strictly convex).
#[derive(Debug, Default, Clone)]
pub struct QpHint {
    working: Vec<Bound>,
    soft: Vec<bool>,
    /// The caller's key of each barrier row of the solve that wrote the hint, and of the next
    /// solve's ([`QpHint::key_rows`]): with both, a row is found by its key, so the hint holds
    /// while rows before it come and go (a road user's rows left out, say).
    keys: Vec<usize>,
    next_keys: Vec<usize>,
    /// Solves that the hint answered, and solves in all.
    hits: u64,
    solves: u64,
}

impl QpHint {
    /// A hint that never allocates for r inputs and up to k barriers.
    pub fn with_capacity(r: usize, k: usize) -> QpHint {
        QpHint {
            working: Vec::with_capacity(2 * r),
            soft: Vec::with_capacity(k),
            keys: Vec::with_capacity(k),
            next_keys: Vec::with_capacity(k),
            ..QpHint::default()
        }
    }

    /// The next solve's rows have these keys, one per row, distinct (the same key for the same
    /// barrier row from one solve to the next).
    pub fn key_rows(&mut self, keys: impl IntoIterator<Item = usize>) {
        self.next_keys.clear();
        self.next_keys.extend(keys);
    }

    /// (solves the hint answered, solves in all).
    pub fn hits(&self) -> (u64, u64) {
        (self.hits, self.solves)
    }
}

/// The scratch space of the active-set solver; keep one per filter so that solving allocates
/// nothing once it has seen the largest problem (r inputs, k barriers).
#[derive(Debug, Default, Clone)]
pub struct QpWorkspace {
    /// c_k = a_k + b_k·u0.
    c: Vec<f64>,
    /// The box for v: lower − u0, upper − u0 (±∞ without a limit).
    lower: Vec<f64>,
    upper: Vec<f64>,
    v: Vec<f64>,
    p: Vec<f64>,
    gradient: Vec<f64>,
    soft: Vec<bool>,
    /// The cold start's `soft` while a hint is tried.
    cold_soft: Vec<bool>,
    working: Vec<Bound>,
    /// The working set's normals (row-major, |W| × r), their Gram matrix and multipliers.
    normals: Vec<f64>,
    gram: Vec<f64>,
    multipliers: Vec<f64>,
    correction: Vec<f64>,
    /// Problems the active set could not solve (handed to Clarabel).
    fallbacks: u64,
    /// The constraints scaled to ‖b_k‖ = 1 (see [`QpWorkspace::solve`]).
    scaled: Vec<Constraint>,
    /// The barriers the iteration looks at, ascending (see [`QpWorkspace::screen`]), and per
    /// barrier whether it is among them.
    considered: Vec<usize>,
    is_considered: Vec<bool>,
    /// g_k at the start v.
    start: Vec<f64>,
    /// A candidate's normal and its row of the working set's Cholesky factor
    /// ([`Working::spans`]).
    span: Vec<f64>,
}

/// The working set as the last equality step factored it: its size, its normals (row-major,
/// |W| × r) and the Cholesky factor L of N Nᵀ (`gram`, row stride |W|).
struct Working<'a> {
    count: usize,
    normals: &'a [f64],
    gram: &'a [f64],
    r: usize,
}

impl Working<'_> {
    /// Whether `bound`'s normal is numerically in the span of the working set's: the next
    /// equality step, with it appended, would find N Nᵀ singular (the same [`cholesky_row`]).
    fn spans(&self, bound: Bound, constraints: &[Constraint], scratch: &mut Vec<f64>) -> bool {
        scratch.clear();
        scratch.extend((0..self.r).map(|i| bound.normal(constraints, i)));
        scratch.resize(self.r + self.count, 0.0);
        let (candidate, row) = scratch.split_at_mut(self.r);
        cholesky_row(candidate, self.normals, self.gram, self.count, row).is_none()
    }
}

/// Row `row.len()` of the Cholesky factor of N Nᵀ with the normal `n` appended after the rows
/// whose normals (`normals`, row-major) and factor rows (`factor`, row stride `stride`) are
/// given: `row` ← its entries left of the diagonal; returns the diagonal entry, or None when
/// `n` is numerically in the span of those rows (N Nᵀ singular).
fn cholesky_row(n: &[f64], normals: &[f64], factor: &[f64], stride: usize, row: &mut [f64]) -> Option<f64> {
    let r = n.len();
    for b in 0..row.len() {
        let mut sum = dot(n, &normals[b * r..(b + 1) * r]);
        for (j, value) in row[..b].iter().enumerate() {
            sum -= value * factor[b * stride + j];
        }
        row[b] = sum / factor[b * stride + b];
    }
    let diagonal = dot(n, n);
    let mut sum = diagonal;
    for value in row.iter() {
        sum -= value * value;
    }
    (sum > 1e-14 * diagonal).then(|| sum.sqrt())
}

fn finite_limit(bound: f64) -> bool {
    bound.abs() < INFINITE_BOUND
}

/// Σ a_i b_i summed from 0 in order (the bits of `Constraint::value`'s and nalgebra's `norm`'s
/// sums), written out for four entries (the per-channel QPs of the γm filter with two channels;
/// a loop of unknown length costs as much again in its set-up).
#[inline(always)]
fn ordered_dot(a: &[f64], b: &[f64]) -> f64 {
    if let (Ok(a), Ok(b)) = (<&[f64; 4]>::try_from(a), <&[f64; 4]>::try_from(b)) {
        return 0.0 + a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3];
    }
    crate::barrier::dot(a, b)
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl QpWorkspace {
    /// A workspace sized for r inputs and up to k barriers: solving such problems never
    /// allocates.
    pub fn with_capacity(r: usize, k: usize) -> QpWorkspace {
        let mut workspace = QpWorkspace::default();
        for buffer in [
            &mut workspace.lower,
            &mut workspace.upper,
            &mut workspace.v,
            &mut workspace.p,
            &mut workspace.gradient,
        ] {
            buffer.reserve_exact(r);
        }
        for buffer in [&mut workspace.multipliers, &mut workspace.correction] {
            buffer.resize(r, 0.0);
        }
        for buffer in [&mut workspace.normals, &mut workspace.gram] {
            buffer.resize(r * r, 0.0);
        }
        // (A candidate's normal and its factor row: r + |W| ≤ 2r.)
        workspace.span.reserve_exact(2 * r);
        workspace.c.reserve_exact(k);
        workspace.soft.reserve_exact(k);
        workspace.cold_soft.reserve_exact(k);
        workspace.considered.reserve_exact(k);
        workspace.is_considered.reserve_exact(k);
        workspace.start.reserve_exact(k);
        workspace.scaled = (0..k).map(|_| Constraint::zeros(r)).collect();
        workspace.working.reserve_exact(r);
        workspace
    }

    /// Problems handed to Clarabel because the active set did not converge (0 is expected).
    pub fn fallbacks(&self) -> u64 {
        self.fallbacks
    }

    /// u ← the CBF-QP's solution around u0 (see the module docs); returns (active, infeasible,
    /// μ) as in [`QpOutcome`].
    ///
    /// Each constraint is scaled to ‖b_k‖ = 1 first (a_k + b_k·u ≥ 0 is the same set), so the
    /// slack penalty compares violations as distances in input space: in the constraint's own
    /// units it would exceed the multipliers only for some scalings (a barrier in metres whose
    /// b is 3e-3 per newton needed multipliers near 1e6, and was reported infeasible where it
    /// was not).
    pub fn solve(
        &mut self,
        constraints: &[Constraint],
        u0: &DVector<f64>,
        limits: Option<(&[f64], &[f64])>,
        u: &mut DVector<f64>,
    ) -> (bool, bool, f64) {
        self.solve_from(constraints, u0, limits, u, None)
    }

    /// [`QpWorkspace::solve`], trying first where the last solve with this `hint` ended (its
    /// working set, checked against every optimality condition before it is accepted), and
    /// leaving in `hint` where this one ended. The same solution, formed the same way on the
    /// same working set, taken in a fixed order: consecutive decisions of one channel
    /// mostly keep their active barriers, and then take one equality solve instead of an
    /// iteration per barrier crossed.
    pub fn solve_hinted(
        &mut self,
        constraints: &[Constraint],
        u0: &DVector<f64>,
        limits: Option<(&[f64], &[f64])>,
        u: &mut DVector<f64>,
        hint: &mut QpHint,
    ) -> (bool, bool, f64) {
        self.solve_from(constraints, u0, limits, u, Some(hint))
    }

    fn solve_from(
        &mut self,
        constraints: &[Constraint],
        u0: &DVector<f64>,
        limits: Option<(&[f64], &[f64])>,
        u: &mut DVector<f64>,
        hint: Option<&mut QpHint>,
    ) -> (bool, bool, f64) {
        let copy = |k: usize, out: &mut Constraint| {
            let c = &constraints[k];
            (out.h, out.a) = (c.h, c.a);
            out.b.copy_from(&c.b);
        };
        self.solve_rows(constraints.len(), copy, u0, limits, u, hint)
    }

    /// [`QpWorkspace::solve_hinted`] of `count` rows that `row(k, out)` writes (h, a and b, with
    /// u0's length), each valued at u0 and scaled where it is written: one pass over the rows
    /// instead of forming them, then reading them for μ and again for the scaling.
    #[allow(clippy::too_many_arguments)]
    pub fn solve_hinted_rows(
        &mut self,
        count: usize,
        row: impl FnMut(usize, &mut Constraint),
        u0: &DVector<f64>,
        limits: Option<(&[f64], &[f64])>,
        u: &mut DVector<f64>,
        hint: &mut QpHint,
    ) -> (bool, bool, f64) {
        self.solve_rows(count, row, u0, limits, u, Some(hint))
    }

    fn solve_rows(
        &mut self,
        count: usize,
        mut row: impl FnMut(usize, &mut Constraint),
        u0: &DVector<f64>,
        limits: Option<(&[f64], &[f64])>,
        u: &mut DVector<f64>,
        hint: Option<&mut QpHint>,
    ) -> (bool, bool, f64) {
        let mut scaled = std::mem::take(&mut self.scaled);
        while scaled.len() < count {
            scaled.push(Constraint::zeros(u0.len()));
        }
        // One pass forms the rows, μ and whether they are finite; only a correction scales them.
        let (r, finite_values) = (u0.len(), |v: &[f64]| v.iter().all(|x| x.is_finite()));
        let (mut mu, mut finite) = (f64::INFINITY, finite_values(u0.as_slice()));
        let origin = u0.as_slice();
        for (k, s) in scaled[..count].iter_mut().enumerate() {
            if s.b.len() != r {
                s.b = DVector::zeros(r);
            }
            row(k, s);
            // (s.value(u0), and the finiteness of a and b.)
            let b = s.b.as_slice();
            mu = mu.min(s.a + ordered_dot(b, origin));
            finite &= s.a.is_finite() && finite_values(b);
        }
        u.copy_from(u0);
        // A non-finite u0 or constraint (a state at NaN or ±1e300) has no solution to look
        // for: u0 is returned, flagged infeasible.
        let within_limits =
            limits.is_none_or(|(lo, hi)| u0.iter().enumerate().all(|(i, v)| *v >= lo[i] && *v <= hi[i]));
        let outcome = if !finite {
            (false, true, mu)
        } else if mu >= 0.0 && within_limits {
            (false, false, mu)
        } else {
            self.c.clear();
            for s in &mut scaled[..count] {
                let b = s.b.as_mut_slice();
                // ‖b‖ summed in nalgebra's order (`norm`), so the same bits.
                let norm = ordered_dot(b, b).sqrt();
                let scale = if norm > 0.0 && norm.is_finite() {
                    1.0 / norm
                } else {
                    1.0
                };
                s.a *= scale;
                for b in b.iter_mut() {
                    *b *= scale;
                }
                self.c.push(s.a + ordered_dot(s.b.as_slice(), origin));
            }
            self.solve_scaled(&scaled[..count], u0, limits, u, mu, hint)
        };
        self.scaled = scaled;
        outcome
    }

    /// [`QpWorkspace::solve`] on finite constraints already scaled and valued at u0 (`c`) that
    /// need a correction; `mu` is the unscaled μ.
    fn solve_scaled(
        &mut self,
        constraints: &[Constraint],
        u0: &DVector<f64>,
        limits: Option<(&[f64], &[f64])>,
        u: &mut DVector<f64>,
        mu: f64,
        hint: Option<&mut QpHint>,
    ) -> (bool, bool, f64) {
        self.prepare(constraints, u0, limits);
        let solved = match hint {
            Some(hint) => self.active_set_hinted(constraints, hint),
            None => self.active_set(constraints),
        };
        if solved {
            let v = DVectorView::from_slice(&self.v, u0.len());
            *u += v;
            // At the solution only the penalised barriers are violated (the others are met,
            // within rounding).
            let worst_slack = (self.c.iter().zip(constraints).zip(&self.soft))
                .filter(|(_, soft)| **soft)
                .map(|((c, constraint), _)| -(c + dot(constraint.b.as_slice(), &self.v)))
                .fold(0.0, f64::max);
            return (v.norm() > 1e-12, worst_slack > SLACK_TOLERANCE, mu);
        }
        self.fallbacks += 1;
        let r = u0.len();
        match clarabel_solve(constraints, u0, limits) {
            Some(z) => {
                let v = DVectorView::from_slice(&z[..r], r);
                *u += v;
                let worst_slack = z[r..].iter().cloned().fold(0.0, f64::max);
                (v.norm() > 1e-12, worst_slack > SLACK_TOLERANCE, mu)
            }
            None => {
                if let Some((lo, hi)) = limits {
                    for (i, value) in u.iter_mut().enumerate() {
                        *value = value.clamp(lo[i], hi[i]);
                    }
                }
                (false, true, mu)
            }
        }
    }

    /// Sizes the buffers (allocating only to grow) and writes the box and the start v = the
    /// point of the box nearest 0, with the barriers violated there soft (c is written).
    fn prepare(&mut self, constraints: &[Constraint], u0: &DVector<f64>, limits: Option<(&[f64], &[f64])>) {
        let (r, k) = (u0.len(), constraints.len());
        self.lower.clear();
        self.upper.clear();
        for i in 0..r {
            let (lo, hi) = limits.map_or((f64::NEG_INFINITY, f64::INFINITY), |(lo, hi)| {
                (
                    if finite_limit(lo[i]) {
                        lo[i] - u0[i]
                    } else {
                        f64::NEG_INFINITY
                    },
                    if finite_limit(hi[i]) {
                        hi[i] - u0[i]
                    } else {
                        f64::INFINITY
                    },
                )
            });
            self.lower.push(lo);
            self.upper.push(hi);
        }
        self.start_nearest_zero();
        self.p.clear();
        self.p.resize(r, 0.0);
        self.gradient.clear();
        self.gradient.resize(r, 0.0);
        self.soft.clear();
        self.start.clear();
        let moved = self.v.iter().any(|v| *v != 0.0);
        for (c, constraint) in self.c.iter().zip(constraints) {
            let g = if moved {
                c + dot(constraint.b.as_slice(), &self.v)
            } else {
                *c
            };
            self.soft.push(g < 0.0);
            self.start.push(g);
        }
        self.screen();
        self.working.clear();
        self.working.reserve(r);
        self.normals.resize(r * r, 0.0);
        self.gram.resize(r * r, 0.0);
        self.multipliers.resize(r, 0.0);
        self.correction.resize(r, 0.0);
        debug_assert_eq!(self.soft.len(), k);
    }

    /// The barriers the cold iteration starts with: those within twice the largest violation
    /// of the start v (a row k with ‖b_k‖ = 1 and g_k(v) > 0 is met within ‖Δv‖ < g_k(v)
    /// of v, and the correction must move v at least as far as the largest violation). The
    /// others are checked at each optimum over these and join when violated
    /// ([`QpWorkspace::admit_violated`]): a screen changes the path, never the solution, and
    /// [`QpWorkspace::settle`] forms it from the optimal working set alone.
    fn screen(&mut self) {
        let within = 2.0 * self.start.iter().fold(0.0_f64, |m, g| m.max(-g));
        self.considered.clear();
        self.is_considered.clear();
        for (k, &g) in self.start.iter().enumerate() {
            let near = self.soft[k] || g <= within;
            self.is_considered.push(near);
            if near {
                self.considered.push(k);
            }
        }
    }

    /// At an optimum over the considered barriers: each other barrier violated at v (beyond
    /// rounding) joins them, penalised (it is violated at v). Whether any joined.
    fn admit_violated(&mut self, constraints: &[Constraint]) -> bool {
        let tolerance = 1e-12 * (1.0 + self.v.iter().fold(0.0_f64, |m, v| m.max(v.abs())));
        let mut admitted = false;
        for (k, constraint) in constraints.iter().enumerate() {
            if self.is_considered[k] {
                continue;
            }
            let g = self.c[k] + dot(constraint.b.as_slice(), &self.v);
            if g < -(tolerance + 1e-12 * self.c[k].abs()) {
                (self.is_considered[k], self.soft[k], admitted) = (true, true, true);
                self.considered.push(k);
            }
        }
        if admitted {
            self.considered.sort_unstable();
        }
        admitted
    }

    /// [`QpWorkspace::active_set`], answered by the hint's working set when it is optimal;
    /// leaves in `hint` where this solve ended.
    fn active_set_hinted(&mut self, constraints: &[Constraint], hint: &mut QpHint) -> bool {
        let hit = self.hot_start(constraints, hint);
        let solved = hit || self.active_set(constraints);
        (hint.solves, hint.hits) = (hint.solves + 1, hint.hits + u64::from(hit));
        hint.working.clear();
        hint.soft.clear();
        std::mem::swap(&mut hint.keys, &mut hint.next_keys);
        hint.next_keys.clear();
        if solved {
            hint.working.extend_from_slice(&self.working);
            hint.soft.extend_from_slice(&self.soft);
        }
        solved
    }

    /// Whether the hint's working set and penalised barriers, with the minimiser on them, meet
    /// every optimality condition of the problem [`QpWorkspace::prepare`] set up: each
    /// multiplier in its range ([0, ρ] for a barrier, [0, ∞) for a limit), every other hard
    /// barrier met and every other penalised one not (within rounding), v within the box. Then
    /// v is the problem's unique solution; else the workspace is left for the cold start.
    fn hot_start(&mut self, constraints: &[Constraint], hint: &QpHint) -> bool {
        let (r, k) = (self.v.len(), constraints.len());
        // Keyed: each of the hint's rows is where its key now is (None: gone).
        let keyed = !hint.keys.is_empty() && hint.keys.len() == hint.soft.len() && hint.next_keys.len() == k;
        let rows = if keyed { hint.keys.len() } else { k };
        let valid = |bound: &Bound| match *bound {
            Bound::Barrier(j) => j < rows,
            Bound::Upper(i) => i < r && self.upper[i].is_finite(),
            Bound::Lower(i) => i < r && self.lower[i].is_finite(),
        };
        let now = |row: usize| match keyed {
            true => hint.next_keys.iter().position(|key| *key == hint.keys[row]),
            false => Some(row),
        };
        if hint.working.is_empty() || !(keyed || hint.soft.len() == k) || !hint.working.iter().all(valid) {
            return false;
        }
        // (The cold start's penalised barriers kept aside, in a buffer that keeps its capacity.)
        std::mem::swap(&mut self.soft, &mut self.cold_soft);
        self.soft.clear();
        self.soft.resize(k, false);
        for (row, _) in hint.soft.iter().enumerate().filter(|(_, soft)| **soft) {
            if let Some(j) = now(row) {
                self.soft[j] = true;
            }
        }
        self.working.clear();
        for bound in &hint.working {
            self.working.push(match *bound {
                Bound::Barrier(row) => match now(row) {
                    Some(j) => Bound::Barrier(j),
                    // (A row of the optimal working set is gone: the cold start's state again.)
                    None => {
                        std::mem::swap(&mut self.soft, &mut self.cold_soft);
                        self.working.clear();
                        return false;
                    }
                },
                other => other,
            });
        }
        self.working.sort_unstable();
        for bound in &self.working {
            if let Bound::Barrier(j) = *bound {
                self.soft[j] = false;
            }
        }
        if self.hint_is_optimal(constraints) == Some(true) {
            return true;
        }
        // The cold start's state again.
        std::mem::swap(&mut self.soft, &mut self.cold_soft);
        self.start_nearest_zero();
        self.working.clear();
        false
    }

    /// [`QpWorkspace::hot_start`]'s test, with v ← the minimiser on the working set (None
    /// when it has none, or not a finite one).
    fn hint_is_optimal(&mut self, constraints: &[Constraint]) -> Option<bool> {
        let r = self.v.len();
        self.penalty_gradient(constraints);
        if !(self.equality_step(constraints) && self.p.iter().all(|p| p.is_finite())) {
            return None;
        }
        self.v.copy_from_slice(&self.p);
        let largest = |x: &[f64]| x.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
        let size = 1.0 + largest(&self.gradient) + 2.0 * largest(&self.v);
        let tolerance = MULTIPLIER_TOLERANCE * size;
        let multipliers_in_range = self.working.iter().zip(&self.multipliers).all(|(bound, &lambda)| {
            let excess = match bound {
                Bound::Barrier(_) => (-lambda).max(lambda - SLACK_PENALTY),
                _ => -lambda,
            };
            excess <= tolerance
        });
        // Rounding of the constraint values: rows have ‖b_k‖ = 1, so |b_k·v| ≤ ‖v‖.
        let slack = 1e-12 * (1.0 + largest(&self.v));
        let within_box = (0..r).all(|i| self.v[i] >= self.lower[i] - slack && self.v[i] <= self.upper[i] + slack);
        let optimal = multipliers_in_range
            && within_box
            && constraints.iter().enumerate().all(|(k, constraint)| {
                if self.working.contains(&Bound::Barrier(k)) {
                    return true;
                }
                let g = self.c[k] + dot(constraint.b.as_slice(), &self.v);
                let tolerance = slack + 1e-12 * self.c[k].abs();
                if self.soft[k] {
                    g <= tolerance
                } else {
                    g >= -tolerance
                }
            });
        Some(optimal)
    }

    /// v ← the minimiser on the optimal working set taken in its canonical order, so that the
    /// solution's bits depend on that set and the rows alone, not on the path that found it
    /// (the cold iteration, a hint, or the same rows at other positions: leaving out rows of
    /// road users out of reach changes no command bit for bit).
    fn settle(&mut self, constraints: &[Constraint]) {
        self.working.sort_unstable();
        self.penalty_gradient(constraints);
        if self.equality_step(constraints) && self.p.iter().all(|p| p.is_finite()) {
            self.v.copy_from_slice(&self.p);
        }
    }

    /// v ← the point of the box nearest 0.
    fn start_nearest_zero(&mut self) {
        self.v.clear();
        self.v.extend(
            self.lower
                .iter()
                .zip(&self.upper)
                .map(|(lo, hi)| 0.0_f64.clamp(*lo, *hi)),
        );
    }

    /// d ← −ρ Σ_soft b_k: F = ‖v‖² + d·v (+ const) while the soft set holds.
    fn penalty_gradient(&mut self, constraints: &[Constraint]) {
        penalty_gradient_over(&mut self.gradient, constraints, &self.soft, 0..constraints.len());
    }

    /// [`QpWorkspace::penalty_gradient`] over the considered barriers (every penalised
    /// barrier is among them, in the same ascending order: the same sum).
    fn considered_penalty_gradient(&mut self, constraints: &[Constraint]) {
        let rows = self.considered.iter().copied();
        penalty_gradient_over(&mut self.gradient, constraints, &self.soft, rows);
    }

    /// β_w of working constraint w (n_w·v = β_w when it holds with equality).
    fn beta(&self, w: usize) -> f64 {
        match self.working[w] {
            Bound::Barrier(k) => -self.c[k],
            Bound::Upper(i) => -self.upper[i],
            Bound::Lower(i) => self.lower[i],
        }
    }

    /// The active-set iteration from [`QpWorkspace::prepare`]'s start; false if it did not
    /// converge (or the working set became numerically dependent).
    fn active_set(&mut self, constraints: &[Constraint]) -> bool {
        let r = self.v.len();
        // After a full step the point minimises on the working set: p = 0 in exact arithmetic.
        let mut at_minimum = false;
        for _ in 0..MAX_ITERATIONS.max(ITERATIONS_PER_ROW * constraints.len()) {
            self.considered_penalty_gradient(constraints);
            if !self.equality_step(constraints) {
                return false;
            }
            for i in 0..r {
                self.p[i] -= self.v[i];
            }
            let largest = |x: &[f64]| x.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
            // The size of 2v + d, which the multipliers balance.
            let scale = 1.0 + largest(&self.gradient) + 2.0 * largest(&self.v);
            let step = self.p.iter().fold(0.0_f64, |m, p| m.max(p.abs()));
            if at_minimum || step <= 1e-15 * (1.0 + self.v.iter().fold(0.0_f64, |m, v| m.max(v.abs()))) {
                // v ← the minimiser itself (computed afresh: no drift off the working set).
                for i in 0..r {
                    self.v[i] += self.p[i];
                }
                // Stationary on the working set: optimal unless a multiplier leaves its range
                // ([0, ρ] for a barrier at g_k = 0, [0, ∞) for a limit); drop the worst.
                let tolerance = MULTIPLIER_TOLERANCE * scale;
                let mut worst: Option<(usize, f64)> = None;
                for (w, bound) in self.working.iter().enumerate() {
                    let lambda = self.multipliers[w];
                    let excess = match bound {
                        Bound::Barrier(_) => (-lambda).max(lambda - SLACK_PENALTY),
                        _ => -lambda,
                    };
                    if excess > tolerance && worst.is_none_or(|(_, e)| excess > e) {
                        worst = Some((w, excess));
                    }
                }
                let Some((w, _)) = worst else {
                    if self.admit_violated(constraints) {
                        at_minimum = false;
                        continue;
                    }
                    self.settle(constraints);
                    return true;
                };
                if let Bound::Barrier(k) = self.working[w] {
                    // Above ρ: paying the penalty is cheaper than keeping g_k = 0.
                    self.soft[k] = self.multipliers[w] > SLACK_PENALTY;
                }
                self.working.remove(w);
                at_minimum = false;
                continue;
            }
            // Ratio test: the first constraint outside the working set that p reaches. A rate
            // n·p within p's rounding (`noise`: ε times the size of 2v + d, which a penalised
            // barrier makes ρ-sized) is no step, nor is that of a normal in the span of the
            // working set's (the test the next equality step would fail, bit for bit): n·p = 0
            // there in exact arithmetic, since p keeps the working set. Taking such a row at
            // t = 0 made N Nᵀ singular or cycled, and handed the problem to Clarabel: γm's rows
            // of two channels all lie in one plane ([b, b/√m]), and a footprint's three circles
            // against one circle give three rows through one point (stop 79).
            let mut alpha = 1.0;
            let mut blocking = None;
            let noise = 1e-15 * scale;
            let mut span = std::mem::take(&mut self.span);
            let working = Working {
                count: self.working.len(),
                normals: &self.normals,
                gram: &self.gram,
                r,
            };
            let mut consider = |bound: Bound, value: f64, rate: f64, alpha: &mut f64| {
                // value + t·rate reaches 0 at t = −value/rate (value has the sign of the side
                // the point is on, rate the other).
                let t = (-value / rate).max(0.0);
                if t < *alpha && rate.abs() > noise && !working.spans(bound, constraints, &mut span) {
                    *alpha = t;
                    blocking = Some(bound);
                }
            };
            for &k in &self.considered {
                if self.working.contains(&Bound::Barrier(k)) {
                    continue;
                }
                let constraint = &constraints[k];
                let g = self.c[k] + dot(constraint.b.as_slice(), &self.v);
                let rate = dot(constraint.b.as_slice(), &self.p);
                // Hard: g ≥ 0 decreasing to 0; soft: g ≤ 0 increasing to 0 (the kink).
                if (!self.soft[k] && rate < 0.0) || (self.soft[k] && rate > 0.0) {
                    consider(Bound::Barrier(k), g, rate, &mut alpha);
                }
            }
            for i in 0..r {
                if self.p[i] > 0.0 && self.upper[i].is_finite() && !self.working.contains(&Bound::Upper(i)) {
                    consider(Bound::Upper(i), self.upper[i] - self.v[i], -self.p[i], &mut alpha);
                }
                if self.p[i] < 0.0 && self.lower[i].is_finite() && !self.working.contains(&Bound::Lower(i)) {
                    consider(Bound::Lower(i), self.v[i] - self.lower[i], self.p[i], &mut alpha);
                }
            }
            self.span = span;
            for i in 0..r {
                self.v[i] += alpha * self.p[i];
            }
            match blocking {
                Some(bound) => {
                    if let Bound::Barrier(k) = bound {
                        self.soft[k] = false;
                    }
                    if self.working.len() == r {
                        return false;
                    }
                    self.working.push(bound);
                    at_minimum = false;
                }
                None => at_minimum = true,
            }
        }
        false
    }

    /// p ← the minimiser of ‖v‖² + d·v (d in `gradient`) with n_w·v = β_w on the working set
    /// (its constraints held with equality), and its multipliers: 2v + d = Nᵀλ, so
    /// (N Nᵀ) λ = 2β + N d and v = (Nᵀλ − d)/2. False if N Nᵀ is numerically singular.
    fn equality_step(&mut self, constraints: &[Constraint]) -> bool {
        let (r, m) = (self.v.len(), self.working.len());
        for w in 0..m {
            for i in 0..r {
                self.normals[w * r + i] = self.working[w].normal(constraints, i);
            }
        }
        // Cholesky N Nᵀ = L Lᵀ in place (lower triangle of `gram`), a row at a time.
        for a in 0..m {
            let (before, rest) = self.gram.split_at_mut(a * m);
            let n = &self.normals[a * r..(a + 1) * r];
            let Some(diagonal) = cholesky_row(n, &self.normals, before, m, &mut rest[..a]) else {
                return false;
            };
            rest[a] = diagonal;
        }
        // λ = (L Lᵀ)⁻¹ (2β + N d).
        for a in 0..m {
            let rhs = 2.0 * self.beta(a) + dot(&self.normals[a * r..(a + 1) * r], &self.gradient);
            self.multipliers[a] = rhs;
        }
        cholesky_solve(&self.gram, m, &mut self.multipliers[..m]);
        for i in 0..r {
            let pushed: f64 = (0..m).map(|w| self.normals[w * r + i] * self.multipliers[w]).sum();
            self.p[i] = 0.5 * (pushed - self.gradient[i]);
        }
        // One step of iterative refinement of N v = β: λ and d are of size ρ when a barrier is
        // soft, and their cancellation leaves errors of ρ ε in v, i.e. in g_k on the working set.
        for a in 0..m {
            let residual = self.beta(a) - dot(&self.normals[a * r..(a + 1) * r], &self.p);
            self.correction[a] = residual;
        }
        cholesky_solve(&self.gram, m, &mut self.correction[..m]);
        for i in 0..r {
            self.p[i] += (0..m)
                .map(|w| self.normals[w * r + i] * self.correction[w])
                .sum::<f64>();
        }
        true
    }
}

/// gradient ← −ρ Σ b_k over the penalised (`soft`) barriers among `rows`, in their order.
fn penalty_gradient_over(
    gradient: &mut [f64],
    constraints: &[Constraint],
    soft: &[bool],
    rows: impl Iterator<Item = usize>,
) {
    gradient.fill(0.0);
    for k in rows.filter(|&k| soft[k]) {
        for (d, b) in gradient.iter_mut().zip(constraints[k].b.iter()) {
            *d -= SLACK_PENALTY * b;
        }
    }
}

/// x ← (L Lᵀ)⁻¹ x for the m × m lower-triangular L in `gram` (row-major): forward, then back
/// substitution.
fn cholesky_solve(gram: &[f64], m: usize, x: &mut [f64]) {
    for a in 0..m {
        let mut sum = x[a];
        for j in 0..a {
            sum -= gram[a * m + j] * x[j];
        }
        x[a] = sum / gram[a * m + a];
    }
    for a in (0..m).rev() {
        let mut sum = x[a];
        for j in a + 1..m {
            sum -= gram[j * m + a] * x[j];
        }
        x[a] = sum / gram[a * m + a];
    }
}

/// The problem in (v, s) solved by Clarabel with a fresh solver (dense matrices, default
/// settings); `None` if Clarabel refuses it or does not solve it.
fn clarabel_solve(constraints: &[Constraint], u0: &DVector<f64>, limits: Option<(&[f64], &[f64])>) -> Option<Vec<f64>> {
    let (r, k) = (u0.len(), constraints.len());
    let n = r + k;
    // Objective ½ zᵀPz + qᵀz with P = diag(2 I_r, 0), q = (0, ρ 1_k).
    let mut p = vec![vec![0.0; n]; n];
    for (i, row) in p.iter_mut().enumerate().take(r) {
        row[i] = 2.0;
    }
    let mut q = vec![0.0; n];
    q[r..].fill(SLACK_PENALTY);
    // Constraints A z ≤ b (Clarabel: A z + s = b, s ≥ 0).
    let (mut a_rows, mut b_rhs): (Vec<Vec<f64>>, Vec<f64>) = (Vec::new(), Vec::new());
    for (j, c) in constraints.iter().enumerate() {
        let mut row = vec![0.0; n];
        for (entry, b) in row.iter_mut().zip(c.b.iter()) {
            *entry = -b;
        }
        row[r + j] = -1.0;
        a_rows.push(row);
        b_rhs.push(c.value(u0));
    }
    for j in 0..k {
        let mut row = vec![0.0; n];
        row[r + j] = -1.0;
        a_rows.push(row);
        b_rhs.push(0.0);
    }
    if let Some((lo, hi)) = limits {
        for i in 0..r {
            let mut up = vec![0.0; n];
            up[i] = 1.0;
            a_rows.push(up);
            b_rhs.push(hi[i] - u0[i]);
            let mut down = vec![0.0; n];
            down[i] = -1.0;
            a_rows.push(down);
            b_rhs.push(u0[i] - lo[i]);
        }
    }
    let cones = [SupportedConeT::NonnegativeConeT(b_rhs.len())];
    let settings = DefaultSettingsBuilder::default().verbose(false).build().ok()?;
    let mut solver = DefaultSolver::new(
        &CscMatrix::from(&p),
        &q,
        &CscMatrix::from(&a_rows),
        &b_rhs,
        &cones,
        settings,
    )
    .ok()?;
    solver.solve();
    matches!(
        solver.solution.status,
        SolverStatus::Solved | SolverStatus::AlmostSolved
    )
    .then(|| solver.solution.x.clone())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::cbf_qp_closed_form;
    use crate::random::SplitMix64;
    use allocation_counter::measure;

    /// Constraints, u0 and (lower, upper) limits.
    type Problem = (Vec<Constraint>, DVector<f64>, Option<(Vec<f64>, Vec<f64>)>);

    /// A random problem: r inputs, k barriers (some b entries exactly 0), limits or not.
    fn random_problem(rng: &mut SplitMix64, r: usize, k: usize, limited: bool) -> Problem {
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
        let mut constraints = Vec::new();
        for _ in 0..k {
            let a = uniform(-20.0, 5.0);
            let b = DVector::from_iterator(
                r,
                (0..r).map(|_| {
                    if uniform(0.0, 1.0) < 0.15 {
                        0.0
                    } else {
                        uniform(-10.0, 10.0)
                    }
                }),
            );
            constraints.push(Constraint { h: 1.0, a, b });
        }
        let u0 = DVector::from_iterator(r, (0..r).map(|_| uniform(-4.0, 4.0)));
        let limits = limited.then(|| {
            let lower: Vec<f64> = (0..r).map(|_| uniform(-3.0, -0.1)).collect();
            let upper: Vec<f64> = (0..r).map(|_| uniform(0.1, 3.0)).collect();
            (lower, upper)
        });
        (constraints, u0, limits)
    }

    fn constraint(a: f64, b: &[f64]) -> Constraint {
        Constraint {
            h: 1.0,
            a,
            b: DVector::from_column_slice(b),
        }
    }

    /// The same constraints in other units (each row scaled by a positive factor) are the same
    /// set: the solution and its feasibility do not change. Ames et al.'s headway barrier in
    /// metres has b ≈ 3e-3 per newton; a correction of 1e4 N then needs multipliers near 7e6,
    /// above the slack penalty, unless the rows are normalised.
    #[test]
    fn the_solution_does_not_depend_on_the_units_of_a_constraint() {
        let u0 = DVector::from_column_slice(&[0.0]);
        let base = [constraint(-30.0, &[3e-3]), constraint(5.0, &[1.0])];
        let reference = cbf_qp_multi(&base, &u0, None);
        assert!(!reference.infeasible, "{reference:?}");
        assert!((reference.input[0] - 1e4).abs() < 1e-6, "{reference:?}");
        for scale in [1e-6, 1e-3, 1e3, 1e6] {
            let scaled = [
                constraint(-30.0 * scale, &[3e-3 * scale]),
                constraint(5.0 / scale, &[1.0 / scale]),
            ];
            let out = cbf_qp_multi(&scaled, &u0, None);
            assert!(!out.infeasible, "scale {scale}: {out:?}");
            assert!(
                (out.input[0] - reference.input[0]).abs() < 1e-6,
                "scale {scale}: {out:?}"
            );
        }
    }

    #[test]
    fn one_constraint_without_limits_matches_the_closed_form() {
        let c = constraint(-3.0, &[1.0, 2.0]);
        let u0 = DVector::from_column_slice(&[0.5, -0.2]);
        let qp = cbf_qp_multi(std::slice::from_ref(&c), &u0, None);
        let closed = cbf_qp_closed_form(&c, &u0);
        assert!((&qp.input - &closed.input).norm() < 1e-6, "{qp:?}");
        assert!(qp.active && !qp.infeasible);
    }

    #[test]
    fn a_barrier_left_out_of_the_first_screen_joins_when_the_correction_crosses_it() {
        // v0 ≥ 1 and a nearly opposite row push v far along v1 (to ≈ (1, 9.95, 0)); the
        // third row, 3 > twice the largest violation from 0, is outside the first screen and
        // violated there, so it must join and bind (v2 ≈ 3.7).
        let theta: f64 = 0.2;
        let cs = [
            constraint(-1.0, &[1.0, 0.0, 0.0]),
            constraint(-1.0, &[-theta.cos(), theta.sin(), 0.0]),
            constraint(3.0, &[0.0, -0.6, 0.8]),
        ];
        let u0 = DVector::zeros(3);
        let qp = cbf_qp_multi(&cs, &u0, None);
        let reference = clarabel_outcome(&cs, &u0, None);
        assert!(
            (&qp.input - &reference.input).amax() < 1e-6,
            "{qp:?} against {reference:?}"
        );
        assert!(qp.input[2] > 1.0 && cs[2].value(&qp.input).abs() < 1e-9, "{qp:?}");
        assert!(!qp.infeasible);
    }

    #[test]
    fn two_constraints_are_both_met_with_the_smallest_correction() {
        // u ≥ 1 and u2 ≥ 2 from u0 = 0: v = (1, 2).
        let cs = [constraint(-1.0, &[1.0, 0.0]), constraint(-2.0, &[0.0, 1.0])];
        let qp = cbf_qp_multi(&cs, &DVector::zeros(2), None);
        assert!(
            (qp.input[0] - 1.0).abs() < 1e-6 && (qp.input[1] - 2.0).abs() < 1e-6,
            "{qp:?}"
        );
        assert!(!qp.infeasible);
    }

    #[test]
    fn limits_are_respected_and_infeasibility_falls_back_to_least_violation() {
        // Needs u ≥ 3 but u ≤ 1: infeasible; the fallback pushes to the limit.
        let c = constraint(-3.0, &[1.0]);
        let qp = cbf_qp_multi(std::slice::from_ref(&c), &DVector::zeros(1), Some((&[-1.0], &[1.0])));
        assert!(qp.infeasible);
        assert!((qp.input[0] - 1.0).abs() < 1e-6, "{qp:?}");
        // A nominal outside the limits is brought inside even when the barrier is satisfied.
        let c = constraint(10.0, &[1.0]);
        let qp = cbf_qp_multi(
            std::slice::from_ref(&c),
            &DVector::from_element(1, 4.0),
            Some((&[-1.0], &[1.0])),
        );
        assert!((qp.input[0] - 1.0).abs() < 1e-6 && !qp.infeasible, "{qp:?}");
    }

    /// The outcome of the former path: a fresh Clarabel solver, flags derived from its (v, s).
    fn clarabel_outcome(constraints: &[Constraint], u0: &DVector<f64>, limits: Option<(&[f64], &[f64])>) -> QpOutcome {
        let mu = constraints.iter().map(|c| c.value(u0)).fold(f64::INFINITY, f64::min);
        let within = limits.is_none_or(|(lo, hi)| u0.iter().enumerate().all(|(i, v)| *v >= lo[i] && *v <= hi[i]));
        if mu >= 0.0 && within {
            return QpOutcome {
                input: u0.clone(),
                active: false,
                infeasible: false,
                mu,
            };
        }
        let r = u0.len();
        let z = clarabel_solve(constraints, u0, limits).expect("Clarabel solves the reference problem");
        let v = DVector::from_column_slice(&z[..r]);
        QpOutcome {
            input: u0 + &v,
            active: v.norm() > 1e-12,
            infeasible: z[r..].iter().cloned().fold(0.0, f64::max) > SLACK_TOLERANCE,
            mu,
        }
    }

    #[test]
    fn the_active_set_matches_clarabel_on_random_problems() {
        // One workspace across 20 000 problems of every shape r, k ≤ 4, with and without limits,
        // feasible or not, some b entries exactly 0, against Clarabel (the former solver). The
        // active set's answer is exact up to rounding, Clarabel's to its tolerances (≈1e-8 on an
        // objective of size ρ·s when infeasible), so the check is: within the limits, and an
        // objective no higher than at Clarabel's answer (clamped to the limits).
        let mut rng = SplitMix64(19);
        let mut workspace = QpWorkspace::default();
        let mut u = DVector::zeros(0);
        let (mut largest_feasible, mut largest_infeasible) = (0.0_f64, 0.0_f64);
        let (mut active_count, mut infeasible_count, mut flags_differ) = (0, 0, 0);
        // The largest relative objective excess over Clarabel's (feasible, infeasible).
        let mut worst_excess = (f64::NEG_INFINITY, f64::NEG_INFINITY);
        for trial in 0..20_000 {
            let (r, k, limited) = (1 + trial % 4, 1 + (trial / 4) % 4, trial % 3 != 0);
            let (raw, u0, limits) = random_problem(&mut rng, r, k, limited);
            let limits = limits.as_ref().map(|(lo, hi)| (lo.as_slice(), hi.as_slice()));
            u.resize_vertically_mut(r, 0.0);
            let (active, infeasible, mu) = workspace.solve(&raw, &u0, limits, &mut u);
            // The problem `solve` defines: each row scaled to ‖b_k‖ = 1 (the slack penalty on
            // distances in input space), solved by Clarabel independently.
            let constraints: Vec<Constraint> = raw
                .iter()
                .map(|c| {
                    let norm = c.b.norm();
                    let scale = if norm > 0.0 { 1.0 / norm } else { 1.0 };
                    Constraint {
                        h: c.h,
                        a: c.a * scale,
                        b: &c.b * scale,
                    }
                })
                .collect();
            let reference = clarabel_outcome(&constraints, &u0, limits);
            assert_eq!(mu, raw.iter().map(|c| c.value(&u0)).fold(f64::INFINITY, f64::min));
            let clamped = DVector::from_iterator(
                r,
                (0..r).map(|i| limits.map_or(reference.input[i], |(lo, hi)| reference.input[i].clamp(lo[i], hi[i]))),
            );
            let objective = |u: &DVector<f64>| {
                (u - &u0).norm_squared()
                    + SLACK_PENALTY * constraints.iter().map(|c| (-c.value(u)).max(0.0)).sum::<f64>()
            };
            let (ours, theirs) = (objective(&u), objective(&clamped));
            // Clarabel's answer meets the constraints to ≈1e-9 only, which may lower ‖v‖² by ≈1e-8
            // (measured: 8.8e-9 relative); infeasible, its objective is never lower (4.6e-13).
            let slack = if infeasible { 1e-11 } else { 1e-7 };
            assert!(
                ours <= theirs + slack * (1.0 + theirs),
                "trial {trial}: objective {ours} > Clarabel's {theirs}"
            );
            // Optimal (convex: locally so suffices): no small move within the limits does better.
            for _ in 0..8 {
                let moved = DVector::from_iterator(
                    r,
                    (0..r).map(|i| {
                        let x = u[i] + 1e-6 * (2.0 * rng.next_f64() - 1.0);
                        limits.map_or(x, |(lo, hi)| x.clamp(lo[i], hi[i]))
                    }),
                );
                let nearby = objective(&moved);
                assert!(
                    ours <= nearby + 1e-9 * (1.0 + ours),
                    "trial {trial}: {ours} > {nearby} nearby"
                );
            }
            if let Some((lo, hi)) = limits {
                assert!(
                    (0..r).all(|i| u[i] >= lo[i] - 1e-12 && u[i] <= hi[i] + 1e-12),
                    "trial {trial}: {u} outside the limits"
                );
            }
            if !infeasible {
                assert!(
                    constraints.iter().all(|c| c.value(&u) >= -1e-9),
                    "trial {trial}: a barrier is violated"
                );
            }
            let difference = (&u - &reference.input).amax();
            let excess = (ours - theirs) / (1.0 + theirs);
            if infeasible {
                worst_excess.1 = worst_excess.1.max(excess);
                largest_infeasible = largest_infeasible.max(difference);
            } else {
                worst_excess.0 = worst_excess.0.max(excess);
                largest_feasible = largest_feasible.max(difference);
            }
            active_count += usize::from(active);
            infeasible_count += usize::from(infeasible);
            // Slacks near the tolerance may fall either side, and Clarabel leaves |v| ~ 1e-10
            // where the exact v is 0. With rows of unit norm, opposing violated constraints
            // often make the penalty flat along a segment: the active set returns its point of
            // least ‖v‖ (often v = 0, "not active"), Clarabel an interior point of it with the
            // same objective (checked above): 422 of 20 000 flags differ, all such ties.
            if (active, infeasible) != (reference.active, reference.infeasible) {
                flags_differ += 1;
            }
        }
        println!(
            "largest |u - u_clarabel|: {largest_feasible:e} (feasible), {largest_infeasible:e} (infeasible) over 20000 \
             problems ({active_count} active, {infeasible_count} infeasible), {flags_differ} flags differ, {} fallbacks; \
             largest relative objective excess over Clarabel's {worst_excess:?}",
            workspace.fallbacks()
        );
        assert_eq!(workspace.fallbacks(), 0);
        assert!(largest_feasible < 1e-3, "{largest_feasible}");
        assert!(
            active_count > 10_000 && infeasible_count > 1000 && flags_differ <= 600,
            "{flags_differ}"
        );
    }

    /// A stream of slowly changing problems (a channel's decisions, tick after tick): the hinted
    /// solve answers most from the last one's working set, and every answer is the cold
    /// solve's (the same flags, the input to rounding), with or without limits, when the
    /// hint is wrong (the barriers changed), and when barriers come and go.
    #[test]
    fn a_hinted_solve_gives_the_cold_solution() {
        let mut rng = SplitMix64(11);
        let mut hits = (0, 0);
        for stream in 0..40 {
            let (r, k, limited) = (1 + stream % 4, 2 + stream % 7, stream % 3 == 0);
            let (mut constraints, u0, limits) = random_problem(&mut rng, r, k, limited);
            let limits = limits.as_ref().map(|(lo, hi)| (lo.as_slice(), hi.as_slice()));
            let mut hint = QpHint::default();
            let (mut workspace, mut hot) = (QpWorkspace::default(), QpWorkspace::default());
            for step in 0..60 {
                for c in constraints.iter_mut() {
                    c.a += 0.05 * (rng.next_f64() - 0.5);
                    for b in c.b.iter_mut() {
                        *b += 0.02 * (rng.next_f64() - 0.5);
                    }
                }
                // Now and then a barrier leaves or another comes (the hint then cannot hold).
                let count = if step % 17 == 16 { k - 1 } else { k };
                let rows = &constraints[..count];
                let (mut cold_u, mut hot_u) = (DVector::zeros(r), DVector::zeros(r));
                let cold_flags = workspace.solve(rows, &u0, limits, &mut cold_u);
                let hot_flags = hot.solve_hinted(rows, &u0, limits, &mut hot_u, &mut hint);
                assert_eq!(cold_flags.1, hot_flags.1, "stream {stream} step {step}");
                assert_eq!(cold_flags.2, hot_flags.2, "stream {stream} step {step}");
                let size = 1.0 + cold_u.amax();
                assert!(
                    (&cold_u - &hot_u).amax() <= 1e-9 * size,
                    "stream {stream} step {step}: {cold_u} vs {hot_u}"
                );
            }
            assert_eq!(hot.fallbacks(), workspace.fallbacks(), "stream {stream}");
            hits = (hits.0 + hint.hits().0, hits.1 + hint.hits().1);
        }
        // (Most solves of a slowly changing stream keep their working set.)
        assert!(hits.0 * 2 > hits.1, "{hits:?}");
    }

    /// Rows that never bind, put among a problem's rows (as the rows of road users out of
    /// reach are, when they are kept): the same solution bit for bit, from a cold start and
    /// along a hinted stream whose problems drift (what lets leaving those rows out change no
    /// command).
    #[test]
    fn rows_that_never_bind_change_no_bit_of_the_solution() {
        let mut rng = SplitMix64(5);
        for stream in 0..60 {
            let (r, k) = (1 + stream % 4, 2 + stream % 5);
            let (mut rows, u0, _) = random_problem(&mut rng, r, k, false);
            let far = constraint(1e9, &vec![1.0; r]);
            let (mut hint, mut padded_hint) = (QpHint::default(), QpHint::default());
            let (mut workspace, mut padded_workspace) = (QpWorkspace::default(), QpWorkspace::default());
            for step in 0..30 {
                for c in rows.iter_mut() {
                    c.a += 0.05 * (rng.next_f64() - 0.5);
                }
                let padded: Vec<Constraint> = rows
                    .iter()
                    .enumerate()
                    .flat_map(|(i, c)| (i % 2 == 0).then(|| far.clone()).into_iter().chain([c.clone()]))
                    .collect();
                let (mut u, mut u_padded) = (DVector::zeros(r), DVector::zeros(r));
                let flags = workspace.solve_hinted(&rows, &u0, None, &mut u, &mut hint);
                let padded_flags = padded_workspace.solve_hinted(&padded, &u0, None, &mut u_padded, &mut padded_hint);
                assert_eq!((flags, &u), (padded_flags, &u_padded), "stream {stream} step {step}");
                let mut cold = DVector::zeros(r);
                QpWorkspace::default().solve(&padded, &u0, None, &mut cold);
                assert_eq!(cold, u, "stream {stream} step {step}: cold against hinted");
            }
        }
    }

    /// The hint holds the solution of a problem seen again: it answers it (one equality
    /// solve) with what the cold solve finds.
    #[test]
    fn a_problem_seen_again_is_answered_by_its_hint() {
        let constraints = [
            constraint(-3.0, &[1.0, 2.0]),
            constraint(-1.0, &[1.0, -1.0]),
            constraint(9.0, &[0.5, 1.0]),
        ];
        let u0 = DVector::from_column_slice(&[0.5, -0.2]);
        let (mut workspace, mut hint) = (QpWorkspace::default(), QpHint::default());
        let (mut first, mut again) = (DVector::zeros(2), DVector::zeros(2));
        workspace.solve_hinted(&constraints, &u0, None, &mut first, &mut hint);
        assert_eq!(hint.hits(), (0, 1));
        workspace.solve_hinted(&constraints, &u0, None, &mut again, &mut hint);
        assert_eq!(hint.hits(), (1, 2));
        assert!((&first - &again).amax() < 1e-12, "{first} vs {again}");
        // Both barriers at equality: g_1 = g_2 = 0.
        for c in &constraints[..2] {
            assert!(c.value(&again).abs() < 1e-12, "{}", c.value(&again));
        }
    }

    /// Keyed rows: a row that came in before the hint's rows (another barrier's, met) and one
    /// that went leave the hint answering, with what the cold solve finds; unkeyed, the hint
    /// cannot follow the rows and the solve is cold.
    #[test]
    fn a_keyed_hint_holds_while_other_rows_come_and_go() {
        let (a, b) = (constraint(-3.0, &[1.0, 2.0]), constraint(-1.0, &[1.0, -1.0]));
        let (met, gone) = (constraint(9.0, &[0.5, 1.0]), constraint(7.0, &[-1.0, 0.3]));
        let u0 = DVector::from_column_slice(&[0.5, -0.2]);
        let first = [a.clone(), gone.clone(), b.clone()];
        let again = [met.clone(), a.clone(), b.clone()];
        for keyed in [true, false] {
            let (mut workspace, mut hint) = (QpWorkspace::default(), QpHint::default());
            let mut u = DVector::zeros(2);
            if keyed {
                hint.key_rows([10, 11, 12]);
            }
            workspace.solve_hinted(&first, &u0, None, &mut u, &mut hint);
            if keyed {
                hint.key_rows([9, 10, 12]);
            }
            workspace.solve_hinted(&again, &u0, None, &mut u, &mut hint);
            assert_eq!(hint.hits(), (u64::from(keyed), 2), "keyed {keyed}");
            let mut cold = DVector::zeros(2);
            QpWorkspace::default().solve(&again, &u0, None, &mut cold);
            assert_eq!(u, cold, "keyed {keyed}");
        }
    }

    #[test]
    fn a_reused_workspace_gives_what_a_fresh_one_gives() {
        // No state carried from one problem to the next: bit-identical results.
        let mut rng = SplitMix64(7);
        let mut reused = QpWorkspace::default();
        for trial in 0..500 {
            let (constraints, u0, limits) = random_problem(&mut rng, 1 + trial % 3, 1 + trial % 4, trial % 2 == 0);
            let limits = limits.as_ref().map(|(lo, hi)| (lo.as_slice(), hi.as_slice()));
            let (mut u_reused, mut u_fresh) = (DVector::zeros(u0.len()), DVector::zeros(u0.len()));
            let reused_flags = reused.solve(&constraints, &u0, limits, &mut u_reused);
            let fresh_flags = QpWorkspace::default().solve(&constraints, &u0, limits, &mut u_fresh);
            assert_eq!((reused_flags, &u_reused), (fresh_flags, &u_fresh));
        }
    }

    #[test]
    fn solving_allocates_nothing() {
        let mut rng = SplitMix64(3);
        let problems: Vec<_> = (0..200).map(|i| random_problem(&mut rng, 2, 1 + i % 3, true)).collect();
        // Sized when built (as the filter does): not even the first solve allocates.
        let mut workspace = QpWorkspace::with_capacity(2, 3);
        let mut u = DVector::zeros(2);
        let solve_all = |workspace: &mut QpWorkspace, u: &mut DVector<f64>| {
            for (constraints, u0, limits) in &problems {
                let (lo, hi) = limits.as_ref().unwrap();
                workspace.solve(constraints, u0, Some((lo, hi)), u);
            }
        };
        let counted = measure(|| solve_all(&mut workspace, &mut u));
        assert_eq!(counted.count_total, 0, "a solve allocated");
        // Nor a hinted one, the hint answering or not.
        let mut hint = QpHint::with_capacity(2, 3);
        let counted = measure(|| {
            for (constraints, u0, limits) in problems.iter().chain(&problems) {
                let (lo, hi) = limits.as_ref().unwrap();
                workspace.solve_hinted(constraints, u0, Some((lo, hi)), &mut u, &mut hint);
                workspace.solve_hinted(constraints, u0, Some((lo, hi)), &mut u, &mut hint);
            }
        });
        assert_eq!(counted.count_total, 0, "a hinted solve allocated");
        assert!(hint.hits().0 > 0, "{:?}", hint.hits());
        // A default workspace grows once, then allocates no more.
        let mut grown = QpWorkspace::default();
        solve_all(&mut grown, &mut u);
        let counted = measure(|| solve_all(&mut grown, &mut u));
        assert_eq!(counted.count_total, 0, "a warm solve allocated");
        // Timing (dev profile, shared machine: indicative only).
        let timed = std::time::Instant::now();
        for _ in 0..20 {
            solve_all(&mut workspace, &mut u);
        }
        let active_set = timed.elapsed().as_secs_f64() / (20.0 * problems.len() as f64);
        let timed = std::time::Instant::now();
        for (constraints, u0, limits) in &problems {
            let (lo, hi) = limits.as_ref().unwrap();
            clarabel_solve(constraints, u0, Some((lo, hi)));
        }
        let clarabel = timed.elapsed().as_secs_f64() / problems.len() as f64;
        println!(
            "per solve: active set {:.2} µs, fresh Clarabel {:.1} µs",
            active_set * 1e6,
            clarabel * 1e6
        );
    }

    /// The rows scaled to ‖b_k‖ = 1, as `solve` scales them (the problem it defines).
    fn unit_rows(constraints: &[Constraint]) -> Vec<Constraint> {
        let unit = |c: &Constraint| Constraint {
            h: c.h,
            a: c.a / c.b.norm(),
            b: &c.b / c.b.norm(),
        };
        constraints.iter().map(unit).collect()
    }

    /// That problem's objective at u.
    fn unit_objective(rows: &[Constraint], u0: &DVector<f64>, u: &DVector<f64>) -> f64 {
        (u - u0).norm_squared() + SLACK_PENALTY * rows.iter().map(|c| (-c.value(u)).max(0.0)).sum::<f64>()
    }

    /// γm's QP of two channels (several.rs: v = the real corrections and σ, each row
    /// [b, b/√m]) has every normal in one plane of R⁴, and a footprint's three circles against
    /// one circle of a road user give three rows through one point: with two of them in the
    /// working set the third meets the ratio test at t = 0 with a rate that is 0 up to
    /// rounding. Taking it made N Nᵀ singular or cycled, and handed the problem to Clarabel
    /// (785 of these 4000 problems; 13 decisions of USA_Peach-4_8_T-1). The active set now
    /// solves every one, no worse than Clarabel and optimal against every small move.
    #[test]
    fn rows_in_one_subspace_never_fall_back_to_clarabel() {
        let mut rng = SplitMix64(23);
        let mut workspace = QpWorkspace::default();
        let root_m = 50.0_f64.sqrt();
        let u0 = DVector::zeros(4);
        let mut u = DVector::zeros(4);
        let mut corrected = 0;
        for trial in 0..4000 {
            // Triples affine in one parameter, as a footprint's three circles along the body
            // against one circle of a road user: the middle row is the mean of the outer two,
            // so the three lines meet in one point.
            let triples = 1 + trial % 12;
            let mut constraints = Vec::with_capacity(3 * triples);
            for _ in 0..triples {
                let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
                let (a, da) = (uniform(-8.0, 4.0), uniform(-3.0, 3.0));
                let (b0, db0, b1) = (uniform(-2.0, 2.0), uniform(-2.0, 2.0), uniform(-1.0, 1.0));
                for j in 0..3 {
                    let (a, b0) = (a + j as f64 * da, b0 + j as f64 * db0);
                    constraints.push(Constraint {
                        h: 0.0,
                        a,
                        b: DVector::from_column_slice(&[b0, b1, b0 / root_m, b1 / root_m]),
                    });
                }
            }
            let (active, ..) = workspace.solve(&constraints, &u0, None, &mut u);
            corrected += usize::from(active);
            let rows = unit_rows(&constraints);
            let reference = clarabel_outcome(&rows, &u0, None).input;
            let (ours, theirs) = (unit_objective(&rows, &u0, &u), unit_objective(&rows, &u0, &reference));
            assert!(
                ours <= theirs + 1e-7 * (1.0 + theirs),
                "trial {trial}: {ours} > Clarabel's {theirs}"
            );
            for _ in 0..8 {
                let moved = DVector::from_iterator(4, (0..4).map(|i| u[i] + 1e-6 * (2.0 * rng.next_f64() - 1.0)));
                let nearby = unit_objective(&rows, &u0, &moved);
                assert!(
                    ours <= nearby + 1e-9 * (1.0 + ours),
                    "trial {trial}: {ours} > {nearby} nearby"
                );
            }
        }
        assert!(corrected > 3000, "{corrected} of 4000 corrected");
        assert_eq!(workspace.fallbacks(), 0);
    }

    /// A problem an episode formed (rows (h, a, b) from testdata/) solved from u0 without limits
    /// by a fresh workspace, which must not fall back; (active, infeasible, u, Clarabel's
    /// solution), with the objective checked against Clarabel's.
    fn recorded_problem(rows: &[(f64, f64, Vec<f64>)], u0: &[f64]) -> (bool, bool, DVector<f64>, DVector<f64>) {
        let to_row = |(h, a, b): &(f64, f64, Vec<f64>)| Constraint {
            h: *h,
            a: *a,
            b: DVector::from_column_slice(b),
        };
        let constraints: Vec<Constraint> = rows.iter().map(to_row).collect();
        let u0 = DVector::from_column_slice(u0);
        let mut workspace = QpWorkspace::default();
        let mut u = DVector::zeros(u0.len());
        let (active, infeasible, _) = workspace.solve(&constraints, &u0, None, &mut u);
        assert_eq!(workspace.fallbacks(), 0);
        let rows = unit_rows(&constraints);
        let reference = clarabel_outcome(&rows, &u0, None).input;
        let (ours, theirs) = (unit_objective(&rows, &u0, &u), unit_objective(&rows, &u0, &reference));
        assert!(ours <= theirs + 1e-9 * (1.0 + theirs), "{ours} > Clarabel's {theirs}");
        (active, infeasible, u, reference)
    }

    /// The first of Peach's 13 (above), as the episode formed it.
    #[test]
    fn peachs_degenerate_gamma_m_decision_is_solved_by_the_active_set() {
        let (active, _, u, reference) = recorded_problem(include!("testdata/peach_gamma_m_rows.in"), &[0.0; 4]);
        assert!(active);
        // (Clarabel's answer is within its tolerance: 1.3e-6 here.)
        assert!(
            (&u - &reference).amax() < 1e-5 * (1.0 + u.amax()),
            "{u} vs Clarabel's {reference}"
        );
    }

    /// An infeasible problem of many rows crosses one kink of the penalty per iteration (a
    /// row turns penalised or met): Flensburg's delay-free CBF-QP after its collision had 160
    /// decisions of 400–550 rows that ran out of 200 iterations and went to Clarabel. This one,
    /// as the episode formed it, is solved by the active set (four iterations per row at most).
    #[test]
    fn a_problem_of_many_violated_rows_is_solved_by_the_active_set() {
        let u0 = [0.018839010037539412, 0.0767512734369955];
        let (_, infeasible, ..) = recorded_problem(include!("testdata/flensburg_cbf_qp_rows.in"), &u0);
        assert!(infeasible);
    }
}
