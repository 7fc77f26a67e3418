//! How the bus is doing: the share of replies lost over the last second, and what the driver
//! tells the user about it (a log line on each change, and every 10 s while it lasts).

use std::collections::VecDeque;

use crate::Totals;

/// The bus as the driver reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Bus {
    /// Replies come and the motor data is fresh.
    Good,
    /// Replies are being lost (at least [`DEGRADED_PERMILLE`]), the data still fresh.
    Degraded,
    /// Most replies are lost ([`FAILING_PERMILLE`]), or the motor data is older than the
    /// controller's input time-out: the controller holds.
    Failing,
}

/// Losing 1 % of the replies is more than a sound bus does (a cable, a termination, noise).
pub(crate) const DEGRADED_PERMILLE: u32 = 10;
pub(crate) const FAILING_PERMILLE: u32 = 500;

/// Replies asked for and lost per cycle, over the last second.
pub(crate) struct Health {
    window: VecDeque<(u32, u32)>,
    cycles: usize,
    lost: u64,
    asked: u64,
    last: Bus,
    logged_ns: u64,
}

/// While the bus is not good, a summary this often.
const LOG_EVERY_NS: u64 = 10_000_000_000;
const CHANGE_EVERY_NS: u64 = 1_000_000_000;

impl Health {
    pub fn new(rate_hz: f64) -> Self {
        let cycles = (rate_hz.round() as usize).max(1);
        Self {
            window: VecDeque::with_capacity(cycles),
            cycles,
            lost: 0,
            asked: 0,
            last: Bus::Good,
            logged_ns: 0,
        }
    }

    /// One read closed: `lost` of `asked` replies did not come whole.
    pub fn add(&mut self, lost: usize, asked: usize) {
        if self.window.len() == self.cycles
            && let Some((l, a)) = self.window.pop_front()
        {
            self.lost -= u64::from(l);
            self.asked -= u64::from(a);
        }
        self.window.push_back((lost as u32, asked as u32));
        self.lost += lost as u64;
        self.asked += asked as u64;
    }

    /// `n` replies counted lost came after all (late): they were not lost on the line.
    pub fn found(&mut self, n: u64) {
        let n = n.min(self.lost);
        self.lost -= n;
        let mut left = n;
        for (l, _) in self.window.iter_mut().rev() {
            let take = u64::from(*l).min(left);
            *l -= take as u32;
            left -= take;
        }
    }

    /// Replies lost per thousand asked for, over the last second.
    pub fn loss_permille(&self) -> u32 {
        (self.lost * 1000)
            .checked_div(self.asked)
            .map_or(0, |p| p as u32)
    }

    /// The bus given the motor data's age (`None`: no data yet) and the controller's input
    /// time-out.
    pub fn bus(&self, age_ns: Option<u64>, stale_after_ns: u64) -> Bus {
        let loss = self.loss_permille();
        if loss >= FAILING_PERMILLE || age_ns.is_none_or(|a| a > stale_after_ns) {
            Bus::Failing
        } else if loss >= DEGRADED_PERMILLE {
            Bus::Degraded
        } else {
            Bus::Good
        }
    }

    /// Says so when the bus changes, and every 10 s while it is not good.
    pub fn log(&mut self, now: u64, bus: Bus, age_ns: Option<u64>, c: &Totals) {
        // A bus losing some replies flips between the three often: a change is said at
        // most once a second, the state in force every 10 s.
        let since = now.saturating_sub(self.logged_ns);
        let changed = bus != self.last && since >= CHANGE_EVERY_NS;
        let due = bus != Bus::Good && since >= LOG_EVERY_NS;
        if !(changed || due) {
            return;
        }
        self.last = bus;
        self.logged_ns = now;
        let percent = f64::from(self.loss_permille()) / 10.0;
        let age_ms = age_ns.map(|a| a / 1_000_000);
        match bus {
            Bus::Good => tracing::info!(
                loss_percent = percent,
                dropped = c.dropped,
                crc_errors = c.crc_errors,
                "motor bus answering again: motor data fresh"
            ),
            Bus::Degraded => tracing::warn!(
                loss_percent = percent,
                dropped = c.dropped,
                crc_errors = c.crc_errors,
                garbage_bytes = c.garbage_bytes,
                "motor bus degraded: replies are being lost (check the cable, its termination \
                 and its routing away from the motor power); the goals still go out and the \
                 motor data is fresh"
            ),
            Bus::Failing => tracing::error!(
                loss_percent = percent,
                motor_data_age_ms = ?age_ms,
                dropped = c.dropped,
                crc_errors = c.crc_errors,
                garbage_bytes = c.garbage_bytes,
                "motor bus failing: most replies are lost or the motor data is too old for \
                 the controller, which holds the arm; check the bus cable, its termination and \
                 tendon.baud"
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_loss_rate_covers_the_last_second() {
        let mut h = Health::new(10.0);
        for _ in 0..10 {
            h.add(3, 6);
        }
        assert_eq!(h.loss_permille(), 500);
        for _ in 0..10 {
            h.add(0, 6);
        }
        assert_eq!(h.loss_permille(), 0, "the lost cycles left the window");
        h.add(1, 6);
        assert_eq!(h.loss_permille(), 1000 / 60);
        assert_eq!(h.bus(Some(0), 100), Bus::Degraded);
        assert_eq!(h.bus(Some(101), 100), Bus::Failing, "stale data");
        assert_eq!(h.bus(None, 100), Bus::Failing, "no data");
        h.found(1);
        assert_eq!(h.loss_permille(), 0, "the lost reply came late");
    }
}
