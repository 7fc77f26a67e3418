//! The control table of the X series (XM430-W350 e-Manual): its addresses, the codes of the
//! protocol and the items (size, access, sign, default). A motor's table bytes and the device's
//! READ and WRITE rules over them are the motor's (`motor.rs`), which reads this file and not the
//! other way round.

// ---------------------------------------------------------------------------------------------
// Control table of the X series (XM430-W350 e-Manual), EEPROM area (addresses < 64).

/// Model Number (2 bytes, R). 1020 for the XM430-W350.
pub const MODEL_NUMBER: u16 = 0;
/// Model Information (4 bytes, R).
pub const MODEL_INFORMATION: u16 = 2;
/// Firmware Version (1 byte, R).
pub const FIRMWARE_VERSION: u16 = 6;
/// ID (1 byte, RW, 0 to 252).
pub const ID: u16 = 7;
/// Baud Rate (1 byte, RW, 0 to 7; 1 = 57600 bps, 3 = 1 Mbps). Stored only: the line's rate is
/// the bus's (`Bus::set_baud`).
pub const BAUD_RATE: u16 = 8;
/// Return Delay Time (1 byte, RW, unit 2 µs, factory 250 = 500 µs): how long the motor waits
/// before each status packet (`Bus::hear`).
pub const RETURN_DELAY_TIME: u16 = 9;
/// Drive Mode (1 byte, RW). Stored only.
pub const DRIVE_MODE: u16 = 10;
/// Operating Mode (1 byte, RW): 0 current, 1 velocity, 3 position, 4 extended position,
/// 5 current-based position, 16 PWM.
pub const OPERATING_MODE: u16 = 11;
/// Secondary (Shadow) ID (1 byte, RW). Stored only.
pub const SECONDARY_ID: u16 = 12;
/// Protocol Type (1 byte, RW). Stored only.
pub const PROTOCOL_TYPE: u16 = 13;
/// Homing Offset (4 bytes, signed, RW): added to the present position.
pub const HOMING_OFFSET: u16 = 20;
/// Moving Threshold (4 bytes, RW, unit 0.229 rev/min): above it, Moving is 1.
pub const MOVING_THRESHOLD: u16 = 24;
/// Temperature Limit (1 byte, RW, °C).
pub const TEMPERATURE_LIMIT: u16 = 31;
/// Max Voltage Limit (2 bytes, RW, unit 0.1 V).
pub const MAX_VOLTAGE_LIMIT: u16 = 32;
/// Min Voltage Limit (2 bytes, RW, unit 0.1 V).
pub const MIN_VOLTAGE_LIMIT: u16 = 34;
/// PWM Limit (2 bytes, RW, 0 to 885).
pub const PWM_LIMIT: u16 = 36;
/// Current Limit (2 bytes, RW, 0 to 1193, unit 2.69 mA).
pub const CURRENT_LIMIT: u16 = 38;
/// Velocity Limit (4 bytes, RW, 0 to 1023, unit 0.229 rev/min).
pub const VELOCITY_LIMIT: u16 = 44;
/// Max Position Limit (4 bytes, RW, 0 to 4095).
pub const MAX_POSITION_LIMIT: u16 = 48;
/// Min Position Limit (4 bytes, RW, 0 to 4095).
pub const MIN_POSITION_LIMIT: u16 = 52;
/// Shutdown (1 byte, RW): which hardware errors turn the torque off. Stored only.
pub const SHUTDOWN: u16 = 63;

// RAM area (addresses >= 64).

/// Torque Enable (1 byte, RW, 0 or 1). While 1 the EEPROM area is locked.
pub const TORQUE_ENABLE: u16 = 64;
/// LED (1 byte, RW).
pub const LED: u16 = 65;
/// Status Return Level (1 byte, RW): 0 PING only, 1 PING and READ, 2 all instructions.
pub const STATUS_RETURN_LEVEL: u16 = 68;
/// Registered Instruction (1 byte, R): 1 while a REG WRITE waits for ACTION.
pub const REGISTERED_INSTRUCTION: u16 = 69;
/// Hardware Error Status (1 byte, R): see [`hardware_error`].
pub const HARDWARE_ERROR_STATUS: u16 = 70;
/// Velocity I Gain (2 bytes, RW).
pub const VELOCITY_I_GAIN: u16 = 76;
/// Velocity P Gain (2 bytes, RW).
pub const VELOCITY_P_GAIN: u16 = 78;
/// Position D Gain (2 bytes, RW).
pub const POSITION_D_GAIN: u16 = 80;
/// Position I Gain (2 bytes, RW).
pub const POSITION_I_GAIN: u16 = 82;
/// Position P Gain (2 bytes, RW).
pub const POSITION_P_GAIN: u16 = 84;
/// Feedforward 2nd Gain (2 bytes, RW).
pub const FEEDFORWARD_2ND_GAIN: u16 = 88;
/// Feedforward 1st Gain (2 bytes, RW).
pub const FEEDFORWARD_1ST_GAIN: u16 = 90;
/// Bus Watchdog (1 byte, RW). Stored only.
pub const BUS_WATCHDOG: u16 = 98;
/// Goal PWM (2 bytes, signed, RW, within ± PWM Limit).
pub const GOAL_PWM: u16 = 100;
/// Goal Current (2 bytes, signed, RW, within ± Current Limit, unit 2.69 mA).
pub const GOAL_CURRENT: u16 = 102;
/// Goal Velocity (4 bytes, signed, RW, within ± Velocity Limit, unit 0.229 rev/min).
pub const GOAL_VELOCITY: u16 = 104;
/// Profile Acceleration (4 bytes, RW). Stored only.
pub const PROFILE_ACCELERATION: u16 = 108;
/// Profile Velocity (4 bytes, RW, unit 0.229 rev/min, 0 = no limit): caps the speed.
pub const PROFILE_VELOCITY: u16 = 112;
/// Goal Position (4 bytes, signed, RW): within the position limits in position mode.
pub const GOAL_POSITION: u16 = 116;
/// Realtime Tick (2 bytes, R, ms modulo 32768).
pub const REALTIME_TICK: u16 = 120;
/// Moving (1 byte, R).
pub const MOVING: u16 = 122;
/// Moving Status (1 byte, R). Always 0 here.
pub const MOVING_STATUS: u16 = 123;
/// Present PWM (2 bytes, signed, R).
pub const PRESENT_PWM: u16 = 124;
/// Present Current (2 bytes, signed, R, unit 2.69 mA).
pub const PRESENT_CURRENT: u16 = 126;
/// Present Velocity (4 bytes, signed, R, unit 0.229 rev/min).
pub const PRESENT_VELOCITY: u16 = 128;
/// Present Position (4 bytes, signed, R, 4096 per revolution).
pub const PRESENT_POSITION: u16 = 132;
/// Velocity Trajectory (4 bytes, signed, R).
pub const VELOCITY_TRAJECTORY: u16 = 136;
/// Position Trajectory (4 bytes, signed, R).
pub const POSITION_TRAJECTORY: u16 = 140;
/// Present Input Voltage (2 bytes, R, unit 0.1 V).
pub const PRESENT_INPUT_VOLTAGE: u16 = 144;
/// Present Temperature (1 byte, R, °C).
pub const PRESENT_TEMPERATURE: u16 = 146;

/// Bytes of the emulated control table (addresses 0 to 146; indirect addresses are not emulated).
pub const TABLE_LEN: usize = 147;
/// First address of the RAM area; below it is the EEPROM area, locked while the torque is on.
pub const RAM_START: u16 = 64;
/// Model number of the XM430-W350.
pub const XM430_W350: u16 = 1020;
/// Firmware version the emulated motors report (the e-Manual gives none; a current X firmware).
pub const DEFAULT_FIRMWARE_VERSION: u8 = 48;

/// Instruction codes (e-Manual "Protocol 2.0", Instruction).
pub mod instruction {
    /// Ping.
    pub const PING: u8 = 0x01;
    /// Read.
    pub const READ: u8 = 0x02;
    /// Write.
    pub const WRITE: u8 = 0x03;
    /// Reg Write.
    pub const REG_WRITE: u8 = 0x04;
    /// Action.
    pub const ACTION: u8 = 0x05;
    /// Factory Reset.
    pub const FACTORY_RESET: u8 = 0x06;
    /// Reboot.
    pub const REBOOT: u8 = 0x08;
    /// Clear.
    pub const CLEAR: u8 = 0x10;
    /// Status (the instruction field of every status packet).
    pub const STATUS: u8 = 0x55;
    /// Sync Read.
    pub const SYNC_READ: u8 = 0x82;
    /// Sync Write.
    pub const SYNC_WRITE: u8 = 0x83;
    /// Bulk Read.
    pub const BULK_READ: u8 = 0x92;
    /// Bulk Write.
    pub const BULK_WRITE: u8 = 0x93;
}

/// The error field of a status packet (e-Manual "Protocol 2.0", Status Packet, Error).
pub mod error {
    /// Result Fail: the instruction could not be processed.
    pub const RESULT_FAIL: u8 = 0x01;
    /// Instruction Error: undefined instruction, or ACTION without REG WRITE.
    pub const INSTRUCTION: u8 = 0x02;
    /// CRC Error (never sent here: a packet with a bad CRC gets no answer).
    pub const CRC: u8 = 0x03;
    /// Data Range Error: value outside the item's range.
    pub const DATA_RANGE: u8 = 0x04;
    /// Data Length Error: the data covers an item only in part, or parameters are missing.
    pub const DATA_LENGTH: u8 = 0x05;
    /// Data Limit Error: value outside a limit item (position, velocity, current, PWM limits).
    pub const DATA_LIMIT: u8 = 0x06;
    /// Access Error: read-only or undefined address, or EEPROM write while the torque is on.
    pub const ACCESS: u8 = 0x07;
    /// Alert bit: set while the Hardware Error Status is not 0.
    pub const ALERT: u8 = 0x80;
}

/// Bits of Hardware Error Status (70) and Shutdown (63) of the X series.
pub mod hardware_error {
    /// Input Voltage Error.
    pub const INPUT_VOLTAGE: u8 = 0x01;
    /// Overheating Error.
    pub const OVERHEATING: u8 = 0x04;
    /// Motor Encoder Error.
    pub const MOTOR_ENCODER: u8 = 0x08;
    /// Electrical Shock Error.
    pub const ELECTRICAL_SHOCK: u8 = 0x10;
    /// Overload Error.
    pub const OVERLOAD: u8 = 0x20;
}

// ---------------------------------------------------------------------------------------------
// The items of the table.

#[derive(Debug, Clone, Copy)]
pub(super) struct Item {
    pub(super) address: u16,
    pub(super) size: u16,
    pub(super) writable: bool,
    signed: bool,
    pub(super) default: i64,
}

impl Item {
    pub(super) fn end(&self) -> usize {
        usize::from(self.address) + usize::from(self.size)
    }

    pub(super) fn decode(&self, bytes: &[u8]) -> i64 {
        match (self.size, self.signed) {
            (1, _) => i64::from(bytes[0]),
            (2, false) => i64::from(u16::from_le_bytes([bytes[0], bytes[1]])),
            (2, true) => i64::from(i16::from_le_bytes([bytes[0], bytes[1]])),
            (_, false) => i64::from(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]])),
            (_, true) => i64::from(i32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]])),
        }
    }
}

const fn r(address: u16, size: u16, default: i64) -> Item {
    Item {
        address,
        size,
        writable: false,
        signed: false,
        default,
    }
}
const fn rs(address: u16, size: u16) -> Item {
    Item {
        address,
        size,
        writable: false,
        signed: true,
        default: 0,
    }
}
const fn rw(address: u16, size: u16, default: i64) -> Item {
    Item {
        address,
        size,
        writable: true,
        signed: false,
        default,
    }
}
const fn rws(address: u16, size: u16, default: i64) -> Item {
    Item {
        address,
        size,
        writable: true,
        signed: true,
        default,
    }
}

// Inputs the emulation keeps constant: 12.0 V and 36 °C (limits on them are not emulated).
const INPUT_VOLTAGE: i64 = 120;
const TEMPERATURE: i64 = 36;

/// The XM430-W350 control table up to Present Temperature, defaults from the e-Manual.
pub(super) const ITEMS: &[Item] = &[
    r(MODEL_NUMBER, 2, XM430_W350 as i64),
    r(MODEL_INFORMATION, 4, 0),
    r(FIRMWARE_VERSION, 1, DEFAULT_FIRMWARE_VERSION as i64),
    rw(ID, 1, 1),
    rw(BAUD_RATE, 1, 1),
    rw(RETURN_DELAY_TIME, 1, 250),
    rw(DRIVE_MODE, 1, 0),
    rw(OPERATING_MODE, 1, 3),
    rw(SECONDARY_ID, 1, 255),
    rw(PROTOCOL_TYPE, 1, 2),
    rws(HOMING_OFFSET, 4, 0),
    rw(MOVING_THRESHOLD, 4, 10),
    rw(TEMPERATURE_LIMIT, 1, 80),
    rw(MAX_VOLTAGE_LIMIT, 2, 160),
    rw(MIN_VOLTAGE_LIMIT, 2, 95),
    rw(PWM_LIMIT, 2, 885),
    rw(CURRENT_LIMIT, 2, 1193),
    rw(VELOCITY_LIMIT, 4, 200),
    rw(MAX_POSITION_LIMIT, 4, 4095),
    rw(MIN_POSITION_LIMIT, 4, 0),
    rw(SHUTDOWN, 1, 52),
    rw(TORQUE_ENABLE, 1, 0),
    rw(LED, 1, 0),
    rw(STATUS_RETURN_LEVEL, 1, 2),
    r(REGISTERED_INSTRUCTION, 1, 0),
    r(HARDWARE_ERROR_STATUS, 1, 0),
    rw(VELOCITY_I_GAIN, 2, 1920),
    rw(VELOCITY_P_GAIN, 2, 100),
    rw(POSITION_D_GAIN, 2, 0),
    rw(POSITION_I_GAIN, 2, 0),
    rw(POSITION_P_GAIN, 2, 800),
    rw(FEEDFORWARD_2ND_GAIN, 2, 0),
    rw(FEEDFORWARD_1ST_GAIN, 2, 0),
    rw(BUS_WATCHDOG, 1, 0),
    rws(GOAL_PWM, 2, 0),
    rws(GOAL_CURRENT, 2, 0),
    rws(GOAL_VELOCITY, 4, 0),
    rw(PROFILE_ACCELERATION, 4, 0),
    rw(PROFILE_VELOCITY, 4, 0),
    rws(GOAL_POSITION, 4, 0),
    r(REALTIME_TICK, 2, 0),
    r(MOVING, 1, 0),
    r(MOVING_STATUS, 1, 0),
    rs(PRESENT_PWM, 2),
    rs(PRESENT_CURRENT, 2),
    rs(PRESENT_VELOCITY, 4),
    rs(PRESENT_POSITION, 4),
    rs(VELOCITY_TRAJECTORY, 4),
    rs(POSITION_TRAJECTORY, 4),
    r(PRESENT_INPUT_VOLTAGE, 2, INPUT_VOLTAGE),
    r(PRESENT_TEMPERATURE, 1, TEMPERATURE),
];

pub(super) fn item_containing(address: usize) -> Option<&'static Item> {
    ITEMS
        .iter()
        .find(|item| usize::from(item.address) <= address && address < item.end())
}
