//! The layering Cargo enforces, checked on the resolved dependency graph (`cargo metadata`),
//! so that a dependency added in the wrong direction fails here with the rule it breaks,
//! rather than quietly linking iceoryx2 into the method or a driver into the controller.

use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;

use serde_json::Value;

/// The workspace's packages as `cargo metadata` describes them. `--no-deps`: no registry
/// needed, the manifests say it all.
fn packages() -> Vec<Value> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--no-deps"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "cargo metadata: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let m: Value = serde_json::from_slice(&out.stdout).expect("cargo metadata is JSON");
    m["packages"].as_array().unwrap().clone()
}

/// Package name -> the names of its normal (not dev, not build) dependencies, for the
/// workspace's packages; other crates are leaves (what matters here is which of ours links
/// them).
fn graph() -> BTreeMap<String, BTreeSet<String>> {
    packages()
        .iter()
        .map(|p| {
            let normal = p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|d| d["kind"].is_null())
                .map(|d| d["name"].as_str().unwrap().to_string())
                .collect();
            (p["name"].as_str().unwrap().to_string(), normal)
        })
        .collect()
}

/// Everything `package` links, itself excluded.
fn links(g: &BTreeMap<String, BTreeSet<String>>, package: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut todo = vec![package.to_string()];
    while let Some(p) = todo.pop() {
        for d in g.get(&p).into_iter().flatten() {
            if seen.insert(d.clone()) {
                todo.push(d.clone());
            }
        }
    }
    seen
}

#[test]
fn each_crate_links_only_what_its_layer_allows() {
    let g = graph();
    let ours = |set: BTreeSet<String>| -> BTreeSet<String> {
        set.into_iter()
            .filter(|n| n.starts_with("softarm"))
            .collect()
    };
    let forbid = |package: &str, names: &[&str], why: &str| {
        let l = links(&g, package);
        for n in names {
            assert!(!l.contains(*n), "{package} links {n}: {why}");
        }
    };
    assert!(
        ours(links(&g, "softarm-space")).is_empty(),
        "softarm-space is the bottom: it links nothing of ours"
    );
    assert_eq!(
        ours(links(&g, "softarm-ipc")),
        BTreeSet::from(["softarm-space".to_string()]),
        "the contract links nothing of ours but the space types"
    );
    forbid(
        "softarm-method",
        &[
            "iceoryx2",
            "softarm-ipc",
            "softarm-runtime",
            "softarm-config",
        ],
        "the method is pure math",
    );
    forbid(
        "softarm-method",
        &["softarm-learning"],
        "the method lies beneath the learning code",
    );
    forbid(
        "softarm-learning",
        &[
            "iceoryx2",
            "softarm-ipc",
            "softarm-runtime",
            "softarm-config",
        ],
        "the learning code is pure math",
    );
    forbid(
        "softarm-identify",
        &[
            "iceoryx2",
            "softarm-ipc",
            "softarm-config",
            "softarm-method",
            "softarm-learning",
            "softarm-model",
        ],
        "identifying an arm from a recording is offline: it reads files and the arm's \
         description, and links neither the stack's services nor its real-time math",
    );
    forbid(
        "softarm-config",
        &["softarm-learning", "softarm-model"],
        "every process reads the config: it links no learning code and no pipeline",
    );
    // The math, the simulator and the learning take their settings from the config's sections
    // (softarm-sections, plain data beneath the config), never the reverse.
    let math = [
        "softarm-method",
        "softarm-kinematics",
        "softarm-sim",
        "softarm-learning",
        "softarm-model",
    ];
    forbid(
        "softarm-config",
        &math,
        "the config is plain data and its checks: every process, the drivers too, reads it \
         without linking the method, the kinematics, the simulator, the learning or the pipeline",
    );
    forbid(
        "softarm-sections",
        &[
            &math[..],
            &[
                "iceoryx2",
                "softarm-ipc",
                "softarm-runtime",
                "softarm-config",
            ],
        ]
        .concat(),
        "the config's sections are plain data beneath the config and the math: they link \
         nothing but the space types",
    );
    for d in ["softarm-tendon", "softarm-tracker"] {
        forbid(
            d,
            &math,
            "a hardware driver needs its config, not the method, the kinematics, the simulator, \
             the learning or the pipeline",
        );
    }
    forbid(
        "softarm-method",
        &["softarm-sim"],
        "the method is the controller's real-time math: the simulated plant is the sim's",
    );
    forbid(
        "softarm-kinematics",
        &["softarm-method"],
        "the kinematics and forward models lie beneath the method (its demonstrations play \
         through a forward model), never the reverse",
    );
    forbid(
        "softarm-kinematics",
        &[
            "iceoryx2",
            "softarm-ipc",
            "softarm-runtime",
            "softarm-config",
            "softarm-learning",
        ],
        "the kinematics are pure math",
    );
    forbid(
        "softarm-model",
        &["iceoryx2", "softarm-config"],
        "the model pipeline takes its settings, it reads no config and speaks no iceoryx2",
    );
    let drivers = [
        "softarm-driver",
        "softarm-sim",
        "softarm-mujoco",
        "softarm-tendon",
        "softarm-tracker",
    ];
    forbid(
        "softarm-controller",
        &[&drivers[..], &["softarm-emulate", "softarm-learner"]].concat(),
        "the controller sees the arm and the learner only through services",
    );
    forbid(
        "softarm-learner",
        &[&drivers[..], &["softarm-controller"]].concat(),
        "the learner sees the controller only through services",
    );
    for d in drivers {
        forbid(
            d,
            &[
                "softarm-learning",
                "softarm-model",
                "safetensors",
                "softarm-controller",
                "softarm-learner",
            ],
            "a driver links neither the learning code, the model pipeline nor another process",
        );
    }
    forbid(
        "softarm-clients",
        &[
            "plotters",
            "mcap",
            "softarm-model",
            "softarm-learning",
            "softarm-train",
            "softarm-watch",
        ],
        "the commands that talk to a running stack (submit, stats, status, estop) link no \
         plotting, no recording, no training pipeline and no learning code",
    );
    forbid(
        "softarm-channels",
        &["plotters", "mcap", "softarm-model", "softarm-learning"],
        "the channels and the scene, what the view and the recorder share, are drawn from the \
         samples alone: no plotting, no file format, no pipeline, no learning code",
    );
    forbid(
        "softarm-record",
        &["softarm-model", "softarm-learning", "softarm-train"],
        "recording and plotting read samples and files: no pipeline and no learning code",
    );
    // The view and the bridge run beside the stack for hours: neither the recorder's plotting
    // nor the pipeline and learner (CACLA) come with them.
    let tools = [
        "plotters",
        "mcap",
        "softarm-record",
        "softarm-train",
        "softarm-model",
        "softarm-learning",
        "softarm-watch",
    ];
    forbid(
        "softarm-view",
        &[
            &drivers[..],
            &["softarm-emulate", "softarm-controller", "softarm-learner"],
            &["softarm-stack"],
        ]
        .concat(),
        "the view is one more subscriber: it sees the stack only through its services",
    );
    forbid(
        "softarm-view",
        &tools,
        "the view serves the channels and the scene: it links no plotting, recording, pipeline, \
         learning code nor test kit",
    );
    forbid(
        "softarm-ros2",
        &[
            &drivers[..],
            &["softarm-emulate", "softarm-controller", "softarm-learner"],
            &["softarm-stack", "softarm-view"],
        ]
        .concat(),
        "the ROS 2 bridge is one more subscriber and client: it sees the stack only through its \
         services, as `softarm submit` and `softarm estop` do",
    );
    forbid(
        "softarm-ros2",
        &tools,
        "the ROS 2 bridge needs the channels, submit and estop: it links no plotting, recording, \
         pipeline, learning code nor test kit",
    );
    // The stack (demo), the binary and what runs the stack's sandbox (the rig's soak and
    // bench, the tests' harness) are the only ones above these.
    let above = [
        "softarm",
        "softarm-stack",
        "softarm-rig",
        "softarm-test-support",
    ];
    for p in g
        .keys()
        .filter(|p| !above.contains(&p.as_str()) && p.as_str() != "softarm-record")
    {
        forbid(
            p,
            &["softarm-record", "plotters", "mcap"],
            "only `softarm record`, `replay`, `plot` and demo write recordings and draw figures",
        );
    }
    // The test kit: what checks, emulates or rehearses the product. Only the root package
    // (its `softarm-rig` binary, through the `rig` feature,
    // [`the_test_kit_comes_into_the_binary_through_its_rig_feature_alone`]) and the kit itself
    // link it.
    let kit = [
        "softarm-rig",
        "softarm-emulate",
        "softarm-watch",
        "softarm-rehearsal",
        "softarm-test-support",
        "softarm-test-alloc",
        "dynamixel2",
    ];
    for p in g
        .keys()
        .filter(|p| p.as_str() != "softarm" && !kit.contains(&p.as_str()))
    {
        forbid(
            p,
            &kit,
            "the test kit (emulators, the safety watch, soak and bench, the rehearsal, the \
             harness) is apart from the product: no process, driver, client nor library of \
             the product links it",
        );
    }
    for p in g
        .keys()
        .filter(|p| !["softarm", "softarm-view"].contains(&p.as_str()))
    {
        forbid(
            p,
            &["softarm-view"],
            "only the binary starts the view: no process nor client links its server",
        );
    }
    for p in g
        .keys()
        .filter(|p| !["softarm", "softarm-ros2"].contains(&p.as_str()))
    {
        forbid(
            p,
            &["softarm-ros2", "ros2-client"],
            "only the binary starts the ROS 2 bridge: no process nor client links DDS",
        );
    }
}

/// The workspace's top folders, bottom to top, each with the folders beneath it whose crates its
/// crates may link (besides their own folder's). Crate `softarm-NAME` lives in `LAYER/NAME/`
/// (ARCHITECTURE §1 says what each holds). The drivers link no model, and no client or process
/// links a driver: they meet through services alone.
const LAYERS: [(&str, &[&str]); 10] = [
    ("contract", &[]),
    ("config", &["contract"]),
    ("math", &["contract", "config"]),
    ("models", &["contract", "config", "math"]),
    ("drivers", &["contract", "config", "math"]),
    ("clients", &["contract", "config", "math", "models"]),
    (
        "processes",
        &["contract", "config", "math", "models", "clients"],
    ),
    ("systemd", &["contract", "config"]),
    (
        "rig",
        &[
            "contract",
            "config",
            "math",
            "models",
            "drivers",
            "clients",
            "processes",
        ],
    ),
    (
        "tests",
        &[
            "contract",
            "config",
            "math",
            "models",
            "drivers",
            "clients",
            "processes",
            "rig",
        ],
    ),
];

/// The packages whose folder is a top folder of their own: the root package (the repository's
/// root, its code in `src/`) and systemd (`softarm install`, beside the units it installs).
const OWN_FOLDER: [(&str, &str); 2] = [("softarm", "./"), ("softarm-systemd", "systemd/")];

/// Package name -> its folder from the repository's root as the crate table writes it:
/// `LAYER/NAME/`, `./` for the root package.
fn folders() -> BTreeMap<String, String> {
    let packages = packages();
    let manifest_dir = |p: &Value| {
        std::path::PathBuf::from(p["manifest_path"].as_str().unwrap())
            .parent()
            .unwrap()
            .to_path_buf()
    };
    let root = manifest_dir(
        packages
            .iter()
            .find(|p| p["name"] == "softarm")
            .expect("the root package"),
    );
    packages
        .iter()
        .map(|p| {
            let dir = manifest_dir(p);
            let dir = dir.strip_prefix(&root).unwrap().to_str().unwrap();
            let folder = if dir.is_empty() {
                "./".to_string()
            } else {
                format!("{dir}/")
            };
            (p["name"].as_str().unwrap().to_string(), folder)
        })
        .collect()
}

/// A folder names a layer, so that the folders alone draw the layering: crate `softarm-NAME`
/// lives in `LAYER/NAME/` (LAYER one of [`LAYERS`]' folders; `softarm-test-NAME` in
/// `tests/NAME/`), none inside another's folder, and it links only crates of its own folder and
/// of the folders beneath it.
#[test]
fn each_crate_lives_in_its_layers_folder() {
    let folders = folders();
    let layers: Vec<&str> = LAYERS.iter().map(|(l, _)| *l).collect();
    let mut wrong = Vec::new();
    for (name, folder) in &folders {
        let short = name.strip_prefix("softarm-").unwrap_or(name);
        let placed = match OWN_FOLDER.iter().find(|(n, _)| n == name) {
            Some((_, own)) => folder == own,
            // The end-to-end tests' own crates are `softarm-test-NAME`, in `tests/NAME/`.
            None => layers.iter().any(|l| {
                let short = if *l == "tests" {
                    short.strip_prefix("test-")
                } else {
                    Some(short)
                };
                short.is_some_and(|s| *folder == format!("{l}/{s}/"))
            }),
        };
        if !placed {
            wrong.push(format!(
                "{name} is in {folder}: a crate softarm-NAME lives in LAYER/NAME/, LAYER the folder \
                 of its layer, one of {} (bottom to top; ARCHITECTURE §1 says what each holds); \
                 the end-to-end tests' softarm-test-NAME in tests/NAME/",
                layers.join("/, ") + "/"
            ));
        }
        for (other, inner) in &folders {
            if other != name && folder != "./" && inner.starts_with(folder.as_str()) {
                wrong.push(format!(
                    "{other} is in {inner}, inside {name}'s folder: crates do not nest"
                ));
            }
        }
    }
    let layer = |name: &str| folders[name].split('/').next().unwrap().to_string();
    for (name, deps) in graph() {
        let Some((mine, beneath)) = LAYERS.iter().find(|(l, _)| *l == layer(&name)) else {
            continue; // the root package: it links what its commands need
        };
        for d in deps.iter().filter(|d| folders.contains_key(*d)) {
            let theirs = layer(d);
            if theirs != *mine && !beneath.contains(&theirs.as_str()) {
                wrong.push(format!(
                    "{name} ({mine}/) links {d} ({theirs}/): a crate of {mine}/ links only crates \
                     of {mine}/ and of {}",
                    if beneath.is_empty() {
                        "nothing beneath it".to_string()
                    } else {
                        beneath.join("/, ") + "/"
                    }
                ));
            }
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

/// A cell of "links (ours, directly)": the names of `a, b, c`, none for `nothing`, sorted.
fn link_names(cell: &str) -> Vec<String> {
    let mut names: Vec<String> = if cell.trim() == "nothing" {
        Vec::new()
    } else {
        cell.split(',').map(|n| n.trim().to_string()).collect()
    };
    names.sort();
    names
}

/// ARCHITECTURE §1's crate table says what the manifests say: a row per package; its folder;
/// its links: its direct normal (not dev, not build) dependencies on the workspace's crates,
/// named without `softarm-` (`nothing` for none), and after them, for each feature that enables
/// some of its optional ones, `; with `FEATURE` (a note): a, b`.
#[test]
fn the_crate_table_says_what_the_manifests_do() {
    let doc = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/ARCHITECTURE.md");
    let text = std::fs::read_to_string(doc).unwrap();
    let header = "| crate | folder | what it does | links (ours, directly) |";
    let mut rows: BTreeMap<String, (String, String)> = BTreeMap::new();
    let mut wrong = Vec::new();
    let lines = text
        .lines()
        .skip_while(|l| *l != header)
        .skip(2)
        .take_while(|l| l.starts_with("| `"));
    for line in lines {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        let (name, folder, links) = (cells[1], cells[2], cells[cells.len() - 2]);
        let name = name.trim_matches('`').to_string();
        let row = (folder.trim_matches('`').to_string(), links.to_string());
        if rows.insert(name.clone(), row).is_some() {
            wrong.push(format!("{name} has two rows"));
        }
    }
    assert!(
        rows.len() > 10,
        "no crate table in {doc} (its header: {header})"
    );
    let folders = folders();
    let short = |n: &str| n.strip_prefix("softarm-").unwrap_or(n).to_string();
    for p in packages() {
        let name = p["name"].as_str().unwrap();
        let Some((folder, links)) = rows.remove(name) else {
            wrong.push(format!("{name} has no row"));
            continue;
        };
        if folder != folders[name] {
            wrong.push(format!(
                "{name}: the table says its folder is {folder}, it is {}",
                folders[name]
            ));
        }
        let ours: Vec<&Value> = p["dependencies"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|d| d["kind"].is_null() && folders.contains_key(d["name"].as_str().unwrap()))
            .collect();
        let mut always: Vec<String> = ours
            .iter()
            .filter(|d| d["optional"] != true)
            .map(|d| short(d["name"].as_str().unwrap()))
            .collect();
        always.sort();
        let mut by_feature = BTreeMap::new();
        for (feature, enables) in p["features"].as_object().unwrap() {
            let mut deps: Vec<String> = ours
                .iter()
                .filter(|d| d["optional"] == true)
                .map(|d| d["name"].as_str().unwrap())
                .filter(|d| {
                    enables
                        .as_array()
                        .unwrap()
                        .contains(&format!("dep:{d}").into())
                })
                .map(short)
                .collect();
            deps.sort();
            if !deps.is_empty() {
                by_feature.insert(feature.clone(), deps);
            }
        }
        let mut parts = links.split("; with `");
        let said = link_names(parts.next().unwrap());
        let said_by_feature: BTreeMap<String, Vec<String>> = parts
            .map(|part| {
                let (feature, rest) = part.split_once('`').unwrap_or((part, ""));
                let list = rest.split_once(": ").map_or("", |(_, l)| l);
                (feature.to_string(), link_names(list))
            })
            .collect();
        if said != always || said_by_feature != by_feature {
            wrong.push(format!(
                "{name}: the table says it links {said:?}, with features {said_by_feature:?}; \
                 its manifest {always:?}, with features {by_feature:?}"
            ));
        }
    }
    for name in rows.keys() {
        wrong.push(format!(
            "{name} has a row, and the workspace no such package"
        ));
    }
    assert!(
        wrong.is_empty(),
        "{doc}, §1's crate table:\n{}",
        wrong.join("\n")
    );
}

/// The root package's dependencies on the test kit's commands (`softarm-rig emulate`, `soak`,
/// `bench`) are optional and enabled by its `rig` feature alone, which the `softarm-rig`
/// binary requires: `--no-default-features` builds the product without them.
#[test]
fn the_test_kit_comes_into_the_binary_through_its_rig_feature_alone() {
    let root = packages()
        .into_iter()
        .find(|p| p["name"] == "softarm")
        .expect("the root package");
    let required = |name: &str| {
        let target = root["targets"]
            .as_array()
            .unwrap()
            .iter()
            .find(|t| t["name"] == name)
            .unwrap_or_else(|| panic!("no target {name}"));
        target["required-features"].clone()
    };
    assert_eq!(required("softarm-rig"), serde_json::json!(["rig"]));
    assert!(
        required("softarm").is_null(),
        "the product needs no feature"
    );
    let kit = ["softarm-rig", "softarm-emulate"];
    for d in root["dependencies"].as_array().unwrap() {
        let name = d["name"].as_str().unwrap();
        if d["kind"].is_null() && kit.contains(&name) {
            assert_eq!(
                d["optional"], true,
                "softarm links {name} whatever its features"
            );
        }
    }
    let features = &root["features"];
    for (feature, enables) in features.as_object().unwrap() {
        for k in kit {
            let dep = format!("dep:{k}");
            let on = enables.as_array().unwrap().iter().any(|e| e == &dep);
            assert_eq!(
                on,
                feature == "rig",
                "the feature {feature} {} {k}",
                if on { "enables" } else { "does not enable" }
            );
        }
    }
    assert_eq!(features["default"], serde_json::json!(["rig"]));
}

/// What `softarm install` installs, the `softarm` binary, is the product alone whatever the
/// features it was built with (the `rig` feature builds `softarm-rig` beside it): none of the
/// test kit's code is in it. Its symbols name every crate whose code it has.
#[test]
fn the_installed_binary_has_none_of_the_test_kit() {
    let product = std::fs::read(env!("CARGO_BIN_EXE_softarm")).unwrap();
    let rig = std::fs::read(env!("CARGO_BIN_EXE_softarm-rig")).unwrap();
    let has = |binary: &[u8], name: &str| {
        let name = name.as_bytes();
        (0..binary.len()).any(|i| binary[i] == name[0] && binary[i..].starts_with(name))
    };
    for kit in [
        "softarm_rig",
        "softarm_emulate",
        "softarm_watch",
        "dynamixel2",
    ] {
        // The check can see it: the rig's binary has each (the watch through soak).
        assert!(
            has(&rig, kit),
            "softarm-rig has no {kit}: the check sees nothing"
        );
        assert!(!has(&product, kit), "the product binary has {kit}");
    }
}

/// `ros2-client` without its defaults: the DDS backend alone (no zenoh, no mio integration),
/// and only in the bridge.
#[test]
fn ros2_client_comes_with_dds_alone_and_only_in_the_bridge() {
    for p in packages() {
        let name = p["name"].as_str().unwrap();
        for d in p["dependencies"].as_array().unwrap() {
            if d["name"] != "ros2-client" {
                continue;
            }
            assert_eq!(name, "softarm-ros2", "{name} links ros2-client");
            assert_eq!(d["uses_default_features"], false, "{name}: {d}");
            let features = d["features"].to_string();
            assert!(
                features.contains("\"dds\"") && !features.contains("zenoh"),
                "{name}: ros2-client features {features}"
            );
        }
    }
}

/// The `foxglove` crate's defaults build a TLS backend (aws-lc-rs, which needs cmake): every
/// crate names only the features it needs, and only the view serves the network.
#[test]
fn foxglove_comes_without_tls_and_only_the_view_serves() {
    for p in packages() {
        let name = p["name"].as_str().unwrap();
        for d in p["dependencies"].as_array().unwrap() {
            if d["name"] != "foxglove" {
                continue;
            }
            assert_eq!(
                d["uses_default_features"], false,
                "{name} takes foxglove's default features (TLS with aws-lc-rs, cmake)"
            );
            let features = d["features"].to_string();
            assert!(
                !features.contains("tls") && !features.contains("remote-access"),
                "{name}: foxglove features {features}"
            );
            assert!(
                name == "softarm-view" || !features.contains("websocket"),
                "{name} links foxglove's WebSocket server: only softarm-view serves"
            );
        }
    }
}

/// A crate's modules named by what `path` (a crate root, `src/lib.rs` or `src/main.rs`)
/// declares beside it: module name -> the crate's other modules its code (tests left out) uses
/// through `crate::`.
fn module_uses(root: &std::path::Path) -> BTreeMap<String, BTreeSet<String>> {
    let dir = root.parent().unwrap();
    let files: Vec<(String, std::path::PathBuf)> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| {
            let path = e.unwrap().path();
            let name = path.file_stem()?.to_str()?.to_string();
            let file = if path.is_dir() {
                path.join("mod.rs")
            } else {
                path.clone()
            };
            (file.extension()? == "rs" && file.exists() && path != root).then_some((name, file))
        })
        .collect();
    let names: BTreeSet<&str> = files.iter().map(|(n, _)| n.as_str()).collect();
    files
        .iter()
        .map(|(name, file)| {
            let text = std::fs::read_to_string(file).unwrap();
            // Code only: no tests, no comments (a doc link is no use).
            let code: String = text
                .split("#[cfg(test)]")
                .next()
                .unwrap()
                .lines()
                .filter(|l| !l.trim_start().starts_with("//"))
                .collect::<Vec<_>>()
                .join("\n");
            let uses = code
                .match_indices("crate::")
                .filter_map(|(i, _)| {
                    let rest = &code[i + "crate::".len()..];
                    let used: String = rest
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || *c == '_')
                        .collect();
                    (used != *name && names.contains(used.as_str())).then_some(used)
                })
                .collect();
            (name.clone(), uses)
        })
        .collect()
}

/// Within a crate, no module uses one that uses it back: each module's job stands on the ones
/// below it, so a fix lands in one place and the modules read bottom up.
#[test]
fn no_module_uses_one_that_uses_it_back() {
    let mut circles = Vec::new();
    for p in packages() {
        for t in p["targets"].as_array().unwrap() {
            let kinds = t["kind"].as_array().unwrap();
            if !kinds.iter().any(|k| k == "lib" || k == "bin") {
                continue;
            }
            let root = std::path::PathBuf::from(t["src_path"].as_str().unwrap());
            if !matches!(
                root.file_name().and_then(|f| f.to_str()),
                Some("lib.rs" | "main.rs")
            ) {
                continue;
            }
            let uses = module_uses(&root);
            for m in uses.keys() {
                if links(&uses, m).contains(m) {
                    circles.push(format!("{}: {m}", p["name"].as_str().unwrap()));
                }
            }
        }
    }
    assert!(
        circles.is_empty(),
        "modules that use themselves through others (move what both need below both): {circles:?}"
    );
}
