//! The network as a graph: where nodes and sensors are, which sensors each
//! node owns, the fusion graph, and Metropolis consensus weights. How a
//! scenario lays it out ([`Topology::from_scenario`]) is `layout.rs`.

use std::collections::VecDeque;
use std::sync::Arc;

mod layout;
mod mixing;
mod partition;

pub use mixing::Mixing;

use crate::channel::Channel;
#[cfg(test)]
use crate::scenario::Scenario;
use wire::ActorId;

/// The layout's lists are shared, not copied, by every clone: each node
/// keeps the topology (its protocol, its rounds, its exchange), and in
/// `sim` a copy of every list per node and holder grew a network's memory
/// as the square of its nodes.
#[derive(Debug, Clone, PartialEq)]
pub struct Topology {
    pub node_positions: Arc<[[f64; 2]]>,
    pub sensor_positions: Arc<[[f64; 2]]>,
    /// The node each sensor reports to.
    pub sensor_owner: Arc<[u16]>,
    /// Each node's sensors, in increasing order.
    pub node_sensors: Arc<[Vec<u16>]>,
    /// Fusion-graph neighbours of each node, in increasing order.
    pub neighbours: Arc<[Vec<u16>]>,
    /// Whether each node hears its sensors through a multiple-access
    /// channel, an actor of its own (`mac-<i>` for node i).
    pub macs: bool,
    /// The payloads the program declared for its own protocols: the
    /// channels between nodes make room for the longest, and the counts
    /// name their kinds.
    pub payloads: wire::payloads::Payloads,
}

/// A breadth-first spanning tree of one live component of the fusion
/// graph, rooted at its centre: what sensor selection gathers its
/// candidates along and sends its choice down. Every node that holds the
/// same membership view builds the same tree.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpanningTree {
    pub root: u16,
    /// Each node's parent; `None` at the root and outside the component.
    pub parent: Vec<Option<u16>>,
    /// Hops from the root; `None` outside the component.
    pub depth: Vec<Option<u16>>,
    /// The levels below each node in the tree: 0 at a leaf.
    pub below: Vec<u16>,
}

impl SpanningTree {
    /// `node`'s children, increasing.
    pub fn children(&self, node: u16) -> impl Iterator<Item = u16> + '_ {
        (0..self.parent.len() as u16).filter(move |m| self.parent[*m as usize] == Some(node))
    }

    /// The tree's height: the levels below its root.
    pub fn height(&self) -> u16 {
        self.below[self.root as usize]
    }
}

/// Consensus weights of one node over its live closed neighbourhood.
#[derive(Debug, Clone, PartialEq)]
pub struct MetropolisWeights {
    pub own: f64,
    /// `(neighbour, W_lm)`.
    pub neighbours: Vec<(u16, f64)>,
    /// Live neighbours whose value did not come in time for the round, so
    /// that their weight went to `own`. Such a neighbour may well have
    /// heard this node: the network's matrix that round is then not
    /// symmetric and the round does not keep the network's average.
    /// [`Topology::metropolis_weights`] leaves it 0; a round engine says.
    pub unheard: usize,
}

impl Topology {
    /// The actors `actor` can exchange messages with: a node's sensors,
    /// fusion-graph neighbours and the launcher; a sensor's node and the
    /// launcher; the launcher's everyone.
    pub fn peers(&self, actor: ActorId) -> usize {
        match actor {
            ActorId::Node(n) => {
                self.node_sensors[n as usize].len()
                    + self.neighbours[n as usize].len()
                    + 1
                    + usize::from(self.macs)
            }
            ActorId::Sensor(_) => 2,
            ActorId::Mac(n) => self.node_sensors[n as usize].len() + 2,
            ActorId::Launcher => self.nodes() + self.sensors() + self.mac_count(),
        }
    }

    /// How many subscribers `channel` has in this network: its readers,
    /// and on an observation channel the launcher's centralized reference.
    pub fn subscribers(&self, channel: Channel) -> usize {
        self.readers(channel).len() + usize::from(matches!(channel, Channel::Observation(_)))
    }

    /// The actors that read `channel` in this network, each of which gets
    /// every message published on it. (In a run with a centralized
    /// reference the launcher reads every observation channel too, which
    /// the topology does not say.)
    pub fn readers(&self, channel: Channel) -> Vec<ActorId> {
        match channel {
            Channel::Lifecycle => (0..self.sensors() as u16)
                .map(ActorId::Sensor)
                .chain((0..self.mac_count() as u16).map(ActorId::Mac))
                .collect(),
            Channel::Observation(s) => vec![self.reports_to(s)],
            Channel::Consensus(n) => self.neighbours[n as usize]
                .iter()
                .map(|m| ActorId::Node(*m))
                .collect(),
            Channel::Activation { to, .. } => vec![to],
            Channel::Control(a) => vec![a],
            Channel::Telemetry(_) => vec![ActorId::Launcher],
            Channel::Pair { to, .. } => vec![ActorId::Node(to)],
            Channel::MacOutput(n) => vec![ActorId::Node(n)],
        }
    }

    /// Whom node `n` activates: each of its sensors, and its
    /// multiple-access channel if it has one.
    pub fn activated_by(&self, n: u16) -> impl Iterator<Item = ActorId> + '_ {
        let sensors = self.node_sensors[n as usize]
            .iter()
            .map(|s| ActorId::Sensor(*s));
        sensors.chain(self.macs.then_some(ActorId::Mac(n)))
    }

    /// The activation channels of node `n`, one to each actor it activates
    /// ([`Topology::activated_by`]).
    pub fn activation_channels(&self, n: u16) -> impl Iterator<Item = Channel> + '_ {
        self.activated_by(n)
            .map(move |to| Channel::Activation { node: n, to })
    }

    pub fn nodes(&self) -> usize {
        self.node_positions.len()
    }

    pub fn sensors(&self) -> usize {
        self.sensor_positions.len()
    }

    /// The multiple-access channels: one per node, or none.
    pub fn mac_count(&self) -> usize {
        if self.macs {
            self.nodes()
        } else {
            0
        }
    }

    /// Where sensor `s` sends what it measures: its node, or the channel
    /// in front of its node.
    pub fn reports_to(&self, s: u16) -> ActorId {
        let owner = self.sensor_owner[s as usize];
        if self.macs {
            ActorId::Mac(owner)
        } else {
            ActorId::Node(owner)
        }
    }

    /// Each sensor's chance of being active in a step when its node picks
    /// `active_per_node` of its own sensors uniformly at random.
    pub fn activation_probabilities(&self, active_per_node: u32) -> Vec<f64> {
        let mut p = vec![0.0; self.sensors()];
        for own in self.node_sensors.iter() {
            let share = (active_per_node as f64 / own.len().max(1) as f64).min(1.0);
            for s in own {
                p[*s as usize] = share;
            }
        }
        p
    }

    /// The most sensors any node owns (0 with no nodes).
    pub fn most_sensors_per_node(&self) -> usize {
        self.node_sensors.iter().map(Vec::len).max().unwrap_or(0)
    }

    pub fn contains(&self, a: ActorId) -> bool {
        match a {
            ActorId::Launcher => true,
            ActorId::Node(i) => (i as usize) < self.nodes(),
            ActorId::Sensor(i) => (i as usize) < self.sensors(),
            ActorId::Mac(i) => (i as usize) < self.mac_count(),
        }
    }

    /// Every actor: the nodes, then the sensors, then the channels.
    pub fn actors(&self) -> impl Iterator<Item = ActorId> + '_ {
        (0..self.nodes() as u16)
            .map(ActorId::Node)
            .chain((0..self.sensors() as u16).map(ActorId::Sensor))
            .chain((0..self.mac_count() as u16).map(ActorId::Mac))
    }

    /// Undirected fusion-graph edges.
    pub fn edge_count(&self) -> usize {
        self.neighbours.iter().map(Vec::len).sum::<usize>() / 2
    }

    pub fn all_alive(&self) -> Vec<bool> {
        vec![true; self.nodes()]
    }

    /// Connected components of the fusion graph restricted to live nodes.
    pub fn components(&self, alive: &[bool]) -> Vec<Vec<u16>> {
        let mut seen = vec![false; self.nodes()];
        let mut out = Vec::new();
        for start in 0..self.nodes() {
            if seen[start] || !alive[start] {
                continue;
            }
            let mut comp = Vec::new();
            let mut queue = VecDeque::from([start]);
            seen[start] = true;
            while let Some(n) = queue.pop_front() {
                comp.push(n as u16);
                for &m in &self.neighbours[n] {
                    if alive[m as usize] && !seen[m as usize] {
                        seen[m as usize] = true;
                        queue.push_back(m as usize);
                    }
                }
            }
            comp.sort_unstable();
            out.push(comp);
        }
        out
    }

    /// The largest number of hops between two connected nodes of the whole
    /// graph: the rounds a value needs to reach every node.
    pub fn diameter(&self) -> usize {
        let n = self.nodes();
        let mut longest = 0;
        for start in 0..n {
            let mut hops = vec![usize::MAX; n];
            hops[start] = 0;
            let mut queue = VecDeque::from([start]);
            while let Some(a) = queue.pop_front() {
                for &b in &self.neighbours[a] {
                    if hops[b as usize] == usize::MAX {
                        hops[b as usize] = hops[a] + 1;
                        longest = longest.max(hops[b as usize]);
                        queue.push_back(b as usize);
                    }
                }
            }
        }
        longest
    }

    /// Hops from `start` to every node through live nodes; `None` where
    /// it cannot reach.
    fn hops_from(&self, start: u16, alive: &[bool]) -> Vec<Option<u16>> {
        let mut hops = vec![None; self.nodes()];
        hops[start as usize] = Some(0);
        let mut queue = VecDeque::from([start]);
        while let Some(a) = queue.pop_front() {
            let next = hops[a as usize].map(|h| h + 1);
            for &b in &self.neighbours[a as usize] {
                if alive[b as usize] && hops[b as usize].is_none() {
                    hops[b as usize] = next;
                    queue.push_back(b);
                }
            }
        }
        hops
    }

    /// The spanning tree of `node`'s live component (`node` counted live):
    /// rooted at the node of least eccentricity, the smallest such on a
    /// tie, so that the tree is as shallow as the component allows; each
    /// other node's parent is its smallest neighbour one hop nearer the root.
    pub fn spanning_tree(&self, node: u16, alive: &[bool]) -> SpanningTree {
        let mut alive = alive.to_vec();
        alive[node as usize] = true;
        let component: Vec<u16> = self
            .hops_from(node, &alive)
            .iter()
            .enumerate()
            .filter_map(|(m, h)| h.map(|_| m as u16))
            .collect();
        let eccentricity = |m: u16| self.hops_from(m, &alive).into_iter().flatten().max();
        let root = component
            .iter()
            .copied()
            .min_by_key(|m| (eccentricity(*m), *m))
            .unwrap_or(node);
        let depth = self.hops_from(root, &alive);
        let parent: Vec<Option<u16>> = (0..self.nodes())
            .map(|m| {
                let d = depth[m].filter(|d| *d > 0)?;
                self.neighbours[m]
                    .iter()
                    .copied()
                    .find(|p| depth[*p as usize] == Some(d - 1))
            })
            .collect();
        let mut below = vec![0u16; self.nodes()];
        let mut by_depth: Vec<u16> = component.clone();
        by_depth.sort_by_key(|m| std::cmp::Reverse(depth[*m as usize]));
        for m in by_depth {
            if let Some(p) = parent[m as usize] {
                below[p as usize] = below[p as usize].max(below[m as usize] + 1);
            }
        }
        SpanningTree {
            root,
            parent,
            depth,
            below,
        }
    }

    /// Size of the live connected component containing `node`: the N_f that
    /// turns an average into a network sum after failures.
    pub fn component_size(&self, node: u16, alive: &[bool]) -> usize {
        self.components(alive)
            .into_iter()
            .find(|c| c.contains(&node))
            .map_or(0, |c| c.len())
    }

    /// Metropolis weights `W_lm = 1/(1 + max(deg_l, deg_m))` over the
    /// neighbours marked live, with degrees counted over live nodes only, and
    /// `W_ll = 1 − Σ_m W_lm`. With the same `alive` everywhere the weights are
    /// symmetric and doubly stochastic on the live graph.
    pub fn metropolis_weights(&self, node: u16, alive: &[bool]) -> MetropolisWeights {
        let degree = |n: u16| {
            self.neighbours[n as usize]
                .iter()
                .filter(|m| alive[**m as usize])
                .count()
        };
        let own_degree = degree(node);
        let neighbours: Vec<(u16, f64)> = self.neighbours[node as usize]
            .iter()
            .filter(|m| alive[**m as usize])
            .map(|&m| (m, 1.0 / (1.0 + own_degree.max(degree(m)) as f64)))
            .collect();
        let own = 1.0 - neighbours.iter().map(|(_, w)| w).sum::<f64>();
        MetropolisWeights {
            own,
            neighbours,
            unheard: 0,
        }
    }
}

pub(crate) fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)
}

/// The default scenario's network laid out as a grid of `cols` × `rows`
/// nodes over a `width` × `height` field: the test networks of this
/// module's parts.
#[cfg(test)]
pub(crate) fn test_grid(cols: u32, rows: u32, width: f64, height: f64) -> Topology {
    let sets = [
        format!("nodes.grid=[{cols},{rows}]"),
        format!("region.width={width}"),
        format!("region.height={height}"),
    ];
    let s = Scenario::from_toml(crate::scenario::DEFAULT_SCENARIO, "grid", &sets).unwrap();
    Topology::from_scenario(&s, "grid").unwrap()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The random-exchange paper: every node senses and processes, so each node's one
    /// sensor stands where the node does, and the graph is the 4-lattice.
    #[test]
    fn the_random_exchange_scenario_puts_one_sensor_on_each_node_of_a_lattice() {
        let s = Scenario::from_toml(
            crate::scenario::RANDOM_EXCHANGE_SCENARIO,
            "random-exchange.toml",
            &[],
        )
        .unwrap();
        let t = Topology::from_scenario(&s, "random-exchange.toml").unwrap();
        assert_eq!((t.nodes(), t.sensors()), (25, 25));
        for (n, sensors) in t.node_sensors.iter().enumerate() {
            assert_eq!(sensors.len(), 1);
            assert_eq!(t.sensor_positions[sensors[0] as usize], t.node_positions[n]);
        }
        let degrees: Vec<usize> = t.neighbours.iter().map(Vec::len).collect();
        assert_eq!(degrees.iter().filter(|&&d| d == 2).count(), 4, "corners");
        assert_eq!(degrees.iter().filter(|&&d| d == 4).count(), 9, "interior");
        assert_eq!(t.edge_count(), 40);
    }

    /// A node that picks 3 of its 25 sensors activates each with chance
    /// 3/25; asking for more than it owns activates all of them.
    #[test]
    fn activation_probability_is_the_share_of_a_nodes_sensors_picked() {
        let t = default_topology();
        assert!(t
            .activation_probabilities(3)
            .iter()
            .all(|&p| p == 3.0 / 25.0));
        assert!(t.activation_probabilities(40).iter().all(|&p| p == 1.0));
        assert!(t.activation_probabilities(0).iter().all(|&p| p == 0.0));
    }

    fn default_topology() -> Topology {
        Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap()
    }

    #[test]
    fn default_scenario_shape() {
        let t = default_topology();
        assert_eq!(t.nodes(), 9);
        assert_eq!(t.sensors(), 225);
        assert!(t.node_sensors.iter().all(|s| s.len() == 25));
        assert_eq!(t.edge_count(), 12);
        assert_eq!(t.node_positions[4], [750.0, 750.0]);
        assert_eq!(t.sensor_positions[0], [50.0, 50.0]);
        assert_eq!(t.neighbours[4], vec![1, 3, 5, 7]);
        // A 3×3 grid with its four-neighbour links: corner to corner is 4 hops.
        assert_eq!(t.diameter(), 4);
    }

    /// On the 3×3 grid the centre roots a tree of height 2; each corner
    /// hangs from its smaller side neighbour.
    #[test]
    fn the_spanning_tree_is_rooted_at_the_centre() {
        let t = default_topology();
        for node in 0..9 {
            let tree = t.spanning_tree(node, &t.all_alive());
            assert_eq!((tree.root, tree.height()), (4, 2));
            assert_eq!(
                tree.parent,
                [1, 4, 1, 4, 9, 4, 3, 4, 5].map(|p| (p != 9).then_some(p))
            );
            assert_eq!(tree.children(1).collect::<Vec<_>>(), [0, 2]);
            assert_eq!(tree.children(7).count(), 0);
            assert_eq!(tree.below, [0, 1, 0, 1, 2, 1, 0, 0, 0]);
            assert_eq!(tree.depth[8], Some(2));
        }
    }

    /// Without the centre the tree roots elsewhere, over the live nodes
    /// only; across a partition each side has its own tree.
    #[test]
    fn the_spanning_tree_spans_the_live_component_only() {
        let t = default_topology();
        let mut alive = t.all_alive();
        alive[4] = false;
        let tree = t.spanning_tree(0, &alive);
        // The ring of 8: every node has eccentricity 4; the smallest roots.
        assert_eq!((tree.root, tree.height()), (0, 4));
        assert_eq!(tree.depth[4], None);
        assert!((0..9).filter(|m| *m != 4).all(|m| tree.depth[m].is_some()));
        // Columns {0, 3, 6} and the rest, apart.
        let left = [true, false, false, true, false, false, true, false, false];
        let tree = t.spanning_tree(6, &left);
        assert_eq!((tree.root, tree.height()), (3, 1));
        assert_eq!(tree.parent[0], Some(3));
        assert_eq!(tree.depth[1], None);
        // A node that sees no one is a tree of its own.
        let alone = t.spanning_tree(2, &[false; 9]);
        assert_eq!((alone.root, alone.height()), (2, 0));
    }

    fn weight_matrix(t: &Topology, alive: &[bool]) -> Vec<Vec<f64>> {
        let n = t.nodes();
        let mut w = vec![vec![0.0; n]; n];
        for l in 0..n {
            if !alive[l] {
                continue;
            }
            let mw = t.metropolis_weights(l as u16, alive);
            w[l][l] = mw.own;
            for (m, v) in mw.neighbours {
                w[l][m as usize] = v;
            }
        }
        w
    }

    fn assert_doubly_stochastic(w: &[Vec<f64>], alive: &[bool]) {
        for l in 0..w.len() {
            if !alive[l] {
                continue;
            }
            let row: f64 = w[l].iter().sum();
            let col: f64 = (0..w.len()).map(|m| w[m][l]).sum();
            assert!(
                (row - 1.0).abs() < 1e-12 && (col - 1.0).abs() < 1e-12,
                "node {l}: row {row} col {col}"
            );
            for (m, row_m) in w.iter().enumerate() {
                assert_eq!(w[l][m], row_m[l], "asymmetric at {l},{m}");
                assert!(w[l][m] >= 0.0);
            }
        }
    }

    #[test]
    fn metropolis_weights_are_symmetric_doubly_stochastic_and_converge_to_the_average() {
        let t = default_topology();
        let alive = t.all_alive();
        let w = weight_matrix(&t, &alive);
        assert_doubly_stochastic(&w, &alive);
        let mut v: Vec<f64> = (0..9).map(|i| (i * i) as f64).collect();
        let avg = v.iter().sum::<f64>() / 9.0;
        for _ in 0..200 {
            v = (0..9)
                .map(|l| (0..9).map(|m| w[l][m] * v[m]).sum())
                .collect();
        }
        assert!(v.iter().all(|x| (x - avg).abs() < 1e-9), "{v:?} vs {avg}");
    }

    #[test]
    fn weights_recomputed_after_a_node_dies_stay_doubly_stochastic() {
        let t = default_topology();
        let mut alive = t.all_alive();
        alive[4] = false;
        let w = weight_matrix(&t, &alive);
        assert_doubly_stochastic(&w, &alive);
        assert_eq!(t.component_size(0, &alive), 8);
        // A corner and its two neighbours gone: node 0 is cut off alone.
        alive[1] = false;
        alive[3] = false;
        assert_eq!(t.component_size(0, &alive), 1);
        assert_eq!(t.metropolis_weights(0, &alive).own, 1.0);
    }

    #[test]
    fn disconnected_graph_is_an_error_unless_intended() {
        let mut s = Scenario::default_scenario();
        s.fusion_graph.radius = 100.0;
        let e = Topology::from_scenario(&s, "x.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("fusion_graph.radius"), "{e}");
        s.fusion_graph.allow_disconnected = true;
        assert!(Topology::from_scenario(&s, "x.toml").is_ok());
    }

    #[test]
    fn fault_naming_an_unknown_actor_is_an_error() {
        let text = format!("{}\n[[faults]]\nkind = \"kill\"\nactor = \"node-42\"\nat_step = 5\nsignal = \"SIGKILL\"\n", crate::scenario::DEFAULT_SCENARIO);
        let s = Scenario::from_toml(&text, "f.toml", &[]).unwrap();
        let e = Topology::from_scenario(&s, "f.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("faults[0].actor") && e.contains("node-42"),
            "{e}"
        );
    }
}
