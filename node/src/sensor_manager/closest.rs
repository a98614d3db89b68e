//! The closest-sensor approach of the selection paper's comparison.

use fusion_graph::Scenario;

use super::{SelectionContext, SensorManager};

/// The sensors nearest the predicted target position, network-wide: walking
/// every live node's sensors from the nearest out, a sensor is taken while
/// its node has fewer than `per_node` and fewer than the network's cap are
/// taken. The node activates the ones of its own among them.
///
/// Every node ranks from its own fusion filter's prediction. The nodes'
/// predictions agree to centimetres, so they agree on the set except when
/// two sensors are that close to the same distance; no message is sent.
#[derive(Debug, Clone)]
pub struct Closest {
    per_node: usize,
    max_total: Option<usize>,
}

impl Closest {
    pub fn new(per_node: usize, max_total: Option<usize>) -> Self {
        Self {
            per_node,
            max_total,
        }
    }

    pub fn for_scenario(scenario: &Scenario) -> Self {
        let s = &scenario.sensors;
        Self::new(
            s.active_per_node as usize,
            s.max_active_total.map(|m| m as usize),
        )
    }
}

impl SensorManager for Closest {
    fn needs_prediction(&self) -> bool {
        true
    }

    fn choose(&mut self, context: &SelectionContext<'_>) -> Vec<usize> {
        let Some(particles) = context.predicted.filter(|p| !p.is_empty()) else {
            return Vec::new();
        };
        let n = particles.len() as f64;
        let (x, y) = particles
            .iter()
            .fold((0.0, 0.0), |(x, y), p| (x + p[0] / n, y + p[1] / n));
        let live = |node: usize| context.view[node] || node == context.node as usize;
        let mut ranked: Vec<(f64, u16, u16)> = context
            .node_sensors
            .iter()
            .enumerate()
            .filter(|(node, _)| live(*node))
            .flat_map(|(node, sensors)| {
                sensors.iter().map(move |&s| {
                    let [sx, sy] = context.sensor_positions[s as usize];
                    ((sx - x).hypot(sy - y), node as u16, s)
                })
            })
            .collect();
        // Distance, then node, then sensor: a total order every node shares.
        ranked.sort_by(|a, b| a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2))));
        let live_nodes = (0..context.view.len()).filter(|i| live(*i)).count();
        let total = share_of_cap(self.max_total, self.per_node, live_nodes);
        let mut taken = vec![0usize; context.node_sensors.len()];
        let mut chosen = 0;
        let mut own = Vec::new();
        for (_, node, sensor) in ranked {
            if chosen == total {
                break;
            }
            if taken[node as usize] < self.per_node {
                taken[node as usize] += 1;
                chosen += 1;
                if node == context.node {
                    let position = context
                        .own_sensors
                        .binary_search(&sensor)
                        .expect("a node's own sensors are in its list");
                    own.push(position);
                }
            }
        }
        own.sort_unstable();
        own
    }
}

/// How many sensors the network activates: `max_total` if set, but never
/// more than `per_node` on each of `live_nodes`.
fn share_of_cap(max_total: Option<usize>, per_node: usize, live_nodes: usize) -> usize {
    let all = per_node * live_nodes;
    max_total.map_or(all, |m| m.min(all))
}

#[cfg(test)]
mod tests {
    use super::*;
    use bounds::State;

    /// Two nodes of four sensors each on a line, the target beside node 1's
    /// first sensor.
    #[test]
    fn the_nearest_sensors_are_chosen_network_wide_within_the_caps() {
        let positions: Vec<[f64; 2]> = (0..8).map(|i| [i as f64 * 100.0, 0.0]).collect();
        let node_sensors = vec![vec![0, 1, 2, 3], vec![4, 5, 6, 7]];
        let view = [true, true];
        let predicted = vec![State::new(410.0, 5.0, 0.0, 0.0); 10];
        let choose = |node: u16, per_node, total| {
            Closest::new(per_node, total).choose(&SelectionContext {
                step: 1,
                node,
                own_sensors: &node_sensors[node as usize],
                view: &view,
                predicted: Some(&predicted),
                sensor_positions: &positions,
                node_sensors: &node_sensors,
            })
        };
        // Nearest first: 4 (10 m), 3 (110 m), 5 (90 m)… sorted: 4, 5, 3, 6, 2.
        assert_eq!(choose(0, 2, Some(3)), vec![3]); // sensor 3
        assert_eq!(choose(1, 2, Some(3)), vec![0, 1]); // sensors 4 and 5
                                                       // Node 1 full at 2: the third goes to node 0's sensor 3, the fourth to 2.
        assert_eq!(choose(0, 2, None), vec![2, 3]);
        assert_eq!(choose(1, 2, None), vec![0, 1]);
        // Without a prediction nothing is activated.
        let none = Closest::new(2, None).choose(&SelectionContext {
            step: 1,
            node: 0,
            own_sensors: &node_sensors[0],
            view: &view,
            predicted: None,
            sensor_positions: &positions,
            node_sensors: &node_sensors,
        });
        assert!(none.is_empty());
    }
}
