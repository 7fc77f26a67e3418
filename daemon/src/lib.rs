//! softarm's controller and learner math: ProMPs, the activations and blend of the paper's
//! Eq. 11, the tick engine the controller evaluates every cycle, RBF models and CACLA-MTL.
//! The math modules (promp, activation, engine, rbf, cacla, skill) are pure computation: no
//! I/O, no iceoryx2. The processes (controller, learner) and the files (config, bundle,
//! waypoints) build on them.

pub mod activation;
pub mod bundle;
pub mod cacla;
pub mod config;
pub mod controller;
pub mod engine;
pub mod learner;
pub mod promp;
pub mod rbf;
pub mod skill;
pub mod waypoints;
