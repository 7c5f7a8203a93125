//! Assembly of an episode from a loaded scenario, one function per block of the control
//! diagram (plant, queues, nominal, filter, obstacles, run info), each owning the checks that
//! need the model. Nothing here runs the loop (`episode/mod.rs`).

use std::sync::Arc;

use nalgebra::DVector;

use super::control::{self, ControlLoop};
use super::{EpisodeError, Obstacle};
use crate::barrier::{Barrier, BarrierForm};
use crate::delay::DelayQueue;
use crate::dynamics::Dynamics;
use crate::filter::{FilterContext, ParamError, SafetyFilter, TICK_TOLERANCE};
use crate::log::{KindInfo, RunInfo};
use crate::mujoco::{self, Model, ObjKind, Simulation};
use crate::nominal::{NominalContext, NominalController};
use crate::plant::{MujocoObstacle, MujocoPlant, OdePlant, Plant, PlantKind};
use crate::predictor::Structure;
use crate::random::{self, Stream};
use crate::scenario::{Integrator, LoadedScenario, ScenarioError};
use crate::vehicle;
use crate::vehicle_registry::VehicleBinding;

/// Most samples of a time-varying delay over the run for its largest value (`max_delay`).
const MAX_DELAY_SAMPLES: usize = 1_000_000;

/// A kind's parameter error as the scenario's field error.
fn param_error(loaded: &LoadedScenario, e: ParamError) -> EpisodeError {
    loaded.field_error(&e.key, e.message).into()
}

/// The plant's pieces before it is built: model (MuJoCo kinds), analytic dynamics, hull.
pub(super) struct PlantParts {
    model: Option<Model>,
    vehicle: Option<Box<dyn vehicle::MujocoVehicle>>,
    pub dynamics: Arc<dyn Dynamics>,
    pub hull_radius: f64,
    pub timestep: f64,
    /// The geom whose contacts are the vehicle's when it is not the hull ([`CONTACT_GEOM`]).
    contact_geom: Option<usize>,
    /// The vehicle kind's own keys, checked and normalised by its parameter type (what the
    /// log's resolved scenario holds).
    pub vehicle_params: toml::Table,
}

/// Where the vehicle's collision geom `hull` sits, read from the compiled bare model: what a
/// footprint's box or a lead's contact box is placed by.
struct HullGeometry {
    /// The name of the body holding the hull (the geom added for contacts goes into it).
    body: String,
    /// The hull's position in that body's frame.
    pos: [f64; 3],
    /// Its half-extents along its own axes.
    half: [f64; 3],
    /// Its position in the world at the model's reference pose (bodies taken as unrotated).
    world: [f64; 3],
}

/// The geom mjsafe adds to the vehicle's body when its contacts are not the hull's: the
/// footprint's box, or, behind a lead, a box whose front face is the vehicle's position.
pub(super) const CONTACT_GEOM: &str = "vehicle_contact";

/// Whether the vehicle's contacts come from an added geom: with a footprint, or a lead to
/// follow (its headway's gap is measured from the vehicle's position, its front).
fn needs_contact_geom(loaded: &LoadedScenario) -> bool {
    let sc = &loaded.scenario;
    sc.plant == PlantKind::Mujoco
        && (sc.vehicle.footprint.is_some() || sc.obstacles.iter().any(|o| o.following.is_some()))
}

/// The hull of the bound vehicle in `model`: its body (a named body other than the world),
/// position and extents.
fn hull_geometry(model: &Model, hull: usize) -> Result<HullGeometry, String> {
    let body = model.geom_body(hull);
    let name = (body != 0).then(|| model.name(ObjKind::Body, body)).flatten();
    let Some(name) = name.filter(|n| !n.is_empty()) else {
        return Err("the collision geom `hull` must be in a named body of the vehicle (a footprint's or a lead's contact box is added to it)".into());
    };
    let Some(half) = model.geom_half_extents(hull) else {
        return Err("the collision geom `hull` must be a sphere, capsule, ellipsoid, cylinder or box".into());
    };
    let pos = model.geom_pos(hull);
    let mut world = pos;
    let mut b = body;
    while b != 0 {
        let p = model.body_pos(b);
        (0..3).for_each(|k| world[k] += p[k]);
        b = model.body_parent(b);
    }
    Ok(HullGeometry {
        body: name,
        pos,
        half,
        world,
    })
}

/// The end of the start tag `<body … name="name" …>` in `xml` (comments skipped), where a
/// child element can be inserted; None if there is none or it closes itself.
fn body_tag_end(xml: &str, name: &str) -> Option<usize> {
    let bytes = xml.as_bytes();
    let mut i = 0;
    while let Some(at) = xml[i..].find('<').map(|k| i + k) {
        if xml[at..].starts_with("<!--") {
            i = at + 4 + xml[at + 4..].find("-->")? + 3;
            continue;
        }
        // The tag's end: the first '>' outside quotes.
        let mut quote = None;
        let mut end = at + 1;
        while end < bytes.len() {
            match (bytes[end], quote) {
                (b'"' | b'\'', None) => quote = Some(bytes[end]),
                (c, Some(q)) if c == q => quote = None,
                (b'>', None) => break,
                _ => {}
            }
            end += 1;
        }
        if end >= bytes.len() {
            return None;
        }
        let tag = &xml[at + 1..end];
        let is_body = tag
            .strip_prefix("body")
            .is_some_and(|rest| rest.starts_with(char::is_whitespace));
        if is_body && !tag.ends_with('/') && attribute(tag, "name").as_deref() == Some(name) {
            return Some(end + 1);
        }
        i = end + 1;
    }
    None
}

/// The value of attribute `key` in a start tag's text (`body name="x" pos="…"`).
fn attribute(tag: &str, key: &str) -> Option<String> {
    let mut rest = tag.split_once(char::is_whitespace)?.1;
    loop {
        rest = rest.trim_start();
        let (attr, after) = rest.split_once('=')?;
        let after = after.trim_start();
        let quote = after.chars().next().filter(|c| *c == '"' || *c == '\'')?;
        let (value, next) = after[1..].split_once(quote)?;
        if attr.trim() == key {
            return Some(value.to_string());
        }
        rest = next;
    }
}

/// The quaternion (w x y z) of a turn by `heading` about z.
fn yaw_quat(heading: f64) -> String {
    let (s, c) = (0.5 * heading).sin_cos();
    format!("{c} 0 0 {s}")
}

/// MJCF of the model with each obstacle added as a geom `obstacle_<i>` (contype 0,
/// conaffinity 1: it collides with the vehicle's contact geom and nothing else): a sphere of
/// its radius, or a box of its length and width (half-height half its longer side) turned by
/// its heading, in the world body (the plant moves a moving one's every step), except a lead's,
/// in a mocap body `obstacle_<i>_body`: it sits at the height and on the
/// line of the vehicle's hull (`hull`). With `hull` (a footprint or a lead), the vehicle's
/// body gets the geom [`CONTACT_GEOM`]: the footprint's box centred on the reference point (the
/// body's origin) at the hull's height, or a box of the hull's extents ending at the body's
/// origin (the vehicle's front, as the headway measures it).
fn model_with_obstacles(
    xml: &str,
    model_path: &std::path::Path,
    loaded: &LoadedScenario,
    hull: Option<&HullGeometry>,
) -> Result<String, ScenarioError> {
    let sc = &loaded.scenario;
    let obstacles = &sc.obstacles;
    if obstacles.is_empty() && hull.is_none() {
        return Ok(xml.to_string());
    }
    let Some(at) = xml.rfind("</worldbody>") else {
        return Err(loaded.field_error(
            "vehicle.model",
            format!(
                "{}: expected a <worldbody> to place the obstacles in",
                model_path.display()
            ),
        ));
    };
    // The names added below must be new to the model (MuJoCo would refuse a repeated name with
    // its own message, about a line of the modified text).
    let added = (0..obstacles.len())
        .flat_map(|i| [obstacle_geom_name(i), obstacle_body_name(i)])
        .chain(hull.map(|_| CONTACT_GEOM.to_string()));
    for name in added {
        if xml.contains(&format!("name=\"{name}\"")) {
            return Err(loaded.field_error(
                "vehicle.model",
                format!(
                    "{}: already has an element named `{name}`, a name mjsafe gives to the obstacles and the vehicle's contact box it adds: expected another name",
                    model_path.display()
                ),
            ));
        }
    }
    let mut geoms = String::new();
    // On the ODE plant the model only gives the dynamics: a box has no geom there (its text
    // as it always was).
    let ode = sc.plant == PlantKind::Ode;
    for (i, o) in obstacles
        .iter()
        .enumerate()
        .filter(|(_, o)| !(ode && o.shape.is_some()))
    {
        let look = "contype=\"0\" conaffinity=\"1\" rgba=\"0.9 0.2 0.2 0.6\"";
        let (name, [x, y]) = (obstacle_geom_name(i), o.centre);
        let shape = match o.shape {
            None => format!("type=\"sphere\" size=\"{}\"", o.radius.unwrap_or_default()),
            Some(crate::scenario::ObstacleShape::Box { length, width, .. }) => format!(
                "type=\"box\" size=\"{} {} {}\" quat=\"{}\"",
                0.5 * length,
                0.5 * width,
                0.5 * length.max(width),
                yaw_quat(
                    o.circles(obstacle_motion(loaded, i)?.0.and_then(|m| m.layout_heading()))
                        .0
                )
            ),
        };
        let lead = hull.filter(|_| o.following.is_some());
        // A sphere's text, static or moving, is as it always was (logs unchanged).
        let moving = o.motion.is_some();
        geoms.push_str(&match (moving, lead) {
            (_, Some(hull)) => format!(
                "    <body name=\"{}\" mocap=\"true\" pos=\"{x} {y} 0\"><geom name=\"{name}\" {shape} pos=\"0 {} {}\" {look}/></body>\n",
                obstacle_body_name(i),
                hull.world[1] - y,
                hull.world[2]
            ),
            (false, None) if o.shape.is_none() => {
                format!("    <geom name=\"{name}\" type=\"sphere\" pos=\"{x} {y} 0\" size=\"{}\" contype=\"0\" conaffinity=\"1\" rgba=\"0.9 0.2 0.2 0.6\"/>\n", o.radius.unwrap_or_default())
            }
            (false, None) => format!("    <geom name=\"{name}\" {shape} pos=\"{x} {y} 0\" {look}/>\n"),
            // A moving road user is a world geom the plant moves (`Simulation::place_world_geom`):
            // as a mocap body it cost the implicit integrator's derivatives (docs/performance.md).
            (true, None) => format!("    <geom name=\"{name}\" {shape} pos=\"{x} {y} 0\" {look}/>\n"),
        });
    }
    let mut text = format!("{}{}{}", &xml[..at], geoms, &xml[at..]);
    if let Some(stack) = stack_for_bodies(xml, geoms.matches("<body ").count(), loaded, model_path)? {
        let Some(end) = text.rfind("</mujoco>") else {
            return Err(loaded.field_error(
                "vehicle.model",
                format!("{}: expected the end tag </mujoco>", model_path.display()),
            ));
        };
        text.insert_str(end, &format!("  <size nstack=\"{stack}\"/>\n"));
    }
    if let Some(hull) = hull {
        let (size, pos) = match &sc.vehicle.footprint {
            Some(f) => (
                [0.5 * f.length, 0.5 * f.width, 0.5 * f.length.max(f.width)],
                [f.offset, 0.0, hull.pos[2]],
            ),
            None => (hull.half, [-hull.half[0], hull.pos[1], hull.pos[2]]),
        };
        let geom = format!(
            "<geom name=\"{CONTACT_GEOM}\" type=\"box\" size=\"{} {} {}\" pos=\"{} {} {}\" mass=\"0\" rgba=\"0.2 0.4 0.9 0.3\"/>",
            size[0], size[1], size[2], pos[0], pos[1], pos[2]
        );
        let Some(end) = body_tag_end(&text, &hull.body) else {
            return Err(loaded.field_error(
                "vehicle.model",
                format!(
                    "{}: expected the start tag <body name=\"{}\"> of the hull's body, to add the vehicle's contact box to",
                    model_path.display(),
                    hull.body
                ),
            ));
        };
        text.insert_str(end, &geom);
    }
    Ok(text)
}

/// MuJoCo 2.2.2's default stack when a model declares no `<size nstack>` (doubles, ~10 MB).
const DEFAULT_NSTACK: f64 = 1_250_000.0;

/// The `nstack` the model needs once `added` mocap bodies are in it, when its own (declared, or
/// MuJoCo's default) is too small; None when it suffices (the text is left as it was). MuJoCo
/// 2.2.2's collision takes about nbody² / 2 integers of the stack (measured: with `nstack`
/// 100 000, 200 000 and 400 000 doubles the bicycle model loads with at most about 433, 620
/// and 881 moving obstacles; beyond, `mj_loadXML` fails with "Stack overflow"): the model's
/// own stack plus nbody² doubles (twice that) is asked for. An error, naming the number of
/// obstacles, when that exceeds [`crate::mujoco::MAX_NSTACK`].
fn stack_for_bodies(
    xml: &str,
    added: usize,
    loaded: &LoadedScenario,
    model_path: &std::path::Path,
) -> Result<Option<u64>, ScenarioError> {
    let (declared, bodies) = crate::mujoco::last_attribute_and_count(xml, ("size", "nstack"), "body");
    let own = (declared.and_then(|v| v.trim().parse::<f64>().ok()))
        .filter(|v| *v >= 0.0)
        .unwrap_or(DEFAULT_NSTACK);
    // (The world body, the model's bodies and the added ones.)
    let nbody = (1 + bodies + added) as f64;
    if added == 0 || nbody * nbody <= own {
        return Ok(None);
    }
    let stack = own + nbody * nbody;
    if stack > crate::mujoco::MAX_NSTACK {
        return Err(loaded.field_error(
            "obstacles",
            format!(
                "{added} moving obstacles in {}: MuJoCo's collision would need a stack of about {stack:.0} doubles, more than mjsafe allows ({}); expected fewer moving obstacles",
                model_path.display(),
                crate::mujoco::MAX_NSTACK
            ),
        ));
    }
    Ok(Some(stack.ceil() as u64))
}

pub(super) fn obstacle_geom_name(index: usize) -> String {
    format!("obstacle_{index}")
}

/// The mocap body of a moving obstacle's geom.
fn obstacle_body_name(index: usize) -> String {
    format!("obstacle_{index}_body")
}

/// The vehicle of the registered `vehicle.kind`: its own keys checked, its MJCF (with the
/// obstacles' geoms) compiled and bound, or the analytic model of a kind without MJCF.
pub(super) fn plant_parts(loaded: &LoadedScenario) -> Result<PlantParts, EpisodeError> {
    let sc = &loaded.scenario;
    let file = loaded.path.display().to_string();
    let vehicles = crate::vehicle_registry::registry();
    let (binding, vehicle_params) = vehicles
        .vehicle(&sc.vehicle.kind)
        .and_then(|binding| Ok((binding, vehicles.check_vehicle(&sc.vehicle.kind, &sc.vehicle.params)?)))
        .map_err(|e| param_error(loaded, e))?;
    drop(vehicles);
    if let VehicleBinding::Analytic(_) = binding {
        let kind = &sc.vehicle.kind;
        if sc.plant != PlantKind::Ode {
            return Err(loaded
                .field_error(
                    "plant",
                    format!("vehicle.kind = \"{kind}\" has no MJCF model: expected plant = \"ode\""),
                )
                .into());
        }
        if sc.vehicle.model.is_none() && sc.vehicle.timestep.is_none() {
            return Err(loaded
                .field_error(
                    "vehicle.timestep",
                    format!("vehicle.kind = \"{kind}\" has no model file: expected the integration step in seconds"),
                )
                .into());
        }
    }
    match (binding, loaded.model_path()) {
        (VehicleBinding::Mjcf(bind), Some(model_path)) => {
            let xml = match crate::models::is_builtin(&model_path) {
                true => crate::models::builtin(&model_path).map(str::to_string),
                false => crate::files::read_text_limited(&model_path, "MJCF model", crate::files::MODEL_LIMIT)
                    .map_err(|e| e.to_string()),
            }
            .map_err(|e| loaded.field_error("vehicle.model", e))?;
            let origin = model_path.display().to_string();
            let compile = |xml: &str| {
                Model::from_xml_string(xml, &origin).map_err(|source| EpisodeError::Model {
                    file: file.clone(),
                    reason: source,
                })
            };
            // A footprint or a lead: the hull's body and extents from the bare model first.
            let hull = match needs_contact_geom(loaded) {
                true => {
                    let bare = compile(&xml)?;
                    let bound = bind(&bare).map_err(|reason| EpisodeError::Model {
                        file: file.clone(),
                        reason,
                    })?;
                    let hull = hull_geometry(&bare, bound.hull_geom())
                        .map_err(|message| loaded.field_error("vehicle.model", format!("{origin}: {message}")))?;
                    Some(hull)
                }
                false => None,
            };
            let xml = model_with_obstacles(&xml, &model_path, loaded, hull.as_ref())?;
            let mut model = compile(&xml)?;
            if let Some(h) = sc.vehicle.timestep {
                model.set_timestep(h);
            }
            if let Some(integrator) = sc.vehicle.integrator {
                model.set_integrator(match integrator {
                    Integrator::Euler => mujoco::Integrator::Euler,
                    Integrator::Rk4 => mujoco::Integrator::Rk4,
                    Integrator::Implicit => mujoco::Integrator::Implicit,
                });
            }
            let mut bound = bind(&model).map_err(|reason| EpisodeError::Model {
                file: file.clone(),
                reason,
            })?;
            let contact_geom = match hull {
                Some(_) => {
                    // The added box takes the hull's contact bits; the hull then touches nothing.
                    let hull = bound.hull_geom();
                    let contact = model
                        .require(ObjKind::Geom, CONTACT_GEOM)
                        .map_err(|reason| EpisodeError::Model {
                            file: file.clone(),
                            reason,
                        })?;
                    if model.geom_body(contact) != model.geom_body(hull) {
                        return Err(loaded
                            .field_error(
                                "vehicle.model",
                                format!("{origin}: the vehicle's contact box did not land in the hull's body"),
                            )
                            .into());
                    }
                    model.set_geom_collision(contact, model.geom_collision(hull));
                    model.set_geom_collision(hull, [0, 0]);
                    bound = bind(&model).map_err(|reason| EpisodeError::Model { file, reason })?;
                    Some(contact)
                }
                None => None,
            };
            Ok(PlantParts {
                dynamics: bound.dynamics(),
                hull_radius: bound.hull_radius(),
                timestep: model.timestep(),
                model: Some(model),
                vehicle: Some(bound),
                contact_geom,
                vehicle_params,
            })
        }
        (VehicleBinding::Analytic(build), None) => Ok(PlantParts {
            model: None,
            vehicle: None,
            dynamics: build(&vehicle_params).map_err(|e| param_error(loaded, e))?,
            hull_radius: 0.0,
            timestep: sc.vehicle.timestep.expect("validated"),
            contact_geom: None,
            vehicle_params,
        }),
        // The scenario's validation pairs MJCF kinds with a model file and the others without.
        (VehicleBinding::Mjcf(_), None) => Err(loaded
            .field_error(
                "vehicle.model",
                format!("expected the MJCF file of the {} model", sc.vehicle.kind),
            )
            .into()),
        (VehicleBinding::Analytic(_), Some(_)) => Err(loaded
            .field_error(
                "vehicle.model",
                format!(
                    "vehicle.kind = \"{}\" is an analytic model: expected no MJCF file",
                    sc.vehicle.kind
                ),
            )
            .into()),
    }
}

/// The initial state's size and the channel names the scenario uses, against the model.
pub(super) fn check_state_and_channels(loaded: &LoadedScenario, model: &dyn Dynamics) -> Result<(), EpisodeError> {
    let sc = &loaded.scenario;
    let n = model.state_dim();
    if sc.vehicle.initial_state.len() != n {
        return Err(loaded
            .field_error(
                "vehicle.initial_state",
                format!(
                    "expected {n} values ({}), found {}",
                    model.state_names().join(", "),
                    sc.vehicle.initial_state.len()
                ),
            )
            .into());
    }
    let channels = model.channel_names();
    for (section, keys) in [
        ("delays", sc.delays.keys().collect::<Vec<_>>()),
        ("assumed_delays", sc.assumed_delays.keys().collect()),
        ("actuation", sc.actuation.keys().collect()),
        ("actuator_dynamics", sc.actuator_dynamics.keys().collect()),
        ("initial_input", sc.initial_input.keys().collect()),
        ("vehicle_limits", sc.vehicle_limits.keys().collect()),
    ] {
        for key in keys {
            if !channels.contains(key) {
                return Err(loaded
                    .field_error(
                        &format!("{section}.{key}"),
                        format!("unknown input channel; this vehicle has: {}", channels.join(", ")),
                    )
                    .into());
            }
        }
    }
    if sc.goal.is_some() && model.planar_position().is_none() {
        return Err(loaded
            .field_error(
                "goal",
                format!(
                    "a goal is a place in the plane: expected a planar vehicle, but this one's state ({}) has no planar position",
                    model.state_names().join(", ")
                ),
            )
            .into());
    }
    Ok(())
}

/// (control period, plant steps per tick): the period must be a whole multiple of h.
pub(super) fn control_period(loaded: &LoadedScenario, timestep: f64) -> Result<(f64, u64), EpisodeError> {
    let period = loaded.scenario.control.period.unwrap_or(timestep);
    let ratio = period / timestep;
    if (ratio - ratio.round()).abs() > 1e-6 || ratio.round() < 1.0 {
        return Err(loaded
            .field_error(
                "control.period",
                format!("expected a whole multiple of the timestep {timestep} s, found {period}"),
            )
            .into());
    }
    Ok((period, ratio.round() as u64))
}

/// The delay queues: one per channel with the delay the controller assumes (Assumptions 1–2
/// checked), the predictor structure they call for, and, when some true delay differs from
/// the assumed one, the actuators' own queues (true delays, only checked to be physical).
pub(super) struct Queues {
    pub assumed: Vec<DelayQueue>,
    pub structure: Structure,
    pub actuators: Option<Vec<DelayQueue>>,
}

pub(super) fn queues(
    loaded: &LoadedScenario,
    channels: &[String],
    timestep: f64,
    period: f64,
) -> Result<Queues, EpisodeError> {
    let sc = &loaded.scenario;
    let sections = crate::delay::DelaySections {
        delays: &sc.delays,
        assumed_delays: &sc.assumed_delays,
        actuation: &sc.actuation,
        initial_input: &sc.initial_input,
        seed: sc.seed,
        duration: sc.duration,
        history: sc.control.history,
    };
    let built = (sections.queues(channels, timestep)).map_err(|e| loaded.field_error(&e.key, e.message))?;
    let structure =
        control::predictor_structure(&built.assumed, period).map_err(|e| loaded.field_error("delays", e))?;
    Ok(Queues {
        assumed: built.assumed,
        structure,
        actuators: built.actuators,
    })
}

/// The nominal controller of the scenario's `nominal` table (registry kind).
pub(super) fn nominal(
    loaded: &LoadedScenario,
    model: &Arc<dyn Dynamics>,
) -> Result<Box<dyn NominalController>, EpisodeError> {
    let spec = &loaded.scenario.nominal;
    let kind = &loaded.scenario.vehicle.kind;
    let ctx = NominalContext {
        model,
        vehicle_kind: kind,
        channels: model.channel_names(),
    };
    crate::registry::registry()
        .build_nominal(&spec.kind, &spec.params, &ctx)
        .map_err(|e| param_error(loaded, e))
}

/// The safety filter of the scenario's `filter` table (registry kind), built knowing the
/// model, the queues, x(0), every barrier (the scenario's, then the obstacles') and the nominal.
pub(super) fn filter(
    loaded: &LoadedScenario,
    model: &Arc<dyn Dynamics>,
    queues: &[DelayQueue],
    barriers: &[Barrier],
    nominal: &dyn NominalController,
    (timestep, hull_radius): (f64, f64),
) -> Result<Box<dyn SafetyFilter>, EpisodeError> {
    let sc = &loaded.scenario;
    let kind = &sc.vehicle.kind;
    let ctx = FilterContext {
        model,
        vehicle_kind: kind,
        queues,
        initial_state: &DVector::from_column_slice(&sc.vehicle.initial_state),
        barriers,
        nominal,
        timestep,
        hull_radius,
        footprint: sc.vehicle.footprint,
    };
    crate::registry::registry()
        .build_filter(&sc.filter.kind, &sc.filter.params, &ctx)
        .map_err(|mut e| {
            // The filter checks the delays the controller assumes.
            if let Some(channel) = e.key.strip_prefix("delays.") {
                if sc.assumed_delays.contains_key(channel) {
                    e.key = format!("assumed_{}", e.key);
                }
            }
            param_error(loaded, e)
        })
}

/// x(0): the scenario's initial state with its seeded perturbation.
pub(super) fn initial_state(loaded: &LoadedScenario) -> DVector<f64> {
    let sc = &loaded.scenario;
    let mut x0 = DVector::from_column_slice(&sc.vehicle.initial_state);
    if let Some(bounds) = &sc.vehicle.initial_perturbation {
        for (i, bound) in bounds.iter().enumerate() {
            x0[i] += bound * random::symmetric_unit(sc.seed, Stream::InitialState, 0, i as u64);
        }
    }
    x0
}

/// The state constraints that are not obstacles (`barrier_<i>`).
pub(super) fn barriers(loaded: &LoadedScenario, n: usize) -> Result<Vec<Barrier>, EpisodeError> {
    let mut barriers = Vec::with_capacity(loaded.scenario.barriers.len());
    for (i, shape) in loaded.scenario.barriers.iter().enumerate() {
        let b = Barrier {
            name: format!("barrier_{i}"),
            shape: shape.clone(),
        };
        if b.max_index() >= n {
            return Err(loaded
                .field_error(
                    &format!("barriers.{i}"),
                    format!("refers to state index {}, the state has {n} components", b.max_index()),
                )
                .into());
        }
        barriers.push(b);
    }
    Ok(barriers)
}

/// The road's edges as barriers with the hull (`crate::road`), each with the vehicle on its
/// road side at the start, after the scenario's own barriers.
pub(super) fn road_edges(
    loaded: &LoadedScenario,
    model: &dyn Dynamics,
    hull_radius: f64,
    x0: &DVector<f64>,
) -> Result<Vec<Barrier>, EpisodeError> {
    let Some(road) = &loaded.scenario.road else {
        return Ok(Vec::new());
    };
    let footprint = (loaded.scenario.vehicle.footprint.as_ref()).map(|_| vehicle_circles(loaded, hull_radius));
    (road.barriers(model, hull_radius, footprint.as_deref(), x0))
        .map_err(|e| loaded.field_error(&e.key, e.message).into())
}

/// The static lines of the 3D view (`road/<edge>`, `road/lane/<marking>` dashed, a CommonRoad
/// world's lanelet bounds (`road/lanelet/…`, dashed ones `road/lane/lanelet_…`), the goal disc's
/// rim dashed (`goal`), and `barrier/<name>` for a half-space barrier on the planar position,
/// drawn where h = 0),
/// lines drawn over the stretch near the points `around` (start, path, obstacles).
pub(super) fn scene_lines(
    loaded: &LoadedScenario,
    planar: Option<[usize; 2]>,
    barriers: &[Barrier],
    around: &[[f64; 2]],
) -> Vec<super::records::SceneLine> {
    use super::records::SceneLine;
    let Some(position) = planar else {
        return Vec::new();
    };
    let mut lines = Vec::new();
    if let Some(road) = &loaded.scenario.road {
        for (i, edge) in road.edges.iter().enumerate() {
            lines.push(SceneLine {
                id: format!("road/{}", edge.name(i)),
                points: edge.drawn(around),
                dashed: false,
            });
        }
        for (i, marking) in road.lanes.iter().enumerate() {
            lines.push(SceneLine {
                id: format!("road/lane/{}", marking.name(i)),
                points: marking.curve().dashes(around),
                dashed: true,
            });
        }
    }
    if let Some(cr) = &loaded.commonroad {
        for (id, points, dashed) in crate::commonroad::lanelet_lines(cr, around) {
            lines.push(SceneLine { id, points, dashed });
        }
    }
    if let Some(goal) = &loaded.scenario.goal {
        if let (Some(position), Some(radius)) = (goal.position, goal.radius) {
            lines.push(SceneLine {
                id: "goal".into(),
                points: dashed_circle(position, radius),
                dashed: true,
            });
        }
        for (k, polygon) in goal.polygons.iter().enumerate() {
            let closed: Vec<[f64; 2]> = polygon.iter().chain(polygon.first()).copied().collect();
            lines.push(SceneLine {
                id: format!("goal/{k}"),
                points: closed.windows(2).flat_map(|w| [w[0], w[1]]).collect(),
                dashed: true,
            });
        }
    }
    for b in barriers {
        if let Some(curve) = crate::road::planar_half_space(&b.shape, position) {
            lines.push(SceneLine {
                id: format!("barrier/{}", b.name),
                points: curve.polyline(around),
                dashed: false,
            });
        }
    }
    lines
}

/// A circle as 24 dashes (point pairs of a line list), half of each arc drawn.
fn dashed_circle(centre: [f64; 2], radius: f64) -> Vec<[f64; 2]> {
    const DASHES: usize = 24;
    let at = |angle: f64| [centre[0] + radius * angle.cos(), centre[1] + radius * angle.sin()];
    (0..DASHES)
        .flat_map(|k| {
            let start = std::f64::consts::TAU * k as f64 / DASHES as f64;
            [at(start), at(start + std::f64::consts::PI / DASHES as f64)]
        })
        .collect()
}

/// A footprint's body circles off the reference point have mixed relative degree; in the
/// relative-degree-2 form their condition factors s² + l1 s + l0 into real rates
/// ([`BarrierForm::real_rates`]), so complex roots are refused.
pub(super) fn check_mixed_relative_degree(
    loaded: &LoadedScenario,
    form: Option<BarrierForm>,
    barriers: &[Barrier],
) -> Result<(), EpisodeError> {
    match form {
        Some(form @ BarrierForm::RelativeDegree2 { l0, l1 })
            if form.real_rates().is_none() && barriers.iter().any(Barrier::mixed_relative_degree) =>
        {
            Err(loaded
                .field_error(
                    "filter.l1",
                    format!(
                        "a footprint's circles need real positive roots of s² + l1 s + l0 (l1² ≥ 4 l0, both > 0) for their mixed-relative-degree condition; found l0 = {l0}, l1 = {l1}"
                    ),
                )
                .into())
        }
        _ => Ok(()),
    }
}

/// When obstacle i becomes known: its `appear_at` plus its seeded jitter, not before t = 0.
fn appear_at(sc: &crate::scenario::Scenario, i: usize) -> f64 {
    let o = &sc.obstacles[i];
    (o.appear_at + o.appear_jitter * random::symmetric_unit(sc.seed, Stream::ObstacleAppearance, i as u64, 0)).max(0.0)
}

/// The vehicle's circles: (offset in its body frame, radius): its hull circle about the
/// planar position, or the covering circles of `vehicle.footprint` (`crate::footprint`).
pub(super) fn vehicle_circles(loaded: &LoadedScenario, hull_radius: f64) -> Vec<([f64; 2], f64)> {
    match &loaded.scenario.vehicle.footprint {
        Some(rectangle) => rectangle.circles().iter().map(|c| (c.offset, c.radius)).collect(),
        None => vec![([0.0, 0.0], hull_radius)],
    }
}

/// For a road user of the CommonRoad file (`cr_<id>`, a dynamic one of the file) overlapping the
/// car at the start: how to say it is the ego's own recording (CommonRoad-CriMe's `ego_id`).
fn own_recording_hint(loaded: &LoadedScenario, o: &crate::scenario::ObstacleSpec) -> String {
    let id = (o.name.as_deref().and_then(|n| n.strip_prefix("cr_"))).and_then(|id| id.parse::<u64>().ok());
    let dynamic = |id: u64| {
        (loaded.commonroad.as_ref().and_then(|cr| cr.obstacle(id)))
            .is_some_and(|road_user| road_user.role == mjsafe_commonroad::ObstacleRole::Dynamic)
    };
    match id.filter(|&id| dynamic(id)) {
        Some(id) => format!("; if it is the ego's own recording, set commonroad.ego_obstacle = {id} (`--set commonroad.ego_obstacle={id}`)"),
        None => String::new(),
    }
}

/// The obstacles: circular barriers (4.81) with r = hull + obstacle radius, clear of x(0),
/// or with a footprint or a box, one barrier per (vehicle circle i, obstacle circle j) pair,
/// named `<obstacle>/<i>-<j>` (a body circle, [`Barrier::body_circle`], for a footprint).
pub(super) fn obstacles(
    loaded: &LoadedScenario,
    model: &dyn Dynamics,
    hull_radius: f64,
    x0: &DVector<f64>,
) -> Result<Vec<Obstacle>, EpisodeError> {
    let sc = &loaded.scenario;
    let vehicle = vehicle_circles(loaded, hull_radius);
    let heading = match (&sc.vehicle.footprint, model.heading_index()) {
        (Some(_), None) => {
            return Err(loaded
                .field_error(
                    "vehicle.footprint",
                    "this vehicle has no heading to turn a footprint with",
                )
                .into());
        }
        (Some(_), _) if model.input_dim() > 4 => {
            return Err(loaded
                .field_error("vehicle.footprint", "footprints need a vehicle with at most 4 inputs")
                .into());
        }
        (_, heading) => heading,
    };
    let mut obstacles = Vec::with_capacity(sc.obstacles.len());
    for (i, o) in sc.obstacles.iter().enumerate() {
        if o.following.is_some() {
            obstacles.push(lead(loaded, model, i, x0)?);
            continue;
        }
        let Some(position) = model.planar_position() else {
            return Err(loaded
                .field_error("obstacles", "this vehicle does not move in a plane")
                .into());
        };
        let name = o.name.clone().unwrap_or_else(|| obstacle_geom_name(i));
        let (motion, centre) = obstacle_motion(loaded, i)?;
        let (box_heading, circles) = o.circles(motion.as_ref().and_then(|m| m.layout_heading()));
        let single = sc.vehicle.footprint.is_none() && o.shape.is_none();
        let mut barriers = Vec::with_capacity(vehicle.len() * circles.len());
        let mut offsets = Vec::with_capacity(barriers.capacity());
        for (vi, &(body_offset, body_radius)) in vehicle.iter().enumerate() {
            for (oj, &(offset, radius)) in circles.iter().enumerate() {
                let at = [centre[0] + offset[0], centre[1] + offset[1]];
                let pair = if single {
                    name.clone()
                } else {
                    format!("{name}/{vi}-{oj}")
                };
                let barrier = match (&sc.vehicle.footprint, heading) {
                    (Some(_), Some(heading)) => {
                        Barrier::body_circle(&pair, (position, heading), body_offset, at, body_radius + radius)
                    }
                    _ => Barrier::circular_obstacle(&pair, position, at, body_radius + radius),
                };
                // (A recorded road user that appears later is not there at the start.)
                if barrier.h(x0) < 0.0 && motion.as_ref().is_none_or(|m| m.exists_at(0.0)) {
                    return Err(loaded
                        .field_error(
                            &format!("obstacles.{i}"),
                            format!(
                                "the obstacle `{name}` overlaps the vehicle at the start (clearance {:.3} m){}",
                                barrier.clearance(x0),
                                own_recording_hint(loaded, o)
                            ),
                        )
                        .into());
                }
                barriers.push(barrier);
                offsets.push(offset);
            }
        }
        let outline = match o.shape {
            Some(crate::scenario::ObstacleShape::Box { length, width, .. }) => super::Outline::Box {
                length,
                width,
                heading: box_heading,
            },
            None => super::Outline::Circle {
                radius: o.radius.unwrap_or(0.0),
            },
        };
        obstacles.push(Obstacle {
            name,
            barriers,
            offsets,
            circles: circles.len(),
            centre,
            outline,
            appear_at: appear_at(sc, i),
            known: false,
            in_contact: false,
            contact_depth: 0.0,
            absent: false,
            motion,
            state: Default::default(),
        });
    }
    Ok(obstacles)
}

/// Obstacle `i`'s true motion with its seeded variations (None for a static one), and where
/// it is at t = 0.
fn obstacle_motion(
    loaded: &LoadedScenario,
    i: usize,
) -> Result<(Option<crate::actor::ActorMotion>, [f64; 2]), ScenarioError> {
    let motion = crate::scenario::motion_of(loaded, i).map_err(|e| loaded.field_error(&e.key, e.message))?;
    let centre = motion
        .as_ref()
        .map_or(loaded.scenario.obstacles[i].centre, |m| m.state_at(0.0).position);
    Ok((motion, centre))
}

/// Obstacle `i`, a lead to follow on the line (`following`): its headway barrier
/// h = D − D_sf − T v (Molnar et al.), with the vehicle's speed the state its position's
/// derivative is (ṗ = x_s: the drift Jacobian's row of p at x(0) is the unit vector e_s), and
/// D measured to the lead's rear (its centre less its radius, or a box's half extent along x).
fn lead(loaded: &LoadedScenario, model: &dyn Dynamics, i: usize, x0: &DVector<f64>) -> Result<Obstacle, EpisodeError> {
    let sc = &loaded.scenario;
    let o = &sc.obstacles[i];
    let following = o.following.expect("a lead");
    let key = format!("obstacles.{i}.following");
    let Some(position) = model.line_position() else {
        return Err(loaded
            .field_error(
                &key,
                "needs a vehicle that moves along a line (e.g. `double_integrator_1d`)",
            )
            .into());
    };
    let n = model.state_dim();
    let mut jacobian = nalgebra::DMatrix::zeros(n, n);
    model.drift_jacobian_into(x0.as_slice(), &mut jacobian);
    let row: Vec<f64> = jacobian.row(position).iter().copied().collect();
    let speed = (0..n).find(|&s| row[s] == 1.0 && row.iter().enumerate().all(|(j, v)| j == s || *v == 0.0));
    let Some(speed) = speed else {
        return Err(loaded
            .field_error(
                &key,
                "needs a vehicle whose position's derivative is one of its states (its speed)",
            )
            .into());
    };
    let name = o.name.clone().unwrap_or_else(|| obstacle_geom_name(i));
    let (motion, centre) = obstacle_motion(loaded, i)?;
    // How far the lead's rear is behind its centre along the line: its radius, or a box's
    // half extent along x at its heading.
    let (rear, outline) = match o.shape {
        Some(crate::scenario::ObstacleShape::Box { length, width, .. }) => {
            let heading = o.circles(motion.as_ref().and_then(|m| m.layout_heading())).0;
            let (s, c) = heading.sin_cos();
            (
                0.5 * (length * c.abs() + width * s.abs()),
                super::Outline::Box { length, width, heading },
            )
        }
        None => {
            let radius = o.radius.unwrap_or(0.0);
            (radius, super::Outline::Circle { radius })
        }
    };
    let barrier = Barrier {
        name: name.clone(),
        shape: crate::barrier::Shape::Headway {
            position,
            speed,
            lead: centre[0],
            rear,
            standstill: following.standstill,
            time_headway: following.time_headway,
        },
    };
    if barrier.clearance(x0) < 0.0 {
        return Err(loaded
            .field_error(
                &format!("obstacles.{i}"),
                format!(
                    "the lead overlaps the vehicle at the start (gap {:.3} m)",
                    barrier.clearance(x0)
                ),
            )
            .into());
    }
    Ok(Obstacle {
        name,
        barriers: vec![barrier],
        offsets: vec![[0.0; 2]],
        circles: 1,
        centre,
        outline,
        appear_at: appear_at(sc, i),
        known: false,
        in_contact: false,
        contact_depth: 0.0,
        absent: false,
        motion,
        state: Default::default(),
    })
}

/// The plant: MuJoCo (the obstacles' geoms looked up for contacts, the moving ones' mocap
/// bodies to move them; `barriers[i]` the number of obstacle i's barriers) or the analytic
/// ODE with the scenario's state disturbance.
pub(super) fn plant(
    loaded: &LoadedScenario,
    parts: PlantParts,
    barriers: &[usize],
    x0: &DVector<f64>,
) -> Result<Box<dyn Plant>, EpisodeError> {
    let sc = &loaded.scenario;
    let file = loaded.path.display().to_string();
    Ok(match sc.plant {
        PlantKind::Mujoco => {
            let model = parts.model.expect("MuJoCo kinds have a model (validated)");
            let obstacles = (sc.obstacles.iter().zip(barriers).enumerate())
                .map(|(i, (o, &barriers))| {
                    let geom = model.require(ObjKind::Geom, &obstacle_geom_name(i))?;
                    // A moving one: a lead's mocap body (its geom offset to the hull's height), or
                    // its world geom.
                    let body = model.id(ObjKind::Body, &obstacle_body_name(i));
                    let mocap = match (o.motion.is_some(), body) {
                        (true, Some(body)) => Some(model.body_mocap_id(body).ok_or(mujoco::MjError::MissingName {
                            kind: "mocap body",
                            name: obstacle_body_name(i),
                        })?),
                        _ => None,
                    };
                    let moves_in_world = o.motion.is_some() && mocap.is_none();
                    Ok(MujocoObstacle {
                        geom,
                        mocap,
                        moves_in_world,
                        barriers,
                    })
                })
                .collect::<Result<Vec<_>, mujoco::MjError>>()
                .map_err(|source| EpisodeError::Model {
                    file: file.clone(),
                    reason: source,
                })?;
            let sim = Simulation::new(model)?;
            let plant = MujocoPlant::new(sim, parts.vehicle.expect("bound with the model"), obstacles, x0);
            Box::new(match parts.contact_geom {
                Some(geom) => plant.with_contact_geom(geom),
                None => plant,
            })
        }
        PlantKind::Ode => {
            let n = parts.dynamics.state_dim();
            let plant = OdePlant::new(parts.dynamics, x0.clone(), parts.timestep);
            Box::new(
                match sc.disturbance.as_ref().and_then(|d| d.state_disturbance(sc.seed, n)) {
                    Some(disturbance) => plant.with_disturbance(disturbance),
                    None => plant,
                },
            )
        }
    })
}

/// The loop's settings: every table's part of it ([`crate::section::Section::configure`]:
/// `[control]`'s predictor step and chain reuse, the sensor, the actuators, …); the
/// non-obstacle barriers are known from the start.
pub(super) fn configure_control(
    loaded: &LoadedScenario,
    control: &mut ControlLoop,
    barriers: &[Barrier],
) -> Result<(), EpisodeError> {
    let sc = &loaded.scenario;
    for barrier in barriers {
        control.add_barrier(barrier.clone());
    }
    // Every table's part of the loop ([control]'s settings, the sensor, the actuators, …).
    let cx = loaded.section_context();
    for (_, section) in sc.sections() {
        section.configure(&cx, control).map_err(|e| param_error(loaded, e))?;
    }
    Ok(())
}

/// What the log's run metadata says about the run; the resolved scenario holds the vehicle
/// kind's own keys as its parameter type normalised them (`vehicle_params`), and the kinds
/// their registrations' labels and descriptions.
pub(super) fn run_info(
    loaded: &LoadedScenario,
    vehicle_params: toml::Table,
    control: &ControlLoop,
    period: f64,
) -> Result<RunInfo, EpisodeError> {
    let sc = &loaded.scenario;
    let timestep = control.timestep();
    let mut resolved = loaded.clone();
    resolved.scenario.vehicle.params = vehicle_params;
    let registry = crate::registry::registry();
    let described = [
        ("filter", registry.describe_filter(&sc.filter.kind, &sc.filter.params)),
        (
            "nominal",
            registry.describe_nominal(&sc.nominal.kind, &sc.nominal.params),
        ),
        (
            "vehicle",
            crate::vehicle_registry::registry().describe_vehicle(&sc.vehicle.kind, &resolved.scenario.vehicle.params),
        ),
    ];
    let mut kinds = Vec::new();
    for (role, description) in described {
        let d = description.map_err(|e| param_error(loaded, e))?;
        kinds.push(KindInfo {
            role: role.to_string(),
            kind: d.kind,
            label: d.label,
            description: d.description,
        });
    }
    Ok(RunInfo {
        scenario_name: sc.name.clone(),
        scenario_path: loaded.path.display().to_string(),
        scenario_text: loaded.source_text.clone(),
        scenario_resolved: resolved.resolved_toml(),
        overrides: loaded.overrides.clone(),
        mujoco_version: mujoco::version_string(),
        timestep,
        control_period: period,
        // A stochastic actuator adds up to its extra-latency bound.
        max_delay: control
            .actuators()
            .iter()
            .map(|q| largest_delay(q, sc.duration, timestep) + q.extra_latency_bound())
            .fold(0.0, f64::max),
        prescribed_time: control.filter().prescribed_time(),
        planar_position: control.model().planar_position(),
        heading_index: control.model().heading_index(),
        predicts: control.predicts(),
        kinds,
        goal: sc.goal.clone(),
        vehicle_limits: sc.vehicle_limits.clone(),
        requirements: requirements(loaded, timestep)?,
        // Set by the episode, which holds the nominal and the obstacles.
        reference_path: None,
        extents: None,
    })
}

/// The scenario's requirements (name, formula), each formula's bounds checked against the
/// plant step h: its signals are sampled every step.
fn requirements(loaded: &LoadedScenario, timestep: f64) -> Result<Vec<(String, String)>, EpisodeError> {
    let mut out = Vec::new();
    for (i, r) in loaded.scenario.requirements.iter().enumerate() {
        let key = format!("requirements[{i}].formula");
        let formula = crate::stl::parse(&r.formula).map_err(|e| loaded.field_error(&key, e.to_string()))?;
        formula
            .check_step(timestep)
            .map_err(|e| loaded.field_error(&key, e.to_string()))?;
        out.push((r.name.clone(), r.formula.clone()));
    }
    Ok(out)
}

/// The largest delay of a queue over [0, duration]: a constant one itself, a time-varying one
/// sampled every step (at most MAX_DELAY_SAMPLES + 1 samples, evenly spaced).
fn largest_delay(q: &DelayQueue, duration: f64, timestep: f64) -> f64 {
    if let Some(d) = q.constant_delay() {
        return d;
    }
    let samples = ((duration / timestep).ceil() as usize).clamp(1, MAX_DELAY_SAMPLES);
    let spacing = duration / samples as f64;
    (0..=samples)
        .map(|k| q.profile().delay((k as f64 * spacing).min(duration)))
        .fold(0.0, f64::max)
}

/// The run's estimated cost ([`super::cost`]): a prediction window of more than
/// [`super::cost::MAX_PREDICTION_STEPS`] steps, or more work than `--max-work`, is refused
/// here; a log over `--max-log-size` is returned as the error its writer raises.
pub(super) fn check_cost(
    loaded: &LoadedScenario,
    control: &ControlLoop,
    steps: u64,
    barriers: usize,
) -> Result<(super::cost::Cost, Option<ScenarioError>), EpisodeError> {
    use super::cost::{self, Cost, RunShape, MAX_PREDICTION_STEPS};
    let sc = &loaded.scenario;
    let timestep = control.timestep();
    let window = control
        .queues()
        .iter()
        .map(|q| largest_delay(q, sc.duration, timestep))
        .fold(0.0, f64::max);
    let shape = RunShape {
        steps,
        steps_per_tick: control.steps_per_tick(),
        timestep,
        states: control.model().state_dim(),
        channels: control.queues().len(),
        barriers,
        prediction: control.predicts().then_some((window, control.predictor_step())),
        sensor: control.has_sensor(),
    };
    let estimate = Cost::of(&shape);
    let step_key = if sc.control.predictor_step.is_some() {
        "control.predictor_step"
    } else if sc.vehicle.timestep.is_some() {
        "vehicle.timestep"
    } else {
        "vehicle.model"
    };
    if estimate.prediction_steps > MAX_PREDICTION_STEPS {
        return Err(loaded
            .field_error(
                step_key,
                format!(
                    "each prediction integrates the longest delay, {window:.4} s, in steps of {} s: {:.4e} steps, more than the limit of {MAX_PREDICTION_STEPS:e} (expected a predictor step of at least {:.4e} s)",
                    control.predictor_step(),
                    estimate.prediction_steps,
                    window / MAX_PREDICTION_STEPS
                ),
            )
            .into());
    }
    let budget = cost::max_work();
    if estimate.work() > budget as f64 {
        return Err(loaded
            .field_error(
                "duration",
                format!(
                    "the run is about {:.3e} integration steps ({steps} plant steps, {:.3e} predictor steps), more than the budget of {budget} (raise it with --max-work)",
                    estimate.work(),
                    estimate.predictor_steps
                ),
            )
            .into());
    }
    let log_budget = cost::max_log_bytes();
    let log_error = (estimate.log_bytes > log_budget as f64).then(|| {
        loaded.field_error(
            "duration",
            format!(
                "its log would be about {} ({steps} steps), more than the log budget of {} (raise it with --max-log-size, or shorten the run)",
                crate::files::human_bytes(estimate.log_bytes as u64),
                crate::files::human_bytes(log_budget)
            ),
        )
    });
    Ok((estimate, log_error))
}

/// Steps of an episode of the scenario's duration.
pub(super) fn steps(loaded: &LoadedScenario, timestep: f64) -> u64 {
    (loaded.scenario.duration / timestep - TICK_TOLERANCE).ceil() as u64
}
