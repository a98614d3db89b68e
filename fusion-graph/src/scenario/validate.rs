//! Every value of a scenario checked against its range and against the
//! others; an error names the file and the key.

use super::*;
use crate::check::Check;

impl Scenario {
    /// The random-exchange paper's trackers are a different node: one particle filter
    /// weighed with raw or quantized measurements and fused as a Gaussian.
    /// The CF/DPF's parts that have no meaning there are refused by name
    /// rather than ignored.
    fn validate_diffusion(&self, file: &str) -> Result<(), ScenarioError> {
        let protocol = self.consensus.protocol;
        if !protocol.is_diffusion() {
            return Ok(());
        }
        self.refuse_cf_dpf_parts(
            file,
            &format!(
                "its default with consensus.protocol = \"{}\" (the random-exchange and KL trackers have no such part)",
                protocol.name()
            ),
        )
    }

    /// The CF/DPF's parts a node of another kind does not have, refused by
    /// key if the scenario asks for one: a sensor manager other than
    /// random, a network-wide cap on active sensors, censoring, the
    /// auxiliary FIM and the innovation gate.
    pub(super) fn refuse_cf_dpf_parts(
        &self,
        file: &str,
        expected: &str,
    ) -> Result<(), ScenarioError> {
        let refuse = |key: &str, got: String| {
            Err(ScenarioError::Invalid {
                file: file.into(),
                key: key.into(),
                expected: expected.into(),
                got,
            })
        };
        if self.sensors.manager != SensorManagerKind::RANDOM {
            return refuse(
                "sensors.manager",
                format!("\"{}\"", self.sensors.manager.name()),
            );
        }
        if let Some(m) = self.sensors.max_active_total {
            return refuse("sensors.max_active_total", m.to_string());
        }
        if self.censoring.policy != CensoringPolicy::Off {
            return refuse("censoring.policy", format!("{:?}", self.censoring.policy));
        }
        if self.consensus.auxiliary_fim {
            return refuse("consensus.auxiliary_fim", "true".into());
        }
        if self.filter.gate > 0.0 {
            return refuse("filter.gate", self.filter.gate.to_string());
        }
        Ok(())
    }

    /// A static target is located, not tracked: by the `ml_location`
    /// protocol's nodes and no other, which have no sensor selection,
    /// censoring, gate or centralized filter (their reference is the
    /// network's summed information itself).
    fn validate_location(&self, file: &str) -> Result<(), ScenarioError> {
        let protocol = self.consensus.protocol;
        let locating = protocol == ConsensusProtocol::ML_LOCATION;
        let static_target = self.target.motion == Motion::Static;
        let invalid = |key: &str, expected: String, got: String| {
            Err(ScenarioError::Invalid {
                file: file.into(),
                key: key.into(),
                expected,
                got,
            })
        };
        if locating != static_target {
            return if locating {
                invalid(
                    "target.motion",
                    "\"static\" with consensus.protocol = \"ml_location\"".into(),
                    "\"moving\"".into(),
                )
            } else {
                invalid(
                    "consensus.protocol",
                    "\"ml_location\" for a static target (target.motion = \"static\")".into(),
                    format!("\"{}\"", protocol.name()),
                )
            };
        }
        if !locating {
            return Ok(());
        }
        let theirs =
            "its default with consensus.protocol = \"ml_location\" (the locator has no such part)";
        self.refuse_cf_dpf_parts(file, theirs)?;
        if self.reference.centralized {
            return invalid("reference.centralized", theirs.into(), "true".into());
        }
        let cells = 1usize << self.quantizer.bits.min(16);
        if !self.quantizer.raw && cells - 1 > wire::MAX_THRESHOLDS {
            return invalid(
                "quantizer.bits",
                format!(
                    "at most 4 with consensus.protocol = \"ml_location\" (its {} thresholds travel with each activation)",
                    wire::MAX_THRESHOLDS
                ),
                self.quantizer.bits.to_string(),
            );
        }
        Ok(())
    }

    /// Checks every value's range; the error names the file and the key.
    pub fn validate(&self, file: &str) -> Result<(), ScenarioError> {
        let check = Check::root(file);
        let bad = |key: &str, expected: &str, got: String| Err(check.fail(key, expected, got));
        if self.steps == 0 {
            return bad("steps", "at least 1", "0".into());
        }
        check.positive("region.width", self.region.width)?;
        check.positive("region.height", self.region.height)?;
        match (&self.nodes.grid, &self.nodes.positions) {
            (Some(g), None) if g[0] > 0 && g[1] > 0 => {}
            (Some(g), None) => return bad("nodes.grid", "two counts >= 1", format!("{g:?}")),
            (None, Some(p)) if !p.is_empty() => {}
            _ => {
                return bad(
                    "nodes",
                    "exactly one of `grid` or `positions` (non-empty)",
                    "neither or both".into(),
                )
            }
        }
        match (&self.sensors.per_cell, &self.sensors.positions) {
            (Some(g), None) if g[0] > 0 && g[1] > 0 => {
                if self.nodes.grid.is_none() {
                    return bad(
                        "sensors.per_cell",
                        "a node grid (nodes.grid) to place the sensors in",
                        "explicit node positions".into(),
                    );
                }
            }
            (Some(g), None) => return bad("sensors.per_cell", "two counts >= 1", format!("{g:?}")),
            (None, Some(p)) if !p.is_empty() => {}
            _ => {
                return bad(
                    "sensors",
                    "exactly one of `per_cell` or `positions` (non-empty)",
                    "neither or both".into(),
                )
            }
        }
        // Indices are u16 on the wire, and every actor is a process: a
        // network past these is refused here, before its topology is built
        // (a 1000 × 1000 grid once took the machine's memory doing so).
        let at_most = |key: &str, count: u64, max: u64, what: &str| {
            if count > max {
                bad(
                    key,
                    &format!("at most {max} {what}"),
                    format!("{count} {what}"),
                )
            } else {
                Ok(())
            }
        };
        let (nodes, nodes_key) = match (&self.nodes.grid, &self.nodes.positions) {
            (Some(g), _) => (g[0] as u64 * g[1] as u64, "nodes.grid"),
            (_, Some(p)) => (p.len() as u64, "nodes.positions"),
            _ => (0, "nodes"),
        };
        at_most(nodes_key, nodes, MAX_NODES, "nodes")?;
        let (sensors, sensors_key) = match (&self.sensors.per_cell, &self.sensors.positions) {
            (Some(g), _) => (g[0] as u64 * g[1] as u64 * nodes, "sensors.per_cell"),
            (_, Some(p)) => (p.len() as u64, "sensors.positions"),
            _ => (0, "sensors"),
        };
        at_most(sensors_key, sensors, MAX_SENSORS, "sensors")?;
        if self.sensors.active_per_node == 0 {
            return bad("sensors.active_per_node", "at least 1", "0".into());
        }
        check.positive("censoring.listen_ms", self.censoring.listen_ms)?;
        let budget = self.censoring.budget;
        if self.censoring.policy != CensoringPolicy::Off
            && !(budget > 0.0 && budget <= self.sensors.active_per_node as f64)
        {
            return bad(
                "censoring.budget",
                &format!(
                    "more than 0 and at most sensors.active_per_node ({})",
                    self.sensors.active_per_node
                ),
                budget.to_string(),
            );
        }
        check.positive("fusion_graph.radius", self.fusion_graph.radius)?;
        for (i, v) in self.target.position.iter().enumerate() {
            if !v.is_finite() {
                return bad(
                    &format!("target.position[{i}]"),
                    "a finite number",
                    v.to_string(),
                );
            }
        }
        if !self.target.course_deg.is_finite() {
            return bad(
                "target.course_deg",
                "a finite number",
                self.target.course_deg.to_string(),
            );
        }
        check.non_negative("target.speed", self.target.speed)?;
        if self.filter.particles < 10 {
            return bad(
                "filter.particles",
                "at least 10",
                self.filter.particles.to_string(),
            );
        }
        // The dynamics, the observation law, the quantizer and the prior,
        // through the constructors the actors use.
        self.models_named(file)?;
        if self.consensus.rounds == 0 {
            return bad("consensus.rounds", "at least 1", "0".into());
        }
        let accuracy = self.consensus.accuracy;
        if !(accuracy > 0.0 && accuracy < 1.0) {
            return bad(
                "consensus.accuracy",
                "a share of the disagreement, between 0 and 1",
                accuracy.to_string(),
            );
        }
        check.positive(
            "consensus.round_timeout_ms",
            self.consensus.round_timeout_ms,
        )?;
        self.validate_diffusion(file)?;
        self.validate_location(file)?;
        self.validate_mac(file)?;
        check.non_negative("filter.gate", self.filter.gate)?;
        check.positive("clock.step_period_ms", self.clock.step_period_ms)?;
        check.positive("clock.step_timeout_ms", self.clock.step_timeout_ms)?;
        for (i, f) in self.faults.iter().enumerate() {
            f.check(file, i, self.steps)?;
        }
        Ok(())
    }
}
