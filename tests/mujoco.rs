//! The sim on a MuJoCo plant (`[sim.mujoco]`, softarm built with `--features mujoco`): a lab's
//! own model of a real arm through its map, driven by setpoints as the sim's own plant is,
//! holding under the e-stop; a plant that cannot run the arm stops the sim as a bad config
//! does. Without the feature, a config with `[sim.mujoco]` is refused saying how to get it.
//! `.ci/run` runs these with the feature (`--features mujoco --test e2e mujoco`).

use std::path::Path;

use softarm_config::plant::Plant;
use softarm_test_support::{TestStack, config_text};

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

/// The shipped plant file of the OpenCR TDCR's model, its `[mujoco]` changed by `change`.
fn ftdcr(change: impl FnOnce(&mut Plant)) -> Plant {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/mujoco/opencr-ftdcr-v6.toml");
    let mut plant = Plant::resolve(file.to_str().unwrap()).unwrap();
    change(&mut plant);
    plant
}

fn on_plant(name: &str, plant: &Plant) -> TestStack {
    TestStack::with_config(BIN, name, false, |dir, ns| {
        plant.into_config(&config_text(dir, ns)).unwrap()
    })
}

#[cfg(not(feature = "mujoco"))]
#[test]
fn mujoco_without_the_feature_the_sim_refuses_a_mujoco_plant_saying_how_to_get_it() {
    let s = on_plant("mujoco-missing", &ftdcr(|_| {}));
    let out = s.run(&["sim"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(78), "{stderr}");
    assert!(
        stderr.contains("built without MuJoCo") && stderr.contains("--features mujoco"),
        "{stderr}"
    );
}

#[cfg(feature = "mujoco")]
mod with_mujoco {
    use super::*;
    use softarm_ipc::{Actuators, DriverState, MotorState, Namespace, Node, Setpoint};
    use softarm_runtime::now_ns;
    use softarm_test_support::eventually;
    use std::time::Duration;

    /// The newest of a subscriber's samples, if any came.
    fn newest<T: Copy + std::fmt::Debug + softarm_ipc::iceoryx2::prelude::ZeroCopySend>(
        sub: &softarm_ipc::Sub<T>,
    ) -> Option<T> {
        let mut last = None;
        while let Ok(Some(s)) = sub.receive() {
            last = Some(*s);
        }
        last
    }

    /// The sim runs the lab's model: at rest the marker stands 230 mm over the base (222 mm of
    /// backbone, 8 mm of marker); tendon 1 pulled bends it towards +x; the e-stop holds the
    /// actuators where they are (STOPPED) and the tip stays there.
    #[test]
    fn mujoco_the_sim_drives_a_labs_model_through_its_map_and_holds_under_the_estop() {
        let s = on_plant("mujoco-lab", &ftdcr(|_| {}));
        let _sim = s.spawn(&["sim"]);
        let n = Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap();
        let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
        let tracker = n.subscriber(&n.tracker().unwrap()).unwrap();
        let rest = eventually("the straight arm", Duration::from_secs(60), || {
            newest(&tracker).filter(|t| (t.position[2] - 0.230).abs() < 0.002)
        });
        assert!(rest.position[0].abs() < 0.002, "{:?}", rest.position);

        let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
        let mut bend = [0.5; 9];
        bend[0] = 0.1;
        let bent = eventually("the arm bent by tendon 1", Duration::from_secs(60), || {
            let _ = setpoints.send_copy(Setpoint {
                stamp_ns: now_ns(),
                actuation: Actuators::new(&bend),
                ..Setpoint::default()
            });
            std::thread::sleep(Duration::from_millis(10));
            newest(&tracker).filter(|t| t.position[0] > 0.03)
        });
        assert!(bent.position[1].abs() < 0.015, "{:?}", bent.position);
        let m: MotorState = eventually("motor state", Duration::from_secs(10), || newest(&motors));
        assert_eq!(m.actuation.len(), 9);

        let out = s.run(&["estop"]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let stopped = eventually("STOPPED", Duration::from_secs(10), || {
            newest(&motors).filter(|m| m.state == DriverState::Stopped as u32)
        });
        // Setpoints elsewhere are not followed: the arm stays bent where it stopped.
        for _ in 0..50 {
            let _ = setpoints.send_copy(Setpoint {
                stamp_ns: now_ns(),
                actuation: Actuators::new(&[0.5; 9]),
                ..Setpoint::default()
            });
            std::thread::sleep(Duration::from_millis(10));
        }
        let held = eventually("a tracker sample", Duration::from_secs(10), || {
            newest(&tracker)
        });
        let m = newest(&motors).unwrap_or(stopped);
        assert!(
            (m.actuation[0] - stopped.actuation[0]).abs() < 0.02,
            "{:?} {:?}",
            stopped.actuation,
            m.actuation
        );
        assert!(held.position[0] > 0.02, "{:?}", held.position);
    }

    /// The lab's model behind emulated devices, as `softarm-rig emulate` runs it for a config with
    /// `[sim.mujoco]`: the real tendon and tracker drivers close the loop through MuJoCo. The
    /// nine motors engage where they stand, the tracker reads the straight arm where the model
    /// has it (230 mm over the base, through the tracker's frame and hemisphere; the arm's PCC
    /// would put it at 233), and a tendon
    /// the driver pulls bends the arm towards it.
    #[test]
    fn mujoco_the_real_drivers_drive_a_labs_model_behind_emulated_devices() {
        use crate::hardware::{eventually, nine_motors, send_each, watch};
        use softarm_emulate::rig::Rig;
        use softarm_test_support::Devices;

        let plant = ftdcr(|_| {});
        let (s, _, rig) = TestStack::with_devices_for(
            BIN,
            "mujoco-emulated",
            Devices::Shared,
            |text| {
                // The arm stands: the sensor stays below the transmitter, on its +z side. Its
                // 26 mm strokes on 10 mm spools.
                let spools = toml::Value::Array(vec![0.01.into(); 9]);
                softarm_test_support::with_overrides(
                    &nine_motors(&plant.into_config(&text).unwrap()),
                    &[
                        ("tracker.hemisphere", "lower".into()),
                        ("tendon.spool_radius_m", spools),
                    ],
                )
            },
            |c| {
                let mujoco = c.sim.mujoco.as_ref().expect("the plant's [sim.mujoco]");
                let arm = softarm_mujoco::MujocoArm::new(mujoco, &c.arm, &c.arm, &[], &c.base_dir)
                    .unwrap();
                let rig = Rig::start_with(c, 0.5, Some(Box::new(arm))).unwrap();
                let (tendon, tracker) = (rig.tendon_path().into(), rig.tracker_path().into());
                (rig, tendon, tracker)
            },
        );
        watch(&rig);
        let n = Node::open(Namespace::new(&s.namespace).unwrap(), "test").unwrap();
        let setpoints = n.publisher(&n.setpoint().unwrap()).unwrap();
        let motors = n.subscriber(&n.motor_state().unwrap()).unwrap();
        let tracker = n.subscriber(&n.tracker().unwrap()).unwrap();
        let _tendon = s.spawn(&["tendon"]);
        let _tracker = s.spawn(&["tracker"]);

        let rest = [0.5; 9];
        eventually("nine motors FOLLOWING at rest", || {
            send_each(&setpoints, &rest);
            std::thread::sleep(Duration::from_millis(10));
            newest(&motors).filter(|m| {
                m.driver_state() == Some(DriverState::Following) && m.actuation.len() == 9
            })
        });
        let straight = eventually("the straight arm on the tracker", || {
            send_each(&setpoints, &rest);
            std::thread::sleep(Duration::from_millis(10));
            newest(&tracker).filter(|t| (t.position[2] - 0.230).abs() < 0.0015)
        });
        assert!(
            straight.position[0].abs() < 0.003 && straight.position[1].abs() < 0.003,
            "{:?}",
            straight.position
        );
        let mut bend = rest;
        bend[0] = 0.1;
        let bent = eventually("the arm bent by tendon 1", || {
            send_each(&setpoints, &bend);
            std::thread::sleep(Duration::from_millis(10));
            newest(&tracker).filter(|t| t.position[0] > 0.03)
        });
        assert!(bent.position[1].abs() < 0.015, "{:?}", bent.position);
    }

    /// A map onto an actuator the model has not: the sim stops as on a bad config (78, not
    /// restarted), naming the key and the model's actuators.
    #[test]
    fn mujoco_a_model_that_cannot_run_the_arm_stops_the_sim_naming_the_key() {
        let plant = ftdcr(|p| p.mujoco.actuators[3].name = "seg_1_tendon_0".into());
        let s = on_plant("mujoco-refused", &plant);
        let out = s.run(&["sim"]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(78), "{stderr}");
        assert!(
            stderr.contains("sim.mujoco.actuators[3].name") && stderr.contains("seg_1_ten_0"),
            "{stderr}"
        );
    }
}
