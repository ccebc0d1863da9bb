//! The driver's settings: [`DriverConfig`], and [`RobotPeer`], the robot controller
//! it answers.

use super::FriError;
use crate::hw::fri::datagram::Quality;
use crate::hw::fri::DEFAULT_PORT;
use serde::Serialize;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};

/// The robot controller the driver answers: every datagram from anyone else is
/// dropped unanswered.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum RobotPeer {
    /// Any port of this IP address (`fri.robot_addr = "192.168.0.10"`).
    Host(IpAddr),
    /// Exactly this address and port (`fri.robot_addr = "192.168.0.10:49938"`).
    Exact(SocketAddr),
}

impl RobotPeer {
    /// Whether a datagram from `from` comes from the robot. IPv4 senders seen on a
    /// dual-stack IPv6 socket (`::ffff:a.b.c.d`) compare as IPv4.
    pub fn admits(&self, from: SocketAddr) -> bool {
        let ip = from.ip().to_canonical();
        match *self {
            RobotPeer::Host(host) => ip == host.to_canonical(),
            RobotPeer::Exact(addr) => ip == addr.ip().to_canonical() && from.port() == addr.port(),
        }
    }
}

impl std::str::FromStr for RobotPeer {
    type Err = FriError;

    fn from_str(text: &str) -> Result<RobotPeer, FriError> {
        let text = text.trim();
        if let Ok(addr) = text.parse::<SocketAddr>() {
            Ok(RobotPeer::Exact(addr))
        } else if let Ok(ip) = text.parse::<IpAddr>() {
            Ok(RobotPeer::Host(ip))
        } else {
            Err(FriError::BadConfig {
                field: "fri.robot_addr",
                value: text.to_string(),
                problem: "not an IP address (the robot controller's, e.g. 192.168.0.10) or an IP address with port (192.168.0.10:49938)",
            })
        }
    }
}

impl std::fmt::Display for RobotPeer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RobotPeer::Host(ip) => write!(f, "{ip} (any port)"),
            RobotPeer::Exact(addr) => write!(f, "{addr}"),
        }
    }
}

/// Settings of the driver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriverConfig {
    /// Local UDP address to bind (FRI default port 49938; port 0 picks a free one).
    pub bind_addr: SocketAddr,
    /// The robot controller; datagrams from anyone else are dropped unanswered.
    pub robot: RobotPeer,
    /// A measurement missing for this long is a safe stop (s).
    pub timeout_s: f64,
    /// Lowest link quality at which the driver commands (BAD, OK or PERFECT).
    pub min_command_quality: Quality,
    /// Largest distance between a trajectory's start and the commanded position (rad).
    pub start_tolerance_rad: f64,
}

impl Default for DriverConfig {
    fn default() -> DriverConfig {
        DriverConfig {
            bind_addr: SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), DEFAULT_PORT),
            // The simulator's host; a cell's configuration always names its robot.
            robot: RobotPeer::Host(IpAddr::V4(Ipv4Addr::LOCALHOST)),
            timeout_s: 0.1,
            min_command_quality: Quality::Bad,
            start_tolerance_rad: 1e-4,
        }
    }
}

impl DriverConfig {
    /// The driver settings of the cell configuration's `[fri]` section.
    pub fn from_cell(fri: &crate::config::FriConfig) -> Result<DriverConfig, FriError> {
        let bind_addr = fri.bind_addr.parse().map_err(|_| FriError::BadConfig {
            field: "fri.bind_addr",
            value: fri.bind_addr.clone(),
            problem: "not an IP address with port, e.g. 127.0.0.1:49938",
        })?;
        let config = DriverConfig {
            bind_addr,
            robot: fri.robot_addr.parse()?,
            timeout_s: fri.timeout_s,
            ..DriverConfig::default()
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks every value is in range.
    pub fn validate(&self) -> Result<(), FriError> {
        if !(self.timeout_s.is_finite() && self.timeout_s > 0.0) {
            return Err(FriError::BadConfig {
                field: "timeout_s",
                value: self.timeout_s.to_string(),
                problem: "must be a finite number > 0",
            });
        }
        if self.min_command_quality < Quality::Bad {
            return Err(FriError::BadConfig {
                field: "min_command_quality",
                value: format!("{:?}", self.min_command_quality),
                problem: "never command below BAD",
            });
        }
        if !(self.start_tolerance_rad.is_finite() && self.start_tolerance_rad >= 0.0) {
            return Err(FriError::BadConfig {
                field: "start_tolerance_rad",
                value: self.start_tolerance_rad.to_string(),
                problem: "must be a finite number >= 0",
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn configuration_comes_from_the_cell_file() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(crate::config::DEFAULT_CONFIG_PATH);
        let cell = crate::config::CellConfig::load(&path).unwrap();
        let config = DriverConfig::from_cell(&cell.fri).unwrap();
        assert_eq!(config.bind_addr, "127.0.0.1:49938".parse().unwrap());
        assert_eq!(config.bind_addr.port(), DEFAULT_PORT);
        assert_eq!(config.timeout_s, cell.fri.timeout_s);
        assert_eq!(config.min_command_quality, Quality::Bad);
        let mut fri = cell.fri.clone();
        fri.bind_addr = "localhost".into();
        let err = DriverConfig::from_cell(&fri).unwrap_err();
        assert!(
            err.to_string().contains("fri.bind_addr = localhost"),
            "{err}"
        );
    }
}
