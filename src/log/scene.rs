//! The Foxglove 3D view of an episode: `/scene` (foxglove.SceneUpdate) with the vehicle, its
//! trail, the obstacles (grey until known, red once known) and the reference path, and `/tf`
//! (foxglove.FrameTransform, world → vehicle), so opening a log in Foxglove's 3D panel shows
//! the episode without any set-up. Messages use Foxglove's own protobuf schemas.

use foxglove::messages::{
    Color, CubePrimitive, CylinderPrimitive, FrameTransform, LinePrimitive, Point3, Pose, Quaternion, SceneEntity,
    SceneUpdate, Timestamp, Vector3,
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
    let r = hull_radius.max(0.05);
    let mut e = entity(time, "vehicle");
    e.cylinders.push(CylinderPrimitive {
        pose: Some(pose(position[0], position[1], 0.05, 0.0)),
        size: Some(Vector3 {
            x: 2.0 * r,
            y: 2.0 * r,
            z: 0.1,
        }),
        bottom_scale: 1.0,
        top_scale: 1.0,
        color: Some(Color {
            r: 0.2,
            g: 0.4,
            b: 0.9,
            a: 0.35,
        }),
    });
    let (s, c) = heading.sin_cos();
    e.cubes.push(CubePrimitive {
        pose: Some(pose(position[0] + 0.5 * r * c, position[1] + 0.5 * r * s, 0.3, heading)),
        size: Some(Vector3 {
            x: 1.6 * r,
            y: 0.7 * r,
            z: 0.4,
        }),
        color: Some(Color {
            r: 0.2,
            g: 0.4,
            b: 0.9,
            a: 1.0,
        }),
    });
    SceneUpdate {
        deletions: vec![],
        entities: vec![e],
    }
}

/// A polyline in the world frame (trail, reference path).
pub fn polyline(time: f64, id: &str, points: &[[f64; 2]], color: Color, thickness: f64) -> SceneUpdate {
    let mut e = entity(time, id);
    e.lines.push(LinePrimitive {
        r#type: foxglove::messages::line_primitive::Type::LineStrip as i32,
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
    let color = if known {
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
    };
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

/// A predicted position p_i(t) of the vehicle: a flat ring of the hull radius (orange) and a
/// line from the vehicle's current position to it.
pub fn prediction(time: f64, id: &str, from: [f64; 2], to: [f64; 2], hull_radius: f64) -> SceneUpdate {
    let r = hull_radius.max(0.05);
    let mut e = entity(time, id);
    e.cylinders.push(CylinderPrimitive {
        pose: Some(pose(to[0], to[1], 0.03, 0.0)),
        size: Some(Vector3 {
            x: 2.0 * r,
            y: 2.0 * r,
            z: 0.05,
        }),
        bottom_scale: 1.0,
        top_scale: 1.0,
        color: Some(PREDICTION),
    });
    e.lines.push(LinePrimitive {
        r#type: foxglove::messages::line_primitive::Type::LineStrip as i32,
        pose: Some(pose(0.0, 0.0, 0.04, 0.0)),
        thickness: 0.1,
        scale_invariant: false,
        points: [from, to]
            .iter()
            .map(|p| Point3 {
                x: p[0],
                y: p[1],
                z: 0.0,
            })
            .collect(),
        color: Some(PREDICTION),
        colors: vec![],
        indices: vec![],
    });
    SceneUpdate {
        deletions: vec![],
        entities: vec![e],
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
    FrameTransform {
        timestamp: Some(timestamp(time)),
        parent_frame_id: WORLD_FRAME.into(),
        child_frame_id: VEHICLE_FRAME.into(),
        translation: Some(Vector3 {
            x: position[0],
            y: position[1],
            z: 0.0,
        }),
        rotation: Some(yaw(heading)),
    }
}

/// Trail colour.
pub const TRAIL: Color = Color {
    r: 0.1,
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
