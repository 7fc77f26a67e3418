//! `softarm estop [--reset]`: engages or releases the e-stop. The running controller and
//! drivers hear it on the `estop` service; the latch file (`<state.dir>/estop`) keeps it for
//! every process that starts later, so it stays engaged until an explicit reset, whoever sent
//! it and whatever restarted since.

use std::time::Duration;

use anyhow::{Context, anyhow};

use softarm_ipc::{EstopState, Namespace, Node};
use softarm_runtime::{EstopLatch, now_ns};

/// Engages (`engaged`) or releases the e-stop; the number of processes that heard it.
///
/// Engaging publishes first (the arm stops at once), then latches on disk; should the latch
/// fail, the running processes are stopped all the same and the error says what a restart
/// would miss. Releasing writes the latch first and publishes only once it is written, so no
/// process can be released while a restarted one would still find it engaged.
pub fn send(namespace: &Namespace, latch: &EstopLatch, engaged: bool) -> anyhow::Result<usize> {
    if engaged {
        let receivers = publish(namespace, true)?;
        latch.set(true).with_context(|| {
            format!(
                "the e-stop reached {receivers} running processes, but a process started from \
                 now on would not know: fix the folder's permissions and send it again"
            )
        })?;
        Ok(receivers)
    } else {
        latch
            .set(false)
            .context("the e-stop stays engaged: its latch could not be released")?;
        publish(namespace, false)
    }
}

fn publish(namespace: &Namespace, engaged: bool) -> anyhow::Result<usize> {
    let ipc = Node::open(namespace.clone(), "estop")?;
    let publisher = ipc.publisher(&ipc.estop()?)?;
    let receivers = publisher
        .send_copy(EstopState {
            seq: now_ns(),
            stamp_ns: now_ns(),
            engaged: engaged as u32,
            _pad: 0,
        })
        .map_err(|e| anyhow!("{e:?}"))
        .context("sending the e-stop")?;
    // Subscribers poll every tick; give them a moment before this node (and its sample) goes.
    std::thread::sleep(Duration::from_millis(200));
    Ok(receivers)
}

/// `softarm estop [--reset]` for the stack of `config`: sends, then says who heard it.
pub fn run(config: &softarm_config::Config, reset: bool) -> anyhow::Result<()> {
    let latch = config.estop_latch();
    let n = send(&Namespace::new(&config.namespace())?, &latch, !reset)?;
    let word = if reset { "released" } else { "engaged" };
    println!("e-stop {word} ({n} receivers)");
    if n == 0 {
        // Not an error: the latch is what a process starting later reads.
        eprintln!(
            "softarm: no running process in namespace {:?} heard it; the latch {} says {word} \
             for every process that starts",
            config.namespace(),
            latch.path().display(),
        );
    }
    Ok(())
}
