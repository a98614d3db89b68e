//! How a scenario lays out its network: nodes on a grid or at positions,
//! sensors in each node's cell or at positions (each then owned by the
//! nearest node), the fusion graph within a radius; and the checks that
//! the faults and hosts name actors of that network.

use super::{dist2, Topology};
use crate::check::Check;
use crate::hosts::Placement;
use crate::scenario::Scenario;
use crate::ScenarioError;
use wire::ActorId;

impl Topology {
    /// Builds the topology and checks the fusion graph and the fault
    /// schedule's actor names against it.
    pub fn from_scenario(s: &Scenario, file: &str) -> Result<Self, ScenarioError> {
        let (node_positions, cells) = place_nodes(s);
        let (sensor_positions, sensor_owner) = place_sensors(s, &node_positions, cells.as_ref());
        let mut node_sensors = vec![Vec::new(); node_positions.len()];
        for (i, owner) in sensor_owner.iter().enumerate() {
            node_sensors[*owner as usize].push(i as u16);
        }
        let r2 = s.fusion_graph.radius * s.fusion_graph.radius;
        let neighbours: Vec<Vec<u16>> = (0..node_positions.len())
            .map(|a| {
                (0..node_positions.len())
                    .filter(|&b| b != a && dist2(node_positions[a], node_positions[b]) <= r2)
                    .map(|b| b as u16)
                    .collect()
            })
            .collect();
        let topology = Self {
            node_positions: node_positions.into(),
            sensor_positions: sensor_positions.into(),
            sensor_owner: sensor_owner.into(),
            node_sensors: node_sensors.into(),
            neighbours: neighbours.into(),
            macs: s.channel.is_some(),
            payloads: s.vocabulary.payloads(),
        };
        if !s.fusion_graph.allow_disconnected
            && topology.components(&topology.all_alive()).len() > 1
        {
            return Err(ScenarioError::Invalid {
                file: file.into(),
                key: "fusion_graph.radius".into(),
                expected:
                    "a radius that connects every node (or fusion_graph.allow_disconnected = true)"
                        .into(),
                got: format!(
                    "{} m gives a disconnected fusion graph",
                    s.fusion_graph.radius
                ),
            });
        }
        // A node activates at most the sensors it has: a cap above every
        // node's count is a mistake, not a wish (with a grid, every node has
        // the same count).
        let most = topology.most_sensors_per_node();
        if s.sensors.active_per_node as usize > most {
            return Err(ScenarioError::Invalid {
                file: file.into(),
                key: "sensors.active_per_node".into(),
                expected: format!("at most the sensors of a node ({most} at the most)"),
                got: s.sensors.active_per_node.to_string(),
            });
        }
        for (i, f) in s.faults.iter().enumerate() {
            let targets = f.kind().targets();
            for name in targets.names {
                let ok = name.parse::<ActorId>().ok().is_some_and(|a| {
                    topology.contains(a)
                        && a != ActorId::Launcher
                        // A channel's links may be faulted; no fault stops
                        // the channel itself.
                        && (targets.key == "links" || !matches!(a, ActorId::Mac(_)))
                        && (!targets.sensors_only || matches!(a, ActorId::Sensor(_)))
                });
                if !ok {
                    let expected = if targets.sensors_only {
                        format!(
                            "a sensor of this network (sensor-0..sensor-{})",
                            topology.sensors() - 1
                        )
                    } else {
                        format!(
                            "an actor of this network (node-0..node-{}, sensor-0..sensor-{})",
                            topology.nodes() - 1,
                            topology.sensors() - 1
                        )
                    };
                    return Err(Check::fault(file, i).fail(targets.key, expected, name));
                }
            }
        }
        Placement::from_scenario(s, &topology, file, false)?;
        Ok(topology)
    }
}

/// Grid cell size and origin of each node, when nodes sit on a grid.
struct Cells {
    width: f64,
    height: f64,
    origins: Vec<[f64; 2]>,
}

fn place_nodes(s: &Scenario) -> (Vec<[f64; 2]>, Option<Cells>) {
    if let Some(p) = &s.nodes.positions {
        return (p.clone(), None);
    }
    let [cols, rows] = s.nodes.grid.expect("validated: grid or positions");
    let (w, h) = (s.region.width / cols as f64, s.region.height / rows as f64);
    let mut positions = Vec::new();
    let mut origins = Vec::new();
    for r in 0..rows {
        for c in 0..cols {
            let origin = [c as f64 * w, r as f64 * h];
            origins.push(origin);
            positions.push([origin[0] + w / 2.0, origin[1] + h / 2.0]);
        }
    }
    (
        positions,
        Some(Cells {
            width: w,
            height: h,
            origins,
        }),
    )
}

fn place_sensors(
    s: &Scenario,
    nodes: &[[f64; 2]],
    cells: Option<&Cells>,
) -> (Vec<[f64; 2]>, Vec<u16>) {
    if let (Some([nx, ny]), Some(cells)) = (s.sensors.per_cell, cells) {
        let mut positions = Vec::new();
        let mut owner = Vec::new();
        for (n, origin) in cells.origins.iter().enumerate() {
            for j in 0..ny {
                for i in 0..nx {
                    // Centres of an nx × ny sub-grid: 50, 150, …, 450 m in a 500 m cell.
                    positions.push([
                        origin[0] + (i as f64 + 0.5) * cells.width / nx as f64,
                        origin[1] + (j as f64 + 0.5) * cells.height / ny as f64,
                    ]);
                    owner.push(n as u16);
                }
            }
        }
        return (positions, owner);
    }
    let positions = s.sensors.positions.clone().unwrap_or_default();
    let owner = positions
        .iter()
        .map(|p| {
            (0..nodes.len())
                .min_by(|&a, &b| dist2(*p, nodes[a]).total_cmp(&dist2(*p, nodes[b])))
                .unwrap_or(0) as u16
        })
        .collect();
    (positions, owner)
}
