//! `softarm-rig emulate`: the real arm's two devices, emulated on pseudo-terminals and coupled
//! through the arm's model, so the hardware stack (`tendon` + `tracker`) runs without hardware.
//! Prints the device paths and, with `--write-config`, writes a copy of the config pointing at
//! them, ready for `softarm up`.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use crate::rig::Rig;
use anyhow::Context;
use softarm_config::{Config, ConfigError};
use softarm_sim::plant::Physics;

#[derive(clap::Args)]
pub struct Args {
    /// The hardware config whose `[tendon]` and `[tracker]` to emulate.
    #[arg(long)]
    config: PathBuf,
    /// Writes the config here with the devices' paths (and absolute model and state folders).
    #[arg(long, value_name = "FILE")]
    write_config: Option<PathBuf>,
    /// Where the motors stand at start (normalised actuation).
    #[arg(long, default_value_t = 0.5, allow_negative_numbers = true)]
    initial: f64,
    /// A noisy motor bus: each byte of a status packet is replaced with this probability
    /// (0.02 = 2 %).
    #[arg(
        long,
        value_name = "RATE",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    corrupt_bytes: f64,
    /// A lossy motor bus: each status packet is lost with this probability (0.02 = 2 %).
    #[arg(
        long,
        value_name = "RATE",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    drop_replies: f64,
    /// Seeds the motor bus's fault draws, so a noisy run can be repeated.
    #[arg(long, value_name = "N", default_value_t = 1)]
    fault_seed: u64,
}

/// A probability given on the command line, in parts per million; `flag` names it in the error.
/// Warns of the kernel's pty stalls that ended since the first `said`; returns how many ended.
fn say_stalls(rig: &Rig, said: usize) -> usize {
    let ended = rig.canary.ended();
    for s in ended.iter().skip(said) {
        tracing::warn!(
            held_ms = (s.to_ns - s.from_ns) / 1_000_000,
            "the kernel held the pseudo-terminals (the machine is loaded): what the drivers \
             saw meanwhile is the computer's doing, not the bus's"
        );
    }
    ended.len()
}

fn ppm(flag: &str, rate: f64) -> anyhow::Result<u32> {
    if !(0.0..=1.0).contains(&rate) {
        anyhow::bail!("--{flag} must be a probability in [0, 1], got {rate}");
    }
    Ok((rate * 1e6).round() as u32)
}

fn text_of(p: &Path) -> String {
    p.display().to_string()
}

/// `text` with the emulated devices as ports and the folders made absolute, so the copy works
/// from wherever it is written.
fn emulated_config(text: &str, c: &Config, rig: &Rig) -> anyhow::Result<String> {
    let absolute = |p: PathBuf| std::path::absolute(&p).unwrap_or(p);
    let extra = (rig.tendon_paths().iter().enumerate().skip(1))
        .map(|(k, p)| (format!("tendon.extra_bus[{}].port", k - 1), text_of(p)));
    let overrides: Vec<_> = [
        ("tendon.port".to_string(), text_of(rig.tendon_path())),
        ("tracker.port".to_string(), text_of(rig.tracker_path())),
        ("model.dir".to_string(), text_of(&absolute(c.model_dir()))),
        ("state.dir".to_string(), text_of(&absolute(c.state_dir()))),
    ]
    .into_iter()
    .chain(extra)
    .collect();
    let overrides: Vec<softarm_config::Override> = (overrides.iter())
        .map(|(k, v)| (k.as_str(), v.as_str().into()))
        .collect();
    softarm_config::with_overrides(text, &overrides).map_err(anyhow::Error::msg)
}

/// Refuses, before the emulators start, a `--write-config` path the copy cannot go to, or that
/// is the config itself (the emulators' paths would replace the real devices').
fn check_write_config(out: &Path, config: &Path) -> anyhow::Result<()> {
    if out.is_dir() {
        anyhow::bail!("--write-config {}: it is a directory", out.display());
    }
    if let (Ok(a), Ok(b)) = (out.canonicalize(), config.canonicalize())
        && a == b
    {
        anyhow::bail!(
            "--write-config {} is the --config it would copy: the emulated devices' paths would \
             replace the real ones; write the copy to another file",
            out.display()
        );
    }
    // Missing folders are created; a file on the way is not a folder.
    if let Some(file) = out.ancestors().skip(1).find(|a| a.exists() && !a.is_dir()) {
        anyhow::bail!(
            "--write-config {}: {} is not a folder",
            out.display(),
            file.display()
        );
    }
    Ok(())
}

/// What gives the physics a config's `[sim.mujoco]` describes, if it describes one (the binary:
/// MuJoCo when built with it).
pub type PhysicsOf = dyn Fn(&Config) -> anyhow::Result<Option<Box<dyn Physics>>>;

/// Runs the emulators of `args.config`'s devices until `stop`; `physics_of` gives the physics
/// its `[sim.mujoco]` describes, if it describes one, which the motors then drive.
pub fn run(args: &Args, stop: &AtomicBool, physics_of: &PhysicsOf) -> anyhow::Result<()> {
    let c = Config::load(&args.config)?;
    // Refused as the drivers refuse it (exit 78): starting again cannot help.
    for (section, there) in [
        ("tendon", c.tendon.is_some()),
        ("tracker", c.tracker.is_some()),
    ] {
        if !there {
            return Err(ConfigError {
                origin: args.config.display().to_string(),
                line: None,
                message: format!(
                    "no [{section}] section to emulate (config/hardware.toml has an example)"
                ),
            }
            .into());
        }
    }
    if !(0.0..=1.0).contains(&args.initial) {
        anyhow::bail!("--initial must be in [0, 1], got {}", args.initial);
    }
    let faults = crate::dynamixel::BusFaults {
        corrupt_byte_ppm: ppm("corrupt-bytes", args.corrupt_bytes)?,
        drop_reply_ppm: ppm("drop-replies", args.drop_replies)?,
        ..Default::default()
    };
    if let Some(out) = &args.write_config {
        check_write_config(out, &args.config)?;
    }
    let text = std::fs::read_to_string(&args.config)
        .with_context(|| format!("reading {}", args.config.display()))?;
    let rig = Rig::start_with(&c, args.initial, physics_of(&c)?)?;
    for bus in &rig.buses {
        if let Ok(mut bus) = bus.lock() {
            bus.set_fault_seed(args.fault_seed);
            bus.set_faults(faults);
        }
    }
    if faults != crate::dynamixel::BusFaults::default() {
        println!(
            "motor bus noise: {} of the status bytes replaced, {} of the status packets lost \
             (seed {})",
            args.corrupt_bytes, args.drop_replies, args.fault_seed
        );
    }
    println!(
        "tendon motors (Dynamixel 2.0): {}",
        rig.tendon_path().display()
    );
    for (k, p) in rig.tendon_paths().iter().enumerate().skip(1) {
        println!("  extra_bus[{}]:                {}", k - 1, p.display());
    }
    println!(
        "tracker (Bird protocol):       {}",
        rig.tracker_path().display()
    );
    match &args.write_config {
        Some(out) => {
            let emulated = emulated_config(&text, &c, &rig)?;
            softarm_runtime::file::write_atomic(out, emulated.as_bytes(), None)
                .with_context(|| format!("writing {}", out.display()))?;
            println!("config:  {}", out.display());
            println!("run:     softarm up --config {}", out.display());
        }
        None => println!(
            "point tendon.port and tracker.port of a copy of {} at these, or rerun with \
             --write-config FILE",
            args.config.display()
        ),
    }
    println!("Ctrl-C stops the emulators");
    let mut stalls_said = 0;
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(Duration::from_millis(50));
        stalls_said = say_stalls(&rig, stalls_said);
    }
    let records = rig.tracker_counts.records.load(Ordering::Relaxed);
    let counters = rig.bus.lock().map(|b| b.counters()).ok();
    rig.stop().context("an emulator failed")?;
    eprintln!("softarm-rig emulate: {records} tracker records sent; motor bus {counters:?}");
    Ok(())
}
