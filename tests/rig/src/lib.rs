//! The test rig's commands, apart from the product: `softarm soak` and `softarm bench`. The
//! binary links them (and `softarm emulate`) through its `rig` feature, on by default; a build
//! without it (`--no-default-features`) is the product alone. They run the product's own
//! processes in a [`softarm_stack::sandbox::Sandbox`].
//!
//! - [`soak`]: a long run with scenario changes and kills, checked by a safety watch
//!   (`softarm-watch`); its pattern of sets ([`soak::sets`]) is the rehearsal's too.
//! - [`bench`]: what the stack costs on this machine.

pub mod bench;
pub mod soak;
