//! The events a live view of a network draws: the map, the true track, each
//! node's estimate, error and bound, the traffic on every fusion-graph link
//! and the faults.
//!
//! The launcher ([`crate::network`]) and the replay of a finished run build
//! the same [`ViewEvent`]s and publish them to a [`Hub`]; whoever serves a
//! page (the `cqnet` command's web server) subscribes to the hub and gets the
//! history first, so a page opened late (or reloaded) draws the whole run so
//! far.

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};

use fusion_graph::faults::FaultSchedule;
use fusion_graph::{ActorId, Scenario, Topology};
use serde::Serialize;
use tokio::sync::broadcast;

use crate::results::TickRow;
use crate::summary::AppliedFault;

/// Work a server's thread does once a second while it serves (the live
/// view reads the actors' byte counters this way).
pub type Poll = Box<dyn FnMut() + Send>;

/// One thing the page draws. Serialized as JSON with a `type` tag.
#[derive(Debug, Clone, Serialize, PartialEq)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ViewEvent {
    /// The map and the schedule, first on every stream.
    Setup {
        title: String,
        /// `live` or `replay`.
        mode: &'static str,
        region: [f64; 2],
        steps: u32,
        nodes: Vec<[f64; 2]>,
        /// `[x, y, owner node]`.
        sensors: Vec<[f64; 3]>,
        /// The fusion graph's undirected links, `[a, b]` with `a < b`.
        links: Vec<[u16; 2]>,
        faults: Vec<AppliedFault>,
    },
    /// Processes started so far (live runs), so the page is never silent
    /// while the network comes up.
    Starting { ready: usize, of: usize },
    /// The world at the start of `step`.
    Step {
        step: u32,
        truth: [f64; 2],
        /// Sensors whose observation the launcher saw this step (known only
        /// with the centralized reference, which receives them).
        active_sensors: Vec<u16>,
        dead_nodes: Vec<u16>,
        /// Per fusion-graph link, in `Setup`'s order: `ok`, `degraded`
        /// (delay or loss injected) or `cut` (partitioned or an end dead).
        link_states: Vec<LinkState>,
    },
    /// Node reports, as they arrive (a late one still lands on its step).
    Estimates { step: u32, rows: Vec<NodeEstimate> },
    /// Bytes per step on each fusion-graph link, both directions, every
    /// message kind, from the actors' own ledgers as they stand, over the
    /// steps run so far.
    Traffic { step: u32, bytes_per_step: Vec<f64> },
    /// A fault the schedule did not contain: an actor that died on its own.
    Fault(AppliedFault),
    /// The run is over.
    End { steps: u32 },
}

#[derive(Debug, Clone, Copy, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum LinkState {
    Ok,
    Degraded,
    Cut,
}

/// One node's (or the centralized reference's) report for a step.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct NodeEstimate {
    /// `node-<i>` or `central`.
    pub node: String,
    pub estimate: [f64; 2],
    pub error: f64,
    pub bound: Option<f64>,
    /// How far the node still was from its neighbours after its last
    /// consensus round, as a share.
    pub disagreement: Option<f64>,
}

impl NodeEstimate {
    pub fn of(row: &TickRow) -> Self {
        Self {
            node: row.node.clone(),
            estimate: [row.telemetry.estimate[0], row.telemetry.estimate[1]],
            error: row.error(),
            bound: row.telemetry.bound,
            disagreement: row.telemetry.disagreement,
        }
    }
}

/// The fusion graph's undirected links, each once, `a < b`.
pub fn fusion_links(topology: &Topology) -> Vec<[u16; 2]> {
    let mut links = Vec::new();
    for (a, ns) in topology.neighbours.iter().enumerate() {
        for &b in ns.iter().filter(|&&b| b as usize > a) {
            links.push([a as u16, b]);
        }
    }
    links
}

pub fn setup_event(scenario: &Scenario, topology: &Topology, mode: &'static str) -> ViewEvent {
    ViewEvent::Setup {
        title: scenario.name.clone(),
        mode,
        region: [scenario.region.width, scenario.region.height],
        steps: scenario.steps,
        nodes: topology.node_positions.to_vec(),
        sensors: topology
            .sensor_positions
            .iter()
            .zip(topology.sensor_owner.iter())
            .map(|(p, &o)| [p[0], p[1], o as f64])
            .collect(),
        links: fusion_links(topology),
        faults: scenario
            .faults
            .iter()
            .map(AppliedFault::from_fault)
            .collect(),
    }
}

/// The `Step` event: what the schedule says of each link at `step`, with
/// the nodes the caller knows to be dead.
pub fn step_event(
    schedule: &FaultSchedule,
    topology: &Topology,
    step: u32,
    truth: [f64; 2],
    active_sensors: &BTreeSet<u16>,
    dead_nodes: &[u16],
) -> ViewEvent {
    let link_states = fusion_links(topology)
        .iter()
        .map(|&[a, b]| {
            if dead_nodes.contains(&a) || dead_nodes.contains(&b) {
                return LinkState::Cut;
            }
            let (na, nb) = (ActorId::Node(a), ActorId::Node(b));
            let rules = [
                schedule.link_rule(step, na, nb),
                schedule.link_rule(step, nb, na),
            ];
            if rules.iter().any(|r| r.blocked) {
                LinkState::Cut
            } else if rules.iter().all(|r| r.is_clear()) {
                LinkState::Ok
            } else {
                LinkState::Degraded
            }
        })
        .collect();
    ViewEvent::Step {
        step,
        truth,
        active_sensors: active_sensors.iter().copied().collect(),
        dead_nodes: dead_nodes.to_vec(),
        link_states,
    }
}

/// Bytes per fusion-graph link (both directions, every kind) in
/// `accounting`, each direction divided by `steps(sender)`: the steps its
/// sender's counts cover.
pub fn link_bytes_per_step(
    topology: &Topology,
    accounting: &transport::accounting::Accounting,
    steps: impl Fn(u16) -> f64,
) -> Vec<f64> {
    let links = fusion_links(topology);
    let mut rate = vec![0.0; links.len()];
    for ((from, to, _), counters) in accounting.iter() {
        let (ActorId::Node(from), ActorId::Node(to)) = (*from, *to) else {
            continue;
        };
        let pair = [from.min(to), from.max(to)];
        if let Some(i) = links.iter().position(|l| *l == pair) {
            rate[i] += counters.sent_bytes as f64 / steps(from).max(1.0);
        }
    }
    rate
}

/// How many events a slow page may fall behind before its stream is cut (it
/// reconnects and is sent the history again).
const LIVE_BACKLOG: usize = 4096;

/// The events of one run: every event so far, and a channel to the pages
/// that are watching.
pub struct Hub {
    inner: Mutex<HubInner>,
    latest_step: AtomicU32,
}

struct HubInner {
    history: Vec<Arc<str>>,
    live: broadcast::Sender<Arc<str>>,
}

impl Default for Hub {
    fn default() -> Self {
        Self {
            inner: Mutex::new(HubInner {
                history: Vec::new(),
                live: broadcast::channel(LIVE_BACKLOG).0,
            }),
            latest_step: AtomicU32::new(0),
        }
    }
}

impl Hub {
    pub fn publish(&self, event: &ViewEvent) {
        if let ViewEvent::Step { step, .. } = event {
            self.latest_step.fetch_max(*step, Ordering::Relaxed);
        }
        let json: Arc<str> = serde_json::to_string(event)
            .expect("view events serialize")
            .into();
        let mut inner = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        inner.history.push(json.clone());
        // No page watching is not an error.
        let _ = inner.live.send(json);
    }

    /// The history so far and the events after it, with none lost or
    /// repeated between the two (both are taken under one lock).
    pub fn subscribe(&self) -> (Vec<Arc<str>>, broadcast::Receiver<Arc<str>>) {
        let inner = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        (inner.history.clone(), inner.live.subscribe())
    }

    /// The latest step published.
    pub fn latest_step(&self) -> u32 {
        self.latest_step.load(Ordering::Relaxed)
    }

    pub fn len(&self) -> usize {
        self.inner
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .history
            .len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn default_topology() -> (Scenario, Topology) {
        let s =
            Scenario::from_toml(fusion_graph::scenario::DEFAULT_SCENARIO, "default", &[]).unwrap();
        let t = Topology::from_scenario(&s, "default").unwrap();
        (s, t)
    }

    #[test]
    fn every_fusion_link_appears_once() {
        let (_, t) = default_topology();
        let links = fusion_links(&t);
        let directed: usize = t.neighbours.iter().map(Vec::len).sum();
        assert_eq!(links.len() * 2, directed);
        assert!(links.iter().all(|[a, b]| a < b));
    }

    #[test]
    fn a_partition_cuts_the_links_across_it_and_only_while_it_holds() {
        let (mut s, t) = default_topology();
        s.faults.push(
            fusion_graph::faults::Partition {
                groups: vec![vec!["node-0".into()], vec!["node-1".into()]],
                at_step: 5,
                duration: Some(3),
            }
            .into(),
        );
        let schedule = FaultSchedule::new(&s.faults);
        let links = fusion_links(&t);
        let i = links
            .iter()
            .position(|l| *l == [0, 1])
            .expect("0-1 is a link");
        let state = |step| match step_event(&schedule, &t, step, [0.0; 2], &BTreeSet::new(), &[]) {
            ViewEvent::Step { link_states, .. } => link_states,
            _ => unreachable!(),
        };
        assert_eq!(state(4)[i], LinkState::Ok);
        assert_eq!(state(5)[i], LinkState::Cut);
        assert_eq!(state(7)[i], LinkState::Cut);
        assert_eq!(state(8)[i], LinkState::Ok);
        assert!(state(5).iter().filter(|s| **s == LinkState::Cut).count() == 1);
    }

    #[test]
    fn link_rates_sum_both_directions_of_node_links_only() {
        use wire::MessageKind;
        let (_, t) = default_topology();
        let mut acc = transport::accounting::Accounting::default();
        acc.record_sent(
            ActorId::Node(0),
            ActorId::Node(1),
            MessageKind::Consensus,
            100,
        );
        acc.record_sent(
            ActorId::Node(1),
            ActorId::Node(0),
            MessageKind::Consensus,
            50,
        );
        acc.record_sent(
            ActorId::Sensor(0),
            ActorId::Node(0),
            MessageKind::Observation,
            12,
        );
        let links = fusion_links(&t);
        let i = links.iter().position(|l| *l == [0, 1]).unwrap();
        let rate = link_bytes_per_step(&t, &acc, |n| if n == 0 { 10.0 } else { 5.0 });
        assert_eq!(rate[i], 100.0 / 10.0 + 50.0 / 5.0);
        assert_eq!(rate.iter().sum::<f64>(), 20.0);
    }

    #[test]
    fn a_subscriber_gets_the_history_then_what_follows_exactly_once() {
        let hub = Hub::default();
        hub.publish(&ViewEvent::Starting { ready: 1, of: 2 });
        let (history, mut live) = hub.subscribe();
        hub.publish(&ViewEvent::End { steps: 3 });
        assert_eq!(history.len(), 1);
        assert!(history[0].contains("\"starting\""));
        assert!(live.try_recv().unwrap().contains("\"end\""));
        assert!(live.try_recv().is_err());
    }
}
