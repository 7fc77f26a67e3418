//! The driver processes this build has, named once. A driver's name is its node's role, its
//! subcommand (`softarm <name>`), its entry in `robot.drivers` and its systemd unit
//! (`softarm-driver@<name>`); what it is decides how the config checks it, what `softarm up`
//! and soak start and kill, and who must confirm an e-stop. Here in the contract, beside the
//! services they open, so that the config and the clients know the drivers without linking
//! their code.

/// A driver process.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Driver {
    pub name: &'static str,
    /// It moves actuators: it takes the e-stop and says STOPPED in its `motor_state`, so an
    /// e-stop is confirmed only once every live one has.
    pub moves: bool,
    /// A device of the real arm, configured in a section of its own name (`[tendon]`), which
    /// the config must then have. Else the whole arm simulated, which is listed alone.
    pub hardware: bool,
}

/// Every driver, in the order the config checks them.
pub const DRIVERS: [Driver; 3] = [
    Driver {
        name: "sim",
        moves: true,
        hardware: false,
    },
    Driver {
        name: "tendon",
        moves: true,
        hardware: true,
    },
    // The tracker only reads: it takes no e-stop.
    Driver {
        name: "tracker",
        moves: false,
        hardware: true,
    },
];

impl Driver {
    /// The driver of this name (a role or a `robot.drivers` entry), if it is one.
    pub fn named(name: &str) -> Option<&'static Driver> {
        DRIVERS.iter().find(|d| d.name == name)
    }

    /// The names of every driver, as the config's error lists them.
    pub fn names() -> [&'static str; DRIVERS.len()] {
        DRIVERS.map(|d| d.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_found() {
        for (i, d) in DRIVERS.iter().enumerate() {
            assert_eq!(Driver::named(d.name), Some(d));
            assert!(!DRIVERS[..i].iter().any(|e| e.name == d.name));
        }
        assert_eq!(Driver::named("controller"), None);
        assert_eq!(Driver::names(), ["sim", "tendon", "tracker"]);
    }
}
