//! The vehicle kinds a scenario's `vehicle.kind` may name: an MJCF binding (joints, actuators
//! and the `hull` geom by name, [`MujocoVehicle`]) or an analytic model for the ODE plant, each
//! with its own typed parameters (the `[vehicle]` keys other than those every vehicle has,
//! [`VehicleSpec::KEYS`]). The built-ins are registered in [`VehicleRegistry::builtin`], one
//! closure each, exactly as user code registers its own ([`register`]; examples/dubins.rs):
//!
//! ```no_run
//! # use std::sync::Arc;
//! use mjsafe::vehicle_registry::{Params, ParamError};
//!
//! #[derive(serde::Serialize, serde::Deserialize)]
//! #[serde(deny_unknown_fields)]
//! struct Decay { rate: f64 }
//! impl Params for Decay {}
//!
//! // [vehicle] kind = "decay", rate = 0.5, timestep = 0.01, initial_state = [1.0] (plant = "ode")
//! mjsafe::vehicle_registry::register(|r| {
//!     r.add_analytic_vehicle("decay", |p: &Decay| {
//!         let a = nalgebra::DMatrix::from_element(1, 1, -p.rate);
//!         let b = nalgebra::DMatrix::from_element(1, 1, 1.0);
//!         Ok(Arc::new(mjsafe::dynamics::LinearModel::new(a, b)))
//!     })
//!     // What the run metadata (`vehicle_label`, `vehicle_description`) says it is.
//!     .label("decay ẋ = −r x + u")
//!     .description("a scalar first-order decay");
//! })
//! .expect("`decay` is not a vehicle kind of mjsafe's");
//! ```
//!
//! A kind's parameters are checked when the episode is built (the scenario schema reaches no
//! MuJoCo type, and this registry holds MuJoCo bindings): a wrong type, an unknown key or a
//! value the kind's [`Params::validate`] refuses is one error line naming the scenario file
//! and the key (`vehicle.a`).

use std::sync::{Arc, LazyLock, RwLock, RwLockReadGuard};

use serde::{Deserialize, Serialize};

use crate::dynamics::{self, Dynamics};
use crate::mujoco::{MjError, Model};
pub use crate::params::{ParamError, Params};
use crate::registry::{
    add, check_of, describe, find, label_of, parse_params, register_guarded, AlreadyRegistered, Checked, Describe,
    Description, Guard, Kind,
};
use crate::scenario::VehicleSpec;
use crate::vehicle::{
    MujocoBicycle, MujocoCar, MujocoDoubleIntegrator, MujocoLongitudinal, MujocoUnicycle, MujocoVehicle,
};

/// Binds a vehicle's MJCF model: joints, actuators and the `hull` geom by name.
pub type BindMjcf = Arc<dyn Fn(&Model) -> Result<Box<dyn MujocoVehicle>, MjError> + Send + Sync>;
/// Builds the analytic model of a vehicle without MJCF (ODE plant only) from its kind's
/// parameters (the checked table of its own keys).
pub type BuildAnalytic = Arc<dyn Fn(&toml::Table) -> Result<Arc<dyn Dynamics>, ParamError> + Send + Sync>;

/// How a vehicle kind becomes a plant.
#[derive(Clone)]
pub enum VehicleBinding {
    /// An MJCF model (`vehicle.model`), run by MuJoCo (or its analytic model on the ODE plant).
    Mjcf(BindMjcf),
    /// An analytic model only: `plant = "ode"`, `vehicle.timestep` required.
    Analytic(BuildAnalytic),
}

/// The parameters of a vehicle kind without keys of its own: its `[vehicle]` table holds only
/// the keys every vehicle has, any other key is refused.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoParams {}

impl Params for NoParams {}

/// `vehicle.kind = "linear"`: ẋ = A x + B u with A, B from the scenario (ODE plant only), e.g.
/// (2.30), (3.34).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinearParams {
    /// A (n × n), as an array of rows.
    pub a: Vec<Vec<f64>>,
    /// B (n × m), as an array of rows.
    pub b: Vec<Vec<f64>>,
}

impl Params for LinearParams {
    fn validate(&self) -> Result<(), ParamError> {
        let n = self.a.len();
        if n == 0 || self.a.iter().any(|row| row.len() != n) {
            return Err(ParamError::new(
                "vehicle.a",
                "expected a square matrix (array of equal-length rows)",
            ));
        }
        let m = self.b.first().map_or(0, Vec::len);
        if self.b.len() != n || m == 0 || self.b.iter().any(|row| row.len() != m) {
            return Err(ParamError::new(
                "vehicle.b",
                format!("expected {n} rows of equal, non-zero length"),
            ));
        }
        for (key, matrix) in [("vehicle.a", &self.a), ("vehicle.b", &self.b)] {
            if matrix.iter().flatten().any(|v| !v.is_finite()) {
                return Err(ParamError::new(key, "matrix entries must be finite"));
            }
        }
        Ok(())
    }
}

/// ẋ = A x + B u from checked [`LinearParams`].
fn linear_model(p: &LinearParams) -> Result<Arc<dyn Dynamics>, ParamError> {
    let matrix = |rows: &[Vec<f64>]| {
        nalgebra::DMatrix::from_row_iterator(
            rows.len(),
            rows.first().map_or(0, Vec::len),
            rows.iter().flatten().copied(),
        )
    };
    Ok(Arc::new(dynamics::LinearModel::new(matrix(&p.a), matrix(&p.b))))
}

/// `vehicle.kind = "longitudinal"`: [`dynamics::LongitudinalModel`], the car of Ames et al.'s
/// adaptive cruise control (CDC 2014, Table 1), whose values are the defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LongitudinalParams {
    /// Mass m (kg, > 0).
    #[serde(default = "default_mass")]
    pub mass: f64,
    /// Constant rolling resistance f0 (N, >= 0).
    #[serde(default = "default_f0")]
    pub f0: f64,
    /// Linear resistance coefficient f1 (N s/m, >= 0).
    #[serde(default = "default_f1")]
    pub f1: f64,
    /// Air resistance coefficient f2 (N s²/m², >= 0).
    #[serde(default = "default_f2")]
    pub f2: f64,
    /// The lead's constant speed v_L (m/s, finite).
    #[serde(default = "default_lead_speed")]
    pub lead_speed: f64,
}

fn default_mass() -> f64 {
    1650.0
}
fn default_f0() -> f64 {
    0.1
}
fn default_f1() -> f64 {
    5.0
}
fn default_f2() -> f64 {
    0.25
}
fn default_lead_speed() -> f64 {
    14.0
}

impl Default for LongitudinalParams {
    fn default() -> Self {
        LongitudinalParams {
            mass: default_mass(),
            f0: default_f0(),
            f1: default_f1(),
            f2: default_f2(),
            lead_speed: default_lead_speed(),
        }
    }
}

impl Params for LongitudinalParams {
    fn validate(&self) -> Result<(), ParamError> {
        if !(self.mass.is_finite() && self.mass > 0.0) {
            return Err(ParamError::new(
                "vehicle.mass",
                format!("expected a finite mass > 0 (kg), found {}", self.mass),
            ));
        }
        for (key, value) in [
            ("vehicle.f0", self.f0),
            ("vehicle.f1", self.f1),
            ("vehicle.f2", self.f2),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(ParamError::new(
                    key,
                    format!("expected a finite resistance coefficient >= 0, found {value}"),
                ));
            }
        }
        if !self.lead_speed.is_finite() {
            return Err(ParamError::new(
                "vehicle.lead_speed",
                format!("expected a finite speed (m/s), found {}", self.lead_speed),
            ));
        }
        Ok(())
    }
}

/// Every vehicle kind a scenario may name.
#[derive(Clone)]
pub struct VehicleRegistry {
    vehicles: Vec<Kind<Checked<VehicleBinding>>>,
    guard: Guard,
}

impl VehicleRegistry {
    /// The built-in vehicles (one closure each).
    pub fn builtin() -> VehicleRegistry {
        let mut r = VehicleRegistry {
            vehicles: Vec::new(),
            guard: Guard::default(),
        };
        r.add_mjcf_vehicle("bicycle", |model| Ok(Box::new(MujocoBicycle::bind(model)?)))
            .label("kinematic bicycle (4.78)")
            .description("x = (x1, x2, heading, speed), u = (tan δ, acceleration), MuJoCo slide/hinge joints");
        r.add_mjcf_vehicle("car", |model| Ok(Box::new(MujocoCar::bind(model)?)))
            .label("wheeled car, (4.78) as its model")
            .description("four wheels on tyre contacts (models/car.xml, docs/car.md), the bicycle's state and inputs");
        r.add_mjcf_vehicle("unicycle", |model| Ok(Box::new(MujocoUnicycle::bind(model)?)))
            .label("unicycle (2.36)")
            .description("x = (x, y, θ), u = (v, ω)");
        r.add_mjcf_vehicle("double_integrator_1d", |model| {
            Ok(Box::new(MujocoDoubleIntegrator::bind(model, 1)?))
        })
        .label("double integrator ẍ = u")
        .description("x = (position, velocity) on a line");
        r.add_mjcf_vehicle("double_integrator_2d", |model| {
            Ok(Box::new(MujocoDoubleIntegrator::bind(model, 2)?))
        })
        .label("planar double integrator ẍ = u")
        .description("x = (x, y, vx, vy)");
        // The `longitudinal` car on MuJoCo: a kind of its own, since an MJCF kind's numbers come
        // from its model (no `[vehicle]` keys), the analytic kind's from its keys.
        r.add_mjcf_vehicle("longitudinal_mjcf", |model| Ok(Box::new(MujocoLongitudinal::bind(model)?)))
            .label("longitudinal car behind a lead (Ames et al. 2014), MuJoCo")
            .description(
                "`longitudinal` on models/longitudinal.xml: the car and the lead on slide joints, ctrl = u − F_r(v) at every RK4 stage",
            );
        r.add_analytic_vehicle("linear", linear_model)
            .label("linear system ẋ = Ax + Bu")
            .description("A, B from the scenario (e.g. (2.30), (3.34)), ODE plant only");
        r.add_analytic_vehicle("nonlinear_example1", |_: &NoParams| {
            Ok(Arc::new(dynamics::NonlinearExample1::default()))
        })
        .label("Example 1 (4.52)")
        .description("ẋ1 = −x1 − x2 + u1, ẋ2 = x1³ + x2 u2, ODE plant only");
        r.add_analytic_vehicle("strict_feedback", |_: &NoParams| {
            Ok(Arc::new(dynamics::StrictFeedbackModel::default()))
        })
        .label("strict-feedback system (5.82)")
        .description("ẋ1 = x1² + x2, ẋ2 = u, ODE plant only");
        r.add_analytic_vehicle("longitudinal", |p: &LongitudinalParams| {
            Ok(Arc::new(dynamics::LongitudinalModel::new(
                p.mass,
                [p.f0, p.f1, p.f2],
                p.lead_speed,
            )))
        })
        .label("longitudinal car behind a lead (Ames et al. 2014)")
        .description(
            "x = (position, speed, gap), u = force; ṗ = v, v̇ = (u − f0 − f1 v − f2 v²)/m, ż = v_L − v; ODE plant only",
        );
        r
    }

    /// Registers the vehicle `kind` with an MJCF model, bound by `bind`; its
    /// `[vehicle]` table has no keys of its own ([`NoParams`]).
    pub fn add_mjcf_vehicle(
        &mut self,
        kind: &str,
        bind: impl Fn(&Model) -> Result<Box<dyn MujocoVehicle>, MjError> + Send + Sync + 'static,
    ) -> Describe<'_> {
        let build = Checked {
            check: check_of::<NoParams>(),
            label: label_of::<NoParams>("vehicle"),
            build: VehicleBinding::Mjcf(Arc::new(bind)),
        };
        self.guard.check(&self.vehicles, "vehicle", kind);
        add(&mut self.vehicles, kind, build)
    }

    /// Registers the vehicle `kind` without MJCF (ODE plant only), built from
    /// parameters P: its `[vehicle]` table's own keys (P = [`NoParams`] for none).
    pub fn add_analytic_vehicle<P: Params + 'static>(
        &mut self,
        kind: &str,
        build: impl Fn(&P) -> Result<Arc<dyn Dynamics>, ParamError> + Send + Sync + 'static,
    ) -> Describe<'_> {
        let binding = VehicleBinding::Analytic(Arc::new(move |table| build(&parse_params::<P>("vehicle", table)?)));
        let build = Checked {
            check: check_of::<P>(),
            label: label_of::<P>("vehicle"),
            build: binding,
        };
        self.guard.check(&self.vehicles, "vehicle", kind);
        add(&mut self.vehicles, kind, build)
    }

    /// The registrations that follow in this [`register`] call replace kinds of the same name
    /// (otherwise refused: [`AlreadyRegistered`]).
    pub fn replacing(&mut self) -> &mut VehicleRegistry {
        self.guard.replacing = true;
        self
    }

    /// The label and description of the vehicle `kind` with its (checked) own keys.
    pub fn describe_vehicle(&self, kind: &str, params: &toml::Table) -> Result<Description, ParamError> {
        describe(find(&self.vehicles, "vehicle", kind)?, params)
    }

    /// How the vehicle `kind` becomes a plant (error at `vehicle.kind` for an unknown kind).
    pub fn vehicle(&self, kind: &str) -> Result<VehicleBinding, ParamError> {
        Ok(find(&self.vehicles, "vehicle", kind)?.build.build.clone())
    }

    /// Checks the vehicle `kind`'s own keys (`vehicle.params`) once; returns them normalised
    /// (defaults filled in), what its [`VehicleBinding::Analytic`] builder takes. An unknown
    /// key's error lists the keys every vehicle has and the kind's own.
    pub fn check_vehicle(&self, kind: &str, params: &toml::Table) -> Result<toml::Table, ParamError> {
        (find(&self.vehicles, "vehicle", kind)?.build.check)("vehicle", params).map_err(|e| unknown_key(kind, e))
    }

    /// The vehicle kinds, in registration order.
    pub fn vehicle_kinds(&self) -> Vec<&str> {
        self.vehicles.iter().map(|k| k.name.as_str()).collect()
    }
}

/// serde's unknown-field error of a kind's table, with the keys every vehicle has: the table
/// the kind sees is `[vehicle]` without them.
fn unknown_key(kind: &str, e: ParamError) -> ParamError {
    let Some((field, own)) = e
        .message
        .strip_prefix("unknown field `")
        .and_then(|rest| rest.split_once('`'))
    else {
        return e;
    };
    let quoted = |keys: &mut dyn Iterator<Item = &str>| keys.map(|k| format!("`{k}`")).collect::<Vec<_>>().join(", ");
    // serde lists the kind's keys after "expected" (`a` / `a` or `b` / one of `a`, `b`, `c`).
    let own = match own.split('`').skip(1).step_by(2).collect::<Vec<_>>() {
        keys if keys.is_empty() => format!("(kind `{kind}` has no keys of its own)"),
        keys => format!("or kind `{kind}`'s own {}", quoted(&mut keys.into_iter())),
    };
    ParamError::new(
        e.key,
        format!(
            "unknown field `{field}`, expected one of {} {own}",
            quoted(&mut VehicleSpec::KEYS.into_iter())
        ),
    )
}

static VEHICLES: LazyLock<RwLock<VehicleRegistry>> = LazyLock::new(|| RwLock::new(VehicleRegistry::builtin()));

/// The process's vehicle kinds (the built-ins plus every kind registered so far).
pub fn registry() -> RwLockReadGuard<'static, VehicleRegistry> {
    VEHICLES.read().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Adds vehicle kinds; call before building the episodes that name them. A kind under a name
/// already registered is refused and nothing of the call is kept, unless the call says it
/// replaces ([`VehicleRegistry::replacing`]).
pub fn register(add_kinds: impl FnOnce(&mut VehicleRegistry)) -> Result<(), AlreadyRegistered> {
    register_guarded(&VEHICLES, |r| &mut r.guard, add_kinds)
}
