//! A road edge given as a polyline (a CommonRoad lanelet bound) made smooth enough for the
//! relative-degree-2 barrier condition (4.85)–(4.86) (docs/commonroad.md, "Road edges"):
//!
//! 1. the polyline is resampled every [`SPACING`] metres of its length (corners cut, the
//!    recorded points' jitter averaged out);
//! 2. x(s) and y(s) are natural cubic splines through the samples (s: the samples' arc length):
//!    a C² curve, its curvature continuous, 0 at both ends, and straight beyond them (the
//!    extension is C² too);
//! 3. the signed distance e(q) from a point to the curve (positive to its left) is C² near it:
//!    ∇e = n(s*), ∇²e = −κ / (1 − κ e) t tᵀ at the nearest point s* (t, n the unit tangent and
//!    left normal, κ the signed curvature), wherever the nearest point is unique and
//!    κ e < 1 (within 1/κ of the curve);
//! 4. [`SmoothCurve::deviation`] δ, the largest distance between the curve and the polyline
//!    (sampled 16 times per piece both ways), is added to the margin: h = ±e − ρ − δ ≥ 0 keeps a
//!    circle of radius ρ at least δ from the smooth curve, so clear of the polyline itself.

use crate::planar::Blocks;

/// The resampling step (m).
pub const SPACING: f64 = 2.0;
/// Most samples of one curve.
pub const MAX_SAMPLES: usize = 100_000;

/// A C² planar curve through a resampled polyline, with its distance to that polyline.
#[derive(Debug, Clone, PartialEq)]
pub struct SmoothCurve {
    /// Arc length of each sample (m), increasing from 0.
    s: Vec<f64>,
    /// Per piece, the cubic coefficients of x and of y in u = s − s_k.
    x: Vec<[f64; 4]>,
    y: Vec<[f64; 4]>,
    deviation: f64,
    /// The samples' positions (where the pieces meet) and their [`Blocks`] index.
    samples: Vec<[f64; 2]>,
    blocks: Blocks,
    /// Which curve this is, for [`SmoothCurve::nearest`]'s memo (not part of its value).
    id: CurveId,
}

/// A curve's identity (a clone shares it; equal for any two curves: not part of the value).
#[derive(Debug, Clone, Copy)]
struct CurveId(u64);

impl PartialEq for CurveId {
    fn eq(&self, _: &CurveId) -> bool {
        true
    }
}

impl CurveId {
    fn next() -> CurveId {
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        CurveId(NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed))
    }
}

thread_local! {
    /// The last nearest point found on this thread, with its curve and query point: a barrier's
    /// h, ∇h and ∇²h ask for the same one in turn.
    static LAST_NEAREST: std::cell::Cell<Option<(u64, [u64; 2], Nearest)>> = const { std::cell::Cell::new(None) };
}

/// The nearest point of a curve to q: its parameter, position, unit tangent, left normal,
/// signed curvature and the signed distance e = (q − c)·n.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Nearest {
    pub s: f64,
    pub point: [f64; 2],
    pub tangent: [f64; 2],
    pub normal: [f64; 2],
    pub curvature: f64,
    pub distance: f64,
}

impl SmoothCurve {
    /// The smooth curve of `points` (at least 2, finite, of positive length).
    pub fn new(points: &[[f64; 2]]) -> Result<SmoothCurve, String> {
        if points.len() < 2 || points.iter().any(|p| !(p[0].is_finite() && p[1].is_finite())) {
            return Err("expected at least 2 points with finite coordinates".into());
        }
        let count = ((crate::planar::length(points) / SPACING).ceil() as usize).clamp(1, MAX_SAMPLES - 1);
        let samples = crate::planar::resample(points, count + 1);
        let mut s = Vec::with_capacity(samples.len());
        let mut total = 0.0;
        for (k, p) in samples.iter().enumerate() {
            if k > 0 {
                total += (p[0] - samples[k - 1][0]).hypot(p[1] - samples[k - 1][1]);
            }
            s.push(total);
        }
        if total.is_nan() || total <= 0.0 || s.windows(2).any(|w| w[1] <= w[0]) {
            return Err("expected a polyline of positive length".into());
        }
        let xs: Vec<f64> = samples.iter().map(|p| p[0]).collect();
        let ys: Vec<f64> = samples.iter().map(|p| p[1]).collect();
        let mut curve = SmoothCurve {
            x: crate::planar::natural_spline(&s, &xs),
            y: crate::planar::natural_spline(&s, &ys),
            s,
            deviation: 0.0,
            samples: Vec::new(),
            blocks: Blocks::default(),
            id: CurveId::next(),
        };
        curve.samples = (0..curve.s.len())
            .map(|k| match k < curve.x.len() {
                true => [curve.x[k][0], curve.y[k][0]],
                false => curve.point_at(curve.s[k]),
            })
            .collect();
        curve.blocks = Blocks::new(&curve.samples);
        let polyline = Blocks::new(points);
        // δ: both ways, 16 points per piece and every polyline point.
        let mut deviation: f64 = 0.0;
        for k in 0..curve.x.len() {
            for j in 0..16 {
                let at = curve.s[k] + (curve.s[k + 1] - curve.s[k]) * j as f64 / 16.0;
                deviation = deviation.max(polyline.polyline_distance(points, curve.point_at(at)));
            }
        }
        for p in points {
            deviation = deviation.max(curve.nearest(*p).distance.abs());
        }
        curve.deviation = deviation;
        Ok(curve)
    }

    /// δ, the largest distance between the curve and its polyline (m).
    pub fn deviation(&self) -> f64 {
        self.deviation
    }

    /// The piece of parameter s (the first or last beyond the ends) and u = s − s_k.
    fn piece(&self, s: f64) -> (usize, f64) {
        let k = self
            .s
            .partition_point(|&v| v <= s)
            .saturating_sub(1)
            .min(self.x.len() - 1);
        (k, s - self.s[k])
    }

    /// Position, first and second derivative at s (straight beyond the ends).
    fn derivatives(&self, s: f64) -> [[f64; 2]; 3] {
        let last = self.s[self.s.len() - 1];
        let at = crate::planar::cubic_at;
        let (inside, beyond) = if s < 0.0 {
            (0.0, s)
        } else if s > last {
            (last, s - last)
        } else {
            (s, 0.0)
        };
        let (k, u) = self.piece(inside);
        let (x, y) = (at(&self.x[k], u), at(&self.y[k], u));
        // Beyond an end: on along its tangent (the natural spline's curvature is 0 there).
        [
            [x[0] + beyond * x[1], y[0] + beyond * y[1]],
            [x[1], y[1]],
            if beyond == 0.0 { [x[2], y[2]] } else { [0.0, 0.0] },
        ]
    }

    /// The curve's samples (where its cubic pieces meet), from s = 0 to its end: points on the
    /// curve, which lies within [`SmoothCurve::deviation`] of the polyline it was built from.
    pub fn samples(&self) -> Vec<[f64; 2]> {
        self.samples.clone()
    }

    /// The curve's point at s.
    pub fn point_at(&self, s: f64) -> [f64; 2] {
        self.derivatives(s)[0]
    }

    /// The nearest point of the curve (extended straight beyond its ends) to q: the nearest
    /// sample first, then Newton's method on (c(s) − q)·c'(s) = 0.
    pub fn nearest(&self, q: [f64; 2]) -> Nearest {
        let key = (self.id.0, [q[0].to_bits(), q[1].to_bits()]);
        if let Some((id, at, found)) = LAST_NEAREST.get() {
            if (id, at) == key {
                return found;
            }
        }
        let found = self.search_nearest(q);
        LAST_NEAREST.set(Some((key.0, key.1, found)));
        found
    }

    /// [`SmoothCurve::nearest`] without the memo.
    fn search_nearest(&self, q: [f64; 2]) -> Nearest {
        // The nearest sample (the first of equal ones), found without visiting most.
        let mut s = self.s[self.blocks.nearest_point(&self.samples, q).0];
        for _ in 0..20 {
            let [c, d1, d2] = self.derivatives(s);
            let r = [c[0] - q[0], c[1] - q[1]];
            let g = r[0] * d1[0] + r[1] * d1[1];
            let h = d1[0] * d1[0] + d1[1] * d1[1] + r[0] * d2[0] + r[1] * d2[1];
            let step = if h > 0.0 {
                g / h
            } else {
                g / (d1[0] * d1[0] + d1[1] * d1[1])
            };
            let step = step.clamp(-SPACING, SPACING);
            s -= step;
            if step.abs() < 1e-13 * (1.0 + s.abs()) {
                break;
            }
        }
        let [c, d1, d2] = self.derivatives(s);
        let speed = d1[0].hypot(d1[1]);
        let tangent = [d1[0] / speed, d1[1] / speed];
        let normal = [-tangent[1], tangent[0]];
        let curvature = (d1[0] * d2[1] - d1[1] * d2[0]) / (speed * speed * speed);
        Nearest {
            s,
            point: c,
            tangent,
            normal,
            curvature,
            distance: (q[0] - c[0]) * normal[0] + (q[1] - c[1]) * normal[1],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A circle's polyline (256 points, radius 40): the smooth curve's signed distance is the
    /// circle's (inside positive: counter-clockwise, its left), its curvature 1/R, δ tiny; the
    /// distance's gradient and Hessian formulas against central differences of e.
    #[test]
    fn distance_to_a_smoothed_circle() {
        let r = 40.0;
        let points: Vec<[f64; 2]> = (0..=200)
            .map(|k| {
                let a = 1.5 * std::f64::consts::PI * k as f64 / 200.0;
                [r * a.cos(), r * a.sin()]
            })
            .collect();
        let curve = SmoothCurve::new(&points).unwrap();
        assert!(curve.deviation() < 0.02, "{}", curve.deviation());
        for (x, y) in [(30.0, 5.0), (-10.0, 35.0), (3.0, 42.0), (-30.0, -20.0)] {
            let n = curve.nearest([x, y]);
            let exact = r - f64::hypot(x, y);
            assert!(
                (n.distance - exact).abs() < 0.02,
                "({x}, {y}): {} vs {exact}",
                n.distance
            );
            assert!((n.curvature - 1.0 / r).abs() < 1e-3, "{}", n.curvature);
            let e = |p: [f64; 2]| curve.nearest(p).distance;
            let step = 1e-4;
            for axis in 0..2 {
                let mut a = [x, y];
                let mut b = [x, y];
                a[axis] -= step;
                b[axis] += step;
                let gradient = (e(b) - e(a)) / (2.0 * step);
                assert!((gradient - n.normal[axis]).abs() < 1e-6, "∇e");
                // ∇²e = −κ/(1 − κe) t tᵀ.
                let grad_at = |p: [f64; 2]| curve.nearest(p).normal;
                let hessian_row: Vec<f64> = (0..2).map(|j| (grad_at(b)[j] - grad_at(a)[j]) / (2.0 * step)).collect();
                let factor = -n.curvature / (1.0 - n.curvature * n.distance);
                for j in 0..2 {
                    let expected = factor * n.tangent[axis] * n.tangent[j];
                    assert!(
                        (hessian_row[j] - expected).abs() < 1e-5,
                        "∇²e {hessian_row:?} vs {expected}"
                    );
                }
            }
        }
    }

    /// Beyond its ends the curve goes on straight; a kinked polyline's δ is its corner cut.
    #[test]
    fn ends_and_corners() {
        let line = SmoothCurve::new(&[[0.0, 0.0], [10.0, 0.0]]).unwrap();
        assert!(line.deviation() < 1e-12);
        let n = line.nearest([15.0, -2.0]);
        assert!((n.distance + 2.0).abs() < 1e-9 && (n.point[0] - 15.0).abs() < 1e-9);
        let corner = SmoothCurve::new(&[[0.0, 0.0], [20.0, 0.0], [20.0, 20.0]]).unwrap();
        assert!(
            corner.deviation() > 0.05 && corner.deviation() < 1.5,
            "{}",
            corner.deviation()
        );
        assert!(SmoothCurve::new(&[[0.0, 0.0]]).is_err() && SmoothCurve::new(&[[1.0, 1.0], [1.0, 1.0]]).is_err());
    }
}
