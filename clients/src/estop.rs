//! `softarm estop [--reset]`: engages or releases the e-stop. The controller and the drivers
//! latch it: it stays engaged until an explicit reset, whoever sent it.

use std::time::Duration;

use anyhow::{Context, anyhow};

use softarm_ipc::{EstopState, Namespace, Node, now_ns};

pub fn send(namespace: &Namespace, engaged: bool) -> anyhow::Result<usize> {
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
