//! Uniform random selection within a node's own sensors.

use fusion_graph::{stream_rng, ActorId, Scenario, Stream};

use super::{SelectionContext, SensorManager};

/// `per_node` sensors (fewer if the node has fewer) drawn uniformly from the
/// node's own, from the node's activation stream.
///
/// With a network-wide cap `max_total`, the cap is shared among the live
/// nodes a node can reach: each gets `⌊max_total / n⌋`, and the remaining
/// `max_total mod n` go one each to nodes chosen by rank, rotating with the
/// step. Every node computes the same split from its membership view, so the
/// cap holds with no message exchanged.
#[derive(Debug, Clone)]
pub struct UniformRandom {
    seed: u64,
    per_node: usize,
    max_total: Option<usize>,
}

impl UniformRandom {
    pub fn new(seed: u64, per_node: usize, max_total: Option<usize>) -> Self {
        Self {
            seed,
            per_node,
            max_total,
        }
    }

    /// The scenario's `sensors.active_per_node` and `sensors.max_active_total`.
    pub fn for_scenario(scenario: &Scenario) -> Self {
        let s = &scenario.sensors;
        Self::new(
            scenario.seed,
            s.active_per_node as usize,
            s.max_active_total.map(|m| m as usize),
        )
    }

    /// This node's share of the network-wide cap.
    fn quota(&self, context: &SelectionContext<'_>) -> usize {
        let Some(total) = self.max_total else {
            return usize::MAX;
        };
        let live: Vec<usize> = (0..context.view.len())
            .filter(|i| context.view[*i] || *i == context.node as usize)
            .collect();
        let n = live.len();
        let rank = live
            .iter()
            .position(|i| *i == context.node as usize)
            .expect("a node is in its own view");
        let extra = total % n;
        let turn = (rank + n - context.step as usize % n) % n;
        total / n + usize::from(turn < extra)
    }
}

impl SensorManager for UniformRandom {
    fn choose(&mut self, context: &SelectionContext<'_>) -> Vec<usize> {
        let own = context.own_sensors.len();
        let k = self.per_node.min(own).min(self.quota(context));
        let mut rng = stream_rng(
            self.seed,
            ActorId::Node(context.node),
            context.step,
            Stream::Activation,
        );
        let mut picks = rand::seq::index::sample(&mut rng, own, k).into_vec();
        picks.sort_unstable();
        picks
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn context<'a>(node: u16, step: u32, own: &'a [u16], view: &'a [bool]) -> SelectionContext<'a> {
        SelectionContext {
            step,
            node,
            own_sensors: own,
            view,
            predicted: None,
            sensor_positions: &[],
            node_sensors: &[],
        }
    }

    #[test]
    fn picks_distinct_own_sensors_and_repeats_from_the_seed() {
        let own: Vec<u16> = (0..25).collect();
        let view = [true; 9];
        let mut m = UniformRandom::new(3, 4, None);
        let a = m.choose(&context(2, 7, &own, &view));
        assert_eq!(a.len(), 4);
        assert!(a.windows(2).all(|w| w[0] < w[1]) && a.iter().all(|i| *i < 25));
        assert_eq!(a, m.choose(&context(2, 7, &own, &view)));
        assert_ne!(a, m.choose(&context(2, 8, &own, &view)));
    }

    #[test]
    fn a_network_cap_is_shared_exactly_among_the_live_nodes() {
        let own: Vec<u16> = (0..25).collect();
        for (total, per_node, alive) in [(18, 4, 9), (20, 4, 9), (7, 4, 3), (18, 4, 8), (50, 4, 9)]
        {
            let mut view = vec![true; 9];
            for v in view.iter_mut().skip(alive) {
                *v = false;
            }
            for step in 1..=12 {
                let mut m = UniformRandom::new(1, per_node, Some(total));
                let sum: usize = (0..alive as u16)
                    .map(|n| m.choose(&context(n, step, &own, &view)).len())
                    .sum();
                assert_eq!(
                    sum,
                    total.min(per_node * alive),
                    "cap {total}, {alive} nodes, step {step}"
                );
            }
        }
    }
}
