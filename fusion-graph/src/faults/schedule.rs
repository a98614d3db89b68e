//! The scenario's fault schedule, evaluated at a step: which link rules hold
//! on each receiver's incoming links, and which actors die or come back.
//! Every actor can evaluate it itself, so link faults need no control traffic.

use crate::shaper::{LinkRule, LinkShaper};
use crate::topology::Topology;
use wire::ActorId;

use super::effects::{ProcessEvent, SensorFault};
use super::fault::Fault;

#[derive(Debug, Clone)]
pub struct FaultSchedule {
    faults: Vec<Fault>,
}

impl FaultSchedule {
    pub fn new(faults: &[Fault]) -> Self {
        Self {
            faults: faults.to_vec(),
        }
    }

    pub fn faults(&self) -> &[Fault] {
        &self.faults
    }

    /// The rule on the link `from → to` at `step` (clear when no fault holds).
    pub fn link_rule(&self, step: u32, from: ActorId, to: ActorId) -> LinkRule {
        let mut rule = LinkRule::default();
        for (i, f) in self.faults.iter().enumerate() {
            if f.holds(step) {
                f.kind().shape_link(i, from, to, &mut rule);
            }
        }
        rule
    }

    /// What sensor `sensor` does instead of measuring honestly at `step`,
    /// if a fault holds it (the first that does, in schedule order).
    pub fn sensor_fault(&self, step: u32, sensor: u16) -> Option<SensorFault> {
        self.faults
            .iter()
            .enumerate()
            .filter(|(_, f)| f.holds(step))
            .find_map(|(i, f)| f.kind().sensor_fault(i, ActorId::Sensor(sensor)))
    }

    /// Whether any fault acts on links (so receivers must set rules).
    fn has_link_faults(&self) -> bool {
        self.faults.iter().any(|f| f.kind().acts_on_links())
    }

    /// Every non-clear rule on `to`'s incoming links at `step`, over the
    /// actors that can send to it.
    pub fn incoming_rules(
        &self,
        step: u32,
        to: ActorId,
        topology: &Topology,
    ) -> Vec<(ActorId, LinkRule)> {
        if !self.has_link_faults() {
            return Vec::new();
        }
        std::iter::once(ActorId::Launcher)
            .chain(topology.actors())
            .filter(|from| *from != to)
            .map(|from| (from, self.link_rule(step, from, to)))
            .filter(|(_, r)| !r.is_clear())
            .collect()
    }

    /// Sets the incoming link rules of `me`'s `shaper` to those in force at
    /// `step`.
    pub fn apply_link_faults(
        &self,
        step: u32,
        me: ActorId,
        shaper: &mut LinkShaper,
        topology: &Topology,
    ) {
        if !self.has_link_faults() {
            return;
        }
        let rules = self.incoming_rules(step, me, topology);
        shaper.clear_rules();
        for (from, rule) in rules {
            shaper.set_rule(from, rule);
        }
    }

    /// Makes `me`'s `shaper` judge each message it receives by the link
    /// rules of the message's own step: for a sensor or a multiple-access
    /// channel, which no `BeginStep` tells when a step begins.
    pub fn follow_link_faults(&self, me: ActorId, shaper: &mut LinkShaper, topology: &Topology) {
        if !self.has_link_faults() {
            return;
        }
        let (schedule, topology) = (self.clone(), topology.clone());
        shaper.follow_steps(move |step| schedule.incoming_rules(step, me, &topology));
    }

    /// What the membership service tells each node at `step`: the live nodes
    /// it can reach over fusion-graph links not cut by a partition. Its size
    /// is the node's N_f; its members are the neighbours it mixes with.
    pub fn membership_views(
        &self,
        step: u32,
        topology: &Topology,
        alive: &[bool],
    ) -> Vec<Vec<bool>> {
        let n = topology.nodes();
        let cut = |a: usize, b: usize| {
            self.link_rule(step, ActorId::Node(a as u16), ActorId::Node(b as u16))
                .blocked
                || self
                    .link_rule(step, ActorId::Node(b as u16), ActorId::Node(a as u16))
                    .blocked
        };
        let mut views = vec![vec![false; n]; n];
        for start in 0..n {
            if !alive[start] {
                continue;
            }
            let mut seen = vec![false; n];
            let mut stack = vec![start];
            seen[start] = true;
            while let Some(a) = stack.pop() {
                for &b in &topology.neighbours[a] {
                    let b = b as usize;
                    if alive[b] && !seen[b] && !cut(a, b) {
                        seen[b] = true;
                        stack.push(b);
                    }
                }
            }
            views[start] = seen;
        }
        views
    }

    /// Kills and restarts due exactly at `step`.
    pub fn process_events(&self, step: u32) -> Vec<ProcessEvent> {
        let mut events = Vec::new();
        for f in &self.faults {
            f.kind().process_events(step, &mut events);
        }
        events
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::faults::select::matches;
    use crate::faults::Signal;
    use crate::scenario::{Scenario, DEFAULT_SCENARIO};
    use std::time::Duration;

    fn schedule(extra: &str) -> (FaultSchedule, Topology) {
        let s = Scenario::from_toml(&format!("{DEFAULT_SCENARIO}\n{extra}"), "f", &[]).unwrap();
        let t = Topology::from_scenario(&s, "f").unwrap();
        (FaultSchedule::new(&s.faults), t)
    }

    #[test]
    fn kind_wildcards_select_every_node_or_every_sensor() {
        assert!(matches("sensor-*", ActorId::Sensor(7)));
        assert!(!matches("sensor-*", ActorId::Node(7)));
        assert!(matches("node-*", ActorId::Node(0)));
        assert!(!matches("node-*", ActorId::Launcher));
        assert!(matches("*", ActorId::Launcher));
        assert!(matches("node-3", ActorId::Node(3)) && !matches("node-3", ActorId::Node(4)));
    }

    #[test]
    fn rules_hold_only_during_their_window() {
        let (f, t) = schedule("[[faults]]\nkind = \"delay\"\nlinks = [{ from = \"node-1\", to = \"*\" }]\nat_step = 5\nduration = 3\nlatency_ms = 80.0\n\n[[faults]]\nkind = \"loss\"\nlinks = [{ from = \"*\", to = \"*\" }]\nat_step = 6\nprobability = 0.3\n");
        let (n0, n1) = (ActorId::Node(0), ActorId::Node(1));
        assert!(f.link_rule(4, n1, n0).is_clear());
        assert_eq!(f.link_rule(5, n1, n0).latency, Duration::from_millis(80));
        assert!((f.link_rule(7, n1, n0).loss - 0.3).abs() < 1e-15);
        assert_eq!(f.link_rule(8, n1, n0).latency, Duration::ZERO);
        assert!(f.link_rule(5, n0, n1).is_clear());
        assert_eq!(f.incoming_rules(5, n0, &t).len(), 1);
    }

    #[test]
    fn partition_blocks_between_groups_and_heals() {
        let (f, _) = schedule("[[faults]]\nkind = \"partition\"\ngroups = [[\"node-0\", \"node-1\"], [\"node-2\"]]\nat_step = 10\nduration = 5\n");
        assert!(f.link_rule(10, ActorId::Node(0), ActorId::Node(2)).blocked);
        assert!(!f.link_rule(10, ActorId::Node(0), ActorId::Node(1)).blocked);
        assert!(!f.link_rule(15, ActorId::Node(0), ActorId::Node(2)).blocked);
    }

    #[test]
    fn membership_views_follow_partitions_and_deaths() {
        let (f, t) = schedule("[[faults]]\nkind = \"partition\"\ngroups = [[\"node-0\", \"node-1\", \"node-3\", \"node-4\"], [\"node-2\", \"node-5\", \"node-6\", \"node-7\", \"node-8\"]]\nat_step = 10\nduration = 5\n");
        let alive = vec![true; 9];
        let count = |v: &Vec<bool>| v.iter().filter(|x| **x).count();
        let whole = f.membership_views(9, &t, &alive);
        assert!(whole.iter().all(|v| count(v) == 9));
        let split = f.membership_views(10, &t, &alive);
        assert_eq!(count(&split[0]), 4);
        assert_eq!(count(&split[8]), 5);
        assert!(!split[0][2] && split[0][4]);
        let mut dead = alive.clone();
        dead[4] = false;
        let views = f.membership_views(15, &t, &dead);
        assert_eq!(count(&views[0]), 8);
        assert!(views[4].iter().all(|x| !x));
    }

    #[test]
    fn kill_and_restart_events() {
        let (f, _) = schedule("[[faults]]\nkind = \"kill\"\nactor = \"node-4\"\nat_step = 20\nsignal = \"SIGSTOP\"\nrestart_after = 5\n");
        assert_eq!(
            f.process_events(20),
            vec![ProcessEvent::Kill {
                actor: ActorId::Node(4),
                signal: Signal::Stop
            }]
        );
        assert_eq!(
            f.process_events(25),
            vec![ProcessEvent::Restart {
                actor: ActorId::Node(4),
                signal: Signal::Stop
            }]
        );
        assert!(f.process_events(21).is_empty());
    }

    #[test]
    fn a_fraction_picks_the_same_share_of_links_every_time() {
        let (f, t) = schedule("[[faults]]\nkind = \"duplicate\"\nlinks = [{ from = \"*\", to = \"*\", fraction = 0.25 }]\nat_step = 2\nprobability = 0.5\n");
        let links: Vec<(ActorId, ActorId)> = t
            .actors()
            .flat_map(|a| t.actors().map(move |b| (a, b)))
            .filter(|(a, b)| a != b)
            .collect();
        let hit = |step| {
            links
                .iter()
                .filter(|(a, b)| f.link_rule(step, *a, *b).duplicate > 0.0)
                .count()
        };
        let share = hit(2) as f64 / links.len() as f64;
        assert!((share - 0.25).abs() < 0.02, "{share}");
        assert_eq!(hit(2), hit(3), "the same links each step");
        assert_eq!(hit(1), 0);
    }

    #[test]
    fn sensor_faults_name_their_sensors_and_window() {
        let (f, _) = schedule("[[faults]]\nkind = \"sensor\"\nsensors = [\"*\"]\nfraction = 0.2\nmode = \"byzantine\"\nphantom = [300.0, 0.0]\nat_step = 5\nduration = 10\n\n[[faults]]\nkind = \"sensor\"\nsensors = [\"sensor-7\"]\nmode = \"stuck\"\nat_step = 1\n");
        let byzantine = (0..225u16)
            .filter(|s| matches!(f.sensor_fault(5, *s), Some(SensorFault::Byzantine(p)) if p == [300.0, 0.0]))
            .count();
        assert!((30..=60).contains(&byzantine), "{byzantine} of 225");
        assert!((0..225u16).all(|s| f.sensor_fault(15, s).is_none() || s == 7));
        assert_eq!(f.sensor_fault(15, 7), Some(SensorFault::Stuck));
    }
}
