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
//! });
//! ```

use std::sync::{Arc, LazyLock, RwLock, RwLockReadGuard};

pub use crate::filter::Params;
use crate::filter::{self, FilterContext, ParamError, SafetyFilter};
use crate::nominal::{self, NominalContext, NominalController};

/// A kind's parameter check: its table (keys without `kind`) under a section (`filter`,
/// `vehicle`, …) in, the table normalised (defaults filled in) out.
pub(crate) type Check = Arc<dyn Fn(&str, &toml::Table) -> Result<toml::Table, ParamError> + Send + Sync>;
type BuildFilter = Arc<dyn Fn(&toml::Table, &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> + Send + Sync>;
type BuildNominal =
    Arc<dyn Fn(&toml::Table, &NominalContext) -> Result<Box<dyn NominalController>, ParamError> + Send + Sync>;

pub(crate) struct Kind<B> {
    pub(crate) name: String,
    pub(crate) build: B,
}

/// A kind (filter, nominal, vehicle): its parameter check and its constructor.
pub(crate) struct Checked<B> {
    pub(crate) check: Check,
    pub(crate) build: B,
}

/// Every filter and nominal kind a scenario may name (vehicle kinds: `mjsafe::vehicle_registry`).
pub struct Registry {
    filters: Vec<Kind<Checked<BuildFilter>>>,
    nominals: Vec<Kind<Checked<BuildNominal>>>,
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
        };
        r.add_filter("none", filter::none::build);
        r.add_filter("cbf_qp", filter::cbf_qp::build);
        r.add_filter("fixed_channel", filter::fixed_channel::build);
        r.add_filter("gamma_m", filter::gamma_m::build);
        r.add_filter("clf_cbf_qp", filter::clf_cbf_qp::build);
        r.add_filter("ptsf", filter::chain::build_ptsf);
        r.add_filter("esf", filter::chain::build_esf);
        r.add_nominal("path_lqr", nominal::build_path_lqr);
        r.add_nominal("constant", nominal::build_constant);
        r.add_nominal("unicycle_stabilizer", nominal::build_unicycle_stabilizer);
        r.add_nominal("quartic_clf", nominal::build_quartic_clf);
        r.add_nominal("red_light", nominal::build_red_light);
        r.add_nominal("pts", nominal::build_pts);
        r
    }

    /// Registers (or replaces) the filter `kind`, built from parameters P.
    pub fn add_filter<P: Params + 'static>(
        &mut self,
        kind: &str,
        build: impl Fn(&P, &FilterContext) -> Result<Box<dyn SafetyFilter>, ParamError> + Send + Sync + 'static,
    ) {
        let build: BuildFilter = Arc::new(move |table, ctx| build(&parse_params::<P>("filter", table)?, ctx));
        add(
            &mut self.filters,
            kind,
            Checked {
                check: check_of::<P>(),
                build,
            },
        );
    }

    /// Registers (or replaces) the nominal controller `kind`, built from parameters P.
    pub fn add_nominal<P: Params + 'static>(
        &mut self,
        kind: &str,
        build: impl Fn(&P, &NominalContext) -> Result<Box<dyn NominalController>, ParamError> + Send + Sync + 'static,
    ) {
        let build: BuildNominal = Arc::new(move |table, ctx| build(&parse_params::<P>("nominal", table)?, ctx));
        add(
            &mut self.nominals,
            kind,
            Checked {
                check: check_of::<P>(),
                build,
            },
        );
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

pub(crate) fn add<B>(kinds: &mut Vec<Kind<B>>, name: &str, build: B) {
    let kind = Kind {
        name: name.to_string(),
        build,
    };
    match kinds.iter_mut().find(|k| k.name == name) {
        Some(existing) => *existing = kind,
        None => kinds.push(kind),
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
pub fn register(add_kinds: impl FnOnce(&mut Registry)) {
    let mut registry = REGISTRY.write().unwrap_or_else(|poisoned| poisoned.into_inner());
    add_kinds(&mut registry);
}
