//! softarm's controller and learner math: ProMPs, the activations and blend of the paper's
//! Eq. 11, the tick engine the controller evaluates every cycle, RBF models and CACLA-MTL.
//! Everything here is pure computation: no I/O, no iceoryx2.

pub mod activation;
pub mod cacla;
pub mod engine;
pub mod promp;
pub mod rbf;
pub mod skill;
