//! The test rig's commands, apart from the product: `softarm-rig soak` and `softarm-rig bench`.
//! Only the `softarm-rig` binary links them (and `emulate`), through the root package's `rig`
//! feature, on by default; `softarm`, the product that `softarm install` installs, never does
//! (decision 0014). They run the product's own processes in a
//! [`softarm_stack::sandbox::Sandbox`].
//!
//! - [`soak`]: a long run with scenario changes and kills, checked by a safety watch
//!   (`softarm-watch`); its pattern of sets ([`soak::sets`]) is the rehearsal's too.
//! - [`bench`]: what the stack costs on this machine.

pub mod bench;
pub mod soak;
