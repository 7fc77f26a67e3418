//! The X-series control table (ROBOTIS e-Manual, e.g. XM430-W350, Protocol 2.0): the items the
//! driver reads and writes. EEPROM items (below 64) are writable only with the torque off.

pub const OPERATING_MODE: u16 = 11;
/// 2 bytes, in units of [`CURRENT_UNIT_A`].
pub const CURRENT_LIMIT: u16 = 38;
/// 4 bytes each, ticks; the motor refuses goal positions outside.
pub const MAX_POSITION_LIMIT: u16 = 48;
pub const MIN_POSITION_LIMIT: u16 = 52;
pub const TORQUE_ENABLE: u16 = 64;
pub const HARDWARE_ERROR_STATUS: u16 = 70;
/// 4 bytes, ticks.
pub const GOAL_POSITION: u16 = 116;
/// 2 bytes signed; followed by Present Velocity (4 bytes) and Present Position (4 bytes,
/// signed, ticks), so one read of 10 bytes from here gets current and position.
pub const PRESENT_CURRENT: u16 = 126;
/// Amperes per unit of the current items.
pub const CURRENT_UNIT_A: f64 = 0.00269;
