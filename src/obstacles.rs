//! The `[[obstacles]]` section and `[actor_knowledge]` (docs/actors.md): each obstacle's spec
//! — a circle or a box, where and when it appears, how it moves (a registered motion kind), a
//! lead it follows — with its checks at load ([`ObstacleSpec::validate`]) and its motion built
//! by its kind ([`ObstacleSpec::motion`]); what the controller assumes of the moving ones
//! ([`ActorKnowledgeSpec`]). The episode's assembly of their barriers and bodies is
//! `episode::build::obstacles`.

use serde::{Deserialize, Serialize};

use crate::params::ParamError;
use crate::section::{ControlSettings, Section, SectionContext};

/// What an obstacle's checks and motion need of the rest of the scenario.
pub struct ObstacleContext<'a> {
    /// The run's duration (s): an appearance later than it never happens.
    pub duration: f64,
    /// The scenario's seed (a motion's seeded jitter).
    pub seed: u64,
    /// The parsed `[commonroad]` file a `recorded` motion reads.
    pub commonroad: Option<&'a mjsafe_commonroad::CommonRoad>,
    /// Largest coordinate or radius accepted (m): h = d² − r² keeps metre-scale precision only
    /// well below 1e9 m (and overflows to inf past 1e154).
    pub extent: f64,
}

impl<'a> From<&SectionContext<'a>> for ObstacleContext<'a> {
    fn from(cx: &SectionContext<'a>) -> ObstacleContext<'a> {
        ObstacleContext {
            duration: cx.duration,
            seed: cx.seed,
            commonroad: cx.commonroad,
            extent: cx.extent,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    /// Name in logs (default `obstacle_<index>`).
    #[serde(default)]
    pub name: Option<String>,
    pub centre: [f64; 2],
    /// A circle's radius (m); a box obstacle (`shape`) has none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// A box instead of a circle (docs/actors.md, "Footprints").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shape: Option<ObstacleShape>,
    /// When the obstacle becomes known to the controller (seconds).
    #[serde(default)]
    pub appear_at: f64,
    /// Uniform random jitter of `appear_at` (± seconds, seeded; the result is kept >= 0).
    #[serde(default)]
    pub appear_jitter: f64,
    /// How the obstacle moves (`[obstacles.motion]`; none: it stands at `centre`). `centre` is
    /// then its position at t = 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motion: Option<MotionSpec>,
    /// A lead to follow on the line, for a vehicle that moves along one (`[obstacles.following]`,
    /// docs/actors.md): its barrier is the headway h = D − D_sf − T v instead of a circle's,
    /// with D the gap between the vehicle's front (its position) and the lead's rear (`centre`'s
    /// x less `radius`, or less a box's half extent along x).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub following: Option<FollowingSpec>,
}

/// The headway barrier of a lead (Molnar et al., arXiv 2112.08445: D_sf = 3 m, T = 2 s).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FollowingSpec {
    /// D_sf, the gap kept at standstill (m).
    pub standstill: f64,
    /// T, the time headway (s).
    pub time_headway: f64,
}

/// An obstacle's shape other than a circle (`shape = { kind = "box", … }`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ObstacleShape {
    /// A rectangle `length` × `width` (m) centred at the obstacle's centre, its length along
    /// `heading` (rad; a moving box's follows its motion direction), covered by `circles`
    /// circles (default ⌈L/W⌉).
    Box {
        length: f64,
        width: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        heading: Option<f64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        circles: Option<usize>,
    },
}

impl ObstacleSpec {
    /// The obstacle's heading (a box's: the one its motion decides, `motion_heading`, e.g. a
    /// straight motion's direction, else its `heading`) and covering circles as (offset from its
    /// centre in the world frame, radius): one circle of `radius` at the centre, or a box's
    /// covering circles.
    pub fn circles(&self, motion_heading: Option<f64>) -> (f64, Vec<([f64; 2], f64)>) {
        match self.shape {
            None => (0.0, vec![([0.0, 0.0], self.radius.unwrap_or(0.0))]),
            Some(ObstacleShape::Box {
                length,
                width,
                heading,
                circles,
            }) => {
                let heading = motion_heading.or(heading).unwrap_or(0.0);
                let rectangle = crate::footprint::Rectangle {
                    length,
                    width,
                    circles,
                    offset: 0.0,
                };
                let circles = rectangle.circles().into_iter();
                (
                    heading,
                    circles
                        .map(|c| (crate::footprint::rotate(c.offset, heading), c.radius))
                        .collect(),
                )
            }
        }
    }
}

/// A moving obstacle's motion (`[obstacles.motion]`, docs/actors.md): a registered motion
/// kind and its parameters (`crate::registry::Registry::add_motion`). Without `kind`, a table
/// with `waypoints` is `waypoints` and any other `straight` (the files written before motions
/// had kinds).
#[derive(Debug, Clone, PartialEq)]
pub struct MotionSpec {
    pub kind: String,
    pub params: toml::Table,
}

impl MotionSpec {
    /// A motion kind with its parameters (not yet checked).
    pub fn new(kind: &str, params: toml::Table) -> MotionSpec {
        MotionSpec {
            kind: kind.to_string(),
            params,
        }
    }
}

impl<'de> Deserialize<'de> for MotionSpec {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let mut params = toml::Table::deserialize(deserializer)?;
        match params.remove("kind") {
            Some(toml::Value::String(kind)) => Ok(MotionSpec { kind, params }),
            Some(other) => Err(D::Error::custom(format!(
                "key `kind`: expected a string, found {}",
                other.type_str()
            ))),
            None if params.contains_key("waypoints") => Ok(MotionSpec::new("waypoints", params)),
            None => Ok(MotionSpec::new("straight", params)),
        }
    }
}

impl Serialize for MotionSpec {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        crate::params::serialize_kind_table(&self.kind, &self.params, serializer)
    }
}

/// What the controller assumes of the moving obstacles over each channel's delay
/// (`[actor_knowledge]`, next to `assumed_delays`; docs/actors.md).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActorKnowledgeSpec {
    /// `static`, `constant_velocity` (default), `constant_acceleration` or `oracle`.
    #[serde(default)]
    pub kind: crate::actor::ActorKnowledge,
    /// A bound on the prediction error of an actor's position (m), added to its radius in the
    /// controller's barriers (a robustness margin; the logged h keeps the true radius).
    #[serde(default)]
    pub margin: f64,
    /// How often the controller observes the road users (s): every control tick when 0 (the
    /// default), else at every tick a whole multiple of this period after the first, as a
    /// perception stack at that rate would; between observations it assumes `kind` from the
    /// last one (`oracle` knows the recording whatever the period).
    #[serde(default)]
    pub period: f64,
}

impl ObstacleSpec {
    /// Obstacle `i`'s checks at load, each error at the key it names (`obstacles.<i>.…`).
    pub fn validate(&self, i: usize, ctx: &ObstacleContext) -> Result<(), ParamError> {
        let (o, extent) = (self, ctx.extent);
        // Built once: the shape's heading check reads it, its error is reported after the shape's.
        let motion = o.motion(i, ctx);
        o.validate_shape(i, extent, motion.as_ref().ok().and_then(Option::as_ref))?;
        if o.centre.iter().any(|v| !v.is_finite()) {
            return Err(ParamError::new(
                format!("obstacles.{i}.centre"),
                "expected two finite coordinates",
            ));
        }
        if o.centre.iter().chain(&o.radius).any(|v| v.abs() > extent) {
            return Err(ParamError::new(
                format!("obstacles.{i}"),
                format!("expected a centre and radius within ±{extent:e} m (h = d² − r² loses its precision beyond)"),
            ));
        }
        if !o.appear_jitter.is_finite() || o.appear_jitter < 0.0 {
            return Err(ParamError::new(
                format!("obstacles.{i}.appear_jitter"),
                format!("expected a jitter >= 0, found {}", o.appear_jitter),
            ));
        }
        if o.appear_jitter > ctx.duration {
            return Err(ParamError::new(
                format!("obstacles.{i}.appear_jitter"),
                format!(
                    "expected at most the run's duration {} s (a later appearance never happens), found {}",
                    ctx.duration, o.appear_jitter
                ),
            ));
        }
        if !o.appear_at.is_finite() || o.appear_at < 0.0 {
            return Err(ParamError::new(
                format!("obstacles.{i}.appear_at"),
                format!("expected a time >= 0, found {}", o.appear_at),
            ));
        }
        motion?;
        if let Some(f) = &o.following {
            for (key, v) in [("standstill", f.standstill), ("time_headway", f.time_headway)] {
                if !(v.is_finite() && (0.0..=extent).contains(&v)) {
                    return Err(ParamError::new(
                        format!("obstacles.{i}.following.{key}"),
                        format!("expected a finite value >= 0, found {v}"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// An obstacle's `radius` (a circle) or `shape` (a box), one of the two; a box's extents
    /// (within `extent`), and its `heading` only where its `motion` does not decide it.
    fn validate_shape(
        &self,
        i: usize,
        extent: f64,
        motion: Option<&crate::actor::ActorMotion>,
    ) -> Result<(), ParamError> {
        let o = self;
        let Some(ObstacleShape::Box {
            length,
            width,
            heading,
            circles,
        }) = o.shape
        else {
            return match o.radius {
                Some(radius) if !(radius.is_finite() && radius > 0.0) => Err(ParamError::new(
                    format!("obstacles.{i}.radius"),
                    format!("expected a positive radius, found {radius}"),
                )),
                Some(_) => Ok(()),
                None => Err(ParamError::new(
                    format!("obstacles.{i}"),
                    "expected a `radius` (a circle) or a `shape` (a box)",
                )),
            };
        };
        if o.radius.is_some() {
            return Err(ParamError::new(
                format!("obstacles.{i}.radius"),
                "a box obstacle has no radius (its covering circles follow from `shape`): expected `radius` or `shape`, not both",
            ));
        }
        let rectangle = crate::footprint::Rectangle {
            length,
            width,
            circles,
            offset: 0.0,
        };
        rectangle
            .check(extent)
            .map_err(|e| ParamError::new(format!("obstacles.{i}.shape.{}", e.key), e.message))?;
        match heading {
            Some(_) if motion.is_some_and(|m| m.layout_heading().is_some()) => Err(ParamError::new(
                format!("obstacles.{i}.shape.heading"),
                "a box moving along a line follows its motion's direction: expected no `heading`",
            )),
            Some(h) if !h.is_finite() => Err(ParamError::new(
                format!("obstacles.{i}.shape.heading"),
                format!("expected a finite angle (rad), found {h}"),
            )),
            _ => Ok(()),
        }
    }

    /// Obstacle `i`'s motion built by its registered kind (None for an obstacle that stands),
    /// with its seeded variations; errors name the scenario key.
    pub fn motion(&self, i: usize, ctx: &ObstacleContext) -> Result<Option<crate::actor::ActorMotion>, ParamError> {
        let Some(m) = &self.motion else {
            return Ok(None);
        };
        let motion_ctx = crate::actor::MotionContext {
            centre: self.centre,
            seed: ctx.seed,
            index: i,
            boxed: self.shape.is_some(),
            commonroad: ctx.commonroad,
        };
        let section = format!("obstacles.{i}.motion");
        crate::registry::registry()
            .build_motion(&section, &m.kind, &m.params, &motion_ctx)
            .map(Some)
    }
}

impl ActorKnowledgeSpec {
    /// The margin is a distance (m) within `extent`, the period a time >= 0 (s).
    pub fn validate(&self, extent: f64) -> Result<(), ParamError> {
        if !(self.margin.is_finite() && self.margin >= 0.0 && self.margin <= extent) {
            return Err(ParamError::new(
                "actor_knowledge.margin",
                format!("expected a distance >= 0 (m), found {}", self.margin),
            ));
        }
        if !(self.period.is_finite() && self.period >= 0.0) {
            return Err(ParamError::new(
                "actor_knowledge.period",
                format!("expected a period >= 0 (s), found {}", self.period),
            ));
        }
        Ok(())
    }
}

/// `[[obstacles]]`: each checked with what the rest of the scenario says of it; the episode
/// assembles them (their bodies go into the MJCF model).
impl Section for Vec<ObstacleSpec> {
    fn validate(&self, _key: &str, cx: &SectionContext<'_>) -> Result<(), ParamError> {
        let obstacles = ObstacleContext::from(cx);
        self.iter().enumerate().try_for_each(|(i, o)| o.validate(i, &obstacles))
    }
}

/// `[actor_knowledge]`: what the controller assumes of the road users over the delay.
impl Section for ActorKnowledgeSpec {
    fn validate(&self, _key: &str, cx: &SectionContext<'_>) -> Result<(), ParamError> {
        ActorKnowledgeSpec::validate(self, cx.extent)
    }

    fn configure(&self, _cx: &SectionContext<'_>, control: &mut dyn ControlSettings) -> Result<(), ParamError> {
        control
            .set_actor_knowledge(self.kind, self.period)
            .map_err(|e| ParamError::new("actor_knowledge.period", e))
    }
}
