//! One emulated motor: its physics (a first-order lag towards the goal), torque, goal and present
//! values, hardware errors, REBOOT and FACTORY RESET. Its table bytes and the READ and WRITE rules
//! are in `table.rs`.

use super::table::{
    BAUD_RATE, FIRMWARE_VERSION, GOAL_CURRENT, GOAL_POSITION, GOAL_VELOCITY, HARDWARE_ERROR_STATUS,
    HOMING_OFFSET, ID, ITEMS, MODEL_NUMBER, MOVING, MOVING_THRESHOLD, OPERATING_MODE,
    POSITION_TRAJECTORY, PRESENT_CURRENT, PRESENT_POSITION, PRESENT_PWM, PRESENT_VELOCITY,
    PROFILE_VELOCITY, RAM_START, REALTIME_TICK, STATUS_RETURN_LEVEL, TABLE_LEN, TORQUE_ENABLE,
    VELOCITY_LIMIT, VELOCITY_TRAJECTORY, error,
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
