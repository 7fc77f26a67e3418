//! The iceoryx2 command line tool (`iox2`, crate iceoryx2-cli 0.10) sees a running stack's
//! services and nodes with iceoryx2's default config, as softarm uses it: no setting needed.

use std::process::Command;

use softarm_test_support::TestStack;

const BIN: &str = env!("CARGO_BIN_EXE_softarm");

/// `iox2 <args>`'s stdout, or `None` when the tool is not installed (CI requires it:
/// SOFTARM_REQUIRE_IOX2=1).
fn iox2(args: &[&str]) -> Option<String> {
    match Command::new("iox2").args(args).output() {
        Ok(out) => {
            assert!(out.status.success(), "iox2 {args:?}: {out:?}");
            Some(String::from_utf8_lossy(&out.stdout).into_owned())
        }
        Err(e) => {
            assert!(
                std::env::var("SOFTARM_REQUIRE_IOX2").as_deref() != Ok("1"),
                "SOFTARM_REQUIRE_IOX2=1 but iox2 cannot run: {e}"
            );
            eprintln!(
                "not run: iox2 is not installed ({e}); cargo install iceoryx2-cli --version 0.10.0"
            );
            None
        }
    }
}

#[test]
fn iox2_lists_the_stacks_services_and_nodes() {
    let mut s = TestStack::new(BIN, "iox2", false);
    s.up();
    let Some(services) = iox2(&["service", "list"]) else {
        return;
    };
    for service in [
        "setpoint",
        "tracker",
        "motor_state",
        "cp_sample",
        "stats",
        "status",
        "estop",
    ] {
        let name = format!("{}/{service}", s.namespace);
        assert!(services.contains(&name), "{name} not in\n{services}");
    }
    assert!(
        services.contains(&format!("RequestResponse(\"{}/waypoints\")", s.namespace)),
        "{services}"
    );
    let nodes = iox2(&["node", "list"]).unwrap();
    for role in ["controller", "learner", "sim"] {
        let name = format!("{}/{role}", s.namespace);
        assert!(nodes.contains(&name), "{name} not in\n{nodes}");
    }
}
