//! Test support for softarm, dev-only:
//!
//! - [`stack`]: a stack of real `softarm` processes in a folder and an iceoryx2 namespace of
//!   its own ([`TestStack`]), so end-to-end tests run in parallel without crosstalk.
//! - [`config`]: the embedded default config with a test's own namespace, folders and quick
//!   training settings, and edits of it by dotted key.
//! - [`model`]: a quick model bundle made by the offline pipeline straight from the kinematic
//!   model.
//! - [`alloc`]: a counting global allocator for the "allocates nothing" tests.
//! - [`process`]: a guard that kills a process the test started, and waiting for a condition.

pub mod alloc;
pub mod config;
pub mod model;
pub mod process;
pub mod stack;

pub use config::{config_text, hardware_config_text, with_overrides};
pub use model::{quick_model, quick_training};
pub use process::{FaultSeed, Guard, eventually};
pub use stack::{DEMO_WAYPOINTS, TestStack, alive, children_of, set_id};
