//! softarm's drivers. For now the simulated plant: piecewise-constant-curvature kinematics of
//! the two-module arm (`pcc`, pure math) and its realism layer (`plant`).

pub mod pcc;
pub mod plant;
pub mod sim;
