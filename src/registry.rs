//! The kinds a scenario can name: `filter.kind` → a [`SafetyFilter`] constructor and
//! `nominal.kind` → a [`NominalController`] constructor, each with its own typed parameter
//! struct read from the rest of the TOML table. The built-ins are registered in
//! [`Registry::builtin`] exactly as user code registers its own kinds ([`register`]), so TOML
//! scenarios, `--set`, sweeps, logs and analysis treat both alike.
//!
//! ```no_run
//! use mjsafe::filter::{ChannelInput, ChannelOutcome, FilterContext, FilterError, ParamError, SafetyFilter};
//! # struct MyFilter;
//! # impl SafetyFilter for MyFilter {
//! #     fn barrier_form(&self) -> Option<mjsafe::barrier::BarrierForm> { None }
//! #     fn uses_prediction(&self) -> bool { true }
//! #     fn filter_channel(&mut self, _: &ChannelInput<'_>) -> Result<Option<ChannelOutcome>, FilterError> { Ok(None) }
//! # }
//! #[derive(serde::Serialize, serde::Deserialize)]
//! #[serde(deny_unknown_fields)]
//! struct MyParams { margin: f64 }
//! impl mjsafe::registry::Params for MyParams {}
//!
//! mjsafe::registry::register(|r| {
//!     r.add_filter("my_filter", |p: &MyParams, ctx: &FilterContext| -> Result<Box<dyn SafetyFilter>, ParamError> {
//!         Ok(Box::new(MyFilter))
//!     })
//!     // What legends, `analyze --brief` and the run metadata call it.
//!     .label("my filter (eq. 7)")
//!     .description("the CBF-QP with my margin");
//! })
//! .expect("`my_filter` is not a kind of mjsafe's");
//! ```

use std::sync::{Arc, LazyLock, RwLock, RwLockReadGuard};

use crate::actor::{self, ActorMotion, MotionContext, MotionError};
pub use crate::filter::Params;
use crate::filter::{self, FilterContext, ParamError, SafetyFilter};
use crate::nominal::{self, NominalContext, NominalController};

/// A kind's parameter check: its table (keys without `kind`) under a section (`filter`,
/// `vehicle`, …) in, the table normalised (defaults filled in) out.
pub(crate) type Check = Arc<dyn Fn(&str, &toml::Table) -> Result<toml::Table, ParamError> + Send + Sync>;
type BuildFilter = Arc<dyn Fn(&toml::Table, &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> + Send + Sync>;
type BuildNominal =
    Arc<dyn Fn(&toml::Table, &NominalContext) -> Result<Box<dyn NominalController>, ParamError> + Send + Sync>;
type BuildMotion = Arc<dyn Fn(&str, &toml::Table, &MotionContext<'_>) -> Result<ActorMotion, ParamError> + Send + Sync>;
type Label = Arc<dyn Fn(&toml::Table, &str) -> Result<String, ParamError> + Send + Sync>;

#[derive(Clone)]
pub(crate) struct Kind<B> {
    pub(crate) name: String,
    /// Its label (with the equation number it implements) and one line on what it is.
    pub(crate) label: String,
    pub(crate) description: String,
    /// The file that registered it, for kinds that are not built in ([`Describe::origin`]).
    pub(crate) origin: Option<String>,
    pub(crate) build: B,
}

/// What a registered kind says of itself: its label (equation number) and one line on what it
/// is (set with [`Describe`]; the kind's name and nothing until then). Both are written into
/// the run metadata (`filter_label`, `filter_description`, …) and read from there by the
/// analysis, plots and legends.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Description {
    pub kind: String,
    /// The run's label: the kind's, completed by its parameters ([`Params::label`]).
    pub label: String,
    pub description: String,
}

/// Sets the label and description of the kind just registered.
pub struct Describe<'a> {
    label: &'a mut String,
    description: &'a mut String,
    origin: &'a mut Option<String>,
}

impl Describe<'_> {
    /// The label plots, legends and `analyze --brief` show (e.g. `γm filter (4.67)`).
    pub fn label(self, label: &str) -> Self {
        *self.label = label.to_string();
        self
    }

    /// One line on what the kind is.
    pub fn description(self, description: &str) -> Self {
        *self.description = description.to_string();
        self
    }

    /// The file that registers the kind when it is not built in (a Python module): what a
    /// counterexample of a run with it says to load.
    pub fn origin(self, file: &str) -> Self {
        *self.origin = Some(file.to_string());
        self
    }
}

/// A kind (filter, nominal, vehicle): its parameter check, its label and its constructor.
#[derive(Clone)]
pub(crate) struct Checked<B> {
    pub(crate) check: Check,
    pub(crate) label: Label,
    pub(crate) build: B,
}

/// Every filter, nominal and actor motion kind a scenario may name (vehicle kinds:
/// `mjsafe::vehicle_registry`).
#[derive(Clone)]
pub struct Registry {
    filters: Vec<Kind<Checked<BuildFilter>>>,
    nominals: Vec<Kind<Checked<BuildNominal>>>,
    motions: Vec<Kind<Checked<BuildMotion>>>,
    guard: Guard,
}

/// A kind registered under a name already taken, without [`Registry::replacing`]: the
/// registration is refused and the registry stays as it was, so a scenario naming a built-in
/// never runs someone else's code under the built-in's name.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{section} kind `{kind}` is already registered ({what}); say that the registration replaces it (Rust: `r.replacing()`, Python: `replace=True`)")]
pub struct AlreadyRegistered {
    /// `filter`, `nominal`, `motion` or `vehicle`.
    pub section: &'static str,
    pub kind: String,
    /// The kind registered under that name: its label, and where it comes from.
    pub what: String,
}

/// What one [`register`] call may replace, and what it tried to replace without saying so.
#[derive(Clone, Default)]
pub(crate) struct Guard {
    pub(crate) replacing: bool,
    conflicts: Vec<AlreadyRegistered>,
}

impl Guard {
    /// Notes a registration of `name` in `section` over an existing kind, unless replacing.
    pub(crate) fn check<B>(&mut self, kinds: &[Kind<B>], section: &'static str, name: &str) {
        if self.replacing {
            return;
        }
        if let Some(kind) = kinds.iter().find(|k| k.name == name) {
            self.conflicts.push(AlreadyRegistered {
                section,
                kind: name.to_string(),
                what: match &kind.origin {
                    None => format!("built in: {}", kind.label),
                    Some(file) => format!("{}, from {file}", kind.label),
                },
            });
        }
    }
}

/// Runs `add_kinds` on the registry behind `lock`; a kind that takes a name already taken
/// without `replacing` leaves the registry as it was and is the error.
pub(crate) fn register_guarded<R: Clone>(
    lock: &RwLock<R>,
    guard: fn(&mut R) -> &mut Guard,
    add_kinds: impl FnOnce(&mut R),
) -> Result<(), AlreadyRegistered> {
    let mut registry = lock.write().unwrap_or_else(|poisoned| poisoned.into_inner());
    let before = registry.clone();
    add_kinds(&mut registry);
    let g = guard(&mut *registry);
    g.replacing = false;
    let conflict = std::mem::take(&mut g.conflicts).into_iter().next();
    match conflict {
        None => Ok(()),
        Some(conflict) => {
            *registry = before;
            Err(conflict)
        }
    }
}

/// P from a kind's table (its keys without `kind`), with serde's error at the inner key.
pub(crate) fn parse_params<P: Params>(section: &str, table: &toml::Table) -> Result<P, ParamError> {
    serde_path_to_error::deserialize::<_, P>(toml::Value::Table(table.clone())).map_err(|e| {
        let inner = e.path().to_string();
        let key = if inner == "." {
            section.to_string()
        } else {
            format!("{section}.{inner}")
        };
        ParamError::new(key, crate::message::plain_serde_message(&e.into_inner().to_string()))
    })
}

/// The run's label of parameters P, given the kind's ([`Params::label`]).
pub(crate) fn label_of<P: Params + 'static>(section: &'static str) -> Label {
    Arc::new(move |table: &toml::Table, kind_label: &str| Ok(parse_params::<P>(section, table)?.label(kind_label)))
}

/// The check of parameters P: parsed ([`parse_params`]), validated, serialized back.
pub(crate) fn check_of<P: Params + 'static>() -> Check {
    Arc::new(|section: &str, table: &toml::Table| {
        let params: P = parse_params(section, table)?;
        params.validate()?;
        match toml::Value::try_from(&params) {
            Ok(toml::Value::Table(t)) => Ok(t),
            _ => Err(ParamError::new(
                section,
                "the parameters do not serialize as a TOML table",
            )),
        }
    })
}

impl Registry {
    /// The built-in kinds (one line each).
    pub fn builtin() -> Registry {
        let mut r = Registry {
            filters: Vec::new(),
            nominals: Vec::new(),
            motions: Vec::new(),
            guard: Guard::default(),
        };
        r.add_filter("none", filter::none::build)
            .label("no filter (nominal only)")
            .description("the nominal input, unfiltered");
        r.add_filter("cbf_qp", filter::cbf_qp::build)
            .label("delay-free CBF-QP (4.9)–(4.11)")
            .description("min-norm CBF-QP at the current state; with compensation = 'predictor' at each channel's prediction (4.34)");
        r.add_filter("fixed_channel", filter::fixed_channel::build)
            .label("fixed-channel filter (4.44)")
            .description("distinct delays: the filtered channel's CBF at its prediction, the other channels as issued (4.44)–(4.47)");
        r.add_filter("gamma_m", filter::gamma_m::build)
            .label("γm filter (4.67)")
            .description(
                "distinct delays: every channel at its own prediction with the γm robustness margin (4.60)–(4.68)",
            );
        r.add_filter("clf_cbf_qp", filter::clf_cbf_qp::build)
            .label("γm CLF-CBF QP (3.27)–(3.33)")
            .description("linear systems with input delays: CLF-CBF QP with the γm buffer η (3.25), Cases A–D");
        r.add_filter("ptsf", filter::chain::build_ptsf)
            .label("PTSf (Ch. 5)")
            .description("prescribed-time safety filter for n-th order chains (Ch. 5)");
        r.add_filter("esf", filter::chain::build_esf)
            .label("ESf (Ch. 5)")
            .description("exponential safety filter for n-th order chains, the PTSf's comparison (Ch. 5)");
        r.add_nominal("path_lqr", nominal::build_path_lqr)
            .label("LQR path tracking")
            .description("LQR tracking of a reference path, linearised about it (Riccati by the matrix sign function)");
        r.add_nominal("route", nominal::route::build)
            .label("route following")
            .description("pure pursuit of a reference path (a CommonRoad route's centre line) at a reference speed, ignoring other road users");
        r.add_nominal("car_following", nominal::build_car_following)
            .label("car following (Molnar et al.)")
            .description("Molnar, Kiss, Ames, Orosz's nominal behind a lead: A (min(κ (D − D_st), v_max) − v) + B (min(v_L, v_max) − v)");
        r.add_nominal("constant", nominal::build_constant)
            .label("constant input")
            .description("the same input at every tick");
        r.add_nominal("external", nominal::build_external)
            .label("external input")
            .description("set from outside the loop at every tick (mjsafe.Env's action), held between settings");
        r.add_nominal("unicycle_stabilizer", nominal::build_unicycle_stabilizer)
            .label("unicycle stabiliser (2.40)–(2.46)")
            .description("drives the unicycle to the origin (2.40)–(2.46)");
        r.add_nominal("quartic_clf", nominal::build_quartic_clf)
            .label("quartic CLF (4.58)")
            .description("the quartic control Lyapunov function controller of Example 1 (4.58)");
        r.add_nominal("red_light", nominal::build_red_light)
            .label("red light (5.20)")
            .description("approaches a red light at the stop line (5.20)");
        r.add_nominal("speed_tracking", nominal::build_speed_tracking)
            .label("speed tracking")
            .description("v̇ = gain (v_d − v) by feedback linearisation of a single-input model's `speed` row");
        r.add_nominal("pts", nominal::build_pts)
            .label("PTS (5.87)")
            .description("prescribed-time stabiliser of the strict-feedback system (5.87)");
        r.add_motion("straight", actor::straight::build_straight)
            .label("straight line")
            .description("along a direction with a piecewise-linear acceleration profile, optionally started by the vehicle coming close");
        r.add_motion("waypoints", actor::straight::build_waypoints)
            .label("polyline path")
            .description("through waypoints with a piecewise-linear acceleration profile along the path");
        r.add_motion("recorded", crate::commonroad::build_recorded)
            .label("recorded trajectory")
            .description("a CommonRoad road user's recorded states, interpolated by natural cubic splines");
        r
    }

    /// Registers the actor motion `kind` (`[obstacles.motion] kind = …`), built
    /// from parameters P for one obstacle; its label and description follow ([`Describe`]).
    /// The keys of P's `validate` errors and of the build's [`MotionError`]s are relative to the
    /// motion's table (`radius` becomes `obstacles.3.motion.radius`).
    pub fn add_motion<P: Params + 'static>(
        &mut self,
        kind: &str,
        build: impl Fn(&P, &MotionContext<'_>) -> Result<ActorMotion, MotionError> + Send + Sync + 'static,
    ) -> Describe<'_> {
        let build: BuildMotion = Arc::new(move |section, table, ctx| {
            build(&parse_params::<P>(section, table)?, ctx)
                .map_err(|e| ParamError::new(format!("{section}.{}", e.key), e.message))
        });
        // `Params::validate`'s keys are relative to the motion's table (the obstacle's index
        // is not known to it).
        let check_params = check_of::<P>();
        let check: Check = Arc::new(move |section: &str, table: &toml::Table| {
            check_params(section, table).map_err(|e| match e.key.starts_with(section) {
                true => e,
                false => ParamError::new(format!("{section}.{}", e.key), e.message),
            })
        });
        self.guard.check(&self.motions, "motion", kind);
        add(
            &mut self.motions,
            kind,
            Checked {
                check,
                label: label_of::<P>("motion"),
                build,
            },
        )
    }

    /// The registrations that follow in this [`register`] call replace kinds of the same name
    /// (a kind registered under a taken name is otherwise refused: [`AlreadyRegistered`]).
    pub fn replacing(&mut self) -> &mut Registry {
        self.guard.replacing = true;
        self
    }

    /// Whether a filter, nominal or motion kind (`section`) of this name is registered.
    pub fn has_kind(&self, section: &str, kind: &str) -> bool {
        let has = |names: Vec<&str>| names.contains(&kind);
        match section {
            "filter" => has(self.filter_kinds()),
            "nominal" => has(self.nominal_kinds()),
            "motion" => has(self.motion_kinds()),
            _ => false,
        }
    }

    /// The actor motion kinds, in registration order.
    pub fn motion_kinds(&self) -> Vec<&str> {
        self.motions.iter().map(|k| k.name.as_str()).collect()
    }

    /// Checks one obstacle's `motion` parameters (keys under `section`, `obstacles.3.motion`);
    /// returns them normalised (defaults filled in).
    pub fn check_motion(&self, section: &str, kind: &str, params: &toml::Table) -> Result<toml::Table, ParamError> {
        (find(&self.motions, section, kind)?.build.check)(section, params)
    }

    /// Builds the motion of one obstacle from its `motion` table (kind and parameters), its
    /// keys under `section` (`obstacles.3.motion`).
    pub fn build_motion(
        &self,
        section: &str,
        kind: &str,
        params: &toml::Table,
        ctx: &MotionContext<'_>,
    ) -> Result<ActorMotion, ParamError> {
        (find(&self.motions, section, kind)?.build.build)(section, params, ctx)
    }

    /// Registers the filter `kind`, built from parameters P; its label and
    /// description follow ([`Describe`]).
    pub fn add_filter<P: Params + 'static>(
        &mut self,
        kind: &str,
        build: impl Fn(&P, &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> + Send + Sync + 'static,
    ) -> Describe<'_> {
        let build: BuildFilter = Arc::new(move |table, ctx| build(&parse_params::<P>("filter", table)?, ctx));
        self.guard.check(&self.filters, "filter", kind);
        add(
            &mut self.filters,
            kind,
            Checked {
                check: check_of::<P>(),
                label: label_of::<P>("filter"),
                build,
            },
        )
    }

    /// Registers the nominal controller `kind`, built from parameters P; its
    /// label and description follow ([`Describe`]).
    pub fn add_nominal<P: Params + 'static>(
        &mut self,
        kind: &str,
        build: impl Fn(&P, &NominalContext) -> Result<Box<dyn NominalController>, ParamError> + Send + Sync + 'static,
    ) -> Describe<'_> {
        let build: BuildNominal = Arc::new(move |table, ctx| build(&parse_params::<P>("nominal", table)?, ctx));
        self.guard.check(&self.nominals, "nominal", kind);
        add(
            &mut self.nominals,
            kind,
            Checked {
                check: check_of::<P>(),
                label: label_of::<P>("nominal"),
                build,
            },
        )
    }

    /// The label and description of a (checked) `filter` table's run.
    pub fn describe_filter(&self, kind: &str, params: &toml::Table) -> Result<Description, ParamError> {
        describe(find(&self.filters, "filter", kind)?, params)
    }

    /// The label and description of a (checked) `nominal` table's run.
    pub fn describe_nominal(&self, kind: &str, params: &toml::Table) -> Result<Description, ParamError> {
        describe(find(&self.nominals, "nominal", kind)?, params)
    }

    /// The file that registered filter kind `kind`, when it is not built in.
    pub fn filter_origin(&self, kind: &str) -> Option<&str> {
        self.filters.iter().find(|k| k.name == kind)?.origin.as_deref()
    }

    /// The file that registered nominal kind `kind`, when it is not built in.
    pub fn nominal_origin(&self, kind: &str) -> Option<&str> {
        self.nominals.iter().find(|k| k.name == kind)?.origin.as_deref()
    }

    /// Every filter and nominal kind that names the file registering it, with that file.
    pub fn origins(&self) -> Vec<(&str, &str)> {
        let filters = self
            .filters
            .iter()
            .filter_map(|k| Some((k.name.as_str(), k.origin.as_deref()?)));
        let nominals = self
            .nominals
            .iter()
            .filter_map(|k| Some((k.name.as_str(), k.origin.as_deref()?)));
        filters.chain(nominals).collect()
    }

    /// The filter kinds, in registration order.
    pub fn filter_kinds(&self) -> Vec<&str> {
        self.filters.iter().map(|k| k.name.as_str()).collect()
    }

    /// The nominal kinds, in registration order.
    pub fn nominal_kinds(&self) -> Vec<&str> {
        self.nominals.iter().map(|k| k.name.as_str()).collect()
    }

    /// Checks a `filter` table's parameters; returns them normalised (defaults filled in).
    pub fn check_filter(&self, kind: &str, params: &toml::Table) -> Result<toml::Table, ParamError> {
        (find(&self.filters, "filter", kind)?.build.check)("filter", params)
    }

    /// Checks a `nominal` table's parameters; returns them normalised.
    pub fn check_nominal(&self, kind: &str, params: &toml::Table) -> Result<toml::Table, ParamError> {
        (find(&self.nominals, "nominal", kind)?.build.check)("nominal", params)
    }

    /// Builds the filter of a (checked) `filter` table.
    pub fn build_filter(
        &self,
        kind: &str,
        params: &toml::Table,
        ctx: &FilterContext,
    ) -> Result<Box<dyn SafetyFilter>, ParamError> {
        (find(&self.filters, "filter", kind)?.build.build)(params, ctx)
    }

    /// Builds the nominal controller of a (checked) `nominal` table.
    pub fn build_nominal(
        &self,
        kind: &str,
        params: &toml::Table,
        ctx: &NominalContext,
    ) -> Result<Box<dyn NominalController>, ParamError> {
        (find(&self.nominals, "nominal", kind)?.build.build)(params, ctx)
    }
}

/// The run's description of a kind with parameters `params`.
pub(crate) fn describe<B>(kind: &Kind<Checked<B>>, params: &toml::Table) -> Result<Description, ParamError> {
    Ok(Description {
        kind: kind.name.clone(),
        label: (kind.build.label)(params, &kind.label)?,
        description: kind.description.clone(),
    })
}

/// Adds (or replaces) the kind `name`, labelled by its name until [`Describe`] says otherwise.
pub(crate) fn add<'a, B>(kinds: &'a mut Vec<Kind<B>>, name: &str, build: B) -> Describe<'a> {
    let kind = Kind {
        name: name.to_string(),
        label: name.to_string(),
        description: String::new(),
        origin: None,
        build,
    };
    let index = match kinds.iter().position(|k| k.name == name) {
        Some(i) => {
            kinds[i] = kind;
            i
        }
        None => {
            kinds.push(kind);
            kinds.len() - 1
        }
    };
    let kind = &mut kinds[index];
    Describe {
        label: &mut kind.label,
        description: &mut kind.description,
        origin: &mut kind.origin,
    }
}

pub(crate) fn find<'a, B>(kinds: &'a [Kind<B>], section: &str, name: &str) -> Result<&'a Kind<B>, ParamError> {
    kinds.iter().find(|k| k.name == name).ok_or_else(|| {
        let known: Vec<String> = kinds.iter().map(|k| format!("`{}`", k.name)).collect();
        ParamError::new(
            format!("{section}.kind"),
            format!("unknown kind `{name}`, expected one of {}", known.join(", ")),
        )
    })
}

static REGISTRY: LazyLock<RwLock<Registry>> = LazyLock::new(|| RwLock::new(Registry::builtin()));

/// The process's registry (the built-ins plus every kind registered so far).
pub fn registry() -> RwLockReadGuard<'static, Registry> {
    REGISTRY.read().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Adds kinds to the process's registry; call before loading the scenarios that name them.
/// A kind under a name already registered (a built-in's, say) is refused and nothing of the
/// call is kept, unless the call says it replaces ([`Registry::replacing`]).
pub fn register(add_kinds: impl FnOnce(&mut Registry)) -> Result<(), AlreadyRegistered> {
    register_guarded(&REGISTRY, |r| &mut r.guard, add_kinds)
}
