//! The vehicle kinds a scenario's `vehicle.kind` may name: an MJCF binding (joints, actuators
//! and the `hull` geom by name, [`MujocoVehicle`]) or an analytic model for the ODE plant. The
//! built-ins are registered here exactly as user code registers its own ([`register`]; see
//! examples/dubins.rs).

use std::sync::{Arc, LazyLock, RwLock, RwLockReadGuard};

use crate::dynamics::{self, Dynamics};
use crate::filter::ParamError;
use crate::mujoco::{MjError, Model};
use crate::registry::{add, find, Kind};
use crate::scenario::VehicleSpec;
use crate::vehicle::{self, MujocoVehicle, VehicleKind};

/// Binds a vehicle's MJCF model: joints, actuators and the `hull` geom by name.
pub type BindMjcf = Arc<dyn Fn(&Model) -> Result<Box<dyn MujocoVehicle>, MjError> + Send + Sync>;
/// Builds the analytic model of a vehicle without MJCF (ODE plant only) from its table.
pub type BuildAnalytic = Arc<dyn Fn(&VehicleSpec) -> Result<Arc<dyn Dynamics>, ParamError> + Send + Sync>;

/// How a vehicle kind becomes a plant.
#[derive(Clone)]
pub enum VehicleBinding {
    /// An MJCF model (`vehicle.model`), run by MuJoCo (or its analytic model on the ODE plant).
    Mjcf(BindMjcf),
    /// An analytic model only: `plant = "ode"`, `vehicle.timestep` required.
    Analytic(BuildAnalytic),
}

/// Every vehicle kind a scenario may name.
pub struct VehicleRegistry {
    vehicles: Vec<Kind<VehicleBinding>>,
}

impl VehicleRegistry {
    /// The built-in vehicles (one line each).
    pub fn builtin() -> VehicleRegistry {
        let mut r = VehicleRegistry { vehicles: Vec::new() };
        for (name, kind) in [
            ("bicycle", VehicleKind::Bicycle),
            ("car", VehicleKind::Car),
            ("unicycle", VehicleKind::Unicycle),
            ("double_integrator_1d", VehicleKind::DoubleIntegrator1d),
            ("double_integrator_2d", VehicleKind::DoubleIntegrator2d),
        ] {
            r.add_mjcf_vehicle(name, move |model| vehicle::bind(kind, model));
        }
        r.add_analytic_vehicle("linear", linear_model);
        r.add_analytic_vehicle("nonlinear_example1", |_| {
            Ok(Arc::new(dynamics::NonlinearExample1::default()))
        });
        r.add_analytic_vehicle("strict_feedback", |_| {
            Ok(Arc::new(dynamics::StrictFeedbackModel::default()))
        });
        r
    }

    /// Registers (or replaces) the vehicle `kind` with an MJCF model, bound by `bind`.
    pub fn add_mjcf_vehicle(
        &mut self,
        kind: &str,
        bind: impl Fn(&Model) -> Result<Box<dyn MujocoVehicle>, MjError> + Send + Sync + 'static,
    ) {
        add(&mut self.vehicles, kind, VehicleBinding::Mjcf(Arc::new(bind)));
    }

    /// Registers (or replaces) the vehicle `kind` without MJCF (ODE plant only).
    pub fn add_analytic_vehicle(
        &mut self,
        kind: &str,
        build: impl Fn(&VehicleSpec) -> Result<Arc<dyn Dynamics>, ParamError> + Send + Sync + 'static,
    ) {
        add(&mut self.vehicles, kind, VehicleBinding::Analytic(Arc::new(build)));
    }

    /// How the vehicle `kind` becomes a plant (error at `vehicle.kind` for an unknown kind).
    pub fn vehicle(&self, kind: &str) -> Result<VehicleBinding, ParamError> {
        Ok(find(&self.vehicles, "vehicle", kind)?.build.clone())
    }

    /// The vehicle kinds, in registration order.
    pub fn vehicle_kinds(&self) -> Vec<&str> {
        self.vehicles.iter().map(|k| k.name.as_str()).collect()
    }
}

/// ẋ = A x + B u from `vehicle.a`, `vehicle.b` (arrays of rows; shapes checked by the scenario).
fn linear_model(spec: &VehicleSpec) -> Result<Arc<dyn Dynamics>, ParamError> {
    let (Some(a), Some(b)) = (&spec.a, &spec.b) else {
        return Err(ParamError::new(
            "vehicle.a",
            "kind = \"linear\" needs both vehicle.a and vehicle.b (arrays of rows)",
        ));
    };
    let matrix = |rows: &[Vec<f64>]| {
        nalgebra::DMatrix::from_row_iterator(
            rows.len(),
            rows.first().map_or(0, Vec::len),
            rows.iter().flatten().copied(),
        )
    };
    Ok(Arc::new(dynamics::LinearModel::new(matrix(a), matrix(b))))
}

static VEHICLES: LazyLock<RwLock<VehicleRegistry>> = LazyLock::new(|| RwLock::new(VehicleRegistry::builtin()));

/// The process's vehicle kinds (the built-ins plus every kind registered so far).
pub fn registry() -> RwLockReadGuard<'static, VehicleRegistry> {
    VEHICLES.read().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Adds vehicle kinds; call before building the episodes that name them.
pub fn register(add_kinds: impl FnOnce(&mut VehicleRegistry)) {
    let mut registry = VEHICLES.write().unwrap_or_else(|poisoned| poisoned.into_inner());
    add_kinds(&mut registry);
}
