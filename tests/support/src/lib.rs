//! Test support for softarm, dev-only:
//!
//! - [`stack`]: a stack of real `softarm` processes in a folder and an iceoryx2 namespace of
//!   its own ([`TestStack`]), so end-to-end tests run in parallel without crosstalk.
//! - [`config`]: the embedded default config with a test's own namespace, folders and quick
//!   training settings, and edits of it by dotted key.
//! - [`model`]: a model bundle made in seconds ([`quick_model`]).
//! - [`turns`]: at most six stacks at a time, and emulated devices taking turns.
//! - [`process`]: a guard that kills a process the test started with all it started in turn,
//!   the check at the end of a run that no process outlived its test, and waiting for a
//!   condition.

pub mod config;
pub mod model;
pub mod process;
pub mod stack;
pub mod turns;

pub use config::{config_text, hardware_config_text, with_overrides};
pub use model::{quick_model, quick_model_of, quick_training};
pub use process::{FaultSeed, Guard, eventually, output};
pub use stack::{DEMO_WAYPOINTS, TestStack, alive, children_of, set_id};
pub use turns::Devices;
