//! `softarm estop [--reset]`: engages or releases the e-stop. The controller and the drivers
//! latch it: it stays engaged until an explicit reset, whoever sent it.

use std::time::Duration;

use softarm_ipc::{EstopState, Namespace, Node, now_ns};

pub fn send(namespace: &Namespace, engaged: bool) -> Result<usize, String> {
    let ipc = Node::open(namespace.clone(), "estop").map_err(|e| e.to_string())?;
    let service = ipc.estop().map_err(|e| e.to_string())?;
    let publisher = ipc.publisher(&service).map_err(|e| e.to_string())?;
    let receivers = publisher
        .send_copy(EstopState {
            seq: now_ns(),
            stamp_ns: now_ns(),
            engaged: engaged as u32,
            _pad: 0,
        })
        .map_err(|e| format!("sending the e-stop: {e:?}"))?;
    // Subscribers poll every tick; give them a moment before this node (and its sample) goes.
    std::thread::sleep(Duration::from_millis(200));
    Ok(receivers)
}
