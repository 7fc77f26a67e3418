//! The X-series control table (ROBOTIS e-Manual, e.g. XM430-W350, Protocol 2.0): the items the
//! driver reads and writes. EEPROM items (below 64) are writable only with the torque off.

/// 1 byte, unit 2 µs (factory 250, 500 µs): how long a motor waits before each reply.
pub const RETURN_DELAY_TIME: u16 = 9;
pub const OPERATING_MODE: u16 = 11;
/// Operating Mode's value for position control (one turn, within the position limits).
pub const POSITION_CONTROL: u8 = 3;
/// 4 bytes each, ticks; the motor refuses goal positions outside.
pub const MAX_POSITION_LIMIT: u16 = 48;
pub const MIN_POSITION_LIMIT: u16 = 52;
/// Followed by LED (65), Status Return Level (68), Registered Instruction (69) and Hardware
/// Error Status (70): one read of 7 bytes from here gets torque and errors.
pub const TORQUE_ENABLE: u16 = 64;
/// 4 bytes, units of 0.229 rev/min; 0 = no limit.
pub const PROFILE_VELOCITY: u16 = 112;
/// 4 bytes, ticks.
pub const GOAL_POSITION: u16 = 116;
/// 2 bytes signed, units of [`CURRENT_UNIT_A`].
pub const PRESENT_CURRENT: u16 = 126;
/// 4 bytes signed, ticks.
pub const PRESENT_POSITION: u16 = 132;
/// Amperes per unit of Present Current.
pub const CURRENT_UNIT_A: f64 = 0.00269;
