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
    let d = [b[0] - a[0], b[1] - a[1]];
    let l2 = d[0] * d[0] + d[1] * d[1];
    let f = if l2 > 0.0 {
        (((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (f, (p[0] - a[0] - f * d[0]).hypot(p[1] - a[1] - f * d[1]))
}

/// The distance from p to the polyline.
pub fn polyline_distance(points: &[[f64; 2]], p: [f64; 2]) -> f64 {
    points
        .windows(2)
        .map(|w| project_on_segment(w[0], w[1], p).1)
        .fold(f64::INFINITY, f64::min)
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
