//! The end-to-end tests, one binary (ripgrep's way: `autotests = false`, one target that
//! `mod`s each file): the real `softarm` binary as separate processes over real iceoryx2
//! services, each test in a namespace and folder of its own. One binary links the workspace
//! once; its tests run side by side in one process, as they would beside a running stack.
//! `cargo test --test e2e -- NAME` runs one.

// The controller's tick is checked for allocations in `tick_allocates_nothing`: the counting
// allocator counts only threads that ask, so every other test runs as under the system one.
#[global_allocator]
static GLOBAL: softarm_test_alloc::Counting = softarm_test_alloc::Counting;

mod adaptation;
mod any_arm;
mod bad_input;
mod bench;
mod changing_arm;
mod cli;
mod docs;
mod estop;
mod faults;
mod hardware;
mod hardware_bus;
mod hardware_faults;
mod hardware_noise;
mod identify;
mod install;
mod iox2;
mod layering;
mod leftovers;
mod mujoco;
mod notify;
mod operators;
mod python;
mod record;
mod restart;
mod ros2;
mod shm;
mod soak;
mod stack;
mod tick_allocates_nothing;
mod train_kill;
mod view;
