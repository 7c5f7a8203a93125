//! The Foxglove 3D view of an episode: `/scene` (foxglove.SceneUpdate) with the vehicle, its
//! trail, the obstacles (grey until known, red once known), the reference path, the road
//! (edges grey, lane markings dashed yellow) and the half-space barriers on the plane, and `/tf`
//! (foxglove.FrameTransform, world → vehicle), so opening a log in Foxglove's 3D panel shows
//! the episode without any set-up. Messages use Foxglove's own protobuf schemas.

use foxglove::messages::{
    scene_entity_deletion, Color, CubePrimitive, CylinderPrimitive, FrameTransform, LinePrimitive, Point3, Pose,
    Quaternion, SceneEntity, SceneEntityDeletion, SceneUpdate, Timestamp, Vector3,
};

/// The world frame every entity is drawn in.
pub const WORLD_FRAME: &str = "world";
/// The vehicle's frame (child of the world frame in `/tf`).
pub const VEHICLE_FRAME: &str = "vehicle";

fn timestamp(time: f64) -> Timestamp {
    let ns = crate::log::mcap::sim_time_ns(time);
    Timestamp::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32)
}

fn yaw(heading: f64) -> Quaternion {
    let (s, c) = (heading / 2.0).sin_cos();
    Quaternion {
        x: 0.0,
        y: 0.0,
        z: s,
        w: c,
    }
}

fn pose(x: f64, y: f64, z: f64, heading: f64) -> Pose {
    Pose {
        position: Some(Vector3 { x, y, z }),
        orientation: Some(yaw(heading)),
    }
}

fn entity(time: f64, id: &str) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp(time)),
        frame_id: WORLD_FRAME.into(),
        id: id.into(),
        ..Default::default()
    }
}

/// The vehicle: its hull (a flat cylinder of the hull radius) and a body box along the heading.
pub fn vehicle(time: f64, position: [f64; 2], heading: f64, hull_radius: f64) -> SceneUpdate {
    let mut update = SceneUpdate::default();
    vehicle_into(&mut update, time, position, heading, hull_radius);
    update
}

/// `update` ← [`vehicle`], reusing its buffers when it already holds the vehicle (the
/// per-tick scene then allocates nothing).
pub fn vehicle_into(update: &mut SceneUpdate, time: f64, position: [f64; 2], heading: f64, hull_radius: f64) {
    let r = hull_radius.max(0.05);
    let shaped =
        matches!(update.entities.as_slice(), [e] if e.id == "vehicle" && e.cylinders.len() == 1 && e.cubes.len() == 1);
    if !shaped {
        let mut e = entity(time, "vehicle");
        e.cylinders.push(CylinderPrimitive {
            pose: None,
            size: None,
            bottom_scale: 1.0,
            top_scale: 1.0,
            color: Some(Color {
                r: 0.2,
                g: 0.4,
                b: 0.9,
                a: 0.35,
            }),
        });
        e.cubes.push(CubePrimitive {
            pose: None,
            size: None,
            color: Some(Color {
                r: 0.2,
                g: 0.4,
                b: 0.9,
                a: 1.0,
            }),
        });
        *update = SceneUpdate {
            deletions: vec![],
            entities: vec![e],
        };
    }
    let e = &mut update.entities[0];
    e.timestamp = Some(timestamp(time));
    e.cylinders[0].pose = Some(pose(position[0], position[1], 0.05, 0.0));
    e.cylinders[0].size = Some(Vector3 {
        x: 2.0 * r,
        y: 2.0 * r,
        z: 0.1,
    });
    let (s, c) = heading.sin_cos();
    e.cubes[0].pose = Some(pose(position[0] + 0.5 * r * c, position[1] + 0.5 * r * s, 0.3, heading));
    e.cubes[0].size = Some(Vector3 {
        x: 1.6 * r,
        y: 0.7 * r,
        z: 0.4,
    });
}

/// `update` ← the vehicle as its footprint: a cube of `size` (length, width) centred at its
/// planar position along its heading (reusing the buffers as [`vehicle_into`]).
pub fn footprint_vehicle_into(update: &mut SceneUpdate, time: f64, position: [f64; 2], heading: f64, size: [f64; 2]) {
    let shaped =
        matches!(update.entities.as_slice(), [e] if e.id == "vehicle" && e.cylinders.is_empty() && e.cubes.len() == 1);
    if !shaped {
        let mut e = entity(time, "vehicle");
        e.cubes.push(CubePrimitive {
            pose: None,
            size: Some(Vector3 {
                x: size[0],
                y: size[1],
                z: 0.4,
            }),
            color: Some(Color {
                r: 0.2,
                g: 0.4,
                b: 0.9,
                a: 0.8,
            }),
        });
        *update = SceneUpdate {
            deletions: vec![],
            entities: vec![e],
        };
    }
    let e = &mut update.entities[0];
    e.timestamp = Some(timestamp(time));
    e.cubes[0].pose = Some(pose(position[0], position[1], 0.2, heading));
}

/// A polyline in the world frame (trail, reference path).
pub fn polyline(time: f64, id: &str, points: &[[f64; 2]], color: Color, thickness: f64) -> SceneUpdate {
    lines(time, id, points, color, thickness, false)
}

/// `update` ← [`polyline`], reusing its buffers when it already holds one (a trail's next
/// segment).
pub fn polyline_into(update: &mut SceneUpdate, time: f64, id: &str, points: &[[f64; 2]], color: Color, thickness: f64) {
    let shaped = matches!(update.entities.as_slice(), [e] if e.lines.len() == 1 && e.cubes.is_empty());
    if !shaped {
        *update = polyline(time, id, points, color, thickness);
        return;
    }
    let e = &mut update.entities[0];
    e.timestamp = Some(timestamp(time));
    e.id.clear();
    e.id.push_str(id);
    let line = &mut e.lines[0];
    line.points.clear();
    line.points.extend(points.iter().map(|p| Point3 {
        x: p[0],
        y: p[1],
        z: 0.0,
    }));
    (line.thickness, line.color) = (thickness, Some(color));
}

/// Lines in the world frame: a polyline, or with `dashed` separate segments between the
/// points taken in pairs (a line list: a lane marking's dashes).
pub fn lines(time: f64, id: &str, points: &[[f64; 2]], color: Color, thickness: f64, dashed: bool) -> SceneUpdate {
    use foxglove::messages::line_primitive::Type;
    let mut e = entity(time, id);
    e.lines.push(LinePrimitive {
        r#type: if dashed { Type::LineList } else { Type::LineStrip } as i32,
        pose: Some(pose(0.0, 0.0, 0.02, 0.0)),
        thickness,
        scale_invariant: false,
        points: points
            .iter()
            .map(|p| Point3 {
                x: p[0],
                y: p[1],
                z: 0.0,
            })
            .collect(),
        color: Some(color),
        colors: vec![],
        indices: vec![],
    });
    SceneUpdate {
        deletions: vec![],
        entities: vec![e],
    }
}

/// A circular obstacle: grey while unknown to the controller, red once known.
pub fn obstacle(time: f64, name: &str, centre: [f64; 2], radius: f64, known: bool) -> SceneUpdate {
    let mut e = entity(time, name);
    let color = obstacle_color(known);
    e.cylinders.push(CylinderPrimitive {
        pose: Some(pose(centre[0], centre[1], 0.5, 0.0)),
        size: Some(Vector3 {
            x: 2.0 * radius,
            y: 2.0 * radius,
            z: 1.0,
        }),
        bottom_scale: 1.0,
        top_scale: 1.0,
        color: Some(color),
    });
    SceneUpdate {
        deletions: vec![],
        entities: vec![e],
    }
}

/// `update` ← [`obstacle`], reusing its buffers when it already holds entity `name` (a moving
/// obstacle redrawn every frame).
pub fn obstacle_into(update: &mut SceneUpdate, time: f64, name: &str, centre: [f64; 2], radius: f64, known: bool) {
    let shaped = matches!(update.entities.as_slice(), [e] if e.id == name && e.cylinders.len() == 1);
    if !shaped {
        *update = obstacle(time, name, centre, radius, known);
        return;
    }
    let e = &mut update.entities[0];
    e.timestamp = Some(timestamp(time));
    e.cylinders[0].pose = Some(pose(centre[0], centre[1], 0.5, 0.0));
    e.cylinders[0].color = Some(obstacle_color(known));
}

/// An obstacle's colour: grey while unknown to the controller, red once known.
fn obstacle_color(known: bool) -> Color {
    if known {
        Color {
            r: 0.9,
            g: 0.2,
            b: 0.2,
            a: 0.8,
        }
    } else {
        Color {
            r: 0.6,
            g: 0.6,
            b: 0.6,
            a: 0.5,
        }
    }
}

/// A box obstacle of `size` (length, width) along `heading`: grey while unknown, red once known.
pub fn box_obstacle(time: f64, name: &str, centre: [f64; 2], heading: f64, size: [f64; 2], known: bool) -> SceneUpdate {
    let mut update = obstacle(time, name, centre, 0.0, known);
    let e = &mut update.entities[0];
    let cylinder = e.cylinders.pop().expect("one cylinder");
    e.cubes.push(CubePrimitive {
        pose: Some(pose(centre[0], centre[1], 0.5, heading)),
        size: Some(Vector3 {
            x: size[0],
            y: size[1],
            z: 1.0,
        }),
        color: cylinder.color,
    });
    update
}

/// `update` ← [`box_obstacle`], reusing its buffers when it already holds entity `name` (a
/// moving road user redrawn every frame).
pub fn box_obstacle_into(
    update: &mut SceneUpdate,
    time: f64,
    name: &str,
    centre: [f64; 2],
    heading: f64,
    size: [f64; 2],
    known: bool,
) {
    let shaped =
        matches!(update.entities.as_slice(), [e] if e.id == name && e.cubes.len() == 1 && e.cylinders.is_empty());
    if !shaped {
        *update = box_obstacle(time, name, centre, heading, size, known);
        return;
    }
    let e = &mut update.entities[0];
    e.timestamp = Some(timestamp(time));
    let cube = &mut e.cubes[0];
    cube.pose = Some(pose(centre[0], centre[1], 0.5, heading));
    cube.size = Some(Vector3 {
        x: size[0],
        y: size[1],
        z: 1.0,
    });
    cube.color = Some(obstacle_color(known));
}

/// A predicted position p_i(t) of the vehicle: a flat ring of the hull radius (orange) and a
/// line from the vehicle's current position to it.
pub fn prediction(time: f64, id: &str, from: [f64; 2], to: [f64; 2], hull_radius: f64) -> SceneUpdate {
    let mut update = SceneUpdate::default();
    prediction_into(&mut update, time, id, from, to, hull_radius);
    update
}

/// `update` ← [`prediction`], reusing its buffers when it already holds entity `id`.
/// Without a finite `to` (the controller assumes nothing of the road user: it has not observed
/// it) the update deletes entity `id` instead.
pub fn prediction_into(update: &mut SceneUpdate, time: f64, id: &str, from: [f64; 2], to: [f64; 2], hull_radius: f64) {
    if !(to[0].is_finite() && to[1].is_finite()) {
        update.entities.clear();
        if !matches!(update.deletions.as_slice(), [d] if d.id == id) {
            update.deletions.clear();
            update.deletions.push(SceneEntityDeletion {
                timestamp: None,
                r#type: scene_entity_deletion::Type::MatchingId as i32,
                id: id.into(),
            });
        }
        update.deletions[0].timestamp = Some(timestamp(time));
        return;
    }
    let shaped = matches!(update.entities.as_slice(), [e] if e.id == id && e.cylinders.len() == 1 && e.lines.len() == 1 && e.lines[0].points.len() == 2);
    if !shaped {
        let mut e = entity(time, id);
        e.cylinders.push(CylinderPrimitive {
            pose: None,
            size: None,
            bottom_scale: 1.0,
            top_scale: 1.0,
            color: Some(PREDICTION),
        });
        e.lines.push(LinePrimitive {
            r#type: foxglove::messages::line_primitive::Type::LineStrip as i32,
            pose: Some(pose(0.0, 0.0, 0.04, 0.0)),
            thickness: 0.1,
            scale_invariant: false,
            points: vec![Point3::default(); 2],
            color: Some(PREDICTION),
            colors: vec![],
            indices: vec![],
        });
        *update = SceneUpdate {
            deletions: vec![],
            entities: vec![e],
        };
    }
    let e = &mut update.entities[0];
    e.timestamp = Some(timestamp(time));
    let r = hull_radius.max(0.05);
    e.cylinders[0].pose = Some(pose(to[0], to[1], 0.03, 0.0));
    e.cylinders[0].size = Some(Vector3 {
        x: 2.0 * r,
        y: 2.0 * r,
        z: 0.05,
    });
    for (point, p) in e.lines[0].points.iter_mut().zip([from, to]) {
        *point = Point3 {
            x: p[0],
            y: p[1],
            z: 0.0,
        };
    }
}

/// Predicted positions' colour.
pub const PREDICTION: Color = Color {
    r: 1.0,
    g: 0.55,
    b: 0.0,
    a: 0.45,
};

/// world → vehicle.
pub fn transform(time: f64, position: [f64; 2], heading: f64) -> FrameTransform {
    let mut transform = FrameTransform::default();
    transform_into(&mut transform, time, position, heading);
    transform
}

/// `transform` ← [`transform`], reusing its frame names.
pub fn transform_into(transform: &mut FrameTransform, time: f64, position: [f64; 2], heading: f64) {
    if transform.parent_frame_id != WORLD_FRAME {
        transform.parent_frame_id = WORLD_FRAME.into();
    }
    if transform.child_frame_id != VEHICLE_FRAME {
        transform.child_frame_id = VEHICLE_FRAME.into();
    }
    transform.timestamp = Some(timestamp(time));
    transform.translation = Some(Vector3 {
        x: position[0],
        y: position[1],
        z: 0.0,
    });
    transform.rotation = Some(yaw(heading));
}

/// Trail colour.
pub const TRAIL: Color = Color {
    r: 0.1,
    g: 0.3,
    b: 0.8,
    a: 0.9,
};
/// Road edge colour.
pub const ROAD_EDGE: Color = Color {
    r: 0.55,
    g: 0.55,
    b: 0.55,
    a: 1.0,
};
/// Lane marking colour.
pub const LANE: Color = Color {
    r: 0.95,
    g: 0.8,
    b: 0.2,
    a: 0.9,
};
/// Colour of a half-space barrier's h = 0 line.
pub const BARRIER: Color = Color {
    r: 0.6,
    g: 0.3,
    b: 0.8,
    a: 0.9,
};
/// Reference path colour.
pub const PATH: Color = Color {
    r: 0.2,
    g: 0.7,
    b: 0.2,
    a: 0.9,
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn updates_in_place_equal_fresh_ones_whatever_they_held() {
        let stale = [
            SceneUpdate::default(),
            vehicle(9.0, [3.0, -4.0], 2.0, 0.5),
            prediction(9.0, "prediction/other", [1.0, 1.0], [2.0, 2.0], 0.5),
        ];
        for k in 0..20 {
            let s = k as f64;
            let (time, position, heading) = (0.01 * s, [s.sin() * 10.0, s.cos()], 0.3 * s - 3.0);
            for old in &stale {
                let mut update = old.clone();
                vehicle_into(&mut update, time, position, heading, 1.5);
                assert_eq!(update, vehicle(time, position, heading, 1.5));
                let mut update = old.clone();
                prediction_into(&mut update, time, "prediction/steering", position, [s, -s], 1.5);
                assert_eq!(update, prediction(time, "prediction/steering", position, [s, -s], 1.5));
            }
            let mut tf = FrameTransform::default();
            transform_into(&mut tf, time, position, heading);
            transform_into(&mut tf, time, position, heading);
            assert_eq!(tf, transform(time, position, heading));
        }
        // The vehicle as drawn: hull at the position, body box half a radius ahead, yawed.
        let v = vehicle(1.5, [2.0, 3.0], 0.0, 2.0);
        let e = &v.entities[0];
        assert_eq!((e.id.as_str(), e.frame_id.as_str()), ("vehicle", WORLD_FRAME));
        assert_eq!(e.timestamp, Some(Timestamp::new(1, 500_000_000)));
        let hull = e.cylinders[0].pose.unwrap().position.unwrap();
        let body = e.cubes[0].pose.unwrap().position.unwrap();
        assert_eq!((hull.x, hull.y, body.x, body.y), (2.0, 3.0, 3.0, 3.0));
        let line = &prediction(0.0, "p", [0.0, 1.0], [2.0, 3.0], 1.0).entities[0].lines[0];
        assert_eq!((line.points[0].y, line.points[1].x), (1.0, 2.0));
    }
}
