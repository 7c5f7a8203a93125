//! Plane geometry shared by the pure-maths blocks (a leaf): natural cubic splines, polylines
//! (length, resampling, distance), points against segments and polygons. Used by the recorded
//! road users (`actor::recorded`), the smooth road edges (`barrier::curve`), the route nominal,
//! CommonRoad routes and the goal metrics.

/// Natural cubic spline through (t_k, y_k) (t strictly increasing, at least 2 knots): per piece
/// the coefficients (y_k, b_k, c_k, d_k) of y_k + b_k u + c_k u² + d_k u³, u = t − t_k (exact at
/// the knots), second derivative continuous and 0 at both ends.
pub fn natural_spline(t: &[f64], values: &[f64]) -> Vec<[f64; 4]> {
    let n = t.len();
    let h: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    let slope: Vec<f64> = (0..n - 1).map(|k| (values[k + 1] - values[k]) / h[k]).collect();
    // Second derivatives M (M_0 = M_{n−1} = 0): h_{k−1} M_{k−1} + 2 (h_{k−1} + h_k) M_k
    // + h_k M_{k+1} = 6 (slope_k − slope_{k−1}), by the Thomas algorithm.
    let mut m = vec![0.0; n];
    if n > 2 {
        let inner = n - 2;
        let (mut diag, mut rhs) = (vec![0.0; inner], vec![0.0; inner]);
        for i in 0..inner {
            diag[i] = 2.0 * (h[i] + h[i + 1]);
            rhs[i] = 6.0 * (slope[i + 1] - slope[i]);
            if i > 0 {
                let w = h[i] / diag[i - 1];
                diag[i] -= w * h[i];
                rhs[i] -= w * rhs[i - 1];
            }
        }
        for i in (0..inner).rev() {
            m[i + 1] = (rhs[i] - h[i + 1] * m[i + 2]) / diag[i];
        }
    }
    (0..n - 1)
        .map(|k| {
            let b = slope[k] - h[k] * (2.0 * m[k] + m[k + 1]) / 6.0;
            [values[k], b, 0.5 * m[k], (m[k + 1] - m[k]) / (6.0 * h[k])]
        })
        .collect()
}

/// Value, first and second derivative of a spline piece ([`natural_spline`]) at u.
#[inline]
pub fn cubic_at(c: &[f64; 4], u: f64) -> [f64; 3] {
    let [y, b, c2, d] = *c;
    [
        y + u * (b + u * (c2 + u * d)),
        b + u * (2.0 * c2 + 3.0 * u * d),
        2.0 * c2 + 6.0 * u * d,
    ]
}

/// The polyline's length.
pub fn length(points: &[[f64; 2]]) -> f64 {
    points
        .windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .sum()
}

/// `n` ≥ 2 points at equal arc-length fractions of the polyline (at least 2 points), its ends
/// included.
pub fn resample(points: &[[f64; 2]], n: usize) -> Vec<[f64; 2]> {
    let lengths: Vec<f64> = points
        .windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .collect();
    let total: f64 = lengths.iter().sum();
    let mut out = Vec::with_capacity(n);
    let (mut k, mut walked) = (0, 0.0);
    for i in 0..n {
        let target = total * i as f64 / (n - 1) as f64;
        while k + 1 < lengths.len() && walked + lengths[k] < target {
            walked += lengths[k];
            k += 1;
        }
        let f = if lengths[k] > 0.0 {
            ((target - walked) / lengths[k]).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (a, b) = (points[k], points[k + 1]);
        out.push([a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])]);
    }
    out
}

/// The point of the segment a–b nearest to p, as its fraction along the segment (0 for a point
/// segment), and its distance from p.
#[inline]
pub fn project_on_segment(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> (f64, f64) {
    let (f, [dx, dy]) = segment_offset(a, b, p);
    (f, dx.hypot(dy))
}

/// [`project_on_segment`]'s fraction and the offset from its nearest point to p (whose norm
/// is the distance).
#[inline]
fn segment_offset(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> (f64, [f64; 2]) {
    let d = [b[0] - a[0], b[1] - a[1]];
    let l2 = d[0] * d[0] + d[1] * d[1];
    let f = if l2 > 0.0 {
        (((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (f, [p[0] - a[0] - f * d[0], p[1] - a[1] - f * d[1]])
}

/// The distance from p to the polyline.
pub fn polyline_distance(points: &[[f64; 2]], p: [f64; 2]) -> f64 {
    points
        .windows(2)
        .map(|w| project_on_segment(w[0], w[1], p).1)
        .fold(f64::INFINITY, f64::min)
}

/// Consecutive points per block of a [`Blocks`] index.
const BLOCK: usize = 16;

/// An index of a point sequence for exact nearest searches that skip most of it: the points in
/// blocks of 16 consecutive ones, each with a circle holding them and the next block's first
/// point (so the segment joining two blocks too). No point or segment of a block is nearer to q
/// than ‖q − c‖ − r; a search visits the block of the least such bound first and then only the
/// blocks whose bound does not exceed the best distance found. The answers are the linear
/// scan's to the bit (the same values, the same tie rule).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Blocks {
    /// Per block, the centre and radius of its circle.
    circles: Vec<([f64; 2], f64)>,
    points: usize,
}

impl Blocks {
    /// The index of `points`.
    pub fn new(points: &[[f64; 2]]) -> Blocks {
        let circles = (0..points.len())
            .step_by(BLOCK)
            .map(|first| {
                let span = &points[first..(first + BLOCK + 1).min(points.len())];
                let (mut lo, mut hi) = (span[0], span[0]);
                for p in span {
                    lo = [lo[0].min(p[0]), lo[1].min(p[1])];
                    hi = [hi[0].max(p[0]), hi[1].max(p[1])];
                }
                let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
                let radius = span
                    .iter()
                    .map(|p| (p[0] - centre[0]).hypot(p[1] - centre[1]))
                    .fold(0.0, f64::max);
                (centre, radius)
            })
            .collect();
        Blocks {
            circles,
            points: points.len(),
        }
    }

    /// ‖q − c‖ and r of block b's circle: nothing in it is nearer to q than their difference.
    #[inline]
    fn reach(&self, b: usize, q: [f64; 2]) -> (f64, f64) {
        let (c, r) = self.circles[b];
        (((q[0] - c[0]).powi(2) + (q[1] - c[1]).powi(2)).sqrt(), r)
    }

    /// Whether block b may hold a point or segment within `best` of q: false only when its
    /// bound exceeds `best` by more than rounding (NaN never prunes).
    #[inline]
    fn may_hold(&self, b: usize, q: [f64; 2], best: f64) -> bool {
        let (to_centre, r) = self.reach(b, q);
        let bound = to_centre - r - 1e-9 * (1.0 + to_centre + r);
        bound.is_nan() || bound <= best
    }

    /// The block of the least bound from q (0 when none is finite).
    fn seed(&self, q: [f64; 2]) -> usize {
        let mut seed = (f64::INFINITY, 0);
        for b in 0..self.circles.len() {
            let (to_centre, r) = self.reach(b, q);
            if to_centre - r < seed.0 {
                seed = (to_centre - r, b);
            }
        }
        seed.1
    }

    /// The indices of block b's points.
    fn range(&self, b: usize) -> std::ops::Range<usize> {
        b * BLOCK..((b + 1) * BLOCK).min(self.points)
    }

    /// The search every query shares: `scan` folds the points of a block's index range into
    /// `best`, the seed block first, then every block that may hold something within
    /// `distance(best)` of q.
    fn search<T>(
        &self,
        q: [f64; 2],
        mut best: T,
        distance: impl Fn(&T) -> f64,
        scan: impl Fn(std::ops::Range<usize>, T) -> T,
    ) -> T {
        if self.circles.is_empty() {
            return best;
        }
        let seed = self.seed(q);
        best = scan(self.range(seed), best);
        for b in (0..self.circles.len()).filter(|&b| b != seed) {
            if self.may_hold(b, q, distance(&best)) {
                best = scan(self.range(b), best);
            }
        }
        best
    }

    /// The first of the indexed `points` at the least squared distance from q (0 when q is
    /// not finite), and that squared distance: the linear scan's answer.
    pub fn nearest_point(&self, points: &[[f64; 2]], q: [f64; 2]) -> (usize, f64) {
        debug_assert_eq!(points.len(), self.points);
        let scan = |range: std::ops::Range<usize>, mut best: (f64, usize)| {
            for k in range {
                let d2 = (points[k][0] - q[0]).powi(2) + (points[k][1] - q[1]).powi(2);
                if d2 < best.0 || (d2 == best.0 && k < best.1) {
                    best = (d2, k);
                }
            }
            best
        };
        let (d2, k) = self.search(q, (f64::INFINITY, 0), |best| best.0.sqrt(), scan);
        (k, d2)
    }

    /// The first segment k (from `points[k]` to `points[k + 1]`) of the polyline through the
    /// indexed `points` at the least distance from q, with the fraction along it of its point
    /// nearest q and that distance ([`project_on_segment`]): the linear scan's answer (0, 0, ∞
    /// without a segment).
    pub fn nearest_segment(&self, points: &[[f64; 2]], q: [f64; 2]) -> (usize, f64, f64) {
        debug_assert_eq!(points.len(), self.points);
        let scan = |range: std::ops::Range<usize>, mut best: (usize, f64, f64)| {
            // A segment whose squared distance exceeds the best's square by more than rounding
            // is not nearer: passed over without the (slow) hypot.
            let mut beyond = best.2 * best.2 * (1.0 + 1e-9);
            for k in range.filter(|&k| k + 1 < points.len()) {
                let (a, b) = (points[k], points[k + 1]);
                let (f, [dx, dy]) = segment_offset(a, b, q);
                if dx * dx + dy * dy > beyond {
                    continue;
                }
                let d = dx.hypot(dy);
                if d < best.2 || (d == best.2 && k < best.0) {
                    best = (k, f, d);
                    beyond = d * d * (1.0 + 1e-9);
                }
            }
            best
        };
        self.search(q, (0, 0.0, f64::INFINITY), |best| best.2, scan)
    }

    /// The distance from q to the polyline through the indexed `points` ([`polyline_distance`]).
    pub fn polyline_distance(&self, points: &[[f64; 2]], q: [f64; 2]) -> f64 {
        debug_assert_eq!(points.len(), self.points);
        // Block b holds the segments starting at its points (the last joins the next block).
        let scan = |range: std::ops::Range<usize>, best: f64| {
            range
                .filter(|&k| k + 1 < points.len())
                .map(|k| project_on_segment(points[k], points[k + 1], q).1)
                .fold(best, f64::min)
        };
        self.search(q, f64::INFINITY, |best| *best, scan)
    }
}

/// Whether p lies inside the polygon (even-odd rule; the last point joins the first).
pub fn polygon_contains(polygon: &[[f64; 2]], p: [f64; 2]) -> bool {
    let n = polygon.len();
    let mut inside = false;
    for i in 0..n {
        let (a, b) = (polygon[i], polygon[(i + n - 1) % n]);
        if (a[1] > p[1]) != (b[1] > p[1]) && p[0] < (b[0] - a[0]) * (p[1] - a[1]) / (b[1] - a[1]) + a[0] {
            inside = !inside;
        }
    }
    inside
}

/// The distance from p to the polygon's boundary (its closing edge included).
pub fn polygon_boundary_distance(polygon: &[[f64; 2]], p: [f64; 2]) -> f64 {
    let n = polygon.len();
    (0..n)
        .map(|i| project_on_segment(polygon[i], polygon[(i + n - 1) % n], p).1)
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The block index answers as the linear scans do, to the bit, on winding polylines with
    /// repeated points and on points all equally far from the query (the first one wins).
    #[test]
    fn blocks_answer_as_the_linear_scan() {
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let scan = |points: &[[f64; 2]], q: [f64; 2]| {
            let mut best = (f64::INFINITY, 0);
            for (k, p) in points.iter().enumerate() {
                let d2 = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
                if d2 < best.0 {
                    best = (d2, k);
                }
            }
            (best.1, best.0)
        };
        // The route nominal's scan: the first segment of the least distance.
        let segment_scan = |points: &[[f64; 2]], q: [f64; 2]| {
            let (mut best, mut k_best, mut f_best) = (f64::INFINITY, 0, 0.0_f64);
            for k in 0..points.len().saturating_sub(1) {
                let (f, d) = project_on_segment(points[k], points[k + 1], q);
                if d < best {
                    (best, k_best, f_best) = (d, k, f);
                }
            }
            (k_best, f_best.to_bits(), best.to_bits())
        };
        for n in [1, 2, 15, 16, 17, 33, 300] {
            let mut points = Vec::new();
            let (mut x, mut y, mut heading) = (1e5, -3e4, 0.0_f64);
            for k in 0..n {
                heading += 0.6 * (uniform() - 0.5);
                x += 2.0 * heading.cos();
                y += 2.0 * heading.sin();
                points.push([x, y]);
                if k % 7 == 3 {
                    points.push([x, y]);
                }
            }
            let blocks = Blocks::new(&points);
            for _ in 0..200 {
                let centre = points[(uniform() * points.len() as f64) as usize];
                let spread = [0.1, 3.0, 50.0, 5e3][(uniform() * 4.0) as usize];
                let q = [
                    centre[0] + spread * (uniform() - 0.5),
                    centre[1] + spread * (uniform() - 0.5),
                ];
                assert_eq!(blocks.nearest_point(&points, q), scan(&points, q));
                let (k, f, d) = blocks.nearest_segment(&points, q);
                assert_eq!((k, f.to_bits(), d.to_bits()), segment_scan(&points, q));
                assert_eq!(
                    blocks.polyline_distance(&points, q).to_bits(),
                    polyline_distance(&points, q).to_bits()
                );
            }
            assert_eq!(blocks.nearest_point(&points, [f64::NAN, 0.0]).0, 0);
        }
        // 64 points on a circle around q, some repeated: the first of the nearest.
        let ring: Vec<[f64; 2]> = (0..64)
            .map(|k| {
                let a = std::f64::consts::TAU * (k % 40) as f64 / 40.0;
                [3.0 * a.cos(), 3.0 * a.sin()]
            })
            .collect();
        let blocks = Blocks::new(&ring);
        for q in [[0.0, 0.0], [0.5, -0.25], [3.0, 0.0], [-2.9, 0.1]] {
            assert_eq!(blocks.nearest_point(&ring, q), scan(&ring, q));
        }
    }

    /// By hand: a unit square, a point-segment, a resampled L.
    #[test]
    fn segments_polygons_and_resampling() {
        let square = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        assert!(polygon_contains(&square, [0.5, 0.5]) && !polygon_contains(&square, [1.5, 0.5]));
        assert!((polygon_boundary_distance(&square, [0.5, 0.2]) - 0.2).abs() < 1e-15);
        assert_eq!(project_on_segment([0.0, 0.0], [0.0, 0.0], [3.0, 4.0]), (0.0, 5.0));
        assert_eq!(project_on_segment([0.0, 0.0], [2.0, 0.0], [1.0, 1.0]), (0.5, 1.0));
        let ell = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]];
        assert_eq!(length(&ell), 4.0);
        assert_eq!(
            resample(&ell, 5),
            vec![[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0], [2.0, 2.0]]
        );
        assert!((polyline_distance(&ell, [3.0, 1.0]) - 1.0).abs() < 1e-15);
    }
}
