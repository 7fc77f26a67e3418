//! Killed mid-write, a bundle or checkpoint is the last complete one, never a mix: a child
//! process (this test binary, re-run as the writer) rewrites a bundle as fast as it can through
//! `bundle::write`, which every model bundle and learner checkpoint goes through, and is
//! SIGKILLed at seeded random moments; after each kill the folder must read back whole, its
//! tensors the ones its metadata names.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};
use softarm_model::bundle::{self, Tensors};

/// The writer's folder, when this binary runs as the writer.
const WRITER_DIR: &str = "SOFTARM_TEST_WRITER_DIR";
/// Values per tensor: 8 MB a write, so a kill lands inside one often.
const VALUES: usize = 1 << 20;

#[derive(Serialize, Deserialize)]
struct Meta {
    generation: u64,
}

fn write_generation(dir: &Path, generation: u64) {
    let mut t = Tensors::default();
    t.put_f64("values", &[VALUES], &vec![generation as f64; VALUES]);
    bundle::write(dir, "bundle", &Meta { generation }, &t).unwrap();
}

/// Runs only as the child: rewrites the bundle until killed.
#[test]
fn writer() {
    let Some(dir) = std::env::var_os(WRITER_DIR) else {
        return;
    };
    let dir = PathBuf::from(dir);
    let mut generation =
        bundle::read::<Meta>(&dir, "bundle", "test bundle").map_or(0, |(m, _, _)| m.generation);
    loop {
        generation += 1;
        write_generation(&dir, generation);
    }
}

#[test]
fn a_bundle_killed_mid_write_reads_back_whole() {
    let dir = std::env::temp_dir().join(format!("softarm-kill-write-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    write_generation(&dir, 0);
    let seed = 12;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut last = 0;
    let mut advanced = 0;
    for kill in 0..20 {
        let mut child = Command::new(std::env::current_exe().unwrap())
            .args(["--exact", "writer", "--nocapture", "--test-threads=1"])
            .env(WRITER_DIR, &dir)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(rng.random_range(20..300)));
        child.kill().unwrap();
        child.wait().unwrap();
        let (meta, t, _) = bundle::read::<Meta>(&dir, "bundle", "test bundle")
            .unwrap_or_else(|e| panic!("kill {kill} (seed {seed}): {e}"));
        let (_, values) = t.f64s("values", &[Some(VALUES)]).unwrap();
        assert!(
            values.iter().all(|&v| v == meta.generation as f64),
            "kill {kill} (seed {seed}): the tensors are not generation {}'s",
            meta.generation
        );
        assert!(
            meta.generation >= last,
            "went back from {last} to {}",
            meta.generation
        );
        advanced += usize::from(meta.generation > last);
        last = meta.generation;
    }
    // The writers did write (on a loaded machine, not every one gets far).
    assert!(advanced > 0, "the writer never completed a bundle");
    // The next complete write clears what the killed ones left half-done.
    write_generation(&dir, last + 1);
    let mut files: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    files.sort();
    assert_eq!(files.len(), 2, "left behind: {files:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}
