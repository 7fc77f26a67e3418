//! Property-based fuzzing of everything that reads user or disk input in this crate: way-point
//! files and sets, the config and scenario files. Whatever the bytes, nothing
//! panics, a refusal says why, and what is accepted holds the invariants the controller relies
//! on. `cargo test -p softarm-config --test fuzz` runs a bounded number of cases (CI);
//! `PROPTEST_CASES=100000 cargo test --release -p softarm-config --test fuzz` runs longer.

use std::path::PathBuf;
use std::sync::OnceLock;

use proptest::prelude::*;
use proptest::strategy::ValueTree;
use softarm_arm::MAX_MODULES;
use softarm_config::arm::MAX_OFFSET_M;
use softarm_config::scenario::Scenario;
use softarm_config::waypoints::{WaypointFile, validate};
use softarm_config::{Config, DEFAULT};
use softarm_kinematics::forward::ForwardModel;
use softarm_kinematics::pcc;

/// Numbers as users and broken tools write them: ordinary, extreme and not numbers at all.
fn number() -> impl Strategy<Value = String> {
    prop_oneof![
        (-2.0f64..2.0).prop_map(|v| format!("{v:?}")),
        (-1e3f64..1e3).prop_map(|v| format!("{v:?}")),
        Just("nan".to_string()),
        Just("inf".to_string()),
        Just("-inf".to_string()),
        Just("1e308".to_string()),
        Just("-0.0".to_string()),
        Just("0".to_string()),
        Just("\"0.5\"".to_string()),
        Just("[]".to_string()),
        Just("true".to_string()),
        any::<i64>().prop_map(|v| v.to_string()),
    ]
}

/// Mostly plausible sets (times in order, positions near the workspace) with a value broken
/// here and there, so that many are accepted and the invariants below are exercised.
fn plausible_waypoint_text() -> impl Strategy<Value = String> {
    (
        0.1f64..2.0,
        prop::collection::vec(
            (0.45f64..1.2, -0.42f64..0.42, -0.42f64..0.42, -0.58f64..0.02),
            1..12,
        ),
        prop::option::of((0usize..12, number())),
    )
        .prop_map(|(margin, points, broken)| {
            let mut t = String::new();
            let mut time = 0.0;
            for (i, (gap, x, y, z)) in points.into_iter().enumerate() {
                time += gap;
                let mut x = format!("{x:?}");
                if let Some((at, v)) = &broken
                    && *at == i
                {
                    x = v.clone();
                }
                t += &format!("[[point]]\nt_s = {time:?}\nposition_m = [{x}, {y:?}, {z:?}]\n");
            }
            format!("duration_s = {:?}\n{t}", time + margin)
        })
}

fn waypoint_text() -> impl Strategy<Value = String> {
    prop_oneof![plausible_waypoint_text(), random_waypoint_text()]
}

fn random_waypoint_text() -> impl Strategy<Value = String> {
    (
        number(),
        prop::collection::vec((number(), number(), number(), number()), 0..20),
        any::<bool>(),
    )
        .prop_map(|(duration, points, junk)| {
            let mut t = format!("duration_s = {duration}\n");
            for (ts, x, y, z) in points {
                t += &format!("[[point]]\nt_s = {ts}\nposition_m = [{x}, {y}, {z}]\n");
            }
            if junk {
                t += "colour = \"red\"\n";
            }
            t
        })
}

#[test]
fn the_waypoint_cases_include_accepted_sets() {
    // The generator at a fixed seed: some cases must pass validation.
    let mut runner = proptest::test_runner::TestRunner::deterministic();
    let c = config();
    let mut accepted = 0;
    for _ in 0..512 {
        let text = waypoint_text().new_tree(&mut runner).unwrap().current();
        if let Ok(file) = WaypointFile::parse(&text)
            && let Ok(set) = file.to_set(1)
            && validate(&set, &c.waypoints, &c.activation).is_ok()
        {
            accepted += 1;
        }
    }
    assert!(
        accepted > 20,
        "only {accepted} of 512 generated sets are valid"
    );
}

/// `n` cases, or `PROPTEST_CASES` when set (longer runs by hand).
fn cases(n: u32) -> ProptestConfig {
    let n = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(n);
    ProptestConfig::with_cases(n)
}

fn config() -> &'static Config {
    static C: OnceLock<Config> = OnceLock::new();
    C.get_or_init(|| Config::default_sim(PathBuf::from(".")))
}

proptest! {
    #![proptest_config(cases(512))]

    #[test]
    fn waypoint_files_are_refused_with_a_reason_or_hold_what_the_controller_needs(
        text in waypoint_text(),
        executions in 0u32..20_000,
    ) {
        let c = config();
        let Ok(file) = WaypointFile::parse(&text) else {
            let e = WaypointFile::parse(&text).unwrap_err();
            prop_assert!(!e.is_empty());
            return Ok(());
        };
        let Ok(set) = file.to_set(executions) else { return Ok(()); };
        match validate(&set, &c.waypoints, &c.activation) {
            Err(e) => prop_assert!(!e.is_empty()),
            Ok(()) => {
                let n = set.count as usize;
                prop_assert!((1..=16).contains(&n));
                prop_assert!(set.duration_s.is_finite() && set.duration_s > 0.0);
                prop_assert!(executions >= 1);
                let need = c.activation.window_s + c.activation.crossfade_s;
                for i in 0..n {
                    let t = set.times_s[i];
                    prop_assert!(t.is_finite() && t >= 0.0 && t <= set.duration_s);
                    if i > 0 {
                        prop_assert!(t - set.times_s[i - 1] >= need - 1e-9);
                    }
                    for d in 0..3 {
                        let p = set.positions_m[i][d];
                        prop_assert!(p.is_finite());
                        prop_assert!(p >= c.waypoints.workspace_min_m[d]);
                        prop_assert!(p <= c.waypoints.workspace_max_m[d]);
                    }
                }
            }
        }
    }

    #[test]
    fn arbitrary_text_is_never_a_panic(text in ".{0,400}") {
        let _ = WaypointFile::parse(&text);
        let _ = Config::parse(&text, "fuzz.toml", PathBuf::from("."));
        let _ = Scenario::parse(&text, "fuzz", "fuzz.toml");
    }

    /// The default config with one value replaced: refused at that value's line, or valid.
    #[test]
    fn a_config_with_one_value_changed_is_refused_at_its_line_or_valid(
        line in 0usize..200,
        value in number(),
    ) {
        let lines: Vec<&str> = DEFAULT.lines().collect();
        let i = line % lines.len();
        let Some((key, _)) = lines[i].split_once(" = ") else { return Ok(()); };
        if key.trim_start().starts_with('#') {
            return Ok(());
        }
        let mut text: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
        text[i] = format!("{key} = {value}");
        let text = text.join("\n");
        if let Err(e) = Config::parse(&text, "fuzz.toml", PathBuf::from(".")) {
            let e = e.to_string();
            prop_assert!(e.starts_with("fuzz.toml:"), "{e}");
        }
    }

    #[test]
    fn scenarios_are_refused_with_a_reason_or_apply(
        keys in prop::collection::vec(
            (
                prop::sample::select(vec![
                    "[arm] tool_m", "[arm] actuator_radius_m", "[arm] connector_m",
                    "[arm] actuator_min_m", "[arm] actuator_max_m",
                    "[sim.realism] lag_s", "[sim.realism] backlash",
                    "[sim.realism] tracker_noise_m", "[sim.realism] seed", "[arm] nonsense",
                    "[sim.realism] curvature_taper", "[sim.realism] actuation_noise_correlation_s",
                    "[[step]] at_s", "[step.arm] tool_m", "[step.arm] actuator_radius_m",
                    "[drift] actuator_radius_amplitude_m", "[drift] actuator_radius_period_s",
                ]),
                number(),
            ),
            0..6,
        ),
    ) {
        let mut text = String::new();
        for (k, v) in keys {
            let (section, key) = k.split_once(' ').unwrap();
            text += &format!("{section}\n{key} = {v}\n");
        }
        let c = config();
        match Scenario::parse(&text, "fuzz", "fuzz.toml") {
            Err(e) => prop_assert!(!e.to_string().is_empty()),
            Ok(s) => {
                // Accepted text may still not make a valid arm with the config's: refused, not
                // a panic; and an arm that is accepted gives finite positions.
                // At every time of its changes too: each arm valid, positions finite.
                if let Ok(on) = s.apply_to(&c.arm, &c.sim) {
                    let arms = std::iter::once(&on.arm).chain(on.steps.iter().map(|(_, a)| a));
                    for arm in arms {
                        prop_assert!(arm.validate().is_ok(), "{arm:?}");
                        let arm = pcc::Arm::of_config(arm).unwrap();
                        for t in [0.0, 1.0, 59.5, 1e3, 1e6, 1e9] {
                            // As the sim's plant drifts it: the creep within its bound.
                            let o = MAX_OFFSET_M;
                            let creep = on.sim.drift.creep_m(t).map(|c| c.clamp(-o, o));
                            let now = arm
                                .changed(0.0, 0.0, &creep, &[0.0; MAX_MODULES])
                                .widened(on.sim.drift.radius_change_m(t));
                            let p = ForwardModel::<6>::position(&now, &[0.5; 6]);
                            prop_assert!(p.iter().all(|v| v.is_finite()), "{p:?} at {t} s");
                        }
                    }
                }
            }
        }
    }
}
