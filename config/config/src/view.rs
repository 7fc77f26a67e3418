//! `[view]`: `softarm view`, the running stack served live over the Foxglove WebSocket
//! protocol, and the 3-D scene it draws (also written by `softarm record`).

use std::net::SocketAddr;

use serde::{Deserialize, Serialize};

use crate::{Closed, Invalid, count, within};

/// The `[view]` section; every key has a default, and the section may be absent (off).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ViewConfig {
    /// `softarm up` starts `softarm view` beside the stack.
    pub enabled: bool,
    /// Where the view listens: an IP address and a port (0: any free port, logged).
    pub listen: String,
    /// A `listen` address other than loopback is refused unless this is set: the view has no
    /// authentication, and whoever reaches it sees every service of the stack.
    pub allow_remote: bool,
    /// Scene updates per second (the arm and the tracker; way-points and reached points when
    /// they change and once a second). `softarm record` writes the scene at this rate too.
    pub scene_hz: f64,
    /// How much of the tracker's path the scene draws (s).
    pub trail_s: f64,
    /// Messages queued per client; a client that falls further behind loses the oldest.
    pub backlog: usize,
}

impl Default for ViewConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            listen: "127.0.0.1:8765".into(),
            allow_remote: false,
            scene_hz: 30.0,
            trail_s: 3.0,
            backlog: 1024,
        }
    }
}

impl ViewConfig {
    /// The address to listen on: `listen` (the config's `view.listen`, or a command line's
    /// `--listen`), loopback unless `allow_remote`. The error starts with `key`.
    pub fn address(&self, listen: &str, key: &str) -> Result<SocketAddr, String> {
        self.check(listen, key)
            .map_err(|(k, m)| format!("{k}: {m}"))
    }

    fn check(&self, listen: &str, key: &str) -> Result<SocketAddr, Invalid> {
        let Ok(a) = listen.parse::<SocketAddr>() else {
            return Err((
                key.into(),
                format!("{listen:?} is not an IP address and port (e.g. 127.0.0.1:8765)"),
            ));
        };
        if !a.ip().is_loopback() && !self.allow_remote {
            return Err((
                key.into(),
                format!(
                    "{a} is not a loopback address: the view has no authentication and shows \
                     every service of the stack to whoever connects; set view.allow_remote = \
                     true in the config to serve other machines"
                ),
            ));
        }
        Ok(a)
    }

    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        self.check(&self.listen, "view.listen")?;
        within("view.scene_hz", self.scene_hz, Closed(1.0), 100.0, " Hz")?;
        within("view.trail_s", self.trail_s, Closed(0.0), 60.0, " s")?;
        count("view.backlog", self.backlog, 16, 65_536)
    }
}

#[cfg(test)]
mod tests {
    use crate::{Config, DEFAULT, with_overrides};

    fn parse(overrides: &[(&str, toml::Value)]) -> Result<Config, String> {
        let text = with_overrides(DEFAULT, overrides).unwrap();
        Config::parse(&text, "v.toml", "/".into()).map_err(|e| e.to_string())
    }

    #[test]
    fn the_view_is_off_and_on_loopback_by_default() {
        let c = parse(&[]).unwrap();
        assert!(!c.view.enabled);
        assert!(
            c.view
                .address(&c.view.listen, "view.listen")
                .unwrap()
                .ip()
                .is_loopback()
        );
        // A config without the section (written before it existed) loads with the same.
        let old = DEFAULT.split("\n[view]").next().unwrap();
        let c2 = Config::parse(old, "old.toml", "/".into()).unwrap();
        assert_eq!(c2.view, c.view);
    }

    #[test]
    fn another_address_than_loopback_is_an_explicit_choice() {
        let e = parse(&[("view.listen", "0.0.0.0:8765".into())]).unwrap_err();
        assert!(
            e.starts_with("v.toml:") && e.contains(": view.listen: 0.0.0.0:8765 is not a loopback"),
            "{e}"
        );
        assert!(e.contains("view.allow_remote = true"), "{e}");
        let c = parse(&[
            ("view.listen", "0.0.0.0:8765".into()),
            ("view.allow_remote", true.into()),
        ])
        .unwrap();
        assert_eq!(c.view.listen, "0.0.0.0:8765");
        let ipv6 = parse(&[("view.listen", "[::1]:0".into())]).unwrap();
        assert!(ipv6.view.address(&ipv6.view.listen, "k").is_ok());
        let e = c.view.address("localhost:8765", "--listen").unwrap_err();
        assert_eq!(
            e,
            "--listen: \"localhost:8765\" is not an IP address and port (e.g. 127.0.0.1:8765)"
        );
    }

    #[test]
    fn rates_and_sizes_are_bounded() {
        for (key, value, want) in [
            (
                "view.scene_hz",
                toml::Value::from(0.0),
                "view.scene_hz: must be in [1, 100] Hz",
            ),
            (
                "view.scene_hz",
                f64::NAN.into(),
                "view.scene_hz: must be in [1, 100] Hz",
            ),
            (
                "view.trail_s",
                (-1.0).into(),
                "view.trail_s: must be in [0, 60] s",
            ),
            (
                "view.backlog",
                1.into(),
                "view.backlog: must be 16 to 65536, got 1",
            ),
            (
                "view.listen",
                "nowhere".into(),
                "view.listen: \"nowhere\" is not an IP address",
            ),
        ] {
            let e = parse(&[(key, value)]).unwrap_err();
            assert!(e.contains(want), "{key}: {e}");
        }
    }
}
