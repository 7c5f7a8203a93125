//! Rectangular footprints as covering circles (pure geometry; docs/actors.md, "Footprints"):
//! a body L × W (length along its heading) is covered by n circles of radius
//! ρ = √((L/2n)² + (W/2)²) centred on its long axis at −L/2 + (2k − 1) L/2n, k = 1…n. Each
//! circle of the vehicle against each circle of an obstacle is one barrier (4.81): smooth, its
//! distance in closed form, conservative by at most ρ − W/2 beside the body (ellipses are
//! tighter, but the distance between two has no closed form).

use serde::{Deserialize, Serialize};

/// Most covering circles of one body.
pub const MAX_CIRCLES: usize = 8;

/// A rectangle L × W (m), length along the body's heading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rectangle {
    pub length: f64,
    pub width: f64,
    /// Covering circles (default [`Rectangle::default_circles`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub circles: Option<usize>,
    /// How far the rectangle's centre lies ahead of the body's reference point along its
    /// heading (m; default 0: centred on it), e.g. a car's centre ahead of its rear axle.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub offset: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// A footprint that cannot be used: the key and what was expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {message}")]
pub struct FootprintError {
    pub key: &'static str,
    pub message: String,
}

/// One covering circle: its centre in the body frame (along, across the heading) and radius.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    pub offset: [f64; 2],
    pub radius: f64,
}

impl Rectangle {
    /// The rule when `circles` is not given: n = ⌈L/W⌉ (at least 1, at most [`MAX_CIRCLES`]),
    /// each circle covering a piece of length L/n ≤ W, so ρ ≤ W/√2.
    pub fn default_circles(&self) -> usize {
        ((self.length / self.width).ceil() as usize).clamp(1, MAX_CIRCLES)
    }

    /// Finite positive sides at most `extent`, and 1…[`MAX_CIRCLES`] circles.
    pub fn check(&self, extent: f64) -> Result<(), FootprintError> {
        if !(self.offset.is_finite() && self.offset.abs() <= extent) {
            return Err(FootprintError {
                key: "offset",
                message: format!("expected a distance (m) within ±{extent:e}, found {}", self.offset),
            });
        }
        for (key, v) in [("length", self.length), ("width", self.width)] {
            if !(v.is_finite() && v > 0.0 && v <= extent) {
                return Err(FootprintError {
                    key,
                    message: format!("expected a positive length (m) up to {extent:e}, found {v}"),
                });
            }
        }
        if let Some(n) = self.circles {
            if !(1..=MAX_CIRCLES).contains(&n) {
                return Err(FootprintError {
                    key: "circles",
                    message: format!("expected 1 to {MAX_CIRCLES} covering circles, found {n}"),
                });
            }
        }
        Ok(())
    }

    /// The covering circles, rear to front.
    pub fn circles(&self) -> Vec<Circle> {
        let n = self.circles.unwrap_or_else(|| self.default_circles());
        let piece = self.length / n as f64;
        let radius = (0.25 * piece * piece + 0.25 * self.width * self.width).sqrt();
        (1..=n)
            .map(|k| Circle {
                offset: [self.offset - 0.5 * self.length + (k as f64 - 0.5) * piece, 0.0],
                radius,
            })
            .collect()
    }

    /// How far the circles reach beyond the sides at most: ρ − W/2.
    pub fn overreach(&self) -> f64 {
        self.circles()[0].radius - 0.5 * self.width
    }
}

/// R(θ) c: a body-frame offset in the world frame.
#[inline]
pub fn rotate(offset: [f64; 2], heading: f64) -> [f64; 2] {
    let (s, c) = sin_cos(heading);
    [c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]]
}

/// sin_cos of the last angle asked for, remembered (one per thread and use: a tick evaluates
/// every covering circle's barriers — h, ∇h, ∇²h, the point's velocity — at one heading, and a
/// turning road user's circles at one turn, hundreds of times with many road users; the same
/// values, bit for bit; docs/performance.md, "Recorded road users").
pub struct SinCosMemo(std::cell::Cell<(u64, f64, f64)>);

impl SinCosMemo {
    /// Remembering nothing yet.
    pub const fn new() -> SinCosMemo {
        SinCosMemo(std::cell::Cell::new((u64::MAX, f64::NAN, f64::NAN)))
    }

    /// angle.sin_cos().
    #[inline]
    pub fn sin_cos(&self, angle: f64) -> (f64, f64) {
        let (bits, s, c) = self.0.get();
        if bits == angle.to_bits() {
            return (s, c);
        }
        let (s, c) = angle.sin_cos();
        self.0.set((angle.to_bits(), s, c));
        (s, c)
    }
}

impl Default for SinCosMemo {
    fn default() -> Self {
        SinCosMemo::new()
    }
}

thread_local! {
    /// The vehicle's heading of [`rotate`].
    static HEADING: SinCosMemo = const { SinCosMemo::new() };
}

/// θ.sin_cos() for a body-frame rotation, remembered for the last θ ([`SinCosMemo`]).
#[inline]
pub fn sin_cos(angle: f64) -> (f64, f64) {
    HEADING.with(|memo| memo.sin_cos(angle))
}

/// Whether two rectangles (centre, heading, length, width) overlap: the separating axis test
/// over the four edge normals (exact; for checks of the covering circles).
pub fn rectangles_overlap(a: ([f64; 2], f64, f64, f64), b: ([f64; 2], f64, f64, f64)) -> bool {
    let corners = |(c, h, l, w): ([f64; 2], f64, f64, f64)| {
        [[0.5, 0.5], [0.5, -0.5], [-0.5, -0.5], [-0.5, 0.5]].map(|[u, v]| {
            let r = rotate([u * l, v * w], h);
            [c[0] + r[0], c[1] + r[1]]
        })
    };
    let (ca, cb) = (corners(a), corners(b));
    for heading in [
        a.1,
        a.1 + std::f64::consts::FRAC_PI_2,
        b.1,
        b.1 + std::f64::consts::FRAC_PI_2,
    ] {
        let (s, c) = heading.sin_cos();
        let span = |pts: &[[f64; 2]; 4]| {
            pts.iter()
                .map(|p| p[0] * c + p[1] * s)
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)))
        };
        let ((a0, a1), (b0, b1)) = (span(&ca), span(&cb));
        if a1 < b0 || b1 < a0 {
            return false;
        }
    }
    true
}

/// A box in space: its centre, its three axes (unit, orthogonal; in world coordinates) and its
/// half extents along them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrientedBox {
    pub centre: [f64; 3],
    pub axes: [[f64; 3]; 3],
    pub half: [f64; 3],
}

/// How deep two boxes penetrate: the length of the shortest translation that separates them
/// (the separating axis theorem over the 15 candidate axes — each box's three face normals
/// and the nine cross products of their edges, where the smallest projected overlap of two
/// convex polyhedra lies), positive when they overlap. Zero or negative means apart (then it
/// is not their distance). Frame-independent and exact, unlike MuJoCo 2.2.2's box-box
/// collider (docs/actors.md, "On MuJoCo").
pub fn boxes_penetration(a: &OrientedBox, b: &OrientedBox) -> f64 {
    let dot = |u: [f64; 3], v: [f64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    let d = [
        b.centre[0] - a.centre[0],
        b.centre[1] - a.centre[1],
        b.centre[2] - a.centre[2],
    ];
    let overlap = |axis: [f64; 3]| {
        let n = dot(axis, axis).sqrt();
        // (Parallel edges give no axis: their common normals are face normals, tested already.)
        if n < 1e-12 {
            return f64::INFINITY;
        }
        let l = axis.map(|c| c / n);
        let radius = |x: &OrientedBox| (0..3).map(|i| x.half[i] * dot(x.axes[i], l).abs()).sum::<f64>();
        radius(a) + radius(b) - dot(d, l).abs()
    };
    let cross = |u: [f64; 3], v: [f64; 3]| {
        [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ]
    };
    let faces = a.axes.iter().chain(&b.axes).map(|&axis| overlap(axis));
    let edges = (0..9).map(|k| overlap(cross(a.axes[k / 3], b.axes[k % 3])));
    faces.chain(edges).fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn circles_cover_the_rectangle_and_reach_at_most_rho_minus_half_width_beyond() {
        for (l, w, n) in [
            (4.6, 1.8, None),
            (4.02, 1.71, None),
            (1.0, 2.0, None),
            (4.6, 1.8, Some(5)),
        ] {
            let r = Rectangle {
                length: l,
                width: w,
                circles: n,
                offset: 0.0,
            };
            let circles = r.circles();
            assert_eq!(circles.len(), n.unwrap_or((l / w).ceil() as usize));
            // Every point of the rectangle on a fine grid is inside some circle.
            for i in 0..=200 {
                for j in 0..=50 {
                    let p = [-0.5 * l + l * i as f64 / 200.0, -0.5 * w + w * j as f64 / 50.0];
                    let inside = circles
                        .iter()
                        .any(|c| (p[0] - c.offset[0]).hypot(p[1] - c.offset[1]) <= c.radius + 1e-12);
                    assert!(inside, "{p:?} of {l} x {w}");
                }
            }
            // The circles' lateral reach is exactly ρ = W/2 + overreach.
            assert!((circles[0].radius - 0.5 * w - r.overreach()).abs() < 1e-15);
        }
        // 4.6 x 1.8: n = 3, ρ = √(0.767² + 0.9²) ≈ 1.182.
        let car = Rectangle {
            length: 4.6,
            width: 1.8,
            circles: None,
            offset: 0.0,
        };
        assert_eq!(car.circles().len(), 3);
        assert!((car.circles()[0].radius - 1.182276).abs() < 1e-6);
    }

    #[test]
    fn bad_rectangles_are_refused_with_the_key() {
        let ok = Rectangle {
            length: 4.0,
            width: 2.0,
            circles: None,
            offset: 0.0,
        };
        assert!(ok.check(1e9).is_ok());
        for (r, key) in [
            (Rectangle { length: 0.0, ..ok }, "length"),
            (Rectangle { width: f64::NAN, ..ok }, "width"),
            (Rectangle { length: 2e9, ..ok }, "length"),
            (Rectangle { circles: Some(0), ..ok }, "circles"),
            (Rectangle { circles: Some(9), ..ok }, "circles"),
            (Rectangle { offset: f64::NAN, ..ok }, "offset"),
        ] {
            assert_eq!(r.check(1e9).unwrap_err().key, key);
        }
    }

    #[test]
    fn separating_axes_agree_with_sampled_points() {
        let a = ([0.0, 0.0], 0.3, 4.6, 1.8);
        let mut agree = 0;
        for k in 0..400 {
            let s = k as f64;
            let b = ([4.0 * (0.37 * s).sin(), 3.0 * (0.53 * s).cos()], 0.7 * s, 4.02, 1.71);
            // Independent: any sampled point of b inside a, or of a inside b.
            let inside = |p: [f64; 2], (c, h, l, w): ([f64; 2], f64, f64, f64)| {
                let q = rotate([p[0] - c[0], p[1] - c[1]], -h);
                q[0].abs() <= 0.5 * l && q[1].abs() <= 0.5 * w
            };
            let sample = |r: ([f64; 2], f64, f64, f64), other| {
                (0..=60).any(|i| {
                    (0..=30).any(|j| {
                        let o = rotate([r.2 * (i as f64 / 60.0 - 0.5), r.3 * (j as f64 / 30.0 - 0.5)], r.1);
                        inside([r.0[0] + o[0], r.0[1] + o[1]], other)
                    })
                })
            };
            let sampled = sample(a, b) || sample(b, a);
            let exact = rectangles_overlap(a, b);
            // Sampling can miss a sliver of overlap, never invent one.
            assert!(!sampled || exact, "{b:?}");
            agree += usize::from(sampled == exact);
        }
        assert!(agree >= 390, "{agree}");
    }

    /// A box of half extents `half` at `centre`, turned by yaw, then pitch, then roll.
    fn turned_box(centre: [f64; 3], [yaw, pitch, roll]: [f64; 3], half: [f64; 3]) -> OrientedBox {
        let (sy, cy) = yaw.sin_cos();
        let (sp, cp) = pitch.sin_cos();
        let (sr, cr) = roll.sin_cos();
        // R = Rz(yaw) Ry(pitch) Rx(roll); its columns are the box's axes.
        let r = [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ];
        OrientedBox {
            centre,
            axes: [0, 1, 2].map(|j| [r[0][j], r[1][j], r[2][j]]),
            half,
        }
    }

    /// The same two boxes seen from another frame: both turned about z by `turn` and shifted.
    fn moved(x: &OrientedBox, turn: f64, shift: [f64; 3]) -> OrientedBox {
        let (s, c) = turn.sin_cos();
        let r = |p: [f64; 3]| [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
        let centre = r(x.centre);
        OrientedBox {
            centre: [centre[0] + shift[0], centre[1] + shift[1], centre[2] + shift[2]],
            axes: x.axes.map(r),
            half: x.half,
        }
    }

    /// The penetration depth is the least, over all directions, of the two boxes' overlap along
    /// it: no direction sampled on a fine sphere, nor the best one refined by a pattern search,
    /// overlaps less, and the sampled least is as near the depth as the sampling allows; where
    /// the boxes are apart some sampled direction separates them. Axis-aligned boxes: the least
    /// overlap along x, y and z.
    #[test]
    fn the_box_penetration_is_the_least_overlap_over_all_directions() {
        let mut rng = crate::random::SplitMix64(7);
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
        // Directions: a Fibonacci sphere.
        let n = 40_000;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let directions: Vec<[f64; 3]> = (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let phi = golden * i as f64;
                [r * phi.cos(), r * phi.sin(), z]
            })
            .collect();
        let (mut overlapping, mut apart) = (0, 0);
        for _ in 0..60 {
            let a = turned_box(
                [0.0; 3],
                [uniform(-3.0, 3.0), uniform(-0.5, 0.5), uniform(-0.5, 0.5)],
                [uniform(0.5, 2.5), uniform(0.3, 1.0), uniform(0.3, 1.5)],
            );
            let b = turned_box(
                [uniform(-3.0, 3.0), uniform(-2.0, 2.0), uniform(-1.0, 1.0)],
                [uniform(-3.0, 3.0), uniform(-0.5, 0.5), uniform(-0.5, 0.5)],
                [uniform(0.5, 2.5), uniform(0.3, 1.0), uniform(0.3, 1.5)],
            );
            let depth = boxes_penetration(&a, &b);
            let along = |l: &[f64; 3]| {
                let dot = |u: [f64; 3]| u[0] * l[0] + u[1] * l[1] + u[2] * l[2];
                let radius = |x: &OrientedBox| (0..3).map(|i| x.half[i] * dot(x.axes[i]).abs()).sum::<f64>();
                let d = [
                    b.centre[0] - a.centre[0],
                    b.centre[1] - a.centre[1],
                    b.centre[2] - a.centre[2],
                ];
                radius(&a) + radius(&b) - dot(d).abs()
            };
            let sampled = directions.iter().map(along).fold(f64::INFINITY, f64::min);
            if depth > 0.0 {
                overlapping += 1;
                assert!(sampled >= depth - 1e-12, "{sampled} < {depth}");
                // The best sample refined by a pattern search on the sphere: the least overlap.
                let best = *directions.iter().min_by(|p, q| along(p).total_cmp(&along(q))).unwrap();
                let (mut polar, mut azimuth) = (best[2].acos(), best[1].atan2(best[0]));
                let at = |polar: f64, azimuth: f64| {
                    along(&[polar.sin() * azimuth.cos(), polar.sin() * azimuth.sin(), polar.cos()])
                };
                let mut step = 0.05;
                while step > 1e-12 {
                    let here = at(polar, azimuth);
                    let moves = [
                        (step, 0.0),
                        (-step, 0.0),
                        (0.0, step),
                        (0.0, -step),
                        (step, step),
                        (-step, -step),
                        (step, -step),
                        (-step, step),
                    ];
                    match moves.iter().find(|(dp, da)| at(polar + dp, azimuth + da) < here) {
                        Some((dp, da)) => (polar, azimuth) = (polar + dp, azimuth + da),
                        None => step *= 0.5,
                    }
                }
                let least = at(polar, azimuth);
                assert!(least >= depth - 1e-12, "{least} < {depth}");
                // The overlap is Lipschitz in the direction (constant ≤ both boxes' half extents
                // and the centres' distance), the sphere sampled every ≤ 0.02 rad.
                let lipschitz =
                    a.half.iter().chain(&b.half).sum::<f64>() + b.centre.iter().map(|c| c * c).sum::<f64>().sqrt();
                assert!(sampled <= depth + 0.02 * lipschitz, "{sampled} against {depth}");
            } else {
                apart += 1;
                assert!(sampled <= 1e-3, "apart, yet every direction overlaps by {sampled}");
            }
            // Another frame: the same depth.
            let (a2, b2) = (moved(&a, 2.3, [37.5, -12.25, 0.5]), moved(&b, 2.3, [37.5, -12.25, 0.5]));
            assert!((boxes_penetration(&a2, &b2) - depth).abs() < 1e-9);
        }
        assert!(
            overlapping >= 15 && apart >= 5,
            "{overlapping} overlapping, {apart} apart"
        );
        let axis_aligned = |c: [f64; 3], h: [f64; 3]| turned_box(c, [0.0; 3], h);
        let depth = boxes_penetration(
            &axis_aligned([0.0; 3], [2.0, 1.0, 1.0]),
            &axis_aligned([3.5, 1.7, 0.2], [2.0, 1.0, 1.0]),
        );
        assert!((depth - 0.3).abs() < 1e-12, "{depth}");
    }

    /// A corner of US-101's road user 554 grazing the car's footprint (the first contact of
    /// tests/commonroad.rs's nominal run on USA_US101-5): 27 µm deep in either frame, where
    /// MuJoCo 2.2.2's box-box collider reported 27 µm in one and 1.05 m in the frame turned
    /// by 2.3 rad (the shapes' relative pose from the two logs).
    #[test]
    fn a_grazing_corner_is_as_shallow_in_every_frame() {
        // The road user's centre in the car's frame (from its rear axle) and relative heading.
        let (dx, dy, dyaw) = (
            -3.895932488732586 - 1.4227170936,
            0.40244834052524436,
            -0.0364482549126377,
        );
        let car = turned_box([0.0; 3], [0.0; 3], [2.254, 0.805, 2.254]);
        let other = turned_box([dx, dy, 0.0], [dyaw, 0.0, 0.0], [3.048, 1.20395, 3.048]);
        let depth = boxes_penetration(&car, &other);
        for turn in [0.0, 0.7, 2.3, std::f64::consts::PI, -1.9] {
            let turned = boxes_penetration(
                &moved(&car, turn, [5.0, -3.0, 0.0]),
                &moved(&other, turn, [5.0, -3.0, 0.0]),
            );
            assert!((turned - depth).abs() < 1e-12, "{turn}: {turned} against {depth}");
        }
        assert!(depth > 0.0 && depth < 1e-4, "{depth}");
    }
}
