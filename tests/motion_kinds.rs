//! Actor motions are registered kinds (docs/actors.md, "Motion kinds"): a kind a user registers
//! runs exactly as the built-ins do (its states in `/actors` are the ones it computes, checked
//! here against the closed form), its parameters are checked by its own type with the key, and
//! an unknown kind or a recorded motion without a CommonRoad file is one line naming the key.

mod common;

use common::*;
use mjsafe::actor::{ActorMotion, ActorState, Motion, MotionContext, MotionError};
use mjsafe::log::proto;

/// A user's motion: around a circle of `radius` about the obstacle's centre at `rate` rad/s,
/// starting on its +x side.
#[derive(Debug, Clone)]
struct Circling {
    centre: [f64; 2],
    radius: f64,
    rate: f64,
}

impl Motion for Circling {
    fn state_at(&self, t: f64) -> ActorState {
        let (s, c) = (self.rate * t).sin_cos();
        let (r, w) = (self.radius, self.rate);
        ActorState {
            position: [self.centre[0] + r * c, self.centre[1] + r * s],
            velocity: [-r * w * s, r * w * c],
            acceleration: [-r * w * w * c, -r * w * w * s],
            ..ActorState::default()
        }
    }

    fn clone_motion(&self) -> Box<dyn Motion> {
        Box::new(self.clone())
    }
}

#[derive(serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct CirclingParams {
    radius: f64,
    rate: f64,
}

impl mjsafe::registry::Params for CirclingParams {
    fn validate(&self) -> Result<(), mjsafe::params::ParamError> {
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return Err(mjsafe::params::ParamError::new("radius", "expected a radius > 0 (m)"));
        }
        Ok(())
    }
}

fn build_circling(p: &CirclingParams, ctx: &MotionContext<'_>) -> Result<ActorMotion, MotionError> {
    Ok(ActorMotion::new(Circling {
        centre: ctx.centre,
        radius: p.radius,
        rate: p.rate,
    }))
}

/// Registers `circling` (again for each test of this process: the same kind, replaced).
fn register() {
    mjsafe::registry::register(|r| {
        r.replacing().add_motion("circling", build_circling).label("circling");
    })
    .expect("a replacing registration is never refused");
}

#[test]
fn a_registered_motion_kind_runs_as_the_built_ins_do() {
    register();
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("circling.mcap");
    // CPNA's pedestrian (centre (53.1, -4.9)) circling 3 m around its centre at 0.5 rad/s.
    let loaded = mjsafe::embed::load_scenario(
        std::path::Path::new("scenarios/ncap_cpna.toml"),
        &["obstacles.0.motion={kind=\"circling\", radius=3.0, rate=0.5}".to_string()],
    )
    .unwrap();
    mjsafe::embed::run_logged(&loaded, &log, &mut []).unwrap();
    let actors = read_topic::<proto::Actors>(&log, "/actors");
    assert!(actors.len() > 100);
    for m in &actors {
        let a = &m.actors[0];
        let (s, c) = (0.5 * m.time).sin_cos();
        let expected = [53.1 + 3.0 * c, -4.9 + 3.0 * s, -1.5 * s, 1.5 * c];
        let got = [a.x, a.y, a.vx, a.vy];
        for (e, g) in expected.iter().zip(got) {
            assert!((e - g).abs() < 1e-9, "t = {}: {got:?} against {expected:?}", m.time);
        }
    }
}

#[test]
fn motion_kinds_are_checked_with_the_key() {
    register();
    let cases: [(&str, &[&str]); 5] = [
        (
            "obstacles.0.motion={kind=\"flying\"}",
            &[
                "obstacles.0.motion.kind",
                "unknown kind `flying`",
                "`straight`, `waypoints`, `recorded`",
            ],
        ),
        (
            "obstacles.0.motion={kind=\"circling\", radius=-1.0, rate=0.5}",
            &["obstacles.0.motion.radius", "expected a radius > 0"],
        ),
        (
            "obstacles.0.motion={kind=\"circling\", radius=1.0, rate=0.5, speed=2.0}",
            &["obstacles.0.motion", "unknown field `speed`"],
        ),
        (
            "obstacles.0.motion={kind=\"recorded\", id=3}",
            &["obstacles.0.motion.id", "expected a `[commonroad] file`"],
        ),
        (
            "obstacles.0.motion={kind=\"straight\", waypoints=[[60.0, 0.0]]}",
            &["obstacles.0.motion.direction", "either a `direction` or `waypoints`"],
        ),
    ];
    for (set, needles) in cases {
        let err =
            match mjsafe::embed::load_scenario(std::path::Path::new("scenarios/ncap_cpna.toml"), &[set.to_string()]) {
                Ok(_) => panic!("{set} was accepted"),
                Err(e) => e.to_string(),
            };
        for n in needles {
            assert!(err.contains(n), "{set}: `{err}` lacks `{n}`");
        }
    }
}

#[test]
fn a_motion_without_kind_is_read_as_before() {
    // The files written before motions had kinds: no `kind` is `straight`, or `waypoints` with
    // waypoints; the resolved scenario spells the kind out.
    let straight = mjsafe::embed::load_scenario(std::path::Path::new("scenarios/ncap_cpna.toml"), &[]).unwrap();
    let path = mjsafe::embed::load_scenario(
        std::path::Path::new("scenarios/ncap_cpna.toml"),
        &["obstacles.0.motion={speed=1.4, waypoints=[[53.1, 5.0]]}".to_string()],
    )
    .unwrap();
    let kind = |l: &mjsafe::embed::LoadedScenario| l.scenario.obstacles[0].motion.as_ref().unwrap().kind.clone();
    assert_eq!(kind(&straight), "straight");
    assert_eq!(kind(&path), "waypoints");
    let text = toml::to_string(&straight.scenario).unwrap();
    assert!(text.contains("kind = \"straight\""), "{text}");
}

#[test]
fn a_scenario_imported_before_motion_kinds_names_the_replacement() {
    let text = std::fs::read_to_string("scenarios/ncap_cpna.toml").unwrap();
    let text = text.replace("[obstacles.motion]", "recorded = 431\n[obstacles.motion]");
    let err = match mjsafe::embed::scenario_from_text(std::path::Path::new("old.toml"), text, &[]) {
        Ok(_) => panic!("`recorded = 431` was accepted"),
        Err(e) => e.to_string(),
    };
    assert!(
        err.contains("obstacles.0.recorded") && err.contains("motion = { kind = \"recorded\", id = 431 }"),
        "{err}"
    );
}
