//! softarm's controller and learner math: ProMPs, the activations and blend of the paper's
//! Eq. 11, the tick engine the controller evaluates every cycle, RBF models and CACLA-MTL.
//! Everything here is pure computation: no I/O, no iceoryx2.

pub mod promp;
