//! The launcher's hold on the processes: starting every actor, applying
//! kills and restarts, noticing the ones that die, and stopping them all.

use std::collections::HashSet;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use anyhow::bail;
use fusion_graph::faults::{FaultSchedule, ProcessEvent};
use fusion_graph::scenario::Signal;
use fusion_graph::{ActorId, Topology};
use tokio::sync::mpsc::UnboundedSender;
use transport::accounting::Accounting;
use transport::{Channel, IceoryxTransport, Transport};
use wire::{Control, Message, Payload};

use crate::actor_process::stop_message;
use crate::feed::{Hub, ViewEvent};
use crate::summary::AppliedFault;
use crate::supervisor::{Command, Event};
use transport::world_memory::TruthRing;

use super::options::RunProgress;

/// How long children get to start and say `ready`.
const START_TIMEOUT: Duration = Duration::from_secs(120);

pub(super) struct Processes<'a> {
    pub(super) transport: IceoryxTransport,
    /// The truth of recent steps, which this host's sensors read.
    pub(super) truths: TruthRing,
    pub(super) commands: &'a UnboundedSender<Command>,
    pub(super) events: &'a Receiver<Event>,
    pub(super) alive: Vec<bool>,
    /// Which sensors run (a stopped or killed one does not).
    pub(super) sensors_alive: Vec<bool>,
    /// Actors we killed on purpose (their exit is not an error).
    pub(super) expected_exits: HashSet<ActorId>,
    pub(super) unexpected_exits: Vec<String>,
    /// Actors that died on their own, and the step the launcher noticed:
    /// faults of the run, and respawned (not continued) at a scheduled restart.
    pub(super) crashed: Vec<(ActorId, u32, String)>,
    /// Of those, the ones not started again yet.
    pub(super) dead: HashSet<ActorId>,
    /// The step being run.
    pub(super) step: u32,
    pub(super) interrupted: bool,
    /// The membership view each node was last told.
    pub(super) views: Vec<Vec<bool>>,
    /// Actors of a lost host whose agent is back, to start again.
    pub(super) returning: Vec<ActorId>,
    /// In real time: actors restarted and not yet ready, which the steps
    /// do not wait for.
    starting: HashSet<ActorId>,
    /// Of those, the ones that said `ready`, to join at the next step.
    ready: Vec<ActorId>,
    /// The program's payloads, which the hosts' counts may name.
    payloads: wire::payloads::Payloads,
}

impl<'a> Processes<'a> {
    pub(super) fn new(
        transport: IceoryxTransport,
        truths: TruthRing,
        topology: &Topology,
        commands: &'a UnboundedSender<Command>,
        events: &'a Receiver<Event>,
    ) -> Self {
        Self {
            transport,
            truths,
            commands,
            events,
            alive: vec![true; topology.nodes()],
            sensors_alive: vec![true; topology.sensors()],
            expected_exits: HashSet::new(),
            unexpected_exits: Vec::new(),
            crashed: Vec::new(),
            dead: HashSet::new(),
            step: 0,
            interrupted: false,
            views: Vec::new(),
            returning: Vec::new(),
            starting: HashSet::new(),
            ready: Vec::new(),
            payloads: topology.payloads,
        }
    }

    /// Spawns every actor and waits until each said it is ready, showing
    /// how many are.
    pub(super) fn start_everyone(
        &mut self,
        topology: &Topology,
        view: Option<&Hub>,
        progress: &mut dyn FnMut(RunProgress<'_>),
    ) -> anyhow::Result<()> {
        let started = Instant::now();
        let actors: Vec<ActorId> = topology.actors().collect();
        for a in &actors {
            self.commands.send(Command::Spawn {
                actor: *a,
                rejoin: false,
            })?;
        }
        let of = actors.len();
        self.await_ready(&actors, &mut |ready| {
            progress(RunProgress::Starting { ready, of });
            if let Some(hub) = view {
                hub.publish(&ViewEvent::Starting { ready, of });
            }
        })?;
        progress(RunProgress::Running);
        self.transport.update_connections();
        tracing::info!(
            actors = actors.len(),
            seconds = started.elapsed().as_secs_f64(),
            "every actor is ready"
        );
        Ok(())
    }

    /// Tells every actor to stop after step `last`, and waits (10 s at
    /// most) until the live ones have exited, so that their byte counts
    /// are final.
    pub(super) fn stop_everyone(&mut self, topology: &Topology, last: u32, started: Instant) {
        for n in 0..topology.nodes() as u16 {
            let to = ActorId::Node(n);
            let _ = self.transport.send(
                Channel::Control(to),
                &Message::new(ActorId::Launcher, last, 0, Payload::Control(Control::Stop)),
                &[to],
            );
        }
        let sensors: Vec<ActorId> = (0..topology.sensors() as u16)
            .map(ActorId::Sensor)
            .chain((0..topology.mac_count() as u16).map(ActorId::Mac))
            .collect();
        let _ = self
            .transport
            .send(Channel::Lifecycle, &stop_message(last), &sensors);
        let mut exited: HashSet<ActorId> = HashSet::new();
        let live: HashSet<ActorId> = topology.actors().filter(|a| self.is_alive(*a)).collect();
        let deadline = Instant::now() + Duration::from_secs(10);
        while !live.is_subset(&exited) && Instant::now() < deadline {
            match self.events.recv_timeout(Duration::from_millis(50)) {
                Ok(Event::Exited { actor, .. }) => {
                    exited.insert(actor);
                }
                Ok(_) | Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
        }
        tracing::info!(
            exited = exited.len(),
            of = live.len(),
            seconds = started.elapsed().as_secs_f64(),
            "actors stopped"
        );
    }

    pub(super) fn is_alive(&self, a: ActorId) -> bool {
        match a {
            ActorId::Node(i) => self.alive[i as usize],
            ActorId::Sensor(i) => self.sensors_alive[i as usize],
            // No fault stops a channel.
            ActorId::Launcher | ActorId::Mac(_) => true,
        }
    }

    /// Waits for every listed actor's `ready`; a child that exits first ends
    /// the run with its name and the end of its stderr.
    pub(super) fn await_ready(
        &mut self,
        actors: &[ActorId],
        on_ready: &mut dyn FnMut(usize),
    ) -> anyhow::Result<()> {
        let mut waiting: HashSet<ActorId> = actors.iter().copied().collect();
        let deadline = Instant::now() + START_TIMEOUT;
        while !waiting.is_empty() {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.events.recv_timeout(left) {
                Ok(Event::Ready(a)) => {
                    waiting.remove(&a);
                    on_ready(actors.len() - waiting.len());
                }
                Ok(Event::Exited {
                    actor,
                    status,
                    stderr_tail,
                }) if waiting.contains(&actor) => {
                    bail!("{actor} exited ({status}) before it was ready; the end of its stderr:\n{stderr_tail}");
                }
                // Another actor died while a restarted one was starting: a
                // fault of the run like any other, not a failed start.
                Ok(e @ (Event::Exited { .. } | Event::HostBack(_))) => self.handle_event(e),
                Ok(Event::Counts { .. }) => {}
                Ok(Event::Interrupted) => bail!("interrupted while starting"),
                Ok(Event::AllReaped) => bail!("the supervisor stopped"),
                Err(_) => {
                    let mut late: Vec<ActorId> = waiting.into_iter().collect();
                    late.sort();
                    bail!(
                        "{} of {} actors were not ready after {:?}: {}",
                        late.len(),
                        actors.len(),
                        START_TIMEOUT,
                        name_some(&late, 10)
                    );
                }
            }
        }
        Ok(())
    }

    /// Handles exits and interrupts reported since the last call.
    pub(super) fn poll_events(&mut self) {
        while let Ok(e) = self.events.try_recv() {
            self.handle_event(e);
        }
    }

    pub(super) fn handle_event(&mut self, e: Event) {
        match e {
            Event::Exited {
                actor,
                status,
                stderr_tail,
            } if !self.expected_exits.contains(&actor) => {
                self.unexpected_exits.push(format!(
                    "{actor} exited unexpectedly ({status}); its stderr ended with:\n{stderr_tail}"
                ));
                self.crashed.push((actor, self.step, status));
                self.dead.insert(actor);
                self.set_alive(actor, false);
            }
            Event::Interrupted => self.interrupted = true,
            Event::HostBack(actors) => self.returning.extend(actors),
            Event::Ready(actor) if self.starting.remove(&actor) => self.ready.push(actor),
            _ => {}
        }
    }

    /// Starts again the actors of a host that came back, as a scheduled
    /// restart would: rejoining, and in the membership from this step.
    pub(super) fn restart_returning(&mut self) -> anyhow::Result<bool> {
        let actors = std::mem::take(&mut self.returning);
        if actors.is_empty() {
            return Ok(false);
        }
        for a in &actors {
            self.dead.remove(a);
            self.expected_exits.remove(a);
            self.commands.send(Command::Spawn {
                actor: *a,
                rejoin: true,
            })?;
        }
        self.await_ready(&actors, &mut |_| {})?;
        self.transport.update_connections();
        for a in actors {
            self.set_alive(a, true);
        }
        Ok(true)
    }

    /// Restarted actors that became ready since the last step join the
    /// network from this one; true if any did.
    pub(super) fn admit_restarted(&mut self) -> bool {
        if self.ready.is_empty() {
            return false;
        }
        self.transport.update_connections();
        for a in std::mem::take(&mut self.ready) {
            self.set_alive(a, true);
        }
        true
    }

    /// Several hosts: every host's actors' counts, merged into `total`,
    /// each bridge's own counts, and what each host sent home.
    pub(super) fn collect_host_counts(&mut self, total: &mut Accounting) -> HostsCollected {
        if self.commands.send(Command::Collect).is_err() {
            return HostsCollected::default();
        }
        let deadline = Instant::now() + Duration::from_secs(15);
        while Instant::now() < deadline {
            match self.events.recv_timeout(Duration::from_millis(50)) {
                Ok(Event::Counts {
                    accounting_csv,
                    bridges,
                    homes,
                }) => {
                    match Accounting::from_csv(&accounting_csv, self.payloads) {
                        Some(a) => total.merge(&a),
                        None => tracing::warn!("the hosts' byte counts did not parse"),
                    }
                    return HostsCollected { bridges, homes };
                }
                Ok(e) => self.handle_event(e),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
        }
        tracing::warn!("no byte counts from the hosts");
        HostsCollected::default()
    }

    /// Kills and restarts the actors the schedule says at `step`; true if
    /// the membership changed. A restarted process takes a while to start:
    /// in lockstep the step waits for it, so that it is back at the step the
    /// schedule says; in real time the steps go on, and it joins at the first
    /// step after it is ready ([`admit_restarted`](Self::admit_restarted)),
    /// since a launcher that waited would make every node miss its deadline.
    pub(super) fn apply_process_faults(
        &mut self,
        schedule: &FaultSchedule,
        step: u32,
        lockstep: bool,
    ) -> anyhow::Result<bool> {
        let mut changed = false;
        for event in schedule.process_events(step) {
            match event {
                ProcessEvent::Kill { actor, signal } => {
                    if signal != Signal::Stop {
                        self.expected_exits.insert(actor);
                    }
                    self.commands.send(Command::Signal { actor, signal })?;
                    self.set_alive(actor, false);
                    changed = true;
                }
                ProcessEvent::Restart { actor, signal } => {
                    // A stopped actor that died meanwhile is started afresh.
                    if signal == Signal::Stop && !self.dead.remove(&actor) {
                        self.commands.send(Command::Continue { actor })?;
                    } else {
                        // The old process must be reaped before its successor
                        // opens the same services (iceoryx2 cleans up dead nodes then).
                        self.expected_exits.remove(&actor);
                        self.dead.remove(&actor);
                        self.commands.send(Command::Spawn {
                            actor,
                            rejoin: true,
                        })?;
                        if !lockstep {
                            self.starting.insert(actor);
                            continue;
                        }
                        self.await_ready(&[actor], &mut |_| {})?;
                        self.transport.update_connections();
                    }
                    self.set_alive(actor, true);
                    changed = true;
                }
            }
        }
        Ok(changed)
    }

    /// Records that `actor` runs, or no longer does (killed, or stopped by
    /// SIGSTOP).
    pub(super) fn set_alive(&mut self, actor: ActorId, alive: bool) {
        match actor {
            ActorId::Node(i) => self.alive[i as usize] = alive,
            ActorId::Sensor(i) => self.sensors_alive[i as usize] = alive,
            ActorId::Launcher | ActorId::Mac(_) => {}
        }
    }
}

/// What the hosts answered at the end of a run.
#[derive(Debug, Default)]
pub(super) struct HostsCollected {
    pub bridges: Vec<(String, fusion_graph::hosts::BridgeCounts)>,
    pub homes: Vec<(String, crate::supervisor::HostFiles)>,
}

pub(super) fn crash_fault(actor: ActorId, step: u32, status: &str) -> AppliedFault {
    AppliedFault::new(step, None, format!("{actor} died unexpectedly ({status})"))
}

/// The first `shown` names, and how many more: 2,358 names in one error
/// line hide the message.
pub(super) fn name_some(actors: &[ActorId], shown: usize) -> String {
    let names: Vec<String> = actors.iter().take(shown).map(ActorId::to_string).collect();
    match actors.len().saturating_sub(shown) {
        0 => names.join(", "),
        more => format!("{} and {more} more", names.join(", ")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_list_of_actors_is_cut_short() {
        let actors: Vec<ActorId> = (0..2358).map(ActorId::Sensor).collect();
        assert_eq!(
            name_some(&actors, 3),
            "sensor-0, sensor-1, sensor-2 and 2355 more"
        );
        assert_eq!(name_some(&actors[..2], 3), "sensor-0, sensor-1");
    }
}
