//! Who is who: the launcher, processing nodes and sensors, and their names.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// An actor of the network. Names are `launcher`, `node-<i>`, `sensor-<i>`
/// and `mac-<i>`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum ActorId {
    Launcher,
    Node(u16),
    Sensor(u16),
    /// The multiple-access channel between node i's sensors and node i
    /// (a scenario with a `[channel]`).
    Mac(u16),
}

impl ActorId {
    /// The (kind, index) pair carried in a message header.
    pub fn to_wire(self) -> (u8, u16) {
        match self {
            ActorId::Launcher => (0, 0),
            ActorId::Node(i) => (1, i),
            ActorId::Sensor(i) => (2, i),
            ActorId::Mac(i) => (3, i),
        }
    }

    pub fn from_wire(kind: u8, index: u16) -> Option<Self> {
        match kind {
            0 if index == 0 => Some(ActorId::Launcher),
            1 => Some(ActorId::Node(index)),
            2 => Some(ActorId::Sensor(index)),
            3 => Some(ActorId::Mac(index)),
            _ => None,
        }
    }
}

impl fmt::Display for ActorId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ActorId::Launcher => write!(f, "launcher"),
            ActorId::Node(i) => write!(f, "node-{i}"),
            ActorId::Sensor(i) => write!(f, "sensor-{i}"),
            ActorId::Mac(i) => write!(f, "mac-{i}"),
        }
    }
}

impl FromStr for ActorId {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s == "launcher" {
            return Ok(ActorId::Launcher);
        }
        let parse = |rest: &str| {
            rest.parse::<u16>().map_err(|_| {
                format!("`{s}` is not an actor name (launcher, node-<i>, sensor-<i>, mac-<i>)")
            })
        };
        if let Some(rest) = s.strip_prefix("node-") {
            Ok(ActorId::Node(parse(rest)?))
        } else if let Some(rest) = s.strip_prefix("sensor-") {
            Ok(ActorId::Sensor(parse(rest)?))
        } else if let Some(rest) = s.strip_prefix("mac-") {
            Ok(ActorId::Mac(parse(rest)?))
        } else {
            Err(format!(
                "`{s}` is not an actor name (launcher, node-<i>, sensor-<i>, mac-<i>)"
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for a in [
            ActorId::Launcher,
            ActorId::Node(3),
            ActorId::Sensor(224),
            ActorId::Mac(0),
        ] {
            assert_eq!(a.to_string().parse::<ActorId>().unwrap(), a);
            let (k, i) = a.to_wire();
            assert_eq!(ActorId::from_wire(k, i), Some(a));
        }
        assert!("node-x".parse::<ActorId>().is_err());
        assert!("robot-1".parse::<ActorId>().is_err());
        assert_eq!(ActorId::from_wire(9, 0), None);
    }
}
