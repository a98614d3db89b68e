//! A program's own protocol payload longer than the built-in consensus
//! messages: the channels between nodes make room for it, and it crosses
//! iceoryx2 between two actors.

use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use fusion_graph::{ActorId, Scenario, Topology, WireError};
use transport::iceoryx::remove_run_resources;
use transport::limits::ChannelLimits;
use transport::{Channel, IceoryxTransport, RunId, Transport};
use wire::payloads::{PayloadEntry, Payloads, ProtocolPayload};
use wire::{Message, WireFormat, HEADER_BYTES};

/// 80 f64s: 640 bytes, twice the built-in consensus message.
#[derive(Debug, Clone, PartialEq)]
struct Wide([f64; 80]);

impl ProtocolPayload for Wide {
    const NAME: &'static str = "wide";
    const LEN: usize = 640;

    fn encode(&self, out: &mut Vec<u8>) {
        for v in self.0 {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }

    fn decode(body: &[u8]) -> Result<Self, WireError> {
        let mut v = [0.0; 80];
        for (x, b) in v.iter_mut().zip(body.chunks_exact(8)) {
            *x = f64::from_le_bytes(b.try_into().map_err(|_| WireError::Truncated)?);
        }
        Ok(Self(v))
    }
}

#[test]
fn a_declared_payload_longer_than_consensus_messages_fits_its_channel() {
    let mut topology = Topology::from_scenario(&Scenario::default_scenario(), "default").unwrap();
    let before = ChannelLimits::of(&topology, Channel::Consensus(0)).message_bytes;
    assert!(before < HEADER_BYTES + Wide::LEN);
    let payloads = Payloads::new(vec![PayloadEntry::next::<Wide>(&[]).unwrap()]);
    // What a scenario read in a program that declares `Wide` lays out.
    topology.payloads = payloads;
    let kind = payloads.of::<Wide>().unwrap();
    let format = WireFormat {
        cell_bytes: 1,
        activation_bytes: 4,
        payloads,
    };
    let limits = ChannelLimits::of(&topology, Channel::Consensus(0));
    assert_eq!(limits.message_bytes, HEADER_BYTES + Wide::LEN);
    // Node 0's round value reaches its neighbour node 1 over iceoryx2.
    let n = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    let run = RunId::new(&format!("t{}-wide-{n:x}", std::process::id())).unwrap();
    let result = std::panic::catch_unwind(|| {
        let (a, b) = (ActorId::Node(0), ActorId::Node(1));
        let mut sender = IceoryxTransport::new(&run, a, &topology, format, 1).unwrap();
        let mut receiver = IceoryxTransport::new(&run, b, &topology, format, 2).unwrap();
        receiver.subscribe(Channel::Consensus(0)).unwrap();
        sender.publish_on(Channel::Consensus(0)).unwrap();
        sender.notify(b).unwrap();
        sender.update_connections();
        let value = Wide(std::array::from_fn(|i| i as f64));
        let message = Message::new(a, 1, 1, kind.payload(&value));
        // Every neighbour of node 0 reads its consensus channel (1 and 3
        // on the default grid): the message is for them both.
        sender
            .send(Channel::Consensus(0), &message, &[b, ActorId::Node(3)])
            .unwrap();
        let mut got = Vec::new();
        let start = Instant::now();
        while got.is_empty() && start.elapsed() < Duration::from_secs(10) {
            let now = receiver.now();
            receiver.receive(now, &mut got).unwrap();
            receiver.wait(Duration::from_millis(20)).unwrap();
        }
        assert_eq!(got.len(), 1);
        assert_eq!(kind.read(&got[0].payload), Some(value));
    });
    let _ = remove_run_resources(&run);
    result.unwrap();
}
