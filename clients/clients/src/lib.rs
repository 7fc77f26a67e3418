//! softarm's user commands that talk to a running stack: `submit`, `stats`, `status` and
//! `estop`. Each is a short-lived iceoryx2 node in the stack's namespace. What the commands of
//! other crates take from here: [`poll`], [`unreachable`] (`softarm train`) and the statistics'
//! formats of [`stats`] (`softarm replay`).

pub mod estop;
pub mod stats;
pub mod status;
pub mod submit;

use std::time::{Duration, Instant};

/// Polls `f` every millisecond until it yields or `timeout` passes.
pub fn poll<T>(timeout: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let start = Instant::now();
    loop {
        if let Some(v) = f() {
            return Some(v);
        }
        if start.elapsed() >= timeout {
            return None;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// The message for a stack that does not answer.
pub fn unreachable(namespace: &str, what: &str) -> String {
    format!(
        "no controller answered {what} in namespace {namespace:?}: is `softarm up` running there \
         (same --config or --namespace)?"
    )
}
