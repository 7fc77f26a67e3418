//! Property-based fuzzing of what this crate reads from disk: model bundles. Whatever the
//! bytes, nothing panics, and a damaged bundle is refused whole, never half-loaded.
//! `cargo test -p softarm-model --test fuzz` runs a bounded number of cases (CI);
//! `PROPTEST_CASES=10000 cargo test --release -p softarm-model --test fuzz` runs longer.

use std::sync::OnceLock;

use proptest::prelude::*;
use softarm_model::bundle::Model;
use softarm_test_support::quick_model;

/// The actuators of the default `[arm]`, which [`quick_model`] is made for.
const N: usize = 6;

/// `n` cases, or `PROPTEST_CASES` when set (longer runs by hand).
fn cases(n: u32) -> ProptestConfig {
    let n = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(n);
    ProptestConfig::with_cases(n)
}

/// The files of a model bundle written once for the bundle cases: (name, bytes).
fn bundle() -> &'static Vec<(String, Vec<u8>)> {
    static B: OnceLock<Vec<(String, Vec<u8>)>> = OnceLock::new();
    B.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("softarm-fuzz-bundle-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        quick_model(&dir);
        let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| {
                let e = e.unwrap();
                (
                    e.file_name().to_string_lossy().to_string(),
                    std::fs::read(e.path()).unwrap(),
                )
            })
            .collect();
        files.sort();
        let _ = std::fs::remove_dir_all(&dir);
        files
    })
}

proptest! {
    #![proptest_config(cases(64))]

    /// Truncated, overwritten or extended files of a bundle are refused whole, never a panic
    /// and never half-loaded.
    #[test]
    fn a_damaged_bundle_is_refused(
        which in 0usize..2,
        at in 0.0f64..1.0,
        bytes in prop::collection::vec(any::<u8>(), 0..16),
        truncate in any::<bool>(),
        case in 0u32..1_000_000,
    ) {
        let files = bundle();
        let dir = std::env::temp_dir().join(format!(
            "softarm-fuzz-damaged-{}-{case}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut changed = false;
        for (i, (name, data)) in files.iter().enumerate() {
            let mut data = data.clone();
            if i == which % files.len() {
                let pos = ((data.len() as f64) * at) as usize;
                let before = data.clone();
                if truncate {
                    data.truncate(pos);
                } else {
                    for (k, b) in bytes.iter().enumerate() {
                        match data.get_mut(pos + k) {
                            Some(x) => *x = *b,
                            None => data.push(*b),
                        }
                    }
                }
                changed = data != before;
            }
            std::fs::write(dir.join(name), &data).unwrap();
        }
        let read = Model::<N>::read(&dir);
        let _ = std::fs::remove_dir_all(&dir);
        if changed {
            // A change in the TOML's comments or whitespace could be harmless; one in the
            // tensors never is (the hash).
            let tensors = files[which % files.len()].0.ends_with(".safetensors");
            if tensors {
                prop_assert!(read.is_err(), "a damaged tensor file was accepted");
            }
            if let Err(e) = read {
                prop_assert!(!e.to_string().is_empty());
            }
        } else {
            prop_assert!(read.is_ok(), "{:?}", read.err());
        }
    }
}
