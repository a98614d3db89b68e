//! Several hosts: which host runs which actor, and which channels must
//! cross between hosts.
//!
//! A scenario with a `[[hosts]]` section spreads its network over hosts.
//! Each host keeps its own iceoryx2 domain (its own run id, so its own
//! shared-memory prefix); one bridge per host carries every message whose
//! receiver is elsewhere (see the runtime's `hosts` module). Nodes are placed
//! by the scenario, a sensor goes where its node is, and the launcher runs
//! on the first host listed.
//!
//! An actor that wakes another on a different host cannot reach its
//! listener: it wakes its own host's bridge instead, with the remote actor's
//! [`wake_id`] as the event id, and the bridge wakes it on the far side
//! once the bytes are there.

use serde::{Deserialize, Serialize};

use crate::channel::{Channel, RunId};
use crate::scenario::Scenario;
use crate::topology::Topology;
use crate::ScenarioError;
use wire::ActorId;

pub use crate::scenario::{HostConfig, HostLink, TrustConfig};

const MAX_HOST_NAME: usize = 8;

/// Where every actor of a network runs.
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    hosts: Vec<HostConfig>,
    trust: TrustConfig,
    node_host: Vec<usize>,
    sensor_host: Vec<usize>,
    /// Whether random exchange's pair channels exist.
    pairs: bool,
    /// Whether the launcher reads every observation (the centralized reference).
    centralized: bool,
}

/// A host link's values in range: `(key, expected, got)` for the first
/// that is not.
fn check_link(l: &HostLink, steps: u32) -> Result<(), (&'static str, &'static str, String)> {
    let non_negative = |key, v: f64| {
        if v.is_finite() && v >= 0.0 {
            Ok(())
        } else {
            Err((key, "a finite number >= 0", v.to_string()))
        }
    };
    non_negative("delay_ms", l.delay_ms)?;
    non_negative("jitter_ms", l.jitter_ms)?;
    non_negative("rate_mbit", l.rate_mbit)?;
    if !(0.0..=1.0).contains(&l.loss) {
        return Err(("loss", "a share from 0 to 1", l.loss.to_string()));
    }
    match l.cut_at_step {
        Some(at) if at == 0 || at > steps => {
            Err(("cut_at_step", "a step of the run", at.to_string()))
        }
        Some(_) if l.cut_steps == 0 => {
            Err(("cut_steps", "at least 1 with cut_at_step", "0".into()))
        }
        None if l.cut_steps > 0 => Err((
            "cut_at_step",
            "the step the cut starts at, with cut_steps",
            "none".into(),
        )),
        _ => Ok(()),
    }
}

/// Host `h`'s endpoint speaks what the scenario's `[trust]` allows: TLS,
/// or plain TCP only where `plain_tcp = true` says so; every host the same.
fn check_protocol(s: &Scenario, h: usize) -> Result<(), (String, &'static str, String)> {
    let endpoint = &s.hosts[h].endpoint;
    let protocol = endpoint.split('/').next().unwrap_or_default();
    let plain = s.trust.as_ref().is_some_and(|t| t.plain_tcp);
    let key = format!("hosts[{h}].endpoint");
    match protocol {
        "quic" if plain => Err((
            "trust.plain_tcp".into(),
            "false with `quic/` endpoints",
            "true".into(),
        )),
        // Zenoh's TLS link reads and writes one rustls connection from two
        // tasks at once, which rustls does not allow: under load it loses
        // messages (`handshake not complete`). Its QUIC link keeps the two
        // directions apart and carries the same certificates.
        "tls" => Err((
            key,
            "a `quic/` endpoint: Zenoh's `tls/` link loses messages under load (it reads and writes one TLS connection concurrently); `quic/` carries the same mutually authenticated TLS",
            format!("{endpoint:?}"),
        )),
        "tcp" if !plain => Err((
            key,
            "a `quic/` endpoint (keys from `cqnet hosts keys`); plain TCP, unauthenticated and unencrypted, only with `[trust] plain_tcp = true`",
            format!("{endpoint:?}"),
        )),
        "quic" | "tcp" if h > 0 && !s.hosts[0].endpoint.starts_with(&format!("{protocol}/")) => {
            Err((key, "the protocol of hosts[0].endpoint", format!("{endpoint:?}")))
        }
        "quic" | "tcp" => Ok(()),
        _ => Err((key, "a `quic/` (or `tcp/`) endpoint", format!("{endpoint:?}"))),
    }
}

impl Placement {
    /// The placement a scenario asks for; `None` for a single-host scenario.
    /// Checks every host, naming the key at fault.
    pub fn from_scenario(
        s: &Scenario,
        topology: &Topology,
        file: &str,
        centralized: bool,
    ) -> Result<Option<Self>, ScenarioError> {
        if s.hosts.is_empty() {
            return Ok(None);
        }
        let bad = |key: String, expected: &str, got: String| ScenarioError::Invalid {
            file: file.into(),
            key,
            expected: expected.into(),
            got,
        };
        let mut node_host = vec![usize::MAX; topology.nodes()];
        for (h, host) in s.hosts.iter().enumerate() {
            let name_ok = !host.name.is_empty()
                && host.name.len() <= MAX_HOST_NAME
                && host
                    .name
                    .bytes()
                    .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-');
            if !name_ok {
                return Err(bad(
                    format!("hosts[{h}].name"),
                    "1 to 8 lowercase letters, digits or `-`",
                    format!("{:?}", host.name),
                ));
            }
            if s.hosts[..h].iter().any(|o| o.name == host.name) {
                return Err(bad(
                    format!("hosts[{h}].name"),
                    "a name no other host has",
                    format!("{:?}", host.name),
                ));
            }
            if !host.endpoint.contains('/')
                || s.hosts[..h].iter().any(|o| o.endpoint == host.endpoint)
            {
                return Err(bad(
                    format!("hosts[{h}].endpoint"),
                    "a Zenoh endpoint (`quic/<address>:<port>`) no other host has",
                    format!("{:?}", host.endpoint),
                ));
            }
            check_protocol(s, h).map_err(|(key, expected, got)| bad(key, expected, got))?;
            if let Some(link) = &host.link {
                check_link(link, s.steps).map_err(|(key, expected, got)| {
                    bad(format!("hosts[{h}].link.{key}"), expected, got)
                })?;
            }
            for &n in &host.nodes {
                let slot = node_host.get_mut(n as usize).ok_or_else(|| {
                    bad(
                        format!("hosts[{h}].nodes"),
                        &format!("nodes of this network (0..{})", topology.nodes() - 1),
                        n.to_string(),
                    )
                })?;
                if *slot != usize::MAX {
                    return Err(bad(
                        format!("hosts[{h}].nodes"),
                        "each node on one host only",
                        format!("node {n} also on {}", s.hosts[*slot].name),
                    ));
                }
                *slot = h;
            }
        }
        if let Some(n) = node_host.iter().position(|h| *h == usize::MAX) {
            return Err(bad(
                "hosts".into(),
                "every node on a host",
                format!("node {n} on none"),
            ));
        }
        let sensor_host = topology
            .sensor_owner
            .iter()
            .map(|owner| node_host[*owner as usize])
            .collect();
        Ok(Some(Self {
            hosts: s.hosts.clone(),
            trust: s.trust.clone().unwrap_or_default(),
            node_host,
            sensor_host,
            pairs: s.talks_in_pairs(),
            centralized,
        }))
    }

    pub fn hosts(&self) -> &[HostConfig] {
        &self.hosts
    }

    /// How the hosts know each other (checked against their endpoints).
    pub fn trust(&self) -> &TrustConfig {
        &self.trust
    }

    /// Whether the hosts speak plain TCP (the scenario asked for it).
    pub fn plain_tcp(&self) -> bool {
        self.trust.plain_tcp
    }

    /// The index of the host named `name`.
    pub fn host_named(&self, name: &str) -> Option<usize> {
        self.hosts.iter().position(|h| h.name == name)
    }

    /// The host `actor` runs on; the launcher's is the first.
    pub fn host_of(&self, actor: ActorId) -> usize {
        match actor {
            ActorId::Launcher => 0,
            ActorId::Node(n) => self.node_host[n as usize],
            ActorId::Sensor(s) => self.sensor_host[s as usize],
            // A channel stands beside its node.
            ActorId::Mac(n) => self.node_host[n as usize],
        }
    }

    /// The actors host `h` runs, launcher excluded, nodes first.
    pub fn actors_on(&self, h: usize, topology: &Topology) -> Vec<ActorId> {
        topology
            .actors()
            .filter(|a| *a != ActorId::Launcher && self.host_of(*a) == h)
            .collect()
    }

    /// Host `h`'s iceoryx2 domain: the run id its actors (and its bridge)
    /// use, so each host's shared memory is its own. The launcher checks
    /// first that every host's is a run id ([`check_domains`](Self::check_domains)).
    pub fn domain(&self, run: &RunId, h: usize) -> RunId {
        let id = format!("{}-{}", run.as_str(), self.hosts[h].name);
        RunId::new(&id).expect("a run id and a host name make a run id")
    }

    /// Whether run id `run` leaves room for every host's name in its
    /// domain: a run id is at most 32 characters, and a domain is the run
    /// id, `-` and the host's name.
    pub fn check_domains(&self, run: &RunId) -> Result<(), String> {
        let longest = self.hosts.iter().map(|h| h.name.len()).max().unwrap_or(0);
        let room = 32usize.saturating_sub(longest + 1);
        if run.as_str().len() > room {
            return Err(format!(
                "run id `{}` is {} characters; with several hosts it may have at most {room} (32 with `-` and the longest host name)",
                run.as_str(),
                run.as_str().len()
            ));
        }
        Ok(())
    }

    /// Every channel of the network, with the actors that read it.
    pub fn channels(&self, topology: &Topology) -> Vec<(Channel, Vec<ActorId>)> {
        let mut all = vec![(
            Channel::Lifecycle,
            topology
                .actors()
                .filter(|a| matches!(a, ActorId::Sensor(_) | ActorId::Mac(_)))
                .collect(),
        )];
        for n in 0..topology.nodes() as u16 {
            let neighbours = || {
                topology.neighbours[n as usize]
                    .iter()
                    .map(|m| ActorId::Node(*m))
            };
            // Each sensor, and the multiple-access channel (which reads the
            // schedule of its slots), has its own.
            all.extend(
                topology
                    .activated_by(n)
                    .map(|to| (Channel::Activation { node: n, to }, vec![to])),
            );
            if topology.macs {
                all.push((Channel::MacOutput(n), vec![ActorId::Node(n)]));
            }
            all.push((Channel::Consensus(n), neighbours().collect()));
            all.push((Channel::Control(ActorId::Node(n)), vec![ActorId::Node(n)]));
            all.push((Channel::Telemetry(n), vec![ActorId::Launcher]));
            if self.pairs {
                for m in neighbours() {
                    let ActorId::Node(to) = m else { unreachable!() };
                    all.push((Channel::Pair { from: n, to }, vec![m]));
                }
            }
        }
        for s in 0..topology.sensors() as u16 {
            let mut readers = vec![topology.reports_to(s)];
            if self.centralized {
                readers.push(ActorId::Launcher);
            }
            all.push((Channel::Observation(s), readers));
        }
        all
    }

    /// The channels host `h` sends out: published there, read elsewhere.
    /// With each, the other hosts that read it.
    pub fn outgoing(&self, h: usize, topology: &Topology) -> Vec<(Channel, Vec<usize>)> {
        self.channels(topology)
            .into_iter()
            .filter(|(c, _)| self.host_of(c.publisher()) == h)
            .filter_map(|(c, readers)| {
                let mut far: Vec<usize> = readers
                    .iter()
                    .map(|r| self.host_of(*r))
                    .filter(|g| *g != h)
                    .collect();
                far.sort_unstable();
                far.dedup();
                (!far.is_empty()).then_some((c, far))
            })
            .collect()
    }

    /// The channels host `h` takes in: published elsewhere, read there.
    pub fn incoming(&self, h: usize, topology: &Topology) -> Vec<Channel> {
        self.channels(topology)
            .into_iter()
            .filter(|(c, readers)| {
                self.host_of(c.publisher()) != h && readers.iter().any(|r| self.host_of(*r) == h)
            })
            .map(|(c, _)| c)
            .collect()
    }

    /// Whether `from → to` crosses between hosts.
    pub fn crosses(&self, from: ActorId, to: ActorId) -> bool {
        self.host_of(from) != self.host_of(to)
    }
}

/// An actor's event id on its host bridge's wake-up service: the launcher
/// 0, then the nodes, then the sensors, then the channels.
pub fn wake_id(actor: ActorId, topology: &Topology) -> usize {
    match actor {
        ActorId::Launcher => 0,
        ActorId::Node(n) => 1 + n as usize,
        ActorId::Sensor(s) => 1 + topology.nodes() + s as usize,
        ActorId::Mac(n) => 1 + topology.nodes() + topology.sensors() + n as usize,
    }
}

/// The actor a [`wake_id`] names, if any.
pub fn actor_of_wake_id(id: usize, topology: &Topology) -> Option<ActorId> {
    let (nodes, sensors) = (topology.nodes(), topology.sensors());
    match id {
        0 => Some(ActorId::Launcher),
        i if i <= nodes => Some(ActorId::Node((i - 1) as u16)),
        i if i <= nodes + sensors => Some(ActorId::Sensor((i - 1 - nodes) as u16)),
        _ => None,
    }
}

/// What a bridge moved between hosts. `message_bytes` are cqnet's encoded
/// messages (what the actors' accounting counts); `batch_bytes` what the
/// bridge handed to Zenoh for them, its framing included; `tcp_*` what the
/// agent's TCP sockets carried (Zenoh's own framing and its control
/// traffic too; read from `TCP_INFO`, so connections closed before the
/// reading are missing).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct BridgeCounts {
    pub batches_sent: u64,
    pub messages_sent: u64,
    pub message_bytes_sent: u64,
    pub wakes_sent: u64,
    pub batch_bytes_sent: u64,
    pub batches_received: u64,
    pub messages_received: u64,
    pub message_bytes_received: u64,
    pub batch_bytes_received: u64,
    /// Batches that did not decode, and frames this host does not take.
    pub malformed_batches: u64,
    pub refused_frames: u64,
    /// Commands the agent refused: for another run, for an actor it does
    /// not run, or a setup it was not started for.
    pub refused_commands: u64,
    pub tcp_bytes_acked: u64,
    pub tcp_bytes_received: u64,
    pub tcp_segments_out: u64,
}

impl BridgeCounts {
    pub fn add(&mut self, o: &BridgeCounts) {
        self.batches_sent += o.batches_sent;
        self.messages_sent += o.messages_sent;
        self.message_bytes_sent += o.message_bytes_sent;
        self.wakes_sent += o.wakes_sent;
        self.batch_bytes_sent += o.batch_bytes_sent;
        self.batches_received += o.batches_received;
        self.messages_received += o.messages_received;
        self.message_bytes_received += o.message_bytes_received;
        self.batch_bytes_received += o.batch_bytes_received;
        self.malformed_batches += o.malformed_batches;
        self.refused_frames += o.refused_frames;
        self.refused_commands += o.refused_commands;
        self.tcp_bytes_acked += o.tcp_bytes_acked;
        self.tcp_bytes_received += o.tcp_bytes_received;
        self.tcp_segments_out += o.tcp_segments_out;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn three_hosts() -> (Scenario, Topology) {
        let mut s = Scenario::default_scenario();
        let t = Topology::from_scenario(&s, "default").unwrap();
        let n = t.nodes() as u16;
        s.hosts = (0..3)
            .map(|h| HostConfig {
                link: None,
                name: format!("h{h}"),
                nodes: (0..n).filter(|i| i % 3 == h).collect(),
                endpoint: format!("quic/127.0.0.1:{}", 17000 + h),
            })
            .collect();
        (s, t)
    }

    #[test]
    fn sensors_go_with_their_node_and_the_launcher_with_the_first_host() {
        let (s, t) = three_hosts();
        let p = Placement::from_scenario(&s, &t, "x", true)
            .unwrap()
            .unwrap();
        assert_eq!(p.host_of(ActorId::Launcher), 0);
        for (sensor, owner) in t.sensor_owner.iter().enumerate() {
            assert_eq!(
                p.host_of(ActorId::Sensor(sensor as u16)),
                p.host_of(ActorId::Node(*owner))
            );
        }
        let on: usize = (0..3).map(|h| p.actors_on(h, &t).len()).sum();
        assert_eq!(on, t.nodes() + t.sensors());
    }

    /// What leaves one host is what the others take in, channel for channel.
    #[test]
    fn every_outgoing_channel_is_incoming_on_each_host_that_reads_it() {
        let (s, t) = three_hosts();
        let p = Placement::from_scenario(&s, &t, "x", true)
            .unwrap()
            .unwrap();
        let mut sent = Vec::new();
        for h in 0..3 {
            for (c, far) in p.outgoing(h, &t) {
                sent.extend(far.into_iter().map(|g| (c, g)));
            }
        }
        let mut taken: Vec<(Channel, usize)> = (0..3)
            .flat_map(|g| p.incoming(g, &t).into_iter().map(move |c| (c, g)))
            .collect();
        sent.sort();
        taken.sort();
        assert_eq!(sent, taken);
        // Observations never cross except to the launcher; activations never.
        assert!(taken
            .iter()
            .all(|(c, g)| !matches!(c, Channel::Activation { .. })
                && (!matches!(c, Channel::Observation(_)) || *g == 0)));
    }

    #[test]
    fn bad_hosts_are_refused_by_key() {
        let (s, t) = three_hosts();
        let check = |edit: &dyn Fn(&mut Scenario), key: &str| {
            let mut s = s.clone();
            edit(&mut s);
            let err = Placement::from_scenario(&s, &t, "x", false)
                .unwrap_err()
                .to_string();
            assert!(err.contains(key), "{err}");
        };
        check(&|s| s.hosts[1].name = "Bad".into(), "hosts[1].name");
        check(&|s| s.hosts[2].name = "h0".into(), "hosts[2].name");
        check(
            &|s| s.hosts[1].endpoint = s.hosts[0].endpoint.clone(),
            "hosts[1].endpoint",
        );
        check(&|s| s.hosts[0].nodes.push(1), "hosts[1].nodes");
        // Plain TCP only in so many words; one protocol for every host.
        let tcp = |s: &mut Scenario| {
            for h in &mut s.hosts {
                h.endpoint = h.endpoint.replace("quic/", "tcp/");
            }
        };
        check(&tcp, "hosts[0].endpoint");
        check(
            &|s| s.hosts[2].endpoint = "udp/127.0.0.1:1".into(),
            "hosts[2].endpoint",
        );
        check(
            &|s| s.hosts[1].endpoint = "tcp/127.0.0.1:1".into(),
            "hosts[1].endpoint",
        );
        // Zenoh's TCP-borne TLS loses messages under load: refused, saying so.
        let mut tls = s.clone();
        tls.hosts[0].endpoint = "tls/127.0.0.1:17000".into();
        let e = Placement::from_scenario(&tls, &t, "x", false).unwrap_err();
        assert!(e.to_string().contains("loses messages"), "{e}");
        check(
            &|s| {
                s.trust = Some(TrustConfig {
                    keys: None,
                    plain_tcp: true,
                })
            },
            "trust.plain_tcp",
        );
        let mut plain = s.clone();
        tcp(&mut plain);
        plain.trust = Some(TrustConfig {
            keys: None,
            plain_tcp: true,
        });
        assert!(Placement::from_scenario(&plain, &t, "x", false)
            .unwrap()
            .unwrap()
            .plain_tcp());
        check(&|s| s.hosts[0].nodes.push(999), "hosts[0].nodes");
        check(
            &|s| {
                s.hosts[2].nodes.pop();
            },
            "`hosts`",
        );
        let link = |l: HostLink| {
            move |s: &mut Scenario| {
                s.hosts[1].link = Some(l.clone());
            }
        };
        check(
            &link(HostLink {
                loss: 1.5,
                ..Default::default()
            }),
            "hosts[1].link.loss",
        );
        check(
            &link(HostLink {
                delay_ms: -1.0,
                ..Default::default()
            }),
            "hosts[1].link.delay_ms",
        );
        check(
            &link(HostLink {
                cut_steps: 5,
                ..Default::default()
            }),
            "hosts[1].link.cut_at_step",
        );
        check(
            &link(HostLink {
                cut_at_step: Some(s.steps + 1),
                cut_steps: 1,
                ..Default::default()
            }),
            "hosts[1].link.cut_at_step",
        );
        check(
            &link(HostLink {
                cut_at_step: Some(3),
                ..Default::default()
            }),
            "hosts[1].link.cut_steps",
        );
        let mut fine = s.clone();
        fine.hosts[1].link = Some(HostLink {
            delay_ms: 5.0,
            rate_mbit: 10.0,
            cut_at_step: Some(3),
            cut_steps: 4,
            ..Default::default()
        });
        assert!(Placement::from_scenario(&fine, &t, "x", false).is_ok());
        // And through a file, its keys named in full.
        let text = fine.to_toml().replace("loss = 0.0", "loss = 2.0");
        let err = Scenario::from_toml(&text, "f.toml", &[])
            .map(|s| Placement::from_scenario(&s, &t, "f.toml", false).map(|_| ()));
        assert!(
            matches!(&err, Ok(Err(e)) if e.to_string().contains("hosts[1].link.loss")),
            "{err:?}"
        );
    }

    #[test]
    fn wake_ids_name_each_actor_once() {
        let (_, t) = three_hosts();
        for a in t.actors() {
            assert_eq!(actor_of_wake_id(wake_id(a, &t), &t), Some(a));
        }
        assert_eq!(actor_of_wake_id(1 + t.nodes() + t.sensors(), &t), None);
    }
}
