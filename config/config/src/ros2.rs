//! `[ros2]`: `softarm ros2`, the running stack bridged to ROS 2 over DDS (no ROS install).

use serde::{Deserialize, Serialize};

use crate::{Closed, Invalid, Open, within};

/// Highest DDS domain id: RTPS maps domain d to UDP ports 7400 + 250 d + ..., which must stay
/// below 65536 with room for the participants.
pub const MAX_DOMAIN_ID: u16 = 232;

/// How far DDS discovery reaches: this host only, or every host of the attached networks (as
/// ROS 2's `ROS_AUTOMATIC_DISCOVERY_RANGE` = LOCALHOST / SUBNET).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Discovery {
    /// Advertises and multicasts on loopback (127.0.0.1) only; peers on this host find it.
    Localhost,
    /// Every network interface, as any ROS 2 node by default.
    Subnet,
}

/// The `[ros2]` section; every key has a default, and the section may be absent (off).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2Config {
    /// `softarm up` starts `softarm ros2` beside the stack.
    pub enabled: bool,
    /// The DDS domain (`ROS_DOMAIN_ID` of the ROS 2 side): 0, ROS 2's own default, so `ros2
    /// topic list` finds the arm without setting anything.
    pub domain_id: u16,
    /// "localhost" (default): only this host's ROS 2 nodes find the bridge; "subnet": any.
    pub discovery: Discovery,
    /// Way-point sets from ROS 2 are executed; false (default): refused, logged, reported.
    pub accept_waypoints: bool,
    /// Diagnostics published per second.
    pub status_hz: f64,
    /// Joint states and tracker positions published per second at most (the newest sample).
    pub topic_hz: f64,
}

impl Default for Ros2Config {
    fn default() -> Self {
        Self {
            enabled: false,
            domain_id: 0,
            discovery: Discovery::Localhost,
            accept_waypoints: false,
            status_hz: 1.0,
            topic_hz: 50.0,
        }
    }
}

impl Ros2Config {
    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        if self.domain_id > MAX_DOMAIN_ID {
            return Err((
                "ros2.domain_id".into(),
                format!(
                    "must be 0 to {MAX_DOMAIN_ID} (RTPS ports 7400 + 250 × domain stay below \
                     65536; 0 to 101 keep them out of Linux's ephemeral range), got {}",
                    self.domain_id
                ),
            ));
        }
        within("ros2.status_hz", self.status_hz, Closed(0.1), 10.0, " Hz")?;
        within("ros2.topic_hz", self.topic_hz, Open(0.0), 500.0, " Hz")
    }
}

#[cfg(test)]
mod tests {
    use super::Discovery;
    use crate::{Config, DEFAULT, with_overrides};

    fn parse(overrides: &[(&str, toml::Value)]) -> Result<Config, String> {
        let text = with_overrides(DEFAULT, overrides).unwrap();
        Config::parse(&text, "r.toml", "/".into()).map_err(|e| e.to_string())
    }

    #[test]
    fn the_bridge_is_off_read_only_and_on_this_host_by_default() {
        let c = parse(&[]).unwrap();
        assert!(!c.ros2.enabled);
        assert!(!c.ros2.accept_waypoints);
        assert_eq!(c.ros2.discovery, Discovery::Localhost);
        assert_eq!(c.ros2.domain_id, 0);
        // A config without the section (written before it existed) loads with the same.
        let old = DEFAULT.split("\n[ros2]").next().unwrap();
        assert!(!old.contains("[ros2]"));
        let c2 = Config::parse(old, "old.toml", "/".into()).unwrap();
        assert_eq!(c2.ros2, c.ros2);
    }

    #[test]
    fn every_key_is_checked_and_named() {
        for (key, value, want) in [
            (
                "ros2.domain_id",
                toml::Value::from(233),
                "ros2.domain_id: must be 0 to 232",
            ),
            // Types the parser refuses name the line (the key is on it).
            ("ros2.domain_id", (-1).into(), "`-1`, expected u16"),
            (
                "ros2.status_hz",
                0.0.into(),
                "ros2.status_hz: must be in [0.1, 10] Hz",
            ),
            (
                "ros2.status_hz",
                f64::NAN.into(),
                "ros2.status_hz: must be in [0.1, 10] Hz",
            ),
            (
                "ros2.topic_hz",
                1000.0.into(),
                "ros2.topic_hz: must be in (0, 500] Hz",
            ),
            ("ros2.discovery", "lan".into(), "unknown variant `lan`"),
            ("ros2.accept_waypoint", true.into(), "accept_waypoint"),
        ] {
            let e = parse(&[(key, value)]).unwrap_err();
            assert!(e.starts_with("r.toml:") && e.contains(want), "{key}: {e}");
        }
        let c = parse(&[
            ("ros2.discovery", "subnet".into()),
            ("ros2.domain_id", 42.into()),
        ])
        .unwrap();
        assert_eq!(
            (c.ros2.discovery, c.ros2.domain_id),
            (Discovery::Subnet, 42)
        );
    }
}
