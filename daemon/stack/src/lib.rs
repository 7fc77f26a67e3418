//! The stack as one unit: its processes as children of one [`supervisor::Supervisor`], and
//! the commands that bring a whole stack up.
//!
//! - [`supervisor`]: children started with common arguments, a dead one restarted with
//!   back-off, all stopped on a signal; `softarm up`.
//! - [`scratch`]: a throwaway stack in a namespace and folder of its own, trained on first use
//!   (the model cached), for `demo`, `soak` and `bench`.
//! - [`demo`]: `softarm demo`, the one-command showcase.
//! - [`soak`]: `softarm soak`, a long run with scenario changes and kills, checked by a watch.
//! - [`bench`]: `softarm bench`, what the stack costs on this machine.

pub mod bench;
pub mod demo;
pub mod scratch;
pub mod soak;
pub mod supervisor;
