//! The scenario's `[channel]` table: a multiple-access channel between a
//! fusion centre's sensors and the centre (dissertation ch. 4). Its
//! sensors transmit at once in M slots; a channel actor hears each slot's
//! sum, adds the receiver's noise and delivers the M values to the centre.

use serde::{Deserialize, Serialize};

use super::{CensoringPolicy, Motion, Scenario};
use crate::check::Check;
use crate::ScenarioError;

/// How the centre decides who transmits in which slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MacDesign {
    /// Transmission probabilities that maximize `det J` under the energy
    /// budget, and a sensing matrix drawn from them (eqs. 4.7, 4.25).
    Compressive,
    /// As `compressive`, but with the expected information of the drawn
    /// matrix, which counts a sensor heard in several slots once, in
    /// place of eq. 4.19's average.
    CountedOnce,
    /// Every sensor with the same probability `E / (M N)`, the matrix
    /// drawn as for `compressive`: random sensors sharing M slots.
    Uniform,
    /// `energy` sensors drawn uniformly, each in a slot of its own.
    Random,
    /// Every sensor in a slot of its own: parallel channels.
    All,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MacConfig {
    pub design: MacDesign,
    /// M, the slots of a step (`compressive`, `counted_once`, `uniform`;
    /// the other designs use one slot per transmitting sensor).
    #[serde(default = "one_slot")]
    pub slots: u32,
    /// E, the transmissions a step may spend on average (`M Σp ≤ E`); with
    /// `random`, the number of sensors drawn.
    pub energy: f64,
    /// ε, the variance of the receiver's noise in each slot.
    pub receiver_noise: f64,
    /// How long the channel waits for a slot's transmissions after the
    /// centre's activation before it delivers what it heard.
    #[serde(default = "default_slot_timeout_ms")]
    pub slot_timeout_ms: f64,
}

fn one_slot() -> u32 {
    1
}

fn default_slot_timeout_ms() -> f64 {
    50.0
}

/// The most slots a step may have: a sensor's column travels as a 32-bit
/// mask.
pub const MAX_SLOTS: u32 = 32;

impl MacConfig {
    /// The slots every step of this design has, given the centre's sensors.
    pub fn slots_for(&self, sensors: usize) -> usize {
        match self.design {
            MacDesign::Compressive | MacDesign::CountedOnce | MacDesign::Uniform => {
                self.slots as usize
            }
            MacDesign::Random => self.energy as usize,
            MacDesign::All => sensors,
        }
    }
}

impl Scenario {
    /// A channel serves one fusion centre that tracks a moving target with
    /// unquantized amplitudes or RSS; it has none of the CF/DPF's parts.
    pub(super) fn validate_mac(&self, file: &str) -> Result<(), ScenarioError> {
        let Some(mac) = &self.channel else {
            return Ok(());
        };
        let check = Check::root(file);
        let with = "with a [channel]";
        match mac.design {
            MacDesign::Compressive | MacDesign::CountedOnce | MacDesign::Uniform
                if !(1..=MAX_SLOTS).contains(&mac.slots) =>
            {
                return Err(check.fail(
                    "channel.slots",
                    format!("1 to {MAX_SLOTS} slots"),
                    mac.slots,
                ))
            }
            MacDesign::Random if !(1.0..=MAX_SLOTS as f64).contains(&mac.energy) => {
                return Err(check.fail(
                    "channel.energy",
                    format!("1 to {MAX_SLOTS} sensors with design = \"random\""),
                    mac.energy,
                ))
            }
            _ => {}
        }
        check.positive("channel.energy", mac.energy)?;
        check.positive("channel.receiver_noise", mac.receiver_noise)?;
        check.positive("channel.slot_timeout_ms", mac.slot_timeout_ms)?;
        let nodes = match (&self.nodes.grid, &self.nodes.positions) {
            (Some(g), _) => g[0] as usize * g[1] as usize,
            (_, Some(p)) => p.len(),
            _ => 0,
        };
        if nodes != 1 {
            return Err(check.fail(
                "nodes",
                format!(
                    "one fusion centre {with} (several centres with a channel each are not built)"
                ),
                format!("{nodes} nodes"),
            ));
        }
        let sensors = match (&self.sensors.per_cell, &self.sensors.positions) {
            (Some(g), _) => g[0] as usize * g[1] as usize,
            (_, Some(p)) => p.len(),
            _ => 0,
        };
        // The schedule carries a column for each transmitter in one
        // message; with every sensor sending, each needs a slot.
        let most = (wire::MAX_MESSAGE_BYTES - wire::HEADER_BYTES - 3) / wire::SLOT_COLUMN_BYTES;
        if sensors > most {
            return Err(check.fail(
                "sensors",
                format!("at most {most} sensors {with} (one schedule message holds their columns)"),
                format!("{sensors} sensors"),
            ));
        }
        if mac.design == MacDesign::All && sensors > MAX_SLOTS as usize {
            return Err(check.fail(
                "channel.design",
                format!("\"all\" with at most {MAX_SLOTS} sensors (one slot each)"),
                format!("\"all\" with {sensors} sensors"),
            ));
        }
        if !self.quantizer.raw {
            return Err(check.fail(
                "quantizer.raw",
                format!("true {with}: the channel adds analog values"),
                "false",
            ));
        }
        let law = self.observation.law();
        if !(law.is::<bounds::observation::Amplitude>() || law.is::<bounds::observation::Rss>()) {
            return Err(check.fail(
                "observation.kind",
                format!("\"amplitude\" or \"rss\" {with}: a sum of bearings means nothing"),
                format!("\"{}\"", law.name()),
            ));
        }
        if self.consensus.protocol != super::ConsensusProtocol::AVERAGE {
            return Err(check.fail(
                "consensus.protocol",
                format!("\"average\" {with} (one centre has no neighbours to fuse with)"),
                format!("\"{}\"", self.consensus.protocol.name()),
            ));
        }
        let linear =
            "the centre's recursion (eq. 4.8) takes a linear, constant-velocity transition";
        match self.dynamics.turn() {
            None => {
                return Err(check.fail(
                    "dynamics.kind",
                    format!("\"coordinated_turn\" {with}: {linear}"),
                    format!("\"{}\"", self.dynamics.kind()),
                ))
            }
            Some(turn) if turn.maneuver_accel != 0.0 => {
                return Err(check.fail(
                    "dynamics.maneuver_accel",
                    format!("0 {with}: {linear}"),
                    turn.maneuver_accel,
                ));
            }
            Some(_) => {}
        }
        if self.target.motion != Motion::Moving {
            return Err(check.fail("target.motion", format!("\"moving\" {with}"), "\"static\""));
        }
        let theirs = "its default with a [channel] (the fusion centre has no such part)";
        self.refuse_cf_dpf_parts(file, theirs)?;
        if self.reference.centralized {
            return Err(check.fail("reference.centralized", theirs, "true"));
        }
        if self.censoring.policy != CensoringPolicy::Off {
            return Err(check.fail(
                "censoring.policy",
                theirs,
                format!("{:?}", self.censoring.policy),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::scenario::{Scenario, COMPRESSIVE_SCENARIO};
    use crate::ScenarioError;

    fn refused_key(overrides: &[&str]) -> String {
        let overrides: Vec<String> = overrides.iter().map(|o| o.to_string()).collect();
        match Scenario::from_toml(COMPRESSIVE_SCENARIO, "c", &overrides) {
            Err(ScenarioError::Invalid { key, .. }) => key,
            other => panic!("{overrides:?}: {other:?}"),
        }
    }

    /// Each value out of range, and each part a fusion centre does not
    /// have, is refused by its key.
    #[test]
    fn a_bad_channel_is_refused_by_its_key() {
        assert!(Scenario::from_toml(COMPRESSIVE_SCENARIO, "c", &[]).is_ok());
        for (overrides, key) in [
            (&["channel.slots=0"][..], "channel.slots"),
            (&["channel.slots=33"], "channel.slots"),
            (&["channel.energy=0"], "channel.energy"),
            (
                &["channel.design=\"random\"", "channel.energy=40"],
                "channel.energy",
            ),
            (&["channel.receiver_noise=0"], "channel.receiver_noise"),
            (&["channel.slot_timeout_ms=-1"], "channel.slot_timeout_ms"),
            (&["nodes.grid=[2,1]"], "nodes"),
            (&["quantizer.raw=false"], "quantizer.raw"),
            (
                &["consensus.protocol=\"kl_consensus\""],
                "consensus.protocol",
            ),
            (&["reference.centralized=true"], "reference.centralized"),
            (
                &["sensors.per_cell=[6,6]", "channel.design=\"all\""],
                "channel.design",
            ),
            (&["sensors.per_cell=[11,10]"], "sensors"),
            (&["dynamics.maneuver_accel=0.5"], "dynamics.maneuver_accel"),
        ] {
            assert_eq!(refused_key(overrides), key, "{overrides:?}");
        }
    }
}
