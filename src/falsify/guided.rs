//! The guided search (`--method guided`, the default): a first generation spread over the box,
//! then generations that trisect the boundary between a qualified candidate that holds and a
//! failing candidate whose baseline fails too, and after those generations of a local model of
//! the score (a Gaussian process in a trust region, Thompson-sampled: [`super::surrogate`])
//! alternating with uniform draws over the box (docs/falsification.md measures each of these
//! ideas; the model replaced CMA-ES in issue 53, measured on a tuning and a test half).
//!
//! Why the boundary: a baseline-qualified violation is a candidate that fails while its
//! baseline holds. Where the baseline is the more capable configuration (no delays, the true
//! delay assumed, no jitter), "the baseline fails" implies "the candidate fails", so on a path
//! from a candidate that holds (class S: qualified, m ≥ T) to one that fails with a failing
//! baseline (class U), the candidate fails first: the points between its failure boundary and
//! the baseline's are violations. Trisection of the closest S–U pair not bracketed yet (two
//! points at the segment's thirds, one generation) shrinks the bracket 3 times per
//! generation; when the two boundaries meet (a bracket shorter than [`BRACKET_TOLERANCE`]) the
//! pair is spent. Without a baseline no candidate is in U and the search is the spread
//! generation plus the model's generations.
//!
//! Noise: where a random seed or actuation jitter decides the outcome, the classes of the
//! points on a bracket's line interleave (`ordered_along`); the score's mean then does not
//! point to violations either, so the rest of the budget goes to uniform draws where the
//! baseline held and barely did: each the proposal, of those whose nearest evaluated
//! candidate (seeds left out of the distance) was qualified, nearest the baseline's edge
//! (`qualified_points`).
//!
//! Determinism: every draw comes from the search's seeded generator in the order of the
//! generations, and a generation's evaluations are recorded in canonical order.

use std::collections::HashSet;

use super::{
    append, done, population_size, surrogate, uniform_points, Evaluation, Evaluator, FalsifyError, Problem, Search,
};
use crate::random::SplitMix64;

/// A bracket whose endpoints are closer than this (Euclidean, in box units) is spent: the
/// candidate's and the baseline's boundaries meet there.
pub const BRACKET_TOLERANCE: f64 = 1e-3;

/// Points of a bracket generation, at k/(n + 1) of the segment: each generation shrinks the
/// bracket 3 times (two runs), where 8 points shrink it 9 times for eight runs. On the
/// rare-failure box (problem 5 of docs/falsification.md) the slab of violations is a few
/// percent of the first segment, and trisection reaches it in fewer runs than generations of
/// 8 (seeds 1–30: median 12 against 14).
const BRACKET_POINTS: usize = 2;

/// At most this many of the latest candidates of each class are paired (bounds the pairing's
/// cost at any budget).
const PAIRING_WINDOW: usize = 400;

/// The two classes of the boundary a violation lies on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Class {
    /// Qualified and holding (m ≥ T).
    Holds,
    /// Failing (m < T) with a baseline that does not qualify it.
    FailsWithBaseline,
    Other,
}

fn class_of(e: &Evaluation, threshold: f64) -> Class {
    match (e.objective, e.baseline, e.error.is_none()) {
        (Some(m), _, true) if e.qualified && m >= threshold => Class::Holds,
        (Some(m), Some(_), true) if !e.qualified && m < threshold => Class::FailsWithBaseline,
        _ => Class::Other,
    }
}

/// Whether `evaluations` (the points on a bracket's line) lie along the direction from `a`
/// (holds) to `b` (fails with its baseline) in the order the bracket assumes: holding, then
/// violations, then failing with the baseline. Where a random seed or actuation jitter decides
/// the outcome the classes interleave (or a candidate holds where its more capable baseline
/// fails), and the brackets do not converge: gamma_m_jitter's first bracket of 8 points shrank
/// from 0.54 to 0.03 box units in five generations without being spent.
fn ordered_along<'a>(
    a: &[f64],
    b: &[f64],
    evaluations: impl IntoIterator<Item = &'a Evaluation>,
    threshold: f64,
) -> bool {
    let direction: Vec<f64> = a.iter().zip(b).map(|(x, y)| y - x).collect();
    let mut ranked: Vec<(f64, u8)> = Vec::new();
    for e in evaluations {
        let rank = match class_of(e, threshold) {
            _ if e.violation => 1,
            Class::Holds => 0,
            Class::FailsWithBaseline => 2,
            Class::Other if e.error.is_some() || e.objective.is_none() => continue,
            // Holds while its baseline fails: the premise of the bracket fails here.
            Class::Other => return false,
        };
        ranked.push((projection(&e.point, a, &direction), rank));
    }
    ranked.sort_by(|x, y| x.0.total_cmp(&y.0));
    ranked.windows(2).all(|w| w[0].1 <= w[1].1)
}

/// The evaluations on the line through `a` and `b` (within 1e-9 box units): a bracket's ends,
/// its points and those of the earlier brackets of its lineage, which all lie on that line.
fn on_line<'a>(a: &'a [f64], b: &'a [f64], evaluations: &'a [Evaluation]) -> impl Iterator<Item = &'a Evaluation> {
    let direction: Vec<f64> = a.iter().zip(b).map(|(x, y)| y - x).collect();
    let length2: f64 = direction.iter().map(|x| x * x).sum();
    evaluations.iter().filter(move |e| {
        let t = projection(&e.point, a, &direction) / length2;
        let off2: f64 = e
            .point
            .iter()
            .zip(a)
            .zip(&direction)
            .map(|((p, x), d)| (p - x - t * d).powi(2))
            .sum();
        off2 < 1e-18
    })
}

/// (p − a) · direction.
fn projection(p: &[f64], a: &[f64], direction: &[f64]) -> f64 {
    p.iter().zip(a).zip(direction).map(|((p, x), d)| (p - x) * d).sum()
}

/// Whether a range is a random seed (`seed`, `….seed`): its value changes the outcome without
/// order, so distances between candidates leave it out.
fn is_seed(key: &str) -> bool {
    key == "seed" || key.ends_with(".seed")
}

/// Proposals drawn for one point of [`qualified_points`] before it takes the last one.
const PROPOSALS_PER_POINT: usize = 64;

/// Qualified proposals [`qualified_points`] chooses each point from (the one nearest the
/// baseline's edge). gamma_m_jitter over seeds 1–100: 1 (the first qualified one) found a
/// violation in 89 seeds (median 46 runs), 4 in 96 (30.5), 8 in 98 (33.5), 32 in 87 (44.5): a
/// stronger choice crowds the draws where the nearest-neighbour model of the margin is wrong.
const QUALIFIED_CHOICES: usize = 8;

/// `count` uniform points of the d-dimensional unit box. Each is the proposal, of the first
/// [`QUALIFIED_CHOICES`] whose nearest evaluated candidate (of the latest [`PAIRING_WINDOW`],
/// distance over the coordinates `dims`) was qualified, whose nearest candidate's baseline
/// margin is the smallest (the last proposal of [`PROPOSALS_PER_POINT`] if none was
/// qualified). A candidate whose baseline fails is never a violation, so the draws avoid the
/// part of the box the baseline is known to fail in; and the less capable candidate fails
/// most often where the baseline itself barely holds (gamma_m_jitter, 2000 uniform draws:
/// 6.4 % violations in the tenth of the qualified draws with the smallest baseline margin,
/// none in the half with the largest).
fn qualified_points(
    generator: &mut SplitMix64,
    count: usize,
    d: usize,
    dims: &[usize],
    evaluations: &[Evaluation],
) -> Vec<Vec<f64>> {
    let known: Vec<&Evaluation> = evaluations[evaluations.len().saturating_sub(PAIRING_WINDOW)..]
        .iter()
        .filter(|e| e.error.is_none() && e.objective.is_some())
        .collect();
    // The nearest known candidate's (qualified, baseline margin); None with none known.
    // Qualified with an unknown margin (no baseline run) ranks last.
    let nearest = |z: &[f64]| {
        known
            .iter()
            .map(|e| (dims.iter().map(|&k| (e.point[k] - z[k]).powi(2)).sum::<f64>(), e))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, e)| (e.qualified, e.baseline.unwrap_or(f64::INFINITY)))
    };
    (0..count)
        .map(|_| {
            let mut best: Option<(f64, Vec<f64>)> = None;
            let mut qualified = 0;
            let mut z = Vec::new();
            for _ in 0..PROPOSALS_PER_POINT {
                z = (0..d).map(|_| generator.next_f64()).collect();
                match nearest(&z) {
                    None => return z,
                    Some((false, _)) => {}
                    Some((true, margin)) => {
                        if best.as_ref().is_none_or(|(m, _)| margin < *m) {
                            best = Some((margin, z.clone()));
                        }
                        qualified += 1;
                        if qualified == QUALIFIED_CHOICES {
                            break;
                        }
                    }
                }
            }
            best.map_or(z, |(_, b)| b)
        })
        .collect()
}

/// The Euclidean distance of two points of the box (box units).
fn euclidean(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt()
}

/// What the guided search knows of its candidates besides their evaluations, in the search's
/// order.
struct Memory {
    /// Whether a candidate no longer ends brackets (its lineage is spent, or it lies near a
    /// violation found when more than one failure mode is asked for).
    used: Vec<bool>,
    /// The bracket lineage a candidate was placed by.
    lineage: Vec<Option<usize>>,
    classes: Vec<Class>,
    /// The pairs (holds, fails) that already ended a bracket. Each end stays free to pair
    /// with the bracket's new points: a trisection's points may all fall on one side.
    bracketed: HashSet<(usize, usize)>,
}

impl Memory {
    /// The closest pair (holds, fails with its baseline) not yet bracketed, if any.
    fn closest_pair(&self, evaluations: &[Evaluation]) -> Option<(usize, usize, f64)> {
        let latest = |class: Class| -> Vec<usize> {
            let mut v: Vec<usize> = (0..self.classes.len())
                .rev()
                .filter(|&i| !self.used[i] && self.classes[i] == class)
                .take(PAIRING_WINDOW)
                .collect();
            v.reverse();
            v
        };
        let holds = latest(Class::Holds);
        let fails = latest(Class::FailsWithBaseline);
        let mut best: Option<(usize, usize, f64)> = None;
        for &s in &holds {
            for &u in &fails {
                if self.bracketed.contains(&(s, u)) {
                    continue;
                }
                let d = euclidean(&evaluations[s].point, &evaluations[u].point);
                if best.is_none_or(|(_, _, b)| d < b) {
                    best = Some((s, u, d));
                }
            }
        }
        best
    }
}

/// Runs the guided search into `found`.
pub(super) fn run_guided(
    problem: &Problem,
    evaluator: &Evaluator<'_>,
    pool: &rayon::ThreadPool,
    found: &mut Search,
    progress: &mut impl FnMut(&Search),
) -> Result<(), FalsifyError> {
    let d = problem.ranges.len();
    let lambda = population_size(d);
    let mut generator = SplitMix64(problem.seed ^ 0x6D1D_ED5E_A2C4);
    let mut memory = Memory {
        used: Vec::new(),
        lineage: Vec::new(),
        classes: Vec::new(),
        bracketed: HashSet::new(),
    };
    let evaluate = |units: Vec<Vec<f64>>| evaluator.evaluate_all(pool, units);
    let mut generation = 0;
    let record = |found: &mut Search,
                  memory: &mut Memory,
                  generation: &mut usize,
                  batch: Vec<Evaluation>,
                  lineage: Option<usize>,
                  progress: &mut dyn FnMut(&Search)| {
        let violated = memory.record(problem, found, (*generation, batch, lineage));
        *generation += 1;
        progress(found);
        violated
    };
    let remaining = |found: &Search| problem.budget.saturating_sub(found.evaluations.len());

    // 1. The first generation: a Latin hypercube (each coordinate's strata hit once).
    if !done(problem, found) {
        // With a baseline it only has to give the brackets a pair: half of λ (problem 5 of
        // docs/falsification.md over seeds 1–30: 10 runs against 12 with λ; problem 1 on seeds
        // 1–10: 4.5 against 10).
        // Without one it is CMA-ES's first look at the box (problem 3 with 4 points: two of
        // ten seeds without a violation).
        let first = if problem.baseline.is_empty() {
            lambda
        } else {
            lambda.div_ceil(2)
        };
        let units = latin_hypercube(&mut generator, first.min(remaining(found)), d);
        let batch = evaluate(units);
        record(found, &mut memory, &mut generation, batch, None, progress);
    }

    // 2. Brackets and CMA-ES generations.
    let mut bracket_evaluations = 0usize;
    let mut lineages = 0usize;
    let (mut model_generations, mut explore_generations) = (0usize, 0usize);
    // Set by a bracket whose classes interleave: noise decides the outcome, the score does not
    // point to violations (CMA-ES minimises its mean and drifts to low jitter), and the rest of
    // the budget goes to uniform draws where the baseline may hold.
    let mut noisy = false;
    let seed_free: Vec<usize> = (0..d).filter(|&k| !is_seed(&problem.ranges[k].key)).collect();
    let (mut region, mut region_start, mut elsewhere) = (surrogate::Region::new(), 0usize, false);
    while !done(problem, found) {
        if !noisy && 2 * bracket_evaluations <= found.evaluations.len() {
            if let Some((s, u, distance)) = memory.closest_pair(&found.evaluations) {
                if distance < BRACKET_TOLERANCE {
                    // The boundaries meet: spend the pair and its lineage.
                    let spent = memory.lineage[s].or(memory.lineage[u]);
                    for i in 0..memory.classes.len() {
                        if i == s || i == u || (spent.is_some() && memory.lineage[i] == spent) {
                            memory.used[i] = true;
                        }
                    }
                    continue;
                }
                let lineage = memory.lineage[s].or(memory.lineage[u]).unwrap_or_else(|| {
                    lineages += 1;
                    lineages
                });
                memory.bracketed.insert((s, u));
                let (a, b) = (&found.evaluations[s].point, &found.evaluations[u].point);
                let units = between(a, b, BRACKET_POINTS.min(remaining(found)));
                bracket_evaluations += units.len();
                let batch = evaluate(units);
                let violated = record(found, &mut memory, &mut generation, batch, Some(lineage), progress);
                let (a, b) = (&found.evaluations[s].point, &found.evaluations[u].point);
                let recent = &found.evaluations[found.evaluations.len().saturating_sub(PAIRING_WINDOW)..];
                if !violated && !ordered_along(a, b, on_line(a, b, recent), problem.threshold) {
                    noisy = true;
                }
                continue;
            }
        }
        // Every other generation explores: uniform draws over the box (what random search does),
        // so an optimiser stuck in a flat or noisy basin costs at most half the budget.
        if noisy || model_generations > explore_generations {
            let count = lambda.min(remaining(found));
            let units = if noisy {
                qualified_points(&mut generator, count, d, &seed_free, &found.evaluations)
            } else {
                uniform_points(&mut generator, count, d)
            };
            explore_generations += 1;
            let batch = evaluate(units);
            record(found, &mut memory, &mut generation, batch, None, progress);
            continue;
        }
        // A generation of the model's trust region about the lowest score since the region
        // started (super::surrogate). A collapsed region, or a violation when another failure
        // mode is wanted, starts a new one after a generation of uniform draws.
        let own = &found.evaluations[region_start..];
        let Some(best) = surrogate::lowest_score(own) else {
            // After a collapse the next region is about the search's lowest score; after a
            // violation when another mode is wanted, about the lowest of these draws.
            if !elsewhere {
                region_start = 0;
            }
            elsewhere = false;
            let units = uniform_points(&mut generator, lambda.min(remaining(found)), d);
            model_generations += 1;
            let batch = evaluate(units);
            record(found, &mut memory, &mut generation, batch, None, progress);
            continue;
        };
        let units = region.propose(&mut generator, own, &own[best].point, lambda.min(remaining(found)));
        let before = own[best].score;
        model_generations += 1;
        let batch = evaluate(units);
        let violated = record(found, &mut memory, &mut generation, batch, None, progress);
        let own = &found.evaluations[region_start..];
        let after = surrogate::lowest_score(own).map_or(before, |i| own[i].score);
        region.update(after < before - 1e-3 * before.abs());
        elsewhere = violated && problem.counterexamples > 1 && !problem.worst;
        if region.collapsed() || elsewhere {
            region = surrogate::Region::new();
            region_start = found.evaluations.len();
        }
    }
    Ok(())
}

/// `count` points of the unit box in a Latin hypercube: along each coordinate, one in each of
/// `count` equal strata (the strata shuffled per coordinate, the point uniform in its stratum).
pub(super) fn latin_hypercube(generator: &mut SplitMix64, count: usize, d: usize) -> Vec<Vec<f64>> {
    let mut units = vec![vec![0.0; d]; count];
    for i in 0..d {
        let mut strata: Vec<usize> = (0..count).collect();
        for k in (1..count).rev() {
            strata.swap(k, generator.below(k + 1));
        }
        for (unit, stratum) in units.iter_mut().zip(strata) {
            unit[i] = (stratum as f64 + generator.next_f64()) / count as f64;
        }
    }
    units
}

/// `count` points evenly spaced strictly between `a` and `b` (a bracket's probes).
fn between(a: &[f64], b: &[f64], count: usize) -> Vec<Vec<f64>> {
    (1..=count)
        .map(|k| {
            let t = k as f64 / (count + 1) as f64;
            a.iter().zip(b).map(|(a, b)| a + t * (b - a)).collect()
        })
        .collect()
}

impl Memory {
    /// Records a generation (in canonical order) into the search and the memory; with more
    /// than one failure mode asked for, the candidates near a new violation stop ending
    /// brackets (the next bracket looks elsewhere). Returns whether it found a violation.
    fn record(
        &mut self,
        problem: &Problem,
        found: &mut Search,
        (generation, batch, lineage): (usize, Vec<Evaluation>, Option<usize>),
    ) -> bool {
        let start = found.evaluations.len();
        append(found, problem.seed, generation, batch);
        for e in &found.evaluations[start..] {
            self.used.push(false);
            self.lineage.push(lineage);
            self.classes.push(class_of(e, problem.threshold));
        }
        let new_violations: Vec<&Evaluation> = found.evaluations[start..].iter().filter(|e| e.violation).collect();
        if problem.counterexamples > 1 {
            for v in &new_violations {
                for (i, e) in found.evaluations.iter().enumerate() {
                    if e.box_distance(v) < super::MODE_SEPARATION {
                        self.used[i] = true;
                    }
                }
            }
        }
        !new_violations.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn evaluation(point: [f64; 2], m: f64, baseline: f64) -> Evaluation {
        Evaluation {
            index: 0,
            generation: 0,
            parameters: Vec::new(),
            objective: Some(m),
            baseline: Some(baseline),
            score: 0.0,
            qualified: baseline >= 0.0,
            baseline_progress: None,
            violation: m < 0.0 && baseline >= 0.0,
            severity: Default::default(),
            error: None,
            failure_mode: None,
            within_delay: None,
            point: point.to_vec(),
        }
    }

    #[test]
    fn brackets_pair_the_closest_holding_and_doubly_failing_candidates_once() {
        let evaluations = vec![
            evaluation([0.0, 0.0], 0.3, 0.2),    // holds
            evaluation([0.4, 0.0], 0.1, 0.05),   // holds
            evaluation([0.9, 0.0], -2.0, -1.0),  // fails with its baseline
            evaluation([0.6, 0.0], -0.5, -0.01), // fails with its baseline
            evaluation([0.5, 0.5], -0.2, 0.0),   // a violation: neither class
        ];
        let classes: Vec<Class> = evaluations.iter().map(|e| class_of(e, 0.0)).collect();
        assert_eq!(
            classes,
            [
                Class::Holds,
                Class::Holds,
                Class::FailsWithBaseline,
                Class::FailsWithBaseline,
                Class::Other
            ]
        );
        let mut memory = Memory {
            used: vec![false; 5],
            lineage: vec![None; 5],
            classes,
            bracketed: HashSet::new(),
        };
        let (s, u, d) = memory.closest_pair(&evaluations).unwrap();
        assert_eq!((s, u), (1, 3));
        assert!((d - 0.2).abs() < 1e-12);
        // A pair ends one bracket; its ends pair with others (0.5 apart before 0.6 and 0.9).
        memory.bracketed.insert((1, 3));
        assert_eq!(memory.closest_pair(&evaluations).map(|(s, u, _)| (s, u)), Some((1, 2)));
        memory.bracketed.insert((1, 2));
        assert_eq!(memory.closest_pair(&evaluations).map(|(s, u, _)| (s, u)), Some((0, 3)));
        // A candidate that no longer ends brackets leaves every pair it is in.
        memory.used[0] = true;
        assert_eq!(memory.closest_pair(&evaluations), None);
    }

    #[test]
    fn a_bracket_is_ordered_only_when_holding_violations_and_failures_follow_each_other() {
        let (a, b) = ([0.0, 0.0], [1.0, 0.0]);
        let holds = |t: f64| evaluation([t, 0.1], 0.2, 0.1);
        let violates = |t: f64| evaluation([t, -0.1], -0.2, 0.1);
        let fails = |t: f64| evaluation([t, 0.0], -1.0, -0.5);
        // Canonical order is not segment order: the points are ranked by their projection.
        let ordered = [fails(0.8), holds(0.2), violates(0.5), holds(0.1), fails(0.9)];
        assert!(ordered_along(&a, &b, &ordered, 0.0));
        assert!(!ordered_along(&a, &b, &[holds(0.2), fails(0.5), holds(0.7)], 0.0));
        assert!(!ordered_along(&a, &b, &[violates(0.6), holds(0.7)], 0.0));
        // Holding where the baseline fails contradicts the bracket's premise.
        assert!(!ordered_along(
            &a,
            &b,
            &[holds(0.2), evaluation([0.5, 0.0], 0.3, -0.1), fails(0.8)],
            0.0
        ));
        // A failed run says nothing about the order.
        let mut failed = holds(0.9);
        failed.objective = None;
        failed.error = Some("run failed".into());
        assert!(ordered_along(&a, &b, &[holds(0.2), failed, fails(0.8)], 0.0));
    }

    #[test]
    fn draws_after_noise_avoid_where_the_nearest_candidate_was_not_qualified() {
        // The baseline fails for x > 0.5, its margin shrinking toward it (the second
        // coordinate is a seed: left out).
        let evaluations: Vec<Evaluation> = (0..20)
            .map(|i| {
                let x = (i as f64 + 0.5) / 20.0;
                let seed = if i % 2 == 0 { 0.05 } else { 0.95 };
                evaluation([x, seed], 0.1, if x < 0.5 { 0.5 - x } else { -0.1 })
            })
            .collect();
        let mut generator = SplitMix64(7);
        let points = qualified_points(&mut generator, 200, 2, &[0], &evaluations);
        assert_eq!(points.len(), 200);
        assert!(points.iter().all(|p| p[0] < 0.5), "{points:?}");
        // The best of 8 toward the baseline's edge: uniform on [0, 0.5] would average 0.25,
        // the largest of 8 such draws about 0.44 (the neighbours' cells round it).
        let mean = points.iter().map(|p| p[0]).sum::<f64>() / 200.0;
        assert!(mean > 0.38, "mean x {mean}");
        // Seeds stay uniform draws over the whole range.
        assert!(points.iter().any(|p| p[1] > 0.5) && points.iter().any(|p| p[1] < 0.5));
        // With no qualified candidate the draws are uniform (the last proposal is taken).
        let failing: Vec<Evaluation> = (0..4).map(|i| evaluation([i as f64 / 4.0, 0.5], -1.0, -1.0)).collect();
        let points = qualified_points(&mut generator, 50, 2, &[0], &failing);
        assert!(points.iter().any(|p| p[0] > 0.5) && points.iter().any(|p| p[0] < 0.5));
    }
}
