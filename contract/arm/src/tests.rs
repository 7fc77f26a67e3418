use super::*;
use proptest::prelude::*;

fn parse(text: &str) -> Description {
    toml::from_str(text).unwrap()
}

fn refused(text: &str) -> Invalid {
    Layout::new(&parse(text)).unwrap_err()
}

/// The example arms the tests of this crate and of the kinematics share.
const PAPER: &str = include_str!("../testdata/paper.toml");
const TDCR: &str = include_str!("../testdata/tdcr.toml");

#[test]
fn the_papers_arm_is_two_modules_of_three_tendons_named_a1_to_a6() {
    let l = Layout::new(&parse(PAPER)).unwrap();
    assert_eq!(l.modules().len(), 2);
    assert_eq!(l.modules()[1].actuators, 3..6);
    assert_eq!(
        l.names().collect::<Vec<_>>(),
        ["a1", "a2", "a3", "a4", "a5", "a6"]
    );
    let degrees: Vec<f64> = l
        .actuators()
        .iter()
        .map(|a| a.angle_rad.to_degrees().round())
        .collect();
    assert_eq!(degrees, [0.0, 120.0, 240.0, 60.0, 180.0, 300.0]);
    assert_eq!(l.mount, Mount::Hanging);
    assert_eq!(l.routing(), Routing::Independent);
    assert!(l.passes(4, 1) && !l.passes(4, 0));
    let a = &l.actuators()[2];
    assert!((a.length_of(0.5) - 0.22).abs() < 1e-12);
    assert!((a.actuation_of(0.25) - 1.0).abs() < 1e-12);
}

/// The identity tells arms apart by structure and names, not by the lengths a calibration
/// changes, and fits an iceoryx2 attribute.
#[test]
fn the_identity_names_the_structure_not_the_calibration() {
    let paper = Layout::new(&parse(PAPER)).unwrap();
    let id = paper.identity();
    assert!(
        id.starts_with("6 actuators (a1 .. a6) in 2 modules, layout "),
        "{id}"
    );
    let recalibrated = PAPER.replace("0.025", "0.027").replace("0.19", "0.18");
    assert_eq!(Layout::new(&parse(&recalibrated)).unwrap().identity(), id);
    let renamed = PAPER.replacen(
        "length_m = [0.19, 0.25] }",
        "length_m = [0.19, 0.25], names = [\"x\", \"y\", \"z\"] }",
        1,
    );
    let coupled = format!("routing = \"coupled\"\n{PAPER}");
    let tdcr = Layout::new(&parse(TDCR)).unwrap().identity();
    for other in [renamed, coupled] {
        assert_ne!(
            Layout::new(&parse(&other)).unwrap().identity(),
            id,
            "{other}"
        );
    }
    assert!(
        tdcr.starts_with("9 actuators (a1 .. a9) in 3 modules"),
        "{tdcr}"
    );
    let long = "n".repeat(64);
    let mut d = parse(TDCR);
    d.modules[0].tendons.as_mut().unwrap().names = Some(vec![long.clone(), "b".into(), "c".into()]);
    d.modules[2].tendons.as_mut().unwrap().names =
        Some(vec!["d".into(), "e".into(), "z".repeat(64)]);
    assert!(Layout::new(&d).unwrap().identity().len() <= 256);
}

#[test]
fn coupled_tendons_run_through_every_module_before_their_own() {
    let l = Layout::new(&parse(TDCR)).unwrap();
    assert_eq!(l.actuators().len(), 9);
    for (i, a) in l.actuators().iter().enumerate() {
        for m in 0..3 {
            assert_eq!(l.passes(i, m), m <= a.module, "actuator {i} module {m}");
        }
    }
}

#[test]
fn chambers_come_after_their_modules_tendons_and_default_to_the_axis() {
    let l = Layout::new(&parse(
        r#"
        [[modules]]
        tendons = { count = 3, radius_m = 0.025, length_m = [0.19, 0.25] }
        chambers = { count = 1, length_m = [0.19, 0.25], names = ["p1"] }
        [[modules]]
        tendons = { count = 3, radius_m = 0.025, length_m = [0.19, 0.25] }
        chambers = { count = 1, length_m = [0.19, 0.25], names = ["p2"] }
        "#,
    ))
    .unwrap();
    let names: Vec<_> = l.names().collect();
    assert_eq!(names, ["a1", "a2", "a3", "p1", "a5", "a6", "a7", "p2"]);
    assert_eq!(l.actuators()[3].kind, Kind::Chamber);
    assert_eq!(l.actuators()[3].radius_m, 0.0);
    assert_eq!(l.modules()[1].actuators, 4..8);
}

#[test]
fn a_module_that_cannot_bend_every_way_is_refused_saying_why() {
    // Two tendons: the module bends along one line only.
    let e = refused(
        r#"
        [[modules]]
        tendons = { count = 2, radius_m = 0.02, length_m = [0.1, 0.2] }
        "#,
    );
    assert_eq!(e.key, "arm.modules[0]");
    assert!(e.message.contains("at least three tendons"), "{e}");
    // Three tendons bunched on one side.
    let e = refused(
        r#"
        [[modules]]
        tendons = { count = 3, radius_m = 0.02, length_m = [0.1, 0.2], angles_deg = [0, 60, 120] }
        "#,
    );
    assert!(e.message.contains("gap of 240°"), "{e}");
    // A chamber on the axis bends nothing.
    let e = refused(
        r#"
        [[modules]]
        chambers = { count = 1, length_m = [0.1, 0.2] }
        "#,
    );
    assert_eq!(e.key, "arm.modules[0]");
    // Three chambers off the axis bend it every way (away from each).
    Layout::new(&parse(
        r#"
        [[modules]]
        chambers = { count = 3, radius_m = 0.01, length_m = [0.1, 0.2] }
        "#,
    ))
    .unwrap();
}

#[test]
fn each_bad_key_is_named() {
    let cases = [
        ("modules = []", "arm.modules"),
        (
            "[[modules]]\ntendons = { count = 3, radius_m = 0.0, length_m = [0.1, 0.2] }",
            "arm.modules[0].tendons.radius_m",
        ),
        (
            "[[modules]]\ntendons = { count = 3, radius_m = 0.01, length_m = [0.2, 0.1] }",
            "arm.modules[0].tendons.length_m",
        ),
        (
            "[[modules]]\ntendons = { count = 3, radius_m = 0.01, length_m = [0.1, 0.2], angles_deg = [0, 120] }",
            "arm.modules[0].tendons.angles_deg",
        ),
        (
            "[[modules]]\ntendons = { count = 3, radius_m = 0.01, length_m = [0.1, 0.2], angles_deg = [0, 120, nan] }",
            "arm.modules[0].tendons.angles_deg[2]",
        ),
        (
            "[[modules]]\ntendons = { count = 3, radius_m = 0.01, length_m = [0.1, 0.2], names = [\"x\", \"y\", \"x\"] }",
            "arm.modules[0].tendons.names[2]",
        ),
        (
            "[[modules]]\ntendons = { count = 3, radius_m = 0.01, length_m = [0.1, 0.2], names = [\"x\", \"y z\", \"w\"] }",
            "arm.modules[0].tendons.names[1]",
        ),
        (
            "[[modules]]\nbackbone_m = 0.06\ntendons = { count = 3, radius_m = 0.01, length_m = [0.1, 0.2] }\nchambers = { count = 1, length_m = [0.1, 0.2] }",
            "arm.modules[0].chambers.radius_m",
        ),
        (
            "tool_m = -1.0\n[[modules]]\ntendons = { count = 3, radius_m = 0.01, length_m = [0.1, 0.2] }",
            "arm.tool_m",
        ),
        (
            "[[modules]]\ntendons = { count = 9, radius_m = 0.01, length_m = [0.1, 0.2] }\n[[modules]]\ntendons = { count = 9, radius_m = 0.01, length_m = [0.1, 0.2] }",
            "arm.modules[1]",
        ),
        ("[[modules]]\nrotation_deg = 5", "arm.modules[0]"),
    ];
    for (text, key) in cases {
        let e = refused(text);
        assert_eq!(e.key, key, "{text}: {e}");
        assert!(!e.message.is_empty());
    }
    assert!(toml::from_str::<Description>("[[modules]]\ntendon = {}").is_err());
}

#[test]
fn names_clash_across_modules_and_with_the_defaults() {
    let e = refused(
        r#"
        [[modules]]
        tendons = { count = 3, radius_m = 0.02, length_m = [0.1, 0.2] }
        [[modules]]
        tendons = { count = 3, radius_m = 0.02, length_m = [0.1, 0.2], names = ["b", "a2", "c"] }
        "#,
    );
    assert_eq!(e.key, "arm.modules[1].tendons.names[1]");
    assert!(e.message.contains("actuator 2"), "{e}");
}

proptest! {
    /// Any arm of 1 to 4 modules whose actuators fit is accepted with evenly spaced tendons,
    /// and a module of tendons at any angles exactly when no gap between neighbours reaches
    /// 180°.
    #[test]
    fn modules_bend_every_way_exactly_when_no_gap_reaches_half_a_turn(
        counts in prop::collection::vec(3usize..=5, 1..=4),
        angles in prop::collection::vec(0.0f64..360.0, 3..=6),
    ) {
        let even = counts.iter().map(|c| format!(
            "[[modules]]\ntendons = {{ count = {c}, radius_m = 0.01, length_m = [0.1, 0.2] }}\n"
        )).collect::<String>();
        let total: usize = counts.iter().sum();
        prop_assert_eq!(Layout::new(&parse(&even)).is_ok(), total <= MAX_ACTUATORS);

        let mut sorted = angles.clone();
        sorted.sort_by(f64::total_cmp);
        let wrap = sorted[0] + 360.0 - sorted[sorted.len() - 1];
        let widest = sorted.windows(2).map(|w| w[1] - w[0]).fold(wrap, f64::max);
        prop_assume!((widest - 180.0).abs() > 1e-6);
        let text = format!(
            "[[modules]]\ntendons = {{ count = {}, radius_m = 0.01, length_m = [0.1, 0.2], angles_deg = {:?} }}\n",
            angles.len(),
            angles
        );
        prop_assert_eq!(Layout::new(&parse(&text)).is_ok(), widest < 180.0);
    }
}
