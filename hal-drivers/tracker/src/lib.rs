//! The `tracker` driver process.

pub mod bird;
