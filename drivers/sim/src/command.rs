//! `softarm sim [--scenario NAME|FILE]`: the arm the sim runs, chosen from the config and a
//! scenario, and the sim process on it. The physics `[sim.mujoco]` describes comes from the
//! binary ([`PhysicsOf`]): `softarm-mujoco` links this crate, not the reverse.

use softarm_config::scenario::{OnArm, Scenario};
use softarm_config::sim::SimConfig;
use softarm_config::{Config, ConfigError};
use softarm_runtime::stop_flag;

use crate::plant::{Body, Physics};

/// What gives the physics `[sim.mujoco]` describes for the sim's arm `on`, if it describes one
/// (the binary: MuJoCo when built with it).
pub type PhysicsOf = dyn Fn(&Config, &OnArm) -> anyhow::Result<Option<Box<dyn Physics>>>;

/// The arm the sim runs, and how.
pub struct Configured {
    /// `[sim]`, as the scenario changes it.
    pub sim: SimConfig,
    pub body: Body,
    /// The MuJoCo model the plant's actuators drive, if `[sim.mujoco]` describes one.
    pub physics: Option<Box<dyn Physics>>,
}

impl Configured {
    /// The config's arm, or a scenario's on it (its steps and drift included); a MuJoCo model
    /// of it with `[sim.mujoco]`, from `physics_of`.
    pub fn of(c: &Config, scenario: Option<&str>, physics_of: &PhysicsOf) -> anyhow::Result<Self> {
        let scenario = scenario.map(Scenario::resolve).transpose()?;
        if let Some(s) = &scenario {
            tracing::info!(scenario = %s.name, "the sim runs another arm: {}", s.describe());
        }
        let on = match &scenario {
            Some(s) => s.apply_to(&c.arm, &c.sim)?,
            None => OnArm {
                arm: c.arm.clone(),
                sim: c.sim.clone(),
                steps: Vec::new(),
            },
        };
        let body = Body::of_arm(&on.arm, &on.steps).map_err(anyhow::Error::msg)?;
        let physics = physics_of(c, &on)?;
        Ok(Self {
            sim: on.sim,
            body,
            physics,
        })
    }
}

/// `softarm sim [--scenario NAME|FILE]`: the simulated arm ([`Configured::of`]) until SIGINT
/// or SIGTERM.
pub fn run(c: &Config, scenario: Option<&str>, physics_of: &PhysicsOf) -> anyhow::Result<()> {
    let Configured { sim, body, physics } = Configured::of(c, scenario, physics_of)?;
    crate::run(
        &sim,
        body,
        physics,
        c.bus()?,
        &c.estop_latch(),
        &*stop_flag()?,
    )
}

/// A plant that cannot run the arm, refused as a config is: exit 78, which `up` and systemd do
/// not restart.
pub fn plant_refused(message: String) -> ConfigError {
    ConfigError {
        origin: "the sim's plant".into(),
        line: None,
        message,
    }
}

#[cfg(test)]
mod tests {
    use std::cell::Cell;
    use std::path::PathBuf;
    use std::rc::Rc;

    use super::*;

    fn config_of(arm: &str) -> Config {
        let arm = softarm_config::arms::resolve(arm).unwrap();
        let text = softarm_config::arms::with_arm(softarm_config::DEFAULT, &arm, "test").unwrap();
        Config::parse(&text, "test", PathBuf::from(".")).unwrap()
    }

    /// The default [arm] (the paper's) runs as any arm does: its body from its layout, a
    /// scenario's steps in it, the physics asked for.
    #[test]
    fn the_default_arm_runs_from_its_layout_and_a_scenario_steps_it() {
        let c = Config::default_sim(PathBuf::from("."));
        let none = |_: &Config, _: &OnArm| -> anyhow::Result<_> { Ok(None) };
        let as_configured = Configured::of(&c, None, &none).unwrap();
        let Body::Any(arm) = as_configured.body else {
            panic!("the configured arm has no steps")
        };
        assert_eq!(&arm, Body::of_arm(&c.arm, &[]).unwrap().start());
        let swapped = Configured::of(&c, Some("tool-swap"), &none).unwrap();
        assert!(matches!(swapped.body, Body::Stepped { .. }));
        assert_eq!(swapped.body.start(), &arm);
        let changed = Configured::of(&c, Some("tool-change"), &none).unwrap();
        assert_ne!(changed.body.start(), &arm);
    }

    #[test]
    fn any_other_arm_runs_from_its_layout_asking_for_its_physics() {
        let c = config_of("tdcr");
        // `PhysicsOf` is `'static`, as the binary's function is.
        let asked = Rc::new(Cell::new(0));
        let (counted, arm) = (asked.clone(), c.arm.clone());
        let physics_of = move |_: &Config, on: &OnArm| -> anyhow::Result<_> {
            assert_eq!(on.arm, arm);
            counted.set(counted.get() + 1);
            Ok(None)
        };
        let configured = Configured::of(&c, None, &physics_of).unwrap();
        assert!(matches!(configured.body, Body::Any(_)));
        assert!(configured.physics.is_none());
        assert_eq!(asked.get(), 1);
    }

    #[test]
    fn an_unknown_scenario_is_refused_as_a_config() {
        let c = Config::default_sim(PathBuf::from("."));
        let e = Configured::of(&c, Some("no-such-scenario"), &|_, _| Ok(None))
            .err()
            .unwrap();
        assert!(e.chain().any(|c| c.is::<ConfigError>()), "{e:#}");
    }
}
