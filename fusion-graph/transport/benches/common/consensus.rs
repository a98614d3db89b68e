//! The consensus message the transport's benchmarks (and `launch`'s
//! rounds benchmark, which includes this file) send: a CF/DPF round's
//! values, of the size every round's message has.

use wire::{ActorId, ConsensusValues, Message, Payload};

pub fn consensus_message(node: u16, step: u32, round: u16) -> Message {
    Message::new(
        ActorId::Node(node),
        step,
        round,
        Payload::Consensus(ConsensusValues {
            delta_eta: [1.0; 4],
            delta_lambda: [2.0; 10],
            delta_l: [3.0; 10],
            delta_l_late: None,
        }),
    )
}
