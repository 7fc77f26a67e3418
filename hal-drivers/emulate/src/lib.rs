//! Emulators of softarm's hardware on pseudo-terminals, speaking the real protocols: a bus of
//! Dynamixel Protocol 2.0 motors and an Ascension Bird tracker. Tests and `softarm emulate` run
//! the real drivers against them. [`command`] is `softarm emulate`.

pub mod bird;
pub mod command;
pub mod dynamixel;
pub mod pty;
pub mod rig;
