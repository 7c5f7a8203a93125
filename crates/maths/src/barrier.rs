//! Control barrier functions h(x) and their constraint data a(x), b(x) for the CBF-QP
//! (4.6)–(4.8), including the relative-degree-2 form (4.82)–(4.86).

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use crate::dynamics::Dynamics;

pub mod curve;

/// The shape of a barrier's safe set (scenario `[[barriers]]`, with `kind = "ball"` or
/// `kind = "half_space"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Shape {
    /// Distance from a ball in selected state components: outside, h = ‖x_S − c‖² − r²
    /// ((4.81) for a circular obstacle), or inside, h = r² − ‖x_S − c‖² ((2.32)).
    Ball {
        indices: Vec<usize>,
        centre: Vec<f64>,
        radius: f64,
        #[serde(default)]
        inside: bool,
    },
    /// Half-space h = cᵀx + d ((2.47): h = x − x_bdry).
    HalfSpace { coefficients: Vec<f64>, offset: f64 },
    /// Quadratic h = xᵀQx + cᵀx + d ((4.53): h = x2² − x1 + 1), Q as an array of rows.
    Quadratic { q: Vec<Vec<f64>>, c: Vec<f64>, d: f64 },
    /// A circle fixed to the vehicle body at `offset` (along, across the heading) outside a
    /// circle about `centre`: h = ‖q − o‖² − r², q = p + R(θ) c ((4.81) for one covering circle
    /// of a footprint, `crate::footprint`); p = (`x[position[0]]`, `x[position[1]]`), θ = `x[heading]`.
    /// Built by the episode, not a scenario key. `inside`: the circle stays inside the one
    /// about `centre` instead, h = r² − ‖q − o‖² (a road inside an arc edge).
    #[serde(skip)]
    BodyCircle {
        position: [usize; 2],
        heading: usize,
        offset: [f64; 2],
        centre: [f64; 2],
        radius: f64,
        inside: bool,
    },
    /// A circle fixed to the vehicle body at `offset` on the side of a line that `normal`
    /// (a unit vector) points to: h = n·q + d, q = p + R(θ) c as for [`Shape::BodyCircle`]
    /// (a road's line edge for one covering circle of a footprint, d including its radius).
    /// Built by the episode, not a scenario key.
    #[serde(skip)]
    BodyHalfSpace {
        position: [usize; 2],
        heading: usize,
        offset: [f64; 2],
        normal: [f64; 2],
        distance: f64,
    },
    /// A circle fixed to the vehicle body at `offset` on the `side` (+1: left, −1: right) of a
    /// smooth curve (a polyline road edge, [`curve::SmoothCurve`]): h = side·e(q) − `margin`,
    /// e the signed distance from q = p + R(θ) c to the curve, `margin` the circle's radius
    /// plus the curve's deviation from its polyline. Built by the episode, not a scenario key.
    #[serde(skip)]
    BodyCurve {
        position: [usize; 2],
        heading: usize,
        offset: [f64; 2],
        curve: std::sync::Arc<curve::SmoothCurve>,
        side: f64,
        margin: f64,
    },
    /// Car following behind a lead on the line (Molnar et al., arXiv 2112.08445):
    /// h = D − D_sf − T v with the gap D = `lead` − `rear` − p, p = `x[position]` (the
    /// vehicle's front), v = `x[speed]`, `rear` the lead's rear from its centre `lead`.
    /// Built by the episode from an obstacle's `following`, not a scenario key.
    #[serde(skip)]
    Headway {
        position: usize,
        speed: usize,
        lead: f64,
        rear: f64,
        standstill: f64,
        time_headway: f64,
    },
}

/// The point q = p + R(θ) c of a body circle and w = ∂q/∂θ = R'(θ) c = (−(Rc)_y, (Rc)_x).
#[inline]
fn body_point(position: [usize; 2], heading: usize, offset: [f64; 2], x: &[f64]) -> ([f64; 2], [f64; 2]) {
    let rc = crate::footprint::rotate(offset, x[heading]);
    ([x[position[0]] + rc[0], x[position[1]] + rc[1]], [-rc[1], rc[0]])
}

/// A named barrier function.
#[derive(Debug, Clone, PartialEq)]
pub struct Barrier {
    pub name: String,
    pub shape: Shape,
}

impl Barrier {
    /// A circular obstacle (4.81) centred at `centre`, with r the sum of the radii.
    pub fn circular_obstacle(name: &str, position: [usize; 2], centre: [f64; 2], radius_sum: f64) -> Barrier {
        Barrier {
            name: name.to_string(),
            shape: Shape::Ball {
                indices: position.to_vec(),
                centre: centre.to_vec(),
                radius: radius_sum,
                inside: false,
            },
        }
    }

    /// The circle on the vehicle body at `offset` (m, along and across the heading) outside the
    /// circle about `centre`, with r the sum of the radii (see [`Shape::BodyCircle`]).
    pub fn body_circle(
        name: &str,
        (position, heading): ([usize; 2], usize),
        offset: [f64; 2],
        centre: [f64; 2],
        radius_sum: f64,
    ) -> Barrier {
        Barrier {
            name: name.to_string(),
            shape: Shape::BodyCircle {
                position,
                heading,
                offset,
                centre,
                radius: radius_sum,
                inside: false,
            },
        }
    }

    /// The centre of a planar circle (a ball over two state components, or a body circle).
    #[inline]
    pub fn planar_centre_mut(&mut self) -> Option<&mut [f64]> {
        match &mut self.shape {
            Shape::Ball { centre, .. } if centre.len() == 2 => Some(centre),
            Shape::BodyCircle { centre, .. } => Some(centre),
            _ => None,
        }
    }

    /// Moves the actor a barrier is about to `centre` (a circle's centre, or a headway
    /// barrier's lead to `centre`'s x); false for a barrier about no actor.
    #[inline]
    pub fn move_actor(&mut self, centre: [f64; 2]) -> bool {
        if let Shape::Headway { lead, .. } = &mut self.shape {
            *lead = centre[0];
            return true;
        }
        match self.planar_centre_mut() {
            Some(c) => {
                c[0] = centre[0];
                c[1] = centre[1];
                true
            }
            None => false,
        }
    }

    /// The radius r of a ball or a body circle.
    pub fn radius_mut(&mut self) -> Option<&mut f64> {
        match &mut self.shape {
            Shape::Ball { radius, .. } | Shape::BodyCircle { radius, .. } => Some(radius),
            _ => None,
        }
    }

    /// For a planar circle barrier at x: the point q it measures from (the planar position, or
    /// a body circle's q = p + R(θ) c) and q's velocity along `xdot`, q̇ = ṗ + θ̇ R'(θ) c.
    pub fn point_and_velocity(&self, x: &[f64], xdot: &[f64]) -> Option<([f64; 2], [f64; 2])> {
        match &self.shape {
            Shape::Ball { indices, .. } if indices.len() == 2 => {
                let [i, j] = [indices[0], indices[1]];
                Some(([x[i], x[j]], [xdot[i], xdot[j]]))
            }
            &Shape::BodyCircle {
                position,
                heading,
                offset,
                ..
            } => {
                let (q, w) = body_point(position, heading, offset, x);
                let [i, j] = position;
                let th = xdot[heading];
                Some((q, [xdot[i] + th * w[0], xdot[j] + th * w[1]]))
            }
            _ => None,
        }
    }

    /// For an outside planar circle (a ball on the planar position, or a body circle) at x:
    /// (h, clearance, q, q̇ along `xdot`), the values of [`Barrier::h_at`],
    /// [`Barrier::clearance_at`] and [`Barrier::point_and_velocity`] bit for bit, with q
    /// formed once; None for any other shape.
    pub fn circle_values(&self, x: &[f64], xdot: &[f64]) -> Option<(f64, f64, [f64; 2], [f64; 2])> {
        let (q, q_dot) = self.point_and_velocity(x, xdot)?;
        self.circle_values_at(q, q_dot)
    }

    /// A body circle's point: its position and heading indices and its offset in the body
    /// frame (the barriers of one footprint circle share it, and their q and q̇); None for any
    /// other shape.
    pub fn body_point_of(&self) -> Option<([usize; 2], usize, [f64; 2])> {
        match self.shape {
            Shape::BodyCircle {
                position,
                heading,
                offset,
                ..
            } => Some((position, heading, offset)),
            _ => None,
        }
    }

    /// [`Barrier::circle_values`] with q and q̇ given, as [`Barrier::point_and_velocity`] forms
    /// them (for a point several barriers share).
    #[inline]
    pub fn circle_values_at(&self, q: [f64; 2], q_dot: [f64; 2]) -> Option<(f64, f64, [f64; 2], [f64; 2])> {
        let (centre, radius) = match &self.shape {
            Shape::Ball {
                indices,
                centre,
                radius,
                inside: false,
            } if indices.len() == 2 => ([centre[0], centre[1]], *radius),
            &Shape::BodyCircle {
                centre,
                radius,
                inside: false,
                ..
            } => (centre, radius),
            _ => return None,
        };
        let squared = (q[0] - centre[0]).powi(2) + (q[1] - centre[1]).powi(2);
        Some((squared - radius * radius, squared.sqrt() - radius, q, q_dot))
    }

    /// Whether an input reaches h at first order while another reaches it only at second:
    /// a body circle off the vehicle's reference point (its heading turns with the steering).
    /// In the relative-degree-2 form such a barrier gets the mixed-relative-degree condition
    /// (docs/actors.md, "Footprints"): [`LieWorkspace::constraint_into`] adds λ1 L_G h to b,
    /// and [`LieWorkspace::first_order_part_into`] gives the companion row ḣ + λ1 h ≥ 0.
    #[inline]
    pub fn mixed_relative_degree(&self) -> bool {
        match &self.shape {
            Shape::BodyCircle { offset, .. }
            | Shape::BodyHalfSpace { offset, .. }
            | Shape::BodyCurve { offset, .. } => *offset != [0.0, 0.0],
            _ => false,
        }
    }

    /// Largest state index the barrier reads.
    pub fn max_index(&self) -> usize {
        match &self.shape {
            Shape::Ball { indices, .. } => indices.iter().copied().max().unwrap_or(0),
            Shape::HalfSpace { coefficients, .. } => coefficients.len().saturating_sub(1),
            Shape::Quadratic { q, c, .. } => q.len().max(c.len()).saturating_sub(1),
            Shape::BodyCircle { position, heading, .. }
            | Shape::BodyHalfSpace { position, heading, .. }
            | Shape::BodyCurve { position, heading, .. } => position[0].max(position[1]).max(*heading),
            Shape::Headway { position, speed, .. } => (*position).max(*speed),
        }
    }

    pub fn h(&self, x: &DVector<f64>) -> f64 {
        self.h_at(x.as_slice())
    }

    /// h(x) for a state given as a slice.
    pub fn h_at(&self, x: &[f64]) -> f64 {
        match &self.shape {
            Shape::Ball {
                indices,
                centre,
                radius,
                inside,
            } => {
                let h = squared_distance(indices, centre, x) - radius * radius;
                if *inside {
                    -h
                } else {
                    h
                }
            }
            Shape::HalfSpace { coefficients, offset } => half_space_h(coefficients, offset, x),
            Shape::Quadratic { q, c, d } => {
                let quadratic: f64 = q
                    .iter()
                    .enumerate()
                    .map(|(i, row)| row.iter().enumerate().map(|(j, v)| x[i] * v * x[j]).sum::<f64>())
                    .sum();
                quadratic + c.iter().zip(x.iter()).map(|(c, v)| c * v).sum::<f64>() + d
            }
            &Shape::BodyCircle {
                position,
                heading,
                offset,
                centre,
                radius,
                inside,
            } => {
                let (q, _) = body_point(position, heading, offset, x);
                let h = (q[0] - centre[0]).powi(2) + (q[1] - centre[1]).powi(2) - radius * radius;
                if inside {
                    -h
                } else {
                    h
                }
            }
            &Shape::BodyHalfSpace {
                position,
                heading,
                offset,
                normal,
                distance,
            } => {
                let (q, _) = body_point(position, heading, offset, x);
                normal[0] * q[0] + normal[1] * q[1] + distance
            }
            Shape::BodyCurve {
                position,
                heading,
                offset,
                curve,
                side,
                margin,
            } => {
                let (q, _) = body_point(*position, *heading, *offset, x);
                side * curve.nearest(q).distance - margin
            }
            &Shape::Headway {
                position,
                speed,
                lead,
                rear,
                standstill,
                time_headway,
            } => lead - rear - x[position] - standstill - time_headway * x[speed],
        }
    }

    /// Signed distance to the boundary for an outside ball (negative when overlapping).
    pub fn clearance(&self, x: &DVector<f64>) -> f64 {
        self.clearance_at(x.as_slice())
    }

    /// [`Barrier::clearance`] for a state given as a slice (allocation-free but for a quadratic).
    pub fn clearance_at(&self, x: &[f64]) -> f64 {
        match &self.shape {
            Shape::Ball {
                indices,
                centre,
                radius,
                inside,
            } => {
                let d = squared_distance(indices, centre, x).sqrt();
                if *inside {
                    radius - d
                } else {
                    d - radius
                }
            }
            Shape::HalfSpace { coefficients, .. } => {
                self.h_at(x)
                    / coefficients
                        .iter()
                        .map(|c| c * c)
                        .sum::<f64>()
                        .sqrt()
                        .max(f64::MIN_POSITIVE)
            }
            // First-order distance estimate h / ‖∇h‖.
            Shape::Quadratic { .. } => {
                self.h_at(x)
                    / self
                        .gradient(&DVector::from_column_slice(x))
                        .norm()
                        .max(f64::MIN_POSITIVE)
            }
            &Shape::BodyCircle {
                position,
                heading,
                offset,
                centre,
                radius,
                inside,
            } => {
                let (q, _) = body_point(position, heading, offset, x);
                // (sqrt, not hypot: states and centres are bounded by ±1e9, so the squares
                // cannot overflow.)
                let d = ((q[0] - centre[0]).powi(2) + (q[1] - centre[1]).powi(2)).sqrt() - radius;
                if inside {
                    -d
                } else {
                    d
                }
            }
            // n is a unit vector: h is the distance; e is a distance.
            Shape::BodyHalfSpace { .. } | Shape::BodyCurve { .. } => self.h_at(x),
            // The gap D between the vehicle's front and the lead's rear.
            &Shape::Headway {
                position, lead, rear, ..
            } => lead - rear - x[position],
        }
    }

    /// ∇h(x).
    pub fn gradient(&self, x: &DVector<f64>) -> DVector<f64> {
        let mut g = DVector::zeros(x.len());
        self.gradient_into(x.as_slice(), g.as_mut_slice());
        g
    }

    /// g ← ∇h(x).
    pub fn gradient_into(&self, x: &[f64], g: &mut [f64]) {
        g.fill(0.0);
        match &self.shape {
            Shape::Ball {
                indices,
                centre,
                inside,
                ..
            } => {
                let sign = if *inside { -2.0 } else { 2.0 };
                for (&i, c) in indices.iter().zip(centre) {
                    g[i] = sign * (x[i] - c);
                }
            }
            Shape::HalfSpace { coefficients, .. } => {
                for (i, c) in coefficients.iter().enumerate() {
                    g[i] = *c;
                }
            }
            // ∇(xᵀQx + cᵀx) = (Q + Qᵀ)x + c.
            Shape::Quadratic { q, c, .. } => {
                for (i, row) in q.iter().enumerate() {
                    for (j, v) in row.iter().enumerate() {
                        g[i] += v * x[j];
                        g[j] += v * x[i];
                    }
                }
                for (i, c) in c.iter().enumerate() {
                    g[i] += c;
                }
            }
            // ∂h/∂p = 2 d, ∂h/∂θ = 2 d·w with d = q − o, w = R'(θ) c (negated inside).
            &Shape::BodyCircle {
                position,
                heading,
                offset,
                centre,
                inside,
                ..
            } => {
                let (q, w) = body_point(position, heading, offset, x);
                let sign = if inside { -2.0 } else { 2.0 };
                let d = [q[0] - centre[0], q[1] - centre[1]];
                g[position[0]] = sign * d[0];
                g[position[1]] = sign * d[1];
                g[heading] += sign * (d[0] * w[0] + d[1] * w[1]);
            }
            // ∂h/∂p = n, ∂h/∂θ = n·w.
            &Shape::BodyHalfSpace {
                position,
                heading,
                offset,
                normal,
                ..
            } => {
                let (_, w) = body_point(position, heading, offset, x);
                g[position[0]] = normal[0];
                g[position[1]] = normal[1];
                g[heading] += normal[0] * w[0] + normal[1] * w[1];
            }
            // ∂h/∂p = side n(s*), ∂h/∂θ = side n·w.
            Shape::BodyCurve {
                position,
                heading,
                offset,
                curve,
                side,
                ..
            } => {
                let (q, w) = body_point(*position, *heading, *offset, x);
                let n = curve.nearest(q).normal;
                g[position[0]] = side * n[0];
                g[position[1]] = side * n[1];
                g[*heading] += side * (n[0] * w[0] + n[1] * w[1]);
            }
            &Shape::Headway {
                position,
                speed,
                time_headway,
                ..
            } => {
                g[position] = -1.0;
                g[speed] -= time_headway;
            }
        }
    }

    /// out ← out + ∇²h(x) v (constant but for a body circle's).
    pub fn add_hessian_times(&self, x: &[f64], v: &[f64], out: &mut [f64]) {
        match &self.shape {
            Shape::Ball { indices, inside, .. } => {
                let sign = if *inside { -2.0 } else { 2.0 };
                for &i in indices {
                    out[i] += sign * v[i];
                }
            }
            // (Q + Qᵀ) v.
            Shape::Quadratic { q, .. } => {
                for (i, row) in q.iter().enumerate() {
                    for (j, q_ij) in row.iter().enumerate() {
                        out[i] += q_ij * v[j];
                        out[j] += q_ij * v[i];
                    }
                }
            }
            Shape::HalfSpace { .. } | Shape::Headway { .. } => {}
            // ∂²h/∂p² = 2I, ∂²h/∂p∂θ = 2w, ∂²h/∂θ² = 2(‖w‖² + d·R''c) = 2(‖c‖² − d·Rc)
            // (negated inside).
            &Shape::BodyCircle {
                position,
                heading,
                offset,
                centre,
                inside,
                ..
            } => {
                let (q, w) = body_point(position, heading, offset, x);
                let sign = if inside { -2.0 } else { 2.0 };
                let d = [q[0] - centre[0], q[1] - centre[1]];
                let rc = [w[1], -w[0]];
                let c2 = offset[0] * offset[0] + offset[1] * offset[1];
                let [i, j] = position;
                let vt = v[heading];
                out[i] += sign * (v[i] + w[0] * vt);
                out[j] += sign * (v[j] + w[1] * vt);
                out[heading] += sign * (w[0] * v[i] + w[1] * v[j]) + sign * (c2 - d[0] * rc[0] - d[1] * rc[1]) * vt;
            }
            // With H = side ∇²e(q) = −side κ/(1 − κ e) t tᵀ: ∂²h/∂p² = H, ∂²h/∂p∂θ = H w,
            // ∂²h/∂θ² = wᵀ H w + side n·R''c = wᵀ H w − side n·Rc.
            Shape::BodyCurve {
                position,
                heading,
                offset,
                curve,
                side,
                ..
            } => {
                let (q, w) = body_point(*position, *heading, *offset, x);
                let near = curve.nearest(q);
                let (t, n) = (near.tangent, near.normal);
                let factor = -side * near.curvature / (1.0 - near.curvature * near.distance);
                let [i, j] = *position;
                let vt = v[*heading];
                // H (v_p + w v_θ) = factor t (t·(v_p + w v_θ)).
                let along = t[0] * (v[i] + w[0] * vt) + t[1] * (v[j] + w[1] * vt);
                out[i] += factor * t[0] * along;
                out[j] += factor * t[1] * along;
                let tw = t[0] * w[0] + t[1] * w[1];
                let rc = [w[1], -w[0]];
                out[*heading] += factor * tw * along - side * (n[0] * rc[0] + n[1] * rc[1]) * vt;
            }
            // Only ∂²h/∂θ² = n·R''c = −n·Rc.
            &Shape::BodyHalfSpace {
                position,
                heading,
                offset,
                normal,
                ..
            } => {
                let (_, w) = body_point(position, heading, offset, x);
                let rc = [w[1], -w[0]];
                out[heading] -= (normal[0] * rc[0] + normal[1] * rc[1]) * v[heading];
            }
        }
    }
}

/// h = cᵀx + d of a half-space.
#[inline(always)]
fn half_space_h(coefficients: &[f64], offset: &f64, x: &[f64]) -> f64 {
    coefficients.iter().zip(x.iter()).map(|(c, v)| c * v).sum::<f64>() + offset
}

/// ‖x_S − c‖² over the selected state components.
fn squared_distance(indices: &[usize], centre: &[f64], x: &[f64]) -> f64 {
    indices.iter().zip(centre).map(|(&i, c)| (x[i] - c).powi(2)).sum()
}

/// How the barrier condition is imposed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BarrierForm {
    /// ḣ + α h ≥ 0 with linear α(h) = alpha·h: a = L_f h + α h (4.7), b = L_G h (4.8).
    RelativeDegree1 { alpha: f64 },
    /// ḧ + l1 ḣ + l0 h ≥ 0 (4.82): a = L_f²h + l1 L_f h + l0 h (4.85), b = L_G L_f h (4.86).
    RelativeDegree2 { l0: f64, l1: f64 },
}

impl BarrierForm {
    /// (λ1, λ2) with s² + l1 s + l0 = (s + λ1)(s + λ2), λ1 ≥ λ2 > 0, for the relative-degree-2
    /// form with real positive roots (l0 > 0, l1 > 0, l1² ≥ 4 l0); None otherwise. The
    /// mixed-relative-degree condition of a body circle ([`Barrier::mixed_relative_degree`]) is
    /// built on this factorisation.
    #[inline]
    pub fn real_rates(&self) -> Option<(f64, f64)> {
        let &BarrierForm::RelativeDegree2 { l0, l1 } = self else {
            return None;
        };
        let discriminant = l1 * l1 - 4.0 * l0;
        (l0 > 0.0 && l1 > 0.0 && discriminant >= 0.0).then(|| {
            let root = discriminant.sqrt();
            (0.5 * (l1 + root), 0.5 * (l1 - root))
        })
    }

    pub fn relative_degree(&self) -> u32 {
        match self {
            BarrierForm::RelativeDegree1 { .. } => 1,
            BarrierForm::RelativeDegree2 { .. } => 2,
        }
    }
}

/// The affine constraint a + b·u ≥ 0 of one barrier at one state.
#[derive(Debug, Clone, PartialEq)]
pub struct Constraint {
    pub h: f64,
    pub a: f64,
    /// Row vector b(x), one entry per input channel.
    pub b: DVector<f64>,
}

impl Constraint {
    /// A constraint for `channels` inputs, to be filled by [`LieWorkspace::constraint_into`].
    pub fn zeros(channels: usize) -> Constraint {
        Constraint {
            h: 0.0,
            a: 0.0,
            b: DVector::zeros(channels),
        }
    }

    /// a + b·u.
    #[inline]
    pub fn value(&self, u: &DVector<f64>) -> f64 {
        self.a + dot(self.b.as_slice(), u.as_slice())
    }
}

/// Lie derivatives of a barrier along a control-affine model.
#[derive(Debug, Clone, PartialEq)]
pub struct LieDerivatives {
    pub h: f64,
    pub lf_h: f64,
    pub lg_h: DVector<f64>,
    pub lf2_h: f64,
    pub lg_lf_h: DVector<f64>,
}

/// Scratch space and result of one Lie-derivative evaluation, sized for one model and reused
/// (no allocation per evaluation: the predictors evaluate barriers many times per tick). It
/// serves the model it was built for (its sizes and planar position are that model's).
#[derive(Debug, Clone)]
pub struct LieWorkspace {
    /// The model's [`Dynamics::planar_position`] (looked up once, not per evaluation).
    planar_position: Option<[usize; 2]>,
    f: DVector<f64>,
    g: DMatrix<f64>,
    jacobian: DMatrix<f64>,
    grad_h: DVector<f64>,
    grad_lf_h: DVector<f64>,
    /// The state f, G and ∂f/∂x were last formed at by [`LieWorkspace::evaluate`] (they depend
    /// on the state alone: every barrier evaluated at one state shares them); NaN when they
    /// are not (NaN equals nothing).
    terms_at: Vec<f64>,
    /// The derivatives at the last evaluated state.
    pub lie: LieDerivatives,
}

impl LieWorkspace {
    pub fn new(model: &dyn Dynamics) -> LieWorkspace {
        let (n, r) = (model.state_dim(), model.input_dim());
        LieWorkspace {
            planar_position: model.planar_position(),
            f: DVector::zeros(n),
            g: DMatrix::zeros(n, r),
            jacobian: DMatrix::zeros(n, n),
            grad_h: DVector::zeros(n),
            grad_lf_h: DVector::zeros(n),
            terms_at: vec![f64::NAN; n],
            lie: LieDerivatives {
                h: 0.0,
                lf_h: 0.0,
                lg_h: DVector::zeros(r),
                lf2_h: 0.0,
                lg_lf_h: DVector::zeros(r),
            },
        }
    }

    /// self.lie ← the Lie derivatives of `barrier` along `model` at x.
    pub fn evaluate(&mut self, barrier: &Barrier, model: &dyn Dynamics, x: &[f64]) {
        if self.planar_ball_in_closed_form(barrier, model, x) || self.half_space_in_closed_form(barrier, model, x) {
            return;
        }
        // f, G and ∂f/∂x once per state (bit for bit what forming them again gives).
        if self.terms_at != x {
            // Slice fills (a memset), not nalgebra's element iterator.
            self.g.as_mut_slice().fill(0.0);
            self.jacobian.as_mut_slice().fill(0.0);
            model.lie_terms_into(x, self.f.as_mut_slice(), &mut self.g, &mut self.jacobian);
            self.terms_at.clear();
            self.terms_at.extend_from_slice(x);
        }
        barrier.gradient_into(x, self.grad_h.as_mut_slice());
        // ∇(L_f h) = ∇²h f + (∂f/∂x)ᵀ ∇h.
        transpose_times(&self.jacobian, self.grad_h.as_slice(), self.grad_lf_h.as_mut_slice());
        barrier.add_hessian_times(x, self.f.as_slice(), self.grad_lf_h.as_mut_slice());
        let lie = &mut self.lie;
        lie.h = barrier.h_at(x);
        lie.lf_h = dot(self.grad_h.as_slice(), self.f.as_slice());
        transpose_times(&self.g, self.grad_h.as_slice(), lie.lg_h.as_mut_slice());
        lie.lf2_h = dot(self.grad_lf_h.as_slice(), self.f.as_slice());
        transpose_times(&self.g, self.grad_lf_h.as_slice(), lie.lg_lf_h.as_mut_slice());
    }

    /// (centre, radius, inside) of a ball over the model's planar position (two indices, two
    /// centre coordinates), the shape the closed forms below handle.
    #[inline]
    fn planar_ball(&self, barrier: &Barrier) -> Option<([f64; 2], f64, bool)> {
        let Shape::Ball {
            indices,
            centre,
            radius,
            inside,
        } = &barrier.shape
        else {
            return None;
        };
        match (indices.as_slice(), centre.as_slice()) {
            (&[i, j], &[cx, cy]) if self.planar_position == Some([i, j]) => Some(([cx, cy], *radius, *inside)),
            _ => None,
        }
    }

    /// A ball over the planar position, h = ±(d − r²) with d = ‖p − c‖², from the model's
    /// closed form of d's Lie derivatives ((4.88)–(4.90) for the bicycle), when it has one.
    fn planar_ball_in_closed_form(&mut self, barrier: &Barrier, model: &dyn Dynamics, x: &[f64]) -> bool {
        let Some((centre, radius, inside)) = self.planar_ball(barrier) else {
            return false;
        };
        let lie = &mut self.lie;
        let Some([d, lf_d, lf2_d]) =
            model.squared_distance_lie_into(x, centre, lie.lg_h.as_mut_slice(), lie.lg_lf_h.as_mut_slice())
        else {
            return false;
        };
        let sign = if inside { -1.0 } else { 1.0 };
        (lie.h, lie.lf_h, lie.lf2_h) = (sign * (d - radius * radius), sign * lf_d, sign * lf2_d);
        if inside {
            lie.lg_h.neg_mut();
            lie.lg_lf_h.neg_mut();
        }
        true
    }

    /// A half-space h = cᵀx + d from the model's closed form of the Lie derivatives of cᵀx
    /// ([`Dynamics::linear_lie_into`]), when it has one.
    fn half_space_in_closed_form(&mut self, barrier: &Barrier, model: &dyn Dynamics, x: &[f64]) -> bool {
        let Shape::HalfSpace { coefficients, offset } = &barrier.shape else {
            return false;
        };
        let lie = &mut self.lie;
        let Some([lf_h, lf2_h]) =
            model.linear_lie_into(x, coefficients, lie.lg_h.as_mut_slice(), lie.lg_lf_h.as_mut_slice())
        else {
            return false;
        };
        (lie.h, lie.lf_h, lie.lf2_h) = (half_space_h(coefficients, offset, x), lf_h, lf2_h);
        true
    }

    /// [`LieWorkspace::constraint_into`] from the model's closed form for a half-space (see
    /// [`LieWorkspace::half_space_in_closed_form`]), with the row b written straight into `out`.
    #[inline(always)]
    fn half_space_constraint(
        &mut self,
        barrier: &Barrier,
        form: BarrierForm,
        model: &dyn Dynamics,
        x: &[f64],
        out: &mut Constraint,
    ) -> bool {
        let Shape::HalfSpace { coefficients, offset } = &barrier.shape else {
            return false;
        };
        let lie = &mut self.lie;
        let (lg, lg_lf) = match form {
            BarrierForm::RelativeDegree1 { .. } => (out.b.as_mut_slice(), lie.lg_lf_h.as_mut_slice()),
            BarrierForm::RelativeDegree2 { .. } => (lie.lg_h.as_mut_slice(), out.b.as_mut_slice()),
        };
        let Some([lf_h, lf2_h]) = model.linear_lie_into(x, coefficients, lg, lg_lf) else {
            return false;
        };
        let h = half_space_h(coefficients, offset, x);
        out.h = h;
        out.a = match form {
            BarrierForm::RelativeDegree1 { alpha } => lf_h + alpha * h,
            BarrierForm::RelativeDegree2 { l0, l1 } => lf2_h + l1 * lf_h + l0 * h,
        };
        true
    }

    /// [`LieWorkspace::constraint_into`] from the model's closed form for a planar ball (see
    /// [`LieWorkspace::planar_ball_in_closed_form`]), with the row b written straight into
    /// `out` (the same arithmetic as through `lie`).
    #[inline(always)]
    fn planar_ball_constraint(
        &mut self,
        barrier: &Barrier,
        form: BarrierForm,
        model: &dyn Dynamics,
        x: &[f64],
        out: &mut Constraint,
    ) -> bool {
        let Some((centre, radius, inside)) = self.planar_ball(barrier) else {
            return false;
        };
        let lie = &mut self.lie;
        let (lg, lg_lf) = match form {
            BarrierForm::RelativeDegree1 { .. } => (out.b.as_mut_slice(), lie.lg_lf_h.as_mut_slice()),
            BarrierForm::RelativeDegree2 { .. } => (lie.lg_h.as_mut_slice(), out.b.as_mut_slice()),
        };
        let Some([d, lf_d, lf2_d]) = model.squared_distance_lie_into(x, centre, lg, lg_lf) else {
            return false;
        };
        let sign = if inside { -1.0 } else { 1.0 };
        let (h, lf_h, lf2_h) = (sign * (d - radius * radius), sign * lf_d, sign * lf2_d);
        out.h = h;
        out.a = match form {
            BarrierForm::RelativeDegree1 { alpha } => lf_h + alpha * h,
            BarrierForm::RelativeDegree2 { l0, l1 } => lf2_h + l1 * lf_h + l0 * h,
        };
        if inside {
            for b in out.b.iter_mut() {
                *b = -*b;
            }
        }
        true
    }

    /// out ← the constraint data (a, b) of `barrier` in `form` at x (`lie` is then scratch).
    #[inline(always)]
    pub fn constraint_into(
        &mut self,
        barrier: &Barrier,
        form: BarrierForm,
        model: &dyn Dynamics,
        x: &[f64],
        out: &mut Constraint,
    ) {
        if !self.planar_ball_constraint(barrier, form, model, x, out) {
            self.general_constraint_into(barrier, form, model, x, out);
        }
    }

    /// [`LieWorkspace::constraint_into`] for anything but a planar ball: a half-space in the
    /// model's closed form, else from f and G (and ∂f/∂x for relative degree 2) (out of line:
    /// the ball's closed form stays small enough to inline into the callers).
    #[inline(never)]
    fn general_constraint_into(
        &mut self,
        barrier: &Barrier,
        form: BarrierForm,
        model: &dyn Dynamics,
        x: &[f64],
        out: &mut Constraint,
    ) {
        if self.half_space_constraint(barrier, form, model, x, out) {
            return;
        }
        match form {
            BarrierForm::RelativeDegree1 { alpha } => {
                self.first_order(barrier, model, x);
                let lie = &self.lie;
                (out.h, out.a) = (lie.h, lie.lf_h + alpha * lie.h);
                out.b.copy_from(&lie.lg_h);
            }
            BarrierForm::RelativeDegree2 { l0, l1 } => {
                self.evaluate(barrier, model, x);
                let lie = &self.lie;
                (out.h, out.a) = (lie.h, lie.lf2_h + l1 * lie.lf_h + l0 * lie.h);
                out.b.copy_from(&lie.lg_lf_h);
                // Mixed relative degree: ψ̇ + λ2 ψ ≥ 0 for ψ = L_f h + λ1 h, whose b gains λ1 L_G h.
                if let (true, Some((lambda1, _))) = (barrier.mixed_relative_degree(), form.real_rates()) {
                    out.b.axpy(lambda1, &lie.lg_h, 1.0);
                }
            }
        }
    }

    /// out ← the first-order row ḣ + λ1 h ≥ 0 of a mixed-relative-degree barrier
    /// ([`Barrier::mixed_relative_degree`]): a = L_f h + λ1 h, b = L_G h, from the
    /// derivatives the last [`LieWorkspace::constraint_into`] of that barrier in `form`
    /// computed (so call it right after). False (out untouched) when `form` has no real rates.
    pub fn first_order_part_into(&self, form: BarrierForm, out: &mut Constraint) -> bool {
        let Some((lambda1, _)) = form.real_rates() else {
            return false;
        };
        let lie = &self.lie;
        (out.h, out.a) = (lie.h, lie.lf_h + lambda1 * lie.h);
        out.b.copy_from(&lie.lg_h);
        true
    }

    /// lie.h, lie.lf_h, lie.lg_h as [`LieWorkspace::evaluate`] forms them, from f and G alone
    /// (relative degree 1, (4.7)/(4.8), needs no ∂f/∂x); the second-order terms are left stale.
    fn first_order(&mut self, barrier: &Barrier, model: &dyn Dynamics, x: &[f64]) {
        // (f and G formed here without ∂f/∂x: the next evaluate forms all three again.)
        self.terms_at.fill(f64::NAN);
        self.g.as_mut_slice().fill(0.0);
        model.drift_into(x, self.f.as_mut_slice());
        model.input_matrix_into(x, &mut self.g);
        barrier.gradient_into(x, self.grad_h.as_mut_slice());
        let lie = &mut self.lie;
        lie.h = barrier.h_at(x);
        lie.lf_h = dot(self.grad_h.as_slice(), self.f.as_slice());
        transpose_times(&self.g, self.grad_h.as_slice(), lie.lg_h.as_mut_slice());
    }
}

/// dst ← src (equal lengths): two entries (the planar vehicles' inputs) moved directly,
/// anything else through `copy_from_slice` (a memcpy call).
#[inline]
pub(crate) fn copy_small(dst: &mut [f64], src: &[f64]) {
    match (dst, src) {
        ([d0, d1], &[s0, s1]) => (*d0, *d1) = (s0, s1),
        (dst, src) => dst.copy_from_slice(src),
    }
}

/// a·b summed in order from 0 (as nalgebra's `dot` for fewer than 8 entries).
#[inline]
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).fold(0.0, |sum, (a, b)| sum + a * b)
}

/// out ← mᵀ v (column-wise dot products of the column-major storage).
fn transpose_times(m: &DMatrix<f64>, v: &[f64], out: &mut [f64]) {
    for (out, column) in out.iter_mut().zip(m.as_slice().chunks_exact(m.nrows())) {
        *out = dot(column, v);
    }
}

pub fn lie_derivatives(barrier: &Barrier, model: &dyn Dynamics, x: &DVector<f64>) -> LieDerivatives {
    let mut workspace = LieWorkspace::new(model);
    workspace.evaluate(barrier, model, x.as_slice());
    workspace.lie
}

/// The constraint data (a, b) of `barrier` in `form` at state x.
pub fn constraint(barrier: &Barrier, form: BarrierForm, model: &dyn Dynamics, x: &DVector<f64>) -> Constraint {
    let mut out = Constraint::zeros(model.input_dim());
    LieWorkspace::new(model).constraint_into(barrier, form, model, x.as_slice(), &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::{BicycleModel, LinearModel};

    /// `circle_values` gives h_at, clearance_at and point_and_velocity bit for bit (balls on
    /// the planar position and body circles, outside; random states and centres).
    #[test]
    fn circle_values_are_the_barriers_own_bit_for_bit() {
        let mut rng = crate::random::SplitMix64(3);
        let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * rng.next_f64();
        for trial in 0..2000 {
            let centre = [uniform(-50.0, 50.0), uniform(-50.0, 50.0)];
            let radius = uniform(0.1, 5.0);
            let barrier = match trial % 2 {
                0 => Barrier::circular_obstacle("ball", [0, 1], centre, radius),
                _ => Barrier::body_circle(
                    "body",
                    ([0, 1], 2),
                    [uniform(-1.0, 4.0), uniform(-1.0, 1.0)],
                    centre,
                    radius,
                ),
            };
            let x = [
                uniform(-60.0, 60.0),
                uniform(-60.0, 60.0),
                uniform(-4.0, 4.0),
                uniform(-5.0, 30.0),
            ];
            let xdot = [
                uniform(-30.0, 30.0),
                uniform(-30.0, 30.0),
                uniform(-2.0, 2.0),
                uniform(-5.0, 5.0),
            ];
            let (h, clearance, q, q_dot) = barrier.circle_values(&x, &xdot).expect("a circle");
            assert_eq!(h.to_bits(), barrier.h_at(&x).to_bits());
            assert_eq!(clearance.to_bits(), barrier.clearance_at(&x).to_bits());
            assert_eq!(Some((q, q_dot)), barrier.point_and_velocity(&x, &xdot));
        }
        let inside = Barrier {
            name: "inside".into(),
            shape: Shape::Ball {
                indices: vec![0, 1],
                centre: vec![0.0; 2],
                radius: 1.0,
                inside: true,
            },
        };
        assert_eq!(inside.circle_values(&[0.0; 4], &[0.0; 4]), None);
    }

    #[test]
    fn bicycle_lie_derivatives_match_4_88_to_4_90() {
        let model = BicycleModel::new(6.0);
        let b = Barrier::circular_obstacle("o", [0, 1], [-3.0, 0.5], 6.0);
        let x = DVector::from_column_slice(&[-11.0, 0.7, 0.3, 2.5]);
        let (dx, dy, th, v) = (x[0] + 3.0, x[1] - 0.5, x[2], x[3]);
        let lie = lie_derivatives(&b, &model, &x);
        let lf_h = 2.0 * dx * v * th.cos() + 2.0 * dy * v * th.sin(); // (4.88)
        let lg1 = -2.0 / 6.0 * dx * v * v * th.sin() + 2.0 / 6.0 * dy * v * v * th.cos(); // (4.90)
        let lg2 = 2.0 * dx * th.cos() + 2.0 * dy * th.sin();
        assert!((lie.lf_h - lf_h).abs() < 1e-12);
        assert!((lie.lf2_h - 2.0 * v * v).abs() < 1e-12); // (4.89)
        assert!((lie.lg_lf_h[0] - lg1).abs() < 1e-12 && (lie.lg_lf_h[1] - lg2).abs() < 1e-12);
        assert!((lie.lf_h - v * lie.lg_lf_h[1]).abs() < 1e-12); // (4.91)
    }

    /// A model through its f, G and ∂f/∂x only (no closed forms).
    struct General<'a>(&'a dyn Dynamics);

    impl Dynamics for General<'_> {
        fn state_names(&self) -> &[String] {
            self.0.state_names()
        }
        fn channel_names(&self) -> &[String] {
            self.0.channel_names()
        }
        fn drift_into(&self, x: &[f64], f: &mut [f64]) {
            self.0.drift_into(x, f)
        }
        fn add_input_term(&self, x: &[f64], u: &[f64], xdot: &mut [f64]) {
            self.0.add_input_term(x, u, xdot)
        }
        fn drift_jacobian_into(&self, x: &[f64], j: &mut DMatrix<f64>) {
            self.0.drift_jacobian_into(x, j)
        }
        fn input_matrix_into(&self, x: &[f64], g: &mut DMatrix<f64>) {
            self.0.input_matrix_into(x, g)
        }
        fn planar_position(&self) -> Option<[usize; 2]> {
            self.0.planar_position()
        }
    }

    #[test]
    fn closed_form_planar_ball_derivatives_equal_the_general_ones() {
        let bicycle = BicycleModel::new(2.5);
        let unicycle = crate::dynamics::UnicycleModel::default();
        let models: [&dyn Dynamics; 2] = [&bicycle, &unicycle];
        let mut worst: f64 = 0.0;
        for model in models {
            let n = model.state_dim();
            for k in 0..100 {
                let s = k as f64;
                let mut x = vec![s.sin() * 20.0, s.cos() * 7.0, 0.37 * s - 7.0, 3.0 * (1.3 * s).sin()];
                x.truncate(n);
                let mut b = Barrier::circular_obstacle("o", [0, 1], [-3.0 + s.cos(), 0.5], 1.0 + (k % 5) as f64);
                if let Shape::Ball { inside, .. } = &mut b.shape {
                    *inside = k % 2 == 0;
                }
                let xv = DVector::from_column_slice(&x);
                let (closed, general) = (
                    lie_derivatives(&b, model, &xv),
                    lie_derivatives(&b, &General(model), &xv),
                );
                let scale = 1.0 + general.h.abs() + general.lf2_h.abs();
                for (a, g) in [
                    (closed.h, general.h),
                    (closed.lf_h, general.lf_h),
                    (closed.lf2_h, general.lf2_h),
                    (closed.lg_h[0], general.lg_h[0]),
                    (closed.lg_h[1], general.lg_h[1]),
                    (closed.lg_lf_h[0], general.lg_lf_h[0]),
                    (closed.lg_lf_h[1], general.lg_lf_h[1]),
                ] {
                    worst = worst.max((a - g).abs() / scale);
                }
            }
        }
        assert!(worst < 1e-13, "largest relative difference {worst:e}");
    }

    #[test]
    fn closed_form_planar_ball_constraints_equal_the_general_ones() {
        let bicycle = BicycleModel::new(2.5);
        let unicycle = crate::dynamics::UnicycleModel::default();
        let models: [&dyn Dynamics; 2] = [&bicycle, &unicycle];
        let forms = [
            BarrierForm::RelativeDegree1 { alpha: 1.7 },
            BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.5 },
        ];
        let mut worst: f64 = 0.0;
        for model in models {
            let n = model.state_dim();
            let (mut closed, mut general) = (LieWorkspace::new(model), LieWorkspace::new(&General(model)));
            let (mut c, mut g) = (Constraint::zeros(2), Constraint::zeros(2));
            for k in 0..100 {
                let s = k as f64;
                let mut x = vec![s.sin() * 20.0, s.cos() * 7.0, 0.37 * s - 7.0, 3.0 * (1.3 * s).sin()];
                x.truncate(n);
                let mut b = Barrier::circular_obstacle("o", [0, 1], [-3.0 + s.cos(), 0.5], 1.0 + (k % 5) as f64);
                if let Shape::Ball { inside, .. } = &mut b.shape {
                    *inside = k % 2 == 0;
                }
                for form in forms {
                    closed.constraint_into(&b, form, model, &x, &mut c);
                    general.constraint_into(&b, form, &General(model), &x, &mut g);
                    let scale = 1.0 + g.h.abs() + g.a.abs();
                    for (a, e) in [(c.h, g.h), (c.a, g.a), (c.b[0], g.b[0]), (c.b[1], g.b[1])] {
                        worst = worst.max((a - e).abs() / scale);
                    }
                    // The same arithmetic as through the Lie derivatives of the closed form.
                    let lie = lie_derivatives(&b, model, &DVector::from_column_slice(&x));
                    let (a, row) = match form {
                        BarrierForm::RelativeDegree1 { alpha } => (lie.lf_h + alpha * lie.h, &lie.lg_h),
                        BarrierForm::RelativeDegree2 { l0, l1 } => {
                            (lie.lf2_h + l1 * lie.lf_h + l0 * lie.h, &lie.lg_lf_h)
                        }
                    };
                    assert_eq!((c.h, c.a, &c.b), (lie.h, a, row));
                }
            }
        }
        assert!(worst < 1e-13, "largest relative difference {worst:e}");
    }

    /// (h, a, b) of `form` from the Lie derivatives, as bits.
    fn constraint_bits(lie: &LieDerivatives, form: BarrierForm) -> (u64, u64, Vec<u64>) {
        let (a, row) = match form {
            BarrierForm::RelativeDegree1 { alpha } => (lie.lf_h + alpha * lie.h, &lie.lg_h),
            BarrierForm::RelativeDegree2 { l0, l1 } => (lie.lf2_h + l1 * lie.lf_h + l0 * lie.h, &lie.lg_lf_h),
        };
        (lie.h.to_bits(), a.to_bits(), row.iter().map(|v| v.to_bits()).collect())
    }

    fn bits_of(c: &Constraint) -> (u64, u64, Vec<u64>) {
        (c.h.to_bits(), c.a.to_bits(), c.b.iter().map(|v| v.to_bits()).collect())
    }

    const FORMS: [BarrierForm; 2] = [
        BarrierForm::RelativeDegree1 { alpha: 1.7 },
        BarrierForm::RelativeDegree2 { l0: 4.0, l1: 4.5 },
    ];

    #[test]
    fn closed_form_half_spaces_equal_the_general_path_bit_for_bit() {
        let bicycle = BicycleModel::new(2.5);
        let unicycle = crate::dynamics::UnicycleModel::default();
        let line = crate::dynamics::DoubleIntegratorModel::new(1);
        let plane = crate::dynamics::DoubleIntegratorModel::new(2);
        let models: [&dyn Dynamics; 4] = [&bicycle, &unicycle, &line, &plane];
        for model in models {
            let (n, r) = (model.state_dim(), model.input_dim());
            let (mut closed, mut general) = (LieWorkspace::new(model), LieWorkspace::new(&General(model)));
            let (mut c, mut g) = (Constraint::zeros(r), Constraint::zeros(r));
            for k in 0..200 {
                let s = k as f64;
                let x: Vec<f64> = (0..n).map(|i| 10.0 * (0.7 * s + 1.9 * i as f64).sin() - 2.0).collect();
                // Every length up to n (the rest of ∇h is 0), with zero and −0 coefficients.
                let coefficients = (0..1 + k % n)
                    .map(|i| match (k + i) % 5 {
                        0 => 0.0,
                        1 => -0.0,
                        _ => 3.0 * (1.3 * s + i as f64).cos(),
                    })
                    .collect();
                let b = Barrier {
                    name: "h".into(),
                    shape: Shape::HalfSpace {
                        coefficients,
                        offset: 0.1 * s - 2.0,
                    },
                };
                let xv = DVector::from_column_slice(&x);
                let (lie, general_lie) = (
                    lie_derivatives(&b, model, &xv),
                    lie_derivatives(&b, &General(model), &xv),
                );
                for form in FORMS {
                    let expected = constraint_bits(&general_lie, form);
                    assert_eq!(constraint_bits(&lie, form), expected, "{k}");
                    closed.constraint_into(&b, form, model, &x, &mut c);
                    general.constraint_into(&b, form, &General(model), &x, &mut g);
                    assert_eq!(bits_of(&c), expected, "{k} {form:?}");
                    assert_eq!(bits_of(&g), expected, "{k} {form:?}");
                }
            }
        }
    }

    #[test]
    fn first_order_constraints_without_the_jacobian_equal_the_full_evaluation() {
        let example1 = crate::dynamics::NonlinearExample1::default();
        let quadratic = Barrier {
            name: "h".into(),
            shape: Shape::Quadratic {
                q: vec![vec![0.0, 0.3], vec![-0.2, 1.0]],
                c: vec![-1.0, 0.5],
                d: 1.0,
            },
        };
        let linear = LinearModel::new(
            DMatrix::from_row_slice(3, 3, &[0.1, 1.0, 0.0, 0.0, -0.3, 1.0, 0.2, 0.0, 0.5]),
            DMatrix::from_row_slice(3, 2, &[0.0, 1.0, 0.5, 0.0, 1.0, -2.0]),
        );
        let ball = Barrier::circular_obstacle("o", [0, 2], [1.0, -0.5], 1.5);
        let half = Barrier {
            name: "h".into(),
            shape: Shape::HalfSpace {
                coefficients: vec![1.0, -2.0],
                offset: 0.3,
            },
        };
        let cases: [(&dyn Dynamics, &Barrier); 3] = [(&example1, &quadratic), (&linear, &ball), (&linear, &half)];
        for (model, b) in cases {
            let (n, r) = (model.state_dim(), model.input_dim());
            let mut workspace = LieWorkspace::new(model);
            let mut c = Constraint::zeros(r);
            for k in 0..50 {
                let x: Vec<f64> = (0..n).map(|i| 4.0 * (0.9 * k as f64 + i as f64).cos()).collect();
                let lie = lie_derivatives(b, model, &DVector::from_column_slice(&x));
                for form in FORMS {
                    workspace.constraint_into(b, form, model, &x, &mut c);
                    assert_eq!(bits_of(&c), constraint_bits(&lie, form));
                }
            }
        }
    }

    /// The largest relative difference between `b`'s ∇h and ∇²h v at x (four states) and
    /// central differences of h and of ∇h.
    fn derivatives_against_differences(b: &Barrier, x: [f64; 4]) -> f64 {
        let mut worst: f64 = 0.0;
        let mut g = [0.0; 4];
        b.gradient_into(&x, &mut g);
        let e = 1e-5;
        let shifted = |i: usize, d: f64| {
            let mut y = x;
            y[i] += d;
            y
        };
        for (i, g) in g.iter().enumerate() {
            let fd = (b.h_at(&shifted(i, e)) - b.h_at(&shifted(i, -e))) / (2.0 * e);
            worst = worst.max((fd - g).abs() / (1.0 + g.abs()));
        }
        let v = [0.3, -1.2, 0.8, 0.5];
        let mut hv = [0.0; 4];
        b.add_hessian_times(&x, &v, &mut hv);
        for i in 0..4 {
            // Row i of ∇²h from differences of the gradient, times v.
            let fd_row: f64 = (0..4)
                .map(|j| {
                    let (mut gp, mut gm) = ([0.0; 4], [0.0; 4]);
                    b.gradient_into(&shifted(j, e), &mut gp);
                    b.gradient_into(&shifted(j, -e), &mut gm);
                    (gp[i] - gm[i]) / (2.0 * e) * v[j]
                })
                .sum();
            worst = worst.max((fd_row - hv[i]).abs() / (1.0 + hv[i].abs()));
        }
        worst
    }

    /// The mixed-relative-degree rows of `b` at x on the bicycle (4.78), against differences
    /// along the flow with the input u held (RK4: error O(dt⁵)): the first-order row
    /// a + b·u = ḣ + λ1 h and the second-order row a + b·u = ψ̇ + λ2 ψ for ψ = L_f h + λ1 h (ψ
    /// from central differences of h along the drift alone); the larger relative difference.
    /// The rows are left in `first`, `second`.
    fn rows_against_the_flow(
        b: &Barrier,
        form: BarrierForm,
        model: &BicycleModel,
        (x, u): ([f64; 4], [f64; 2]),
        work: &mut LieWorkspace,
        (first, second): (&mut Constraint, &mut Constraint),
    ) -> f64 {
        let (lambda1, lambda2) = form.real_rates().unwrap();
        work.constraint_into(b, form, model, &x, second);
        assert!(work.first_order_part_into(form, first));
        let flow = |z: [f64; 4], v: [f64; 2], dt: f64| -> [f64; 4] {
            let f = |y: &[f64; 4]| {
                let mut d = [0.0; 4];
                model.dynamics_into(y, &v, &mut d);
                d
            };
            let add = |y: &[f64; 4], d: &[f64; 4], c: f64| std::array::from_fn(|i| y[i] + c * d[i]);
            let k1 = f(&z);
            let k2 = f(&add(&z, &k1, 0.5 * dt));
            let k3 = f(&add(&z, &k2, 0.5 * dt));
            let k4 = f(&add(&z, &k3, dt));
            std::array::from_fn(|i| z[i] + dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
        };
        let e = 1e-4;
        let h_dot = (b.h_at(&flow(x, u, e)) - b.h_at(&flow(x, u, -e))) / (2.0 * e);
        let expected_first = h_dot + lambda1 * b.h_at(&x);
        let psi = |z: [f64; 4]| {
            let drift = (b.h_at(&flow(z, [0.0; 2], e)) - b.h_at(&flow(z, [0.0; 2], -e))) / (2.0 * e);
            drift + lambda1 * b.h_at(&z)
        };
        let psi_dot = (psi(flow(x, u, e)) - psi(flow(x, u, -e))) / (2.0 * e);
        let expected_second = psi_dot + lambda2 * psi(x);
        let value = |c: &Constraint| c.a + c.b[0] * u[0] + c.b[1] * u[1];
        let first_error = (value(first) - expected_first).abs() / (1.0 + expected_first.abs());
        first_error.max((value(second) - expected_second).abs() / (1.0 + expected_second.abs()))
    }

    /// A body circle's ∇h and ∇²h v against central differences of h, at states all round the
    /// heading, with lateral offsets too.
    #[test]
    fn body_circle_gradient_and_hessian_match_finite_differences() {
        let mut worst: f64 = 0.0;
        for k in 0..60 {
            let s = k as f64;
            let b = Barrier::body_circle(
                "o/0-1",
                ([0, 1], 2),
                [1.5 * (0.7 * s).cos(), 0.4 * (1.1 * s).sin()],
                [2.0 * s.sin(), -1.0],
                2.3,
            );
            let x = [3.0 * (0.3 * s).cos(), 2.0 * s.sin(), 0.41 * s - 9.0, 2.5];
            worst = worst.max(derivatives_against_differences(&b, x));
            assert_eq!(b.max_index(), 2);
            let d = b.clearance(&DVector::from_column_slice(&x));
            assert!((((d + 2.3).powi(2) - 2.3 * 2.3) - b.h_at(&x)).abs() < 1e-9);
        }
        assert!(worst < 1e-7, "largest relative difference {worst:e}");
    }

    /// The mixed-relative-degree rows of a body circle off the rear axle on the bicycle
    /// (4.78), against differences along the flow with the input u held: the first-order row
    /// a + b·u = ḣ + λ1 h, and the second-order row a + b·u = ψ̇ + λ2 ψ for ψ = L_f h + λ1 h
    /// (ψ from central differences of h along the drift alone), with (λ1, λ2) the real roots of
    /// s² + l1 s + l0. Real roots only: complex ones give no rates.
    #[test]
    fn mixed_relative_degree_rows_match_differences_along_the_flow() {
        let model = BicycleModel::new(2.5);
        let form = BarrierForm::RelativeDegree2 { l0: 3.0, l1: 4.0 };
        assert_eq!(form.real_rates(), Some((3.0, 1.0)));
        assert_eq!(BarrierForm::RelativeDegree2 { l0: 5.0, l1: 4.0 }.real_rates(), None);
        assert_eq!(BarrierForm::RelativeDegree1 { alpha: 1.0 }.real_rates(), None);
        let mut work = LieWorkspace::new(&model);
        let (mut second, mut first) = (Constraint::zeros(2), Constraint::zeros(2));
        let mut worst: f64 = 0.0;
        for k in 0..40 {
            let s = k as f64;
            let b = Barrier::body_circle("o/2-0", ([0, 1], 2), [1.53, 0.3 * s.sin()], [6.0, 1.0], 2.27);
            assert!(b.mixed_relative_degree());
            let x = [0.5 * s.cos(), 0.2 * s, 0.13 * s - 2.0, 4.0 + 0.1 * s];
            let u = [0.3 * (0.7 * s).sin(), -1.5 + 0.1 * s];
            worst = worst.max(rows_against_the_flow(
                &b,
                form,
                &model,
                (x, u),
                &mut work,
                (&mut first, &mut second),
            ));
            // The steering reaches h at first order here (the case the rows exist for).
            assert!(first.b[0].abs() > 1e-3 && first.b[1] == 0.0, "{:?}", first.b);
        }
        assert!(worst < 1e-5, "largest relative difference {worst:e}");
        // At the reference point there is no first-order row.
        let centre = Barrier::body_circle("o", ([0, 1], 2), [0.0, 0.0], [6.0, 1.0], 2.27);
        assert!(!centre.mixed_relative_degree());
    }

    /// A body circle's road-edge barriers (a line edge, and inside an arc edge): ∇h and ∇²h v
    /// against central differences of h, and h against the geometry (the distance from the
    /// line, the radius minus the distance from the arc's centre).
    #[test]
    fn body_edge_barriers_match_finite_differences_and_geometry() {
        let mut worst: f64 = 0.0;
        for k in 0..40 {
            let s = k as f64;
            let offset = [1.5 * (0.7 * s).cos(), 0.4 * (1.1 * s).sin()];
            let normal = [(0.3 * s).cos(), (0.3 * s).sin()];
            let line = Barrier {
                name: "edge/0".into(),
                shape: Shape::BodyHalfSpace {
                    position: [0, 1],
                    heading: 2,
                    offset,
                    normal,
                    distance: 4.0 - 1.2,
                },
            };
            let arc = Barrier {
                name: "arc/0".into(),
                shape: Shape::BodyCircle {
                    position: [0, 1],
                    heading: 2,
                    offset,
                    centre: [1.0, -2.0],
                    radius: 30.0 - 1.2,
                    inside: true,
                },
            };
            let x = [3.0 * (0.3 * s).cos(), 2.0 * s.sin(), 0.41 * s - 9.0, 2.5];
            let (sn, cs) = x[2].sin_cos();
            let q = [
                x[0] + cs * offset[0] - sn * offset[1],
                x[1] + sn * offset[0] + cs * offset[1],
            ];
            let line_h = normal[0] * q[0] + normal[1] * q[1] + 4.0 - 1.2;
            let arc_h = (30.0f64 - 1.2).powi(2) - (q[0] - 1.0).powi(2) - (q[1] + 2.0).powi(2);
            assert!((line.h_at(&x) - line_h).abs() < 1e-12 && (arc.h_at(&x) - arc_h).abs() < 1e-9);
            let clearance = 30.0 - 1.2 - (q[0] - 1.0).hypot(q[1] + 2.0);
            assert!((arc.clearance(&DVector::from_column_slice(&x)) - clearance).abs() < 1e-12);
            assert!(line.mixed_relative_degree() && arc.mixed_relative_degree());
            for b in [&line, &arc] {
                worst = worst.max(derivatives_against_differences(b, x));
            }
        }
        assert!(worst < 1e-7, "largest relative difference {worst:e}");
    }

    /// A polyline road edge made smooth ([`curve::SmoothCurve`]) for a footprint's circles on the
    /// bicycle (4.78): ∇h and ∇²h v against central differences of h, and the
    /// mixed-relative-degree rows (ḣ + λ1 h, then ψ̇ + λ2 ψ) against differences along the
    /// closed loop with the input held, near a curving, kinked polyline.
    #[test]
    fn a_smoothed_polyline_edge_matches_differences_along_the_flow() {
        let points: Vec<[f64; 2]> = (0..60)
            .map(|k| {
                let s = 1.7 * k as f64;
                [s, 6.0 * (0.05 * s).sin() + if k % 7 == 3 { 0.2 } else { 0.0 }]
            })
            .collect();
        let curve = std::sync::Arc::new(curve::SmoothCurve::new(&points).unwrap());
        let model = BicycleModel::new(2.5789128);
        let form = BarrierForm::RelativeDegree2 { l0: 3.0, l1: 4.0 };
        let mut work = LieWorkspace::new(&model);
        let (mut second, mut first) = (Constraint::zeros(2), Constraint::zeros(2));
        let mut worst: f64 = 0.0;
        let mut worst_derivative: f64 = 0.0;
        for k in 0..40 {
            let s = k as f64;
            let offset = [1.4 + 0.9 * (0.7 * s).cos(), 0.3 * (1.1 * s).sin()];
            let b = Barrier {
                name: "edge/0".into(),
                shape: Shape::BodyCurve {
                    position: [0, 1],
                    heading: 2,
                    offset,
                    curve: curve.clone(),
                    side: if k % 2 == 0 { 1.0 } else { -1.0 },
                    margin: 1.1 + curve.deviation(),
                },
            };
            let x = [
                10.0 + 2.0 * s,
                6.0 * (0.1 + 0.1 * s).sin() - 2.5 + 0.1 * s,
                0.05 * s - 1.0,
                4.0 + 0.1 * s,
            ];
            worst_derivative = worst_derivative.max(derivatives_against_differences(&b, x));
            let u = [0.3 * (0.7 * s).sin(), -1.5 + 0.1 * s];
            worst = worst.max(rows_against_the_flow(
                &b,
                form,
                &model,
                (x, u),
                &mut work,
                (&mut first, &mut second),
            ));
            // h is the distance from the circle to the smooth curve less the margin.
            let (sn, cs) = x[2].sin_cos();
            let q = [
                x[0] + cs * offset[0] - sn * offset[1],
                x[1] + sn * offset[0] + cs * offset[1],
            ];
            let side = if k % 2 == 0 { 1.0 } else { -1.0 };
            assert!((b.h_at(&x) - (side * curve.nearest(q).distance - 1.1 - curve.deviation())).abs() < 1e-12);
        }
        assert!(
            worst_derivative < 1e-6,
            "∇h, ∇²h: largest relative difference {worst_derivative:e}"
        );
        assert!(worst < 1e-5, "rows: largest relative difference {worst:e}");
    }

    /// With a zero offset the body circle is the planar ball (4.81): the same Lie derivatives
    /// along the bicycle (4.78) as its closed form (4.88)–(4.90).
    #[test]
    fn body_circle_at_the_reference_point_is_the_planar_ball() {
        let model = BicycleModel::new(6.0);
        let ball = Barrier::circular_obstacle("o", [0, 1], [-3.0, 0.5], 6.0);
        let body = Barrier::body_circle("o", ([0, 1], 2), [0.0, 0.0], [-3.0, 0.5], 6.0);
        let x = DVector::from_column_slice(&[-11.0, 0.7, 0.3, 2.5]);
        let (a, b) = (lie_derivatives(&ball, &model, &x), lie_derivatives(&body, &model, &x));
        for (p, q) in [
            (a.h, b.h),
            (a.lf_h, b.lf_h),
            (a.lf2_h, b.lf2_h),
            (a.lg_lf_h[0], b.lg_lf_h[0]),
            (a.lg_lf_h[1], b.lg_lf_h[1]),
        ] {
            assert!((p - q).abs() < 1e-12 * (1.0 + p.abs()), "{p} vs {q}");
        }
    }

    #[test]
    fn example1_barrier_matches_4_54_and_4_55() {
        let model = crate::dynamics::NonlinearExample1::default();
        let b = Barrier {
            name: "h".into(),
            shape: Shape::Quadratic {
                q: vec![vec![0.0, 0.0], vec![0.0, 1.0]],
                c: vec![-1.0, 0.0],
                d: 1.0,
            },
        };
        let x = DVector::from_column_slice(&[1.3, -0.85]);
        let lie = lie_derivatives(&b, &model, &x);
        let (x1, x2) = (x[0], x[1]);
        assert!((lie.h - (x2 * x2 - x1 + 1.0)).abs() < 1e-12); // (4.53)
        assert!((lie.lf_h - (x1 + x2 + 2.0 * x1.powi(3) * x2)).abs() < 1e-12); // (4.54)
        assert!((lie.lg_h[0] + 1.0).abs() < 1e-12 && (lie.lg_h[1] - 2.0 * x2 * x2).abs() < 1e-12);
        // (4.55)
    }

    #[test]
    fn scalar_interval_barrier_matches_2_33_and_2_34() {
        let model = LinearModel::new(DMatrix::from_element(1, 1, 1.0), DMatrix::from_element(1, 1, 1.0));
        let b = Barrier {
            name: "interval".into(),
            shape: Shape::Ball {
                indices: vec![0],
                centre: vec![0.0],
                radius: 2.0,
                inside: true,
            },
        };
        let x = DVector::from_element(1, 1.3);
        let lie = lie_derivatives(&b, &model, &x);
        assert!((lie.h - (4.0 - 1.69)).abs() < 1e-12); // (2.32)
        assert!((lie.lf_h + 2.0 * 1.69).abs() < 1e-12); // (2.33)
        assert!((lie.lg_h[0] + 2.6).abs() < 1e-12); // (2.34)
    }
}
