//! The counts of one directed link and message kind, and the counts of a
//! whole actor or run by link: what the accounting keeps in memory and the
//! ledger keeps in a file.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use wire::payloads::Payloads;
use wire::ActorId;
use wire::MessageKind;

/// Messages and encoded bytes on one directed link, of one kind.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counters {
    pub sent_messages: u64,
    pub sent_bytes: u64,
    pub received_messages: u64,
    pub received_bytes: u64,
    /// Dropped by an injected link fault (loss, partition).
    pub dropped_messages: u64,
    pub dropped_bytes: u64,
    /// Failed to decode and were discarded. Counted under the kind that was
    /// sent when an injected `corrupt` fault knows it, else under
    /// [`MessageKind::Malformed`].
    pub malformed_messages: u64,
    pub malformed_bytes: u64,
    /// Extra copies made by an injected `duplicate` fault; each is also
    /// counted received (or malformed), so a link balances as
    /// sent + duplicated = received + dropped + malformed + unaccounted.
    #[serde(default)]
    pub duplicated_messages: u64,
    #[serde(default)]
    pub duplicated_bytes: u64,
}

impl Counters {
    pub fn add(&mut self, o: &Counters) {
        self.sent_messages += o.sent_messages;
        self.sent_bytes += o.sent_bytes;
        self.received_messages += o.received_messages;
        self.received_bytes += o.received_bytes;
        self.dropped_messages += o.dropped_messages;
        self.dropped_bytes += o.dropped_bytes;
        self.malformed_messages += o.malformed_messages;
        self.malformed_bytes += o.malformed_bytes;
        self.duplicated_messages += o.duplicated_messages;
        self.duplicated_bytes += o.duplicated_bytes;
    }

    /// The messages and bytes of one pair: what the ledger's `Pair` names.
    pub(crate) fn pair_mut(&mut self, pair: Pair) -> (&mut u64, &mut u64) {
        match pair {
            Pair::Sent => (&mut self.sent_messages, &mut self.sent_bytes),
            Pair::Received => (&mut self.received_messages, &mut self.received_bytes),
            Pair::Dropped => (&mut self.dropped_messages, &mut self.dropped_bytes),
            Pair::Malformed => (&mut self.malformed_messages, &mut self.malformed_bytes),
            Pair::Duplicated => (&mut self.duplicated_messages, &mut self.duplicated_bytes),
        }
    }

    /// Sent (and duplicated in transit) but neither received, dropped by a
    /// fault nor rejected as malformed: lost to a full queue or a receiver
    /// that died, or still held by a delay when the run ended. Bytes whose
    /// kind could not be read ([`MessageKind::Malformed`]) have no sent
    /// count to balance, so they are left out.
    pub fn unaccounted_messages(&self, kind: MessageKind) -> i64 {
        if kind == MessageKind::Malformed {
            return 0;
        }
        (self.sent_messages + self.duplicated_messages) as i64
            - (self.received_messages + self.dropped_messages + self.malformed_messages) as i64
    }
}

/// Link `(from, to)` and kind.
pub type LinkKey = (ActorId, ActorId, MessageKind);

/// Which pair of [`Counters`] an update touches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pair {
    Sent = 0,
    Received = 1,
    Dropped = 2,
    Malformed = 3,
    Duplicated = 4,
}

/// Counts by link and kind.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Links(pub BTreeMap<LinkKey, Counters>);

impl Links {
    /// Adds `c` to the counts of `key`.
    pub fn add(&mut self, key: LinkKey, c: &Counters) {
        self.0.entry(key).or_default().add(c);
    }

    pub fn get(&self, from: ActorId, to: ActorId, kind: MessageKind) -> Counters {
        self.0.get(&(from, to, kind)).copied().unwrap_or_default()
    }
}

/// A kind byte as the ledger writes it: a message kind, or 255 for a
/// malformed message's line.
pub(crate) fn kind_or_malformed(v: u8, payloads: Payloads) -> Option<MessageKind> {
    if v == 255 {
        Some(MessageKind::Malformed)
    } else {
        MessageKind::from_code(v, payloads)
    }
}
