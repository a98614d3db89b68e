//! Byte accounting per directed link and message kind.

use std::collections::BTreeMap;

use crate::counters::{kind_or_malformed, Links, Pair};
pub use crate::counters::{Counters, LinkKey};
use crate::ledger::{Ledger, LedgerCounts, LedgerError};
use wire::payloads::Payloads;
use wire::ActorId;
use wire::MessageKind;

/// Counters per directed link and kind. An actor of a real network mirrors
/// every update into a [`Ledger`], so that its counts outlive it.
#[derive(Debug, Default)]
pub struct Accounting {
    links: BTreeMap<LinkKey, Link>,
    /// Reads of the world's truth that failed: a sensor that found the
    /// step it was activated for not yet written, or no longer held.
    world_misses: u64,
    ledger: Option<Ledger>,
}

/// One link's counts, with where the ledger keeps them once it does: a
/// message's count then finds its ledger slot with the same lookup that
/// finds its counters. A node counts every consensus message it sends and
/// receives, and dropping the second lookup (the ledger's own map) took a
/// sixth off the time of cqnet's layer in a round of the 100-node grid
/// (`cargo bench -p transport --bench message_path`, the inbox round).
#[derive(Debug, Clone, Copy, Default)]
struct Link {
    counters: Counters,
    slot: Option<usize>,
}

/// A copy is the counts alone: the ledger stays with its one writer.
impl Clone for Accounting {
    fn clone(&self) -> Self {
        Self {
            links: self.links.clone(),
            world_misses: self.world_misses,
            ledger: None,
        }
    }
}

impl PartialEq for Accounting {
    fn eq(&self, other: &Self) -> bool {
        self.iter().eq(other.iter()) && self.world_misses == other.world_misses
    }
}

impl Accounting {
    /// Counts that continue those already in `ledger` (an earlier
    /// incarnation's) and are mirrored into it from now on.
    pub fn backed_by(ledger: Ledger) -> Self {
        let counts = ledger.counts();
        Self {
            ledger: Some(ledger),
            ..Self::from(counts)
        }
    }

    /// Counts a read of the world's truth that failed.
    pub fn record_world_miss(&mut self) {
        self.world_misses += 1;
        if let Some(ledger) = &self.ledger {
            ledger.count_world_miss();
        }
    }

    /// Reads of the world's truth that failed.
    pub fn world_misses(&self) -> u64 {
        self.world_misses
    }

    /// `messages` (±1) of `bytes` each to one counter pair of one link, in
    /// memory and in the ledger: every `record_*` comes through here.
    fn add(&mut self, key: LinkKey, pair: Pair, messages: i64, bytes: usize) {
        let link = self.links.entry(key).or_default();
        let (m, b) = link.counters.pair_mut(pair);
        *m = m.wrapping_add_signed(messages);
        *b = b.wrapping_add_signed(messages * bytes as i64);
        let Some(ledger) = self.ledger.as_mut() else {
            return;
        };
        let bytes = bytes as i64 * messages.signum();
        let mirrored = match link.slot {
            Some(slot) => Ok(slot),
            None => ledger.slot(key),
        }
        .map(|slot| {
            link.slot = Some(slot);
            ledger.add_at(slot, pair, messages, bytes)
        });
        if let Err(e) = mirrored {
            // Sized from the topology, a ledger cannot fill; if it ever does,
            // say so once and go on counting in memory.
            tracing::error!(error = %e, "byte counts are no longer kept across a kill");
            self.ledger = None;
        }
    }

    pub fn record_sent(&mut self, from: ActorId, to: ActorId, kind: MessageKind, bytes: usize) {
        self.add((from, to, kind), Pair::Sent, 1, bytes);
    }

    /// Takes back [`record_sent_to`](Self::record_sent_to) for a message
    /// that could not be published after all.
    pub fn unrecord_sent_to(
        &mut self,
        from: ActorId,
        receivers: &[ActorId],
        kind: MessageKind,
        bytes: usize,
    ) {
        for to in receivers {
            self.add((from, *to, kind), Pair::Sent, -1, bytes);
        }
    }

    /// One message of `bytes` published once for several receivers: one sent
    /// message per directed link.
    pub fn record_sent_to(
        &mut self,
        from: ActorId,
        receivers: &[ActorId],
        kind: MessageKind,
        bytes: usize,
    ) {
        for to in receivers {
            self.record_sent(from, *to, kind, bytes);
        }
    }

    pub fn record_received(&mut self, from: ActorId, to: ActorId, kind: MessageKind, bytes: usize) {
        self.add((from, to, kind), Pair::Received, 1, bytes);
    }

    pub fn record_dropped(&mut self, from: ActorId, to: ActorId, kind: MessageKind, bytes: usize) {
        self.add((from, to, kind), Pair::Dropped, 1, bytes);
    }

    /// A message that did not decode, under the kind it was sent as when
    /// that is known, else [`MessageKind::Malformed`].
    pub fn record_malformed(
        &mut self,
        from: ActorId,
        to: ActorId,
        kind: MessageKind,
        bytes: usize,
    ) {
        self.add((from, to, kind), Pair::Malformed, 1, bytes);
    }

    /// A second copy of a message, made by a `duplicate` fault.
    pub fn record_duplicated(
        &mut self,
        from: ActorId,
        to: ActorId,
        kind: MessageKind,
        bytes: usize,
    ) {
        self.add((from, to, kind), Pair::Duplicated, 1, bytes);
    }

    /// Adds `other`'s counts (in memory only: merging is the reader's work).
    pub fn merge(&mut self, other: &Accounting) {
        for (k, c) in other.iter() {
            self.add_counters(*k, c);
        }
        self.world_misses += other.world_misses;
    }

    pub(crate) fn add_counters(&mut self, key: LinkKey, c: &Counters) {
        self.links.entry(key).or_default().counters.add(c);
    }

    pub fn get(&self, from: ActorId, to: ActorId, kind: MessageKind) -> Counters {
        self.links
            .get(&(from, to, kind))
            .map(|l| l.counters)
            .unwrap_or_default()
    }

    pub fn iter(&self) -> impl Iterator<Item = (&LinkKey, &Counters)> {
        self.links.iter().map(|(k, l)| (k, &l.counters))
    }

    /// Totals over every link, per kind.
    pub fn by_kind(&self) -> BTreeMap<MessageKind, Counters> {
        let mut out: BTreeMap<MessageKind, Counters> = BTreeMap::new();
        for ((_, _, kind), c) in self.iter() {
            out.entry(*kind).or_default().add(c);
        }
        out
    }

    /// `links.csv` rows, header first.
    pub fn to_csv(&self) -> String {
        let mut s = String::from("from,to,kind,sent_messages,sent_bytes,received_messages,received_bytes,dropped_messages,dropped_bytes,malformed_messages,malformed_bytes,duplicated_messages,duplicated_bytes\n");
        for ((from, to, kind), c) in self.iter() {
            s.push_str(&format!(
                "{from},{to},{},{},{},{},{},{},{},{},{},{},{}\n",
                kind.name(),
                c.sent_messages,
                c.sent_bytes,
                c.received_messages,
                c.received_bytes,
                c.dropped_messages,
                c.dropped_bytes,
                c.malformed_messages,
                c.malformed_bytes,
                c.duplicated_messages,
                c.duplicated_bytes
            ));
        }
        s
    }

    /// [`to_csv`](Self::to_csv) and, on a last line, the failed reads of
    /// the world: how an agent sends its host's counts home.
    pub fn to_csv_with_world_misses(&self) -> String {
        format!(
            "{}{WORLD_MISSES_LINE}{}\n",
            self.to_csv(),
            self.world_misses
        )
    }

    /// Reads back what [`to_csv`](Self::to_csv) or
    /// [`to_csv_with_world_misses`](Self::to_csv_with_world_misses) wrote;
    /// `None` on any bad row. `payloads`: the program's, whose kinds the
    /// table may name.
    pub fn from_csv(text: &str, payloads: Payloads) -> Option<Self> {
        let mut a = Accounting::default();
        for line in text.lines().skip(1).filter(|l| !l.is_empty()) {
            if let Some(misses) = line.strip_prefix(WORLD_MISSES_LINE) {
                a.world_misses += misses.parse::<u64>().ok()?;
                continue;
            }
            let f: Vec<&str> = line.split(',').collect();
            // 11 columns before duplicates were counted.
            if f.len() != 11 && f.len() != 13 {
                return None;
            }
            // Every kind byte, so that a kind added later is read back too.
            let kind = (0..=u8::MAX)
                .filter_map(|v| kind_or_malformed(v, payloads))
                .find(|k| k.name() == f[2])?;
            let n: Vec<u64> = f[3..]
                .iter()
                .map(|v| v.parse().ok())
                .collect::<Option<_>>()?;
            let c = Counters {
                sent_messages: n[0],
                sent_bytes: n[1],
                received_messages: n[2],
                received_bytes: n[3],
                dropped_messages: n[4],
                dropped_bytes: n[5],
                malformed_messages: n[6],
                malformed_bytes: n[7],
                duplicated_messages: n.get(8).copied().unwrap_or(0),
                duplicated_bytes: n.get(9).copied().unwrap_or(0),
            };
            a.add_counters((f[0].parse().ok()?, f[1].parse().ok()?, kind), &c);
        }
        Some(a)
    }
}

/// The start of the line that carries the failed reads of the world.
const WORLD_MISSES_LINE: &str = "# world_misses,";

impl From<Links> for Accounting {
    fn from(links: Links) -> Self {
        Self {
            links: links
                .0
                .into_iter()
                .map(|(k, counters)| {
                    (
                        k,
                        Link {
                            counters,
                            slot: None,
                        },
                    )
                })
                .collect(),
            world_misses: 0,
            ledger: None,
        }
    }
}

impl From<LedgerCounts> for Accounting {
    fn from(counts: LedgerCounts) -> Self {
        Self {
            world_misses: counts.world_misses,
            ..Self::from(counts.links)
        }
    }
}

/// The counts an actor left in its ledger at `path` (see
/// [`crate::ledger::read_ledger`]).
pub fn read_ledger(path: &std::path::Path, payloads: Payloads) -> Result<Accounting, LedgerError> {
    crate::ledger::read_ledger(path, payloads).map(Accounting::from)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_merge_and_survive_csv() {
        let mut a = Accounting::default();
        a.record_sent(
            ActorId::Node(0),
            ActorId::Node(1),
            MessageKind::Consensus,
            203,
        );
        a.record_received(
            ActorId::Node(0),
            ActorId::Node(1),
            MessageKind::Consensus,
            203,
        );
        a.record_malformed(
            ActorId::Node(0),
            ActorId::Node(1),
            MessageKind::Malformed,
            17,
        );
        a.record_duplicated(
            ActorId::Node(0),
            ActorId::Node(1),
            MessageKind::Consensus,
            203,
        );
        a.record_sent(
            ActorId::Node(1),
            ActorId::Node(2),
            MessageKind::SelectionReport,
            47,
        );
        let mut b = Accounting::default();
        b.record_dropped(
            ActorId::Sensor(3),
            ActorId::Node(0),
            MessageKind::Observation,
            12,
        );
        b.merge(&a);
        assert_eq!(
            b.get(ActorId::Node(0), ActorId::Node(1), MessageKind::Consensus)
                .sent_bytes,
            203
        );
        assert_eq!(b.by_kind()[&MessageKind::Malformed].malformed_messages, 1);
        assert_eq!(
            Accounting::from_csv(&b.to_csv(), Payloads::NONE).unwrap(),
            b
        );
        // The failed reads of the world travel only on the agents' form.
        b.record_world_miss();
        b.merge(&b.clone());
        assert_eq!(b.world_misses(), 2);
        assert_eq!(
            Accounting::from_csv(&b.to_csv(), Payloads::NONE)
                .unwrap()
                .world_misses(),
            0
        );
        assert_eq!(
            Accounting::from_csv(&b.to_csv_with_world_misses(), Payloads::NONE).unwrap(),
            b
        );
        assert!(
            Accounting::from_csv(&(b.to_csv() + "# world_misses,x\n"), Payloads::NONE).is_none()
        );
    }
}
