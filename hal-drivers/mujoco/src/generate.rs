//! A MuJoCo model (MJCF) generated from `[arm]`.

use softarm_arm::Layout;
use softarm_sections::mujoco::Generated;

/// The MJCF of `layout` made of `generated`'s values, under `gravity` (m/s², world frame).
pub fn mjcf(_layout: &Layout, _generated: &Generated, _gravity: [f64; 3]) -> String {
    unimplemented!("the generator")
}
