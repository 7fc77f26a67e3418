//! An emulated bus of Dynamixel X-series motors (XM430-W350) speaking Protocol 2.0, device side.
//!
//! This is an independent implementation of the device side from the ROBOTIS e-Manual
//! ("DYNAMIXEL Protocol 2.0" and the "XM430-W350" control table), so that the real driver, which
//! uses the `dynamixel2` crate as the bus master, is checked against something that was not
//! written from the same code. Only the CRC-16 is shared (`dynamixel2::checksum`), and the
//! e-Manual's example packets (see the tests) pin it.
//!
//! What it does:
//! - [`Bus::receive`] decodes instruction packets out of a byte stream (split anywhere, garbage
//!   between packets skipped, a bad CRC ignored as a real motor does), undoes byte stuffing,
//!   executes PING, READ, WRITE, REG WRITE, ACTION, FACTORY RESET, REBOOT, CLEAR, SYNC READ,
//!   SYNC WRITE, BULK READ and BULK WRITE, and appends the (stuffed) status packets.
//! - Each [`Motor`] keeps the X-series control table (EEPROM and RAM areas, access rights, ranges
//!   and limits) and a small physics model advanced by [`Bus::step`].
//! - The line's timing ([`Bus::hear`]): each packet takes 10 bits a byte at the bus's baud rate
//!   ([`Bus::set_baud`]), and each motor answers its Return Delay Time (factory 500 µs) after
//!   the packet before its answer, the motors of a SYNC or BULK READ one after another, so a bus
//!   of motors at their factory settings is as slow as a real one. An instruction that comes
//!   while replies are still due is counted ([`BusCounters::collisions`]: on a real half-duplex
//!   bus it collides with them).
//! - [`BusFaults`] injects silence, corrupt CRCs and garbage, and motors that refuse a write;
//!   [`Bus::inject_raw`] sends arbitrary bytes (e.g. a malformed status packet) before the next
//!   status packet.
//! - [`serve`] runs a bus on a pseudo-terminal for a driver that opens the slave's path, sending
//!   each status packet when its last byte would be out on the wire.
//!
//! Not emulated: the Baud Rate item (the pty has no rate; the bus has one), collisions
//! themselves (a pseudo-terminal carries both ways at once), indirect addresses
//! (the table ends at Present Temperature, 146), secondary ID, bus watchdog, drive mode
//! (direction and time-based profile), profile acceleration, the input voltage and temperature
//! limits (inputs are constant 12.0 V and 36 °C).

mod bus;
mod motor;
mod packet;
mod table;

pub use bus::{Bus, BusCounters, BusFaults, RECEIVE_TIMEOUT_S, serve};
pub use motor::Motor;
pub use packet::{
    BROADCAST_ID, MAX_PACKET_LENGTH, instruction_packet, short_status_packet, status_packet, stuff,
    unstuff,
};
pub use table::{
    BAUD_RATE, BUS_WATCHDOG, CURRENT_LIMIT, DEFAULT_FIRMWARE_VERSION, DRIVE_MODE,
    FEEDFORWARD_1ST_GAIN, FEEDFORWARD_2ND_GAIN, FIRMWARE_VERSION, GOAL_CURRENT, GOAL_POSITION,
    GOAL_PWM, GOAL_VELOCITY, HARDWARE_ERROR_STATUS, HOMING_OFFSET, ID, LED, MAX_POSITION_LIMIT,
    MAX_VOLTAGE_LIMIT, MIN_POSITION_LIMIT, MIN_VOLTAGE_LIMIT, MODEL_INFORMATION, MODEL_NUMBER,
    MOVING, MOVING_STATUS, MOVING_THRESHOLD, OPERATING_MODE, POSITION_D_GAIN, POSITION_I_GAIN,
    POSITION_P_GAIN, POSITION_TRAJECTORY, PRESENT_CURRENT, PRESENT_INPUT_VOLTAGE, PRESENT_POSITION,
    PRESENT_PWM, PRESENT_TEMPERATURE, PRESENT_VELOCITY, PROFILE_ACCELERATION, PROFILE_VELOCITY,
    PROTOCOL_TYPE, PWM_LIMIT, RAM_START, REALTIME_TICK, REGISTERED_INSTRUCTION, RETURN_DELAY_TIME,
    SECONDARY_ID, SHUTDOWN, STATUS_RETURN_LEVEL, TABLE_LEN, TEMPERATURE_LIMIT, TORQUE_ENABLE,
    VELOCITY_I_GAIN, VELOCITY_LIMIT, VELOCITY_P_GAIN, VELOCITY_TRAJECTORY, XM430_W350, error,
    hardware_error, instruction,
};

/// Helpers shared by the tests of the submodules.
#[cfg(test)]
mod testing {
    use dynamixel2::checksum::calculate_checksum;

    use super::packet::HEADER;
    use super::{Bus, instruction, instruction_packet, unstuff};

    /// A packet from hex bytes.
    pub(super) fn bytes(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    /// Feeds `input` in one piece, returns what the bus answered.
    pub(super) fn answer(bus: &mut Bus, input: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        bus.receive(input, &mut out);
        out
    }

    /// Parses status packets (test side, independent of the bus's encoder).
    pub(super) fn parse_status(mut s: &[u8]) -> Vec<(u8, u8, Vec<u8>)> {
        let mut v = Vec::new();
        while !s.is_empty() {
            assert_eq!(s[..4], HEADER, "status packet header in {s:02X?}");
            let len = usize::from(u16::from_le_bytes([s[5], s[6]]));
            let total = 7 + len;
            let crc = u16::from_le_bytes([s[total - 2], s[total - 1]]);
            assert_eq!(crc, calculate_checksum(0, &s[..total - 2]));
            let body = unstuff(&s[7..total - 2]);
            assert_eq!(body[0], 0x55);
            v.push((s[4], body[1], body[2..].to_vec()));
            s = &s[total..];
        }
        v
    }

    pub(super) fn read(bus: &mut Bus, id: u8, address: u16, len: u16) -> (u8, Vec<u8>) {
        let mut p = address.to_le_bytes().to_vec();
        p.extend(len.to_le_bytes());
        let s = parse_status(&answer(bus, &instruction_packet(id, instruction::READ, &p)));
        assert_eq!(s.len(), 1);
        (s[0].1, s[0].2.clone())
    }

    pub(super) fn write(bus: &mut Bus, id: u8, address: u16, data: &[u8]) -> u8 {
        let mut p = address.to_le_bytes().to_vec();
        p.extend(data);
        let s = parse_status(&answer(
            bus,
            &instruction_packet(id, instruction::WRITE, &p),
        ));
        assert_eq!(s.len(), 1);
        assert!(s[0].2.is_empty());
        s[0].1
    }
}
