//! One emulated motor: its physics (a first-order lag towards the goal), torque, goal and present
//! values, hardware errors, REBOOT and FACTORY RESET, its table bytes and the device's READ and
//! WRITE rules over them. The table's addresses and items are in `table.rs`.

use super::table::{
    BAUD_RATE, BUS_WATCHDOG, CURRENT_LIMIT, DRIVE_MODE, FEEDFORWARD_1ST_GAIN, FEEDFORWARD_2ND_GAIN,
    FIRMWARE_VERSION, GOAL_CURRENT, GOAL_POSITION, GOAL_PWM, GOAL_VELOCITY, HARDWARE_ERROR_STATUS,
    HOMING_OFFSET, ID, ITEMS, Item, LED, MAX_POSITION_LIMIT, MIN_POSITION_LIMIT, MODEL_NUMBER,
    MOVING, MOVING_THRESHOLD, OPERATING_MODE, POSITION_D_GAIN, POSITION_I_GAIN, POSITION_P_GAIN,
    POSITION_TRAJECTORY, PRESENT_CURRENT, PRESENT_POSITION, PRESENT_PWM, PRESENT_VELOCITY,
    PROFILE_ACCELERATION, PROFILE_VELOCITY, PROTOCOL_TYPE, PWM_LIMIT, RAM_START, REALTIME_TICK,
    RETURN_DELAY_TIME, SECONDARY_ID, STATUS_RETURN_LEVEL, TABLE_LEN, TEMPERATURE_LIMIT,
    TORQUE_ENABLE, VELOCITY_I_GAIN, VELOCITY_LIMIT, VELOCITY_P_GAIN, VELOCITY_TRAJECTORY, error,
    item_containing,
};

// Physics.
pub(super) const TICKS_PER_REV: f64 = 4096.0;
const RPM_PER_UNIT: f64 = 0.229;
const MA_PER_UNIT: f64 = 2.69;
const LAG_S: f64 = 0.020;
const MAX_SPEED_RPM: f64 = 50.0;
const MA_PER_TICK_ERROR: f64 = 1.0;
const MAX_CURRENT_MA: f64 = 300.0;
const MA_PER_TICK_PER_S: f64 = 0.02;

fn rpm_to_ticks_per_s(rpm: f64) -> f64 {
    rpm / 60.0 * TICKS_PER_REV
}

/// One emulated X-series motor: its control table (EEPROM and RAM areas) and its physics.
#[derive(Debug, Clone)]
pub struct Motor {
    pub(super) table: [u8; TABLE_LEN],
    /// Present position in ticks (the Present Position frame, homing offset included).
    pub(super) position: f64,
    /// Ticks per second.
    pub(super) velocity: f64,
    pub(super) current_ma: f64,
    clock_ms: f64,
    pub(super) registered: Option<(u16, Vec<u8>)>,
}

impl Motor {
    /// A motor as shipped (XM430-W350 defaults) with this `id`, at `position` ticks, torque off,
    /// in position mode, its goal position at its present position.
    pub fn new(id: u8, position: i32) -> Self {
        let mut m = Self {
            table: [0; TABLE_LEN],
            position: f64::from(position),
            velocity: 0.0,
            current_ma: 0.0,
            clock_ms: 0.0,
            registered: None,
        };
        for item in ITEMS {
            m.set(item, item.default);
        }
        m.table[usize::from(ID)] = id;
        m.set_i32(GOAL_POSITION, position);
        m.refresh();
        m
    }

    /// Changes the model number and firmware version the motor reports (e.g. to replay the
    /// e-Manual's examples, which use an XM430-W210: 1030, firmware 38).
    pub fn set_model(&mut self, model_number: u16, firmware_version: u8) {
        self.table[0..2].copy_from_slice(&model_number.to_le_bytes());
        self.table[usize::from(FIRMWARE_VERSION)] = firmware_version;
    }

    /// Moves the motor to `ticks` at once, as an outside force would (test hook).
    pub fn set_present_position(&mut self, ticks: i32) {
        self.position = f64::from(ticks);
        self.refresh();
    }

    /// The motor's ID (control table address 7).
    pub fn id(&self) -> u8 {
        self.table[usize::from(ID)]
    }

    /// Torque Enable is 1.
    pub fn torque_enabled(&self) -> bool {
        self.u8_at(TORQUE_ENABLE) == 1
    }

    /// Goal Position (ticks).
    pub fn goal_position(&self) -> i32 {
        self.i32_at(GOAL_POSITION)
    }

    /// Present Position (ticks).
    pub fn present_position(&self) -> i32 {
        self.i32_at(PRESENT_POSITION)
    }

    /// Present Velocity (unit 0.229 rev/min).
    pub fn present_velocity(&self) -> i32 {
        self.i32_at(PRESENT_VELOCITY)
    }

    /// Present Current (unit 2.69 mA).
    pub fn present_current(&self) -> i16 {
        self.i16_at(PRESENT_CURRENT)
    }

    /// Operating Mode.
    pub fn operating_mode(&self) -> u8 {
        self.u8_at(OPERATING_MODE)
    }

    /// Hardware Error Status.
    pub fn hardware_error_status(&self) -> u8 {
        self.u8_at(HARDWARE_ERROR_STATUS)
    }

    pub(super) fn status_return_level(&self) -> u8 {
        self.u8_at(STATUS_RETURN_LEVEL)
    }

    pub(super) fn alert(&self) -> u8 {
        if self.hardware_error_status() != 0 {
            error::ALERT
        } else {
            0
        }
    }

    /// REBOOT: the RAM area back to its initial values (torque off, hardware error cleared,
    /// goal at the present position); the EEPROM area and the position stay.
    pub(super) fn reboot(&mut self) {
        for item in ITEMS.iter().filter(|i| i.address >= RAM_START) {
            self.set(item, item.default);
        }
        self.registered = None;
        self.velocity = 0.0;
        self.current_ma = 0.0;
        self.clock_ms = 0.0;
        self.set_i32(GOAL_POSITION, self.position.round() as i32);
        self.refresh();
    }

    /// FACTORY RESET: 0xFF everything, 0x01 all but the ID, 0x02 all but the ID and baud rate.
    pub(super) fn factory_reset(&mut self, option: u8) {
        let id = self.id();
        let baud = self.u8_at(BAUD_RATE);
        let (model, firmware) = (self.u16_at(MODEL_NUMBER), self.u8_at(FIRMWARE_VERSION));
        let offset = self.i32_at(HOMING_OFFSET);
        for item in ITEMS {
            self.set(item, item.default);
        }
        self.set_model(model, firmware);
        self.position -= f64::from(offset);
        if option != 0xFF {
            self.table[usize::from(ID)] = id;
        }
        if option == 0x02 {
            self.table[usize::from(BAUD_RATE)] = baud;
        }
        self.reboot();
    }

    fn is_position_mode(&self) -> bool {
        matches!(self.operating_mode(), 3..=5)
    }

    /// Advances the physics by `dt` seconds (see [`Bus::step`](super::Bus::step)).
    pub(super) fn step(&mut self, dt: f64) {
        self.clock_ms += dt * 1000.0;
        if !self.torque_enabled() {
            self.velocity = 0.0;
            self.current_ma = 0.0;
            self.refresh();
            return;
        }
        let unit = rpm_to_ticks_per_s(RPM_PER_UNIT);
        let mut max_speed = rpm_to_ticks_per_s(MAX_SPEED_RPM);
        let velocity_limit = f64::from(self.u32_at(VELOCITY_LIMIT)) * unit;
        let profile_velocity = f64::from(self.u32_at(PROFILE_VELOCITY)) * unit;
        for cap in [velocity_limit, profile_velocity] {
            if cap > 0.0 {
                max_speed = max_speed.min(cap);
            }
        }
        let substeps = (dt / 0.001).ceil().clamp(1.0, 10_000.0);
        let h = dt / substeps;
        let decay = 1.0 - (-h / LAG_S).exp();
        match self.operating_mode() {
            3..=5 => {
                let goal = f64::from(self.goal_position());
                for _ in 0..substeps as usize {
                    let v = ((goal - self.position) * decay / h).clamp(-max_speed, max_speed);
                    self.position += v * h;
                    self.velocity = v;
                }
                let error = goal - self.position;
                self.current_ma =
                    (error * MA_PER_TICK_ERROR).clamp(-MAX_CURRENT_MA, MAX_CURRENT_MA);
            }
            1 => {
                let target = (f64::from(self.i32_at(GOAL_VELOCITY)) * unit)
                    .clamp(-velocity_limit, velocity_limit);
                for _ in 0..substeps as usize {
                    self.velocity += (target - self.velocity) * decay;
                    self.position += self.velocity * h;
                }
                self.current_ma =
                    (self.velocity * MA_PER_TICK_PER_S).clamp(-MAX_CURRENT_MA, MAX_CURRENT_MA);
            }
            0 => {
                // Current control: the emulated load holds still, the current is the goal's.
                self.velocity = 0.0;
                self.current_ma = f64::from(self.i16_at(GOAL_CURRENT)) * MA_PER_UNIT;
            }
            _ => {
                self.velocity = 0.0;
                self.current_ma = 0.0;
            }
        }
        self.refresh();
    }

    /// Writes the physics into the read-only items.
    pub(super) fn refresh(&mut self) {
        let clamp_i32 = |x: f64| x.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32;
        let velocity_units = clamp_i32(self.velocity / rpm_to_ticks_per_s(RPM_PER_UNIT));
        let current_units = (self.current_ma / MA_PER_UNIT)
            .round()
            .clamp(-32768.0, 32767.0);
        let pwm = current_units / 1193.0 * 885.0;
        self.set_i32(PRESENT_POSITION, clamp_i32(self.position));
        self.set_i32(PRESENT_VELOCITY, velocity_units);
        self.set_i16(PRESENT_CURRENT, current_units as i16);
        self.set_i16(PRESENT_PWM, pwm.round() as i16);
        self.set_i32(VELOCITY_TRAJECTORY, velocity_units);
        let trajectory = if self.torque_enabled() && self.is_position_mode() {
            self.goal_position()
        } else {
            clamp_i32(self.position)
        };
        self.set_i32(POSITION_TRAJECTORY, trajectory);
        let moving = i64::from(velocity_units).abs() > i64::from(self.u32_at(MOVING_THRESHOLD));
        self.table[usize::from(MOVING)] = u8::from(moving);
        let tick = (self.clock_ms as u64 % 32768) as u16;
        self.table[usize::from(REALTIME_TICK)..][..2].copy_from_slice(&tick.to_le_bytes());
    }
}

// ---------------------------------------------------------------------------------------------
// A motor's table bytes: raw access, and READ and WRITE as the device checks them.

impl Motor {
    /// Raw table bytes `address .. address + len`, or `None` outside the table.
    pub fn read(&self, address: u16, len: usize) -> Option<&[u8]> {
        let start = usize::from(address);
        self.table.get(start..start.checked_add(len)?)
    }

    pub(super) fn bytes<const N: usize>(&self, address: u16) -> [u8; N] {
        let start = usize::from(address);
        match self.table.get(start..start + N) {
            Some(b) => b.try_into().unwrap_or([0; N]),
            None => panic!("address {address} + {N} bytes is outside the control table"),
        }
    }

    /// The byte at `address`. Panics outside the table.
    pub fn u8_at(&self, address: u16) -> u8 {
        self.bytes::<1>(address)[0]
    }

    /// The little-endian `u16` at `address`. Panics outside the table.
    pub fn u16_at(&self, address: u16) -> u16 {
        u16::from_le_bytes(self.bytes(address))
    }

    /// The little-endian `i16` at `address`. Panics outside the table.
    pub fn i16_at(&self, address: u16) -> i16 {
        i16::from_le_bytes(self.bytes(address))
    }

    /// The little-endian `u32` at `address`. Panics outside the table.
    pub fn u32_at(&self, address: u16) -> u32 {
        u32::from_le_bytes(self.bytes(address))
    }

    /// The little-endian `i32` at `address`. Panics outside the table.
    pub fn i32_at(&self, address: u16) -> i32 {
        i32::from_le_bytes(self.bytes(address))
    }

    pub(super) fn set(&mut self, item: &Item, value: i64) {
        let start = usize::from(item.address);
        let bytes = value.to_le_bytes();
        self.table[start..item.end()].copy_from_slice(&bytes[..usize::from(item.size)]);
    }

    pub(super) fn set_i32(&mut self, address: u16, value: i32) {
        let start = usize::from(address);
        self.table[start..start + 4].copy_from_slice(&value.to_le_bytes());
    }

    pub(super) fn set_i16(&mut self, address: u16, value: i16) {
        let start = usize::from(address);
        self.table[start..start + 2].copy_from_slice(&value.to_le_bytes());
    }

    /// READ as the device does it: whole table range, gaps read as 0.
    pub(super) fn read_checked(&self, address: u16, len: u16) -> Result<Vec<u8>, u8> {
        if len == 0 {
            return Err(error::DATA_LENGTH);
        }
        self.read(address, usize::from(len))
            .map(<[u8]>::to_vec)
            .ok_or(error::ACCESS)
    }

    /// WRITE as the device does it: every byte must belong to a writable item covered whole,
    /// EEPROM only with the torque off, every value in range; then all is applied, or nothing.
    pub(super) fn write_checked(&mut self, address: u16, data: &[u8]) -> Result<(), u8> {
        if data.is_empty() {
            return Err(error::DATA_LENGTH);
        }
        let start = usize::from(address);
        let end = start + data.len();
        if end > TABLE_LEN {
            return Err(error::ACCESS);
        }
        let mut items = Vec::new();
        let mut a = start;
        while a < end {
            let Some(item) = item_containing(a) else {
                return Err(error::ACCESS);
            };
            if usize::from(item.address) != a || item.end() > end {
                return Err(error::DATA_LENGTH);
            }
            if !item.writable || (item.address < RAM_START && self.torque_enabled()) {
                return Err(error::ACCESS);
            }
            items.push(item);
            a = item.end();
        }
        for item in &items {
            let offset = usize::from(item.address) - start;
            let value = item.decode(&data[offset..offset + usize::from(item.size)]);
            self.check_value(item.address, value)?;
        }
        let old_offset = self.i32_at(HOMING_OFFSET);
        self.table[start..end].copy_from_slice(data);
        self.position += f64::from(self.i32_at(HOMING_OFFSET)) - f64::from(old_offset);
        if !self.torque_enabled() {
            self.velocity = 0.0;
            self.current_ma = 0.0;
        }
        self.refresh();
        Ok(())
    }

    fn check_value(&self, address: u16, v: i64) -> Result<(), u8> {
        let range = |lo: i64, hi: i64| {
            if (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(error::DATA_RANGE)
            }
        };
        let limit = |lim: i64| {
            if (-lim..=lim).contains(&v) {
                Ok(())
            } else {
                Err(error::DATA_LIMIT)
            }
        };
        match address {
            ID => range(0, 252),
            BAUD_RATE => range(0, 7),
            RETURN_DELAY_TIME => range(0, 254),
            DRIVE_MODE if v & !0x0D != 0 => Err(error::DATA_RANGE),
            OPERATING_MODE if ![0, 1, 3, 4, 5, 16].contains(&v) => Err(error::DATA_RANGE),
            SECONDARY_ID if v != 255 => range(0, 252),
            PROTOCOL_TYPE => range(1, 2),
            HOMING_OFFSET => range(-1_044_479, 1_044_479),
            MOVING_THRESHOLD | VELOCITY_LIMIT => range(0, 1023),
            TEMPERATURE_LIMIT => range(0, 100),
            PWM_LIMIT => range(0, 885),
            CURRENT_LIMIT => range(0, 1193),
            MAX_POSITION_LIMIT | MIN_POSITION_LIMIT => range(0, 4095),
            TORQUE_ENABLE if v == 1 && self.hardware_error_status() != 0 => {
                // Only REBOOT turns the torque on again after a shutdown (e-Manual, Shutdown).
                Err(error::RESULT_FAIL)
            }
            TORQUE_ENABLE | LED => range(0, 1),
            STATUS_RETURN_LEVEL => range(0, 2),
            VELOCITY_I_GAIN | VELOCITY_P_GAIN | POSITION_D_GAIN | POSITION_I_GAIN
            | POSITION_P_GAIN | FEEDFORWARD_2ND_GAIN | FEEDFORWARD_1ST_GAIN => range(0, 16383),
            BUS_WATCHDOG => range(0, 127),
            PROFILE_ACCELERATION | PROFILE_VELOCITY => range(0, 32767),
            GOAL_PWM => limit(i64::from(self.u16_at(PWM_LIMIT))),
            GOAL_CURRENT => limit(i64::from(self.u16_at(CURRENT_LIMIT))),
            GOAL_VELOCITY => limit(i64::from(self.u32_at(VELOCITY_LIMIT))),
            GOAL_POSITION if self.operating_mode() == 3 => {
                let min = i64::from(self.u32_at(MIN_POSITION_LIMIT));
                let max = i64::from(self.u32_at(MAX_POSITION_LIMIT));
                if (min..=max).contains(&v) {
                    Ok(())
                } else {
                    Err(error::DATA_LIMIT)
                }
            }
            GOAL_POSITION => limit(1_048_575),
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamixel::testing::{answer, parse_status, read, write};
    use crate::dynamixel::{Bus, hardware_error, instruction, instruction_packet};

    #[test]
    fn hardware_error_sets_the_alert_bit_until_reboot() {
        let mut bus = Bus::new(&[1, 2], 2048);
        assert_eq!(write(&mut bus, 1, TORQUE_ENABLE, &[1]), 0);
        bus.set_hardware_error(1, hardware_error::OVERLOAD);
        let m = bus.motor(1).unwrap();
        assert!(!m.torque_enabled());
        assert_eq!(
            read(&mut bus, 1, HARDWARE_ERROR_STATUS, 1),
            (0x80, vec![0x20])
        );
        let ping = parse_status(&answer(&mut bus, &instruction_packet(1, 1, &[])));
        assert_eq!(ping[0].1, 0x80);
        assert_eq!(read(&mut bus, 2, HARDWARE_ERROR_STATUS, 1), (0, vec![0]));
        // The torque cannot come back on before a reboot.
        assert_eq!(
            write(&mut bus, 1, TORQUE_ENABLE, &[1]),
            0x80 | error::RESULT_FAIL
        );
        assert!(!bus.motor(1).unwrap().torque_enabled());
        let reboot = answer(&mut bus, &instruction_packet(1, instruction::REBOOT, &[]));
        assert_eq!(
            parse_status(&reboot),
            vec![(1, 0x80, vec![])],
            "answered before rebooting"
        );
        assert_eq!(read(&mut bus, 1, HARDWARE_ERROR_STATUS, 1), (0, vec![0]));
        assert_eq!(write(&mut bus, 1, TORQUE_ENABLE, &[1]), 0);
    }

    // ---- physics ----

    #[test]
    fn torque_off_stays_torque_on_approaches_at_limited_speed() {
        let mut bus = Bus::new(&[1], 1000);
        assert_eq!(write(&mut bus, 1, GOAL_POSITION, &3000i32.to_le_bytes()), 0);
        for _ in 0..100 {
            bus.step(0.01);
        }
        let m = bus.motor(1).unwrap();
        assert_eq!(
            (
                m.present_position(),
                m.present_velocity(),
                m.present_current()
            ),
            (1000, 0, 0)
        );
        assert_eq!(write(&mut bus, 1, TORQUE_ENABLE, &[1]), 0);
        bus.step(0.1);
        let m = bus.motor(1).unwrap();
        let max_speed = rpm_to_ticks_per_s(200.0 * 0.229); // the Velocity Limit
        let moved = f64::from(m.present_position() - 1000);
        assert!(moved > 0.0 && moved <= max_speed * 0.1 + 1.0, "{moved}");
        assert!(m.present_velocity() > 0 && m.present_velocity() <= 200);
        let current_ma = f64::from(m.present_current()) * MA_PER_UNIT;
        assert!(current_ma > 100.0 && current_ma <= 302.0, "{current_ma}");
        assert_eq!(m.u8_at(MOVING), 1);
        for _ in 0..200 {
            bus.step(0.01);
        }
        let m = bus.motor(1).unwrap();
        assert_eq!(m.present_position(), 3000);
        assert_eq!((m.present_velocity(), m.u8_at(MOVING)), (0, 0));
        // Profile Velocity slows it down; a big dt is stable.
        assert_eq!(
            write(&mut bus, 1, PROFILE_VELOCITY, &20u32.to_le_bytes()),
            0
        );
        assert_eq!(write(&mut bus, 1, GOAL_POSITION, &0i32.to_le_bytes()), 0);
        bus.step(0.5);
        let moved = 3000 - bus.motor(1).unwrap().present_position();
        let expected = rpm_to_ticks_per_s(20.0 * 0.229) * 0.5;
        assert!(
            (f64::from(moved) - expected).abs() < 2.0,
            "{moved} vs {expected}"
        );
        bus.step(100.0);
        assert_eq!(bus.motor(1).unwrap().present_position(), 0);
        // Torque off mid-way: it stops where it is.
        assert_eq!(write(&mut bus, 1, GOAL_POSITION, &4000i32.to_le_bytes()), 0);
        bus.step(0.2);
        assert_eq!(write(&mut bus, 1, TORQUE_ENABLE, &[0]), 0);
        let here = bus.motor(1).unwrap().present_position();
        bus.step(1.0);
        let m = bus.motor(1).unwrap();
        assert_eq!((m.present_position(), m.present_current()), (here, 0));
    }

    #[test]
    fn velocity_mode_and_homing_offset() {
        let mut bus = Bus::new(&[1], 0);
        assert_eq!(write(&mut bus, 1, HOMING_OFFSET, &100i32.to_le_bytes()), 0);
        assert_eq!(bus.motor(1).unwrap().present_position(), 100);
        assert_eq!(write(&mut bus, 1, OPERATING_MODE, &[1]), 0);
        assert_eq!(
            write(&mut bus, 1, GOAL_VELOCITY, &(-100i32).to_le_bytes()),
            0
        );
        assert_eq!(write(&mut bus, 1, TORQUE_ENABLE, &[1]), 0);
        bus.step(1.0);
        let m = bus.motor(1).unwrap();
        assert_eq!(m.present_velocity(), -100);
        let per_s = rpm_to_ticks_per_s(100.0 * 0.229);
        let travelled = f64::from(100 - m.present_position());
        assert!(travelled > per_s * 0.9 && travelled < per_s, "{travelled}");
    }
}

/// The table's defaults and the device's READ and WRITE rules, as a motor keeps them.
#[cfg(test)]
mod table_tests {
    use super::*;
    use crate::dynamixel::table::*;
    use crate::dynamixel::testing::{answer, parse_status, read, write};
    use crate::dynamixel::{Bus, instruction_packet};

    #[test]
    fn defaults_are_the_xm430_w350s() {
        let m = Motor::new(7, 2048);
        assert_eq!(m.id(), 7);
        assert_eq!(m.u16_at(MODEL_NUMBER), 1020);
        assert_eq!(m.u8_at(OPERATING_MODE), 3);
        assert_eq!(m.u32_at(MAX_POSITION_LIMIT), 4095);
        assert_eq!(m.u32_at(MIN_POSITION_LIMIT), 0);
        assert_eq!(m.u32_at(VELOCITY_LIMIT), 200);
        assert_eq!(m.u16_at(CURRENT_LIMIT), 1193);
        assert_eq!(m.u8_at(STATUS_RETURN_LEVEL), 2);
        assert_eq!(m.u8_at(RETURN_DELAY_TIME), 250);
        assert_eq!(m.u8_at(SHUTDOWN), 52);
        assert!(!m.torque_enabled());
        assert_eq!((m.present_position(), m.goal_position()), (2048, 2048));
        assert_eq!(m.u16_at(PRESENT_INPUT_VOLTAGE), 120);
        assert_eq!(m.read(140, 7).map(<[u8]>::len), Some(7));
        assert_eq!(m.read(141, 7), None);
    }

    #[test]
    fn eeprom_is_locked_while_the_torque_is_on() {
        let mut bus = Bus::new(&[1], 2048);
        assert_eq!(write(&mut bus, 1, OPERATING_MODE, &[4]), 0);
        assert_eq!(write(&mut bus, 1, TORQUE_ENABLE, &[1]), 0);
        assert_eq!(write(&mut bus, 1, OPERATING_MODE, &[3]), error::ACCESS);
        assert_eq!(write(&mut bus, 1, ID, &[5]), error::ACCESS);
        assert_eq!(bus.motor(1).unwrap().operating_mode(), 4);
        assert_eq!(write(&mut bus, 1, TORQUE_ENABLE, &[0]), 0);
        assert_eq!(write(&mut bus, 1, OPERATING_MODE, &[3]), 0);
    }

    #[test]
    fn access_length_range_and_limit_errors() {
        let mut bus = Bus::new(&[1], 2048);
        // Read-only items, gaps and the end of the table.
        assert_eq!(write(&mut bus, 1, PRESENT_POSITION, &[0; 4]), error::ACCESS);
        assert_eq!(write(&mut bus, 1, MODEL_NUMBER, &[0; 2]), error::ACCESS);
        assert_eq!(write(&mut bus, 1, 14, &[0]), error::ACCESS);
        assert_eq!(write(&mut bus, 1, 146, &[0, 0]), error::ACCESS);
        assert_eq!(write(&mut bus, 1, 2000, &[0]), error::ACCESS);
        assert_eq!(read(&mut bus, 1, 140, 8).0, error::ACCESS);
        assert_eq!(read(&mut bus, 1, 0xFFFF, 0xFFFF).0, error::ACCESS);
        // Part of an item.
        assert_eq!(
            write(&mut bus, 1, GOAL_POSITION, &[0, 0]),
            error::DATA_LENGTH
        );
        assert_eq!(
            write(&mut bus, 1, GOAL_POSITION + 1, &[0]),
            error::DATA_LENGTH
        );
        assert_eq!(read(&mut bus, 1, GOAL_POSITION, 0).0, error::DATA_LENGTH);
        let bad_read = instruction_packet(1, instruction::READ, &[0x74, 0, 4]);
        assert_eq!(
            parse_status(&answer(&mut bus, &bad_read))[0].1,
            error::DATA_LENGTH
        );
        // Ranges and limits.
        assert_eq!(write(&mut bus, 1, TORQUE_ENABLE, &[2]), error::DATA_RANGE);
        assert_eq!(write(&mut bus, 1, OPERATING_MODE, &[2]), error::DATA_RANGE);
        assert_eq!(
            write(&mut bus, 1, GOAL_POSITION, &4096i32.to_le_bytes()),
            error::DATA_LIMIT
        );
        assert_eq!(
            write(&mut bus, 1, GOAL_POSITION, &(-1i32).to_le_bytes()),
            error::DATA_LIMIT
        );
        assert_eq!(
            write(&mut bus, 1, GOAL_VELOCITY, &201i32.to_le_bytes()),
            error::DATA_LIMIT
        );
        assert_eq!(
            bus.motor(1).unwrap().goal_position(),
            2048,
            "refused: not applied"
        );
        // Several items at once, all or nothing.
        let mut two = 4000i32.to_le_bytes().to_vec();
        two.extend(3000i32.to_le_bytes());
        assert_eq!(write(&mut bus, 1, MAX_POSITION_LIMIT, &two), 0);
        assert_eq!(write(&mut bus, 1, GOAL_POSITION, &3500i32.to_le_bytes()), 0);
        assert_eq!(
            write(&mut bus, 1, GOAL_POSITION, &2999i32.to_le_bytes()),
            error::DATA_LIMIT
        );
        assert_eq!(
            write(&mut bus, 1, 63, &[0, 1]),
            0,
            "Shutdown and Torque Enable together"
        );
        assert!(bus.motor(1).unwrap().torque_enabled());
        assert_eq!(
            write(&mut bus, 1, 64, &[0, 1, 0]),
            error::ACCESS,
            "66 is a gap"
        );
        assert!(bus.motor(1).unwrap().torque_enabled());
        // Extended position mode: ±1,048,575.
        assert_eq!(write(&mut bus, 1, TORQUE_ENABLE, &[0]), 0);
        assert_eq!(write(&mut bus, 1, OPERATING_MODE, &[4]), 0);
        assert_eq!(
            write(&mut bus, 1, GOAL_POSITION, &(-100_000i32).to_le_bytes()),
            0
        );
        assert_eq!(
            write(&mut bus, 1, GOAL_POSITION, &1_048_576i32.to_le_bytes()),
            error::DATA_LIMIT
        );
    }
}
