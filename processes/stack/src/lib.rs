//! The stack as one unit: its processes as children of one [`supervisor::Supervisor`], and
//! the commands that bring a whole stack up.
//!
//! - [`supervisor`]: children started with common arguments, a dead one restarted with
//!   back-off, all stopped on a signal; `softarm up`.
//! - [`sandbox`]: a stack in a namespace and folder of its own, trained on first use (the model
//!   cached), for `demo`, the test rig's `soak` and `bench` (`softarm-rig`) and the end-to-end
//!   tests.
//! - [`demo`]: `softarm demo`, the one-command showcase.

pub mod demo;
pub mod sandbox;
pub mod supervisor;
