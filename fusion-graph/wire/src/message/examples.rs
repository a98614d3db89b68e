//! A message of every kind, for tests and the fuzzer to start from.

use super::*;

/// One message of every kind, with plausible values: the seeds that tests
/// and `cqnet fuzz` start from.
pub fn examples() -> Vec<Message> {
    let c = ConsensusValues {
        delta_eta: [1.0, 2.0, 3.0, 4.0],
        delta_lambda: [0.5; 10],
        delta_l: [-0.25; 10],
        delta_l_late: None,
    };
    let t = Telemetry {
        estimate: [1.0; 4],
        bound: Some(1.5),
        local_bound: None,
        aux_bound: Some(2.0),
        rounds_completed: 10,
        live_neighbours: 4,
        missed_neighbours: 1,
        short_rounds: 2,
        observations: 3,
        gated: 1,
        lagged: 2,
        deadline_missed: false,
        late_messages: 2,
        stage_micros: [1, 2, 3, 4, 5, 6],
        unanswered_sensors: 1,
        first_unanswered: Some(17),
        spread: Some(12.5),
        active: vec![3, 17],
        design: vec![6840, 3160, 0],
        without_choice: true,
        disagreement: Some(0.03),
    };
    vec![
        Message::new(
            ActorId::Node(2),
            7,
            0,
            Payload::Activate {
                mask: BitMask::from_bytes(vec![0b101, 0, 0, 1]),
            },
        ),
        Message::new(
            ActorId::Node(2),
            7,
            0,
            Payload::ActivateWithFeedback {
                mask: BitMask::from_bytes(vec![0b11, 0, 0, 0]),
                estimate: [1400.0, 1400.0, -6.4, -7.6],
                covariance: None,
            },
        ),
        Message::new(
            ActorId::Node(2),
            7,
            0,
            Payload::ActivateWithFeedback {
                mask: BitMask::from_bytes(vec![0b110, 0, 0, 0]),
                estimate: [1400.0, 1400.0, -6.4, -7.6],
                covariance: Some([1.0, 0.1, 0.0, 0.2, 2.0, 0.0, 0.3, 0.5, 0.0, 0.6]),
            },
        ),
        Message::new(
            ActorId::Sensor(117),
            7,
            0,
            Payload::Observation { cell: 201 },
        ),
        Message::new(
            ActorId::Sensor(3),
            7,
            0,
            Payload::RawObservation { value: -1.25 },
        ),
        Message::new(ActorId::Node(4), 7, 9, Payload::Consensus(c.clone())),
        Message::new(
            ActorId::Node(4),
            7,
            9,
            Payload::Consensus(ConsensusValues {
                delta_l_late: Some([0.125; 10]),
                ..c
            }),
        ),
        Message::new(
            ActorId::Node(4),
            7,
            9,
            Payload::ConsensusAux { s_obs: [3.0; 10] },
        ),
        Message::new(ActorId::Launcher, 7, 0, Payload::Control(Control::Stop)),
        Message::new(
            ActorId::Launcher,
            7,
            0,
            Payload::Control(Control::Membership {
                alive: BitMask::from_bytes(vec![0xff, 1]),
            }),
        ),
        Message::new(ActorId::Node(0), 7, 0, Payload::Telemetry(t)),
        Message::new(
            ActorId::Node(1),
            7,
            0,
            Payload::StateTransfer(StateTransfer {
                mean: [1.0; 4],
                covariance: [2.0; 10],
                information: [3.0; 10],
                aux_information: [4.0; 10],
            }),
        ),
        Message::new(
            ActorId::Node(3),
            7,
            2,
            Payload::SelectionReport(CandidateReport {
                to: 4,
                part: 2,
                parts: 3,
                node: 0,
                first: 24,
                information: vec![[1e-4, -2e-5, 3e-4]],
            }),
        ),
        Message::new(
            ActorId::Node(4),
            7,
            2,
            Payload::SelectionChoice(ChosenSensors {
                part: 0,
                parts: 1,
                total: 3,
                sum: [3e-4, 1e-5, 2e-4],
                sensors: vec![7, 77, 201],
            }),
        ),
        Message::new(
            ActorId::Node(5),
            7,
            3,
            Payload::KlConsensus(GaussianInformation {
                eta: [2.0, 2.0, 0.0, 0.0],
                lambda: [0.04, 0.0, 0.0, 0.0, 0.04, 0.0, 0.0, 400.0, 0.0, 400.0],
            }),
        ),
        Message::new(ActorId::Node(6), 7, 0, Payload::ExchangeRequest),
        Message::new(
            ActorId::Node(7),
            7,
            0,
            Payload::ExchangeReply { accepted: true },
        ),
        Message::new(
            ActorId::Node(7),
            7,
            0,
            Payload::ExchangePosterior(GaussianMoments {
                mean: [50.0, 50.0, 0.0, 0.0],
                covariance: [25.0, 0.0, 0.0, 0.0, 25.0, 0.0, 0.0, 0.0025, 0.0, 0.0025],
            }),
        ),
        Message::new(
            ActorId::Node(8),
            7,
            0,
            Payload::NeighbourObservation {
                sensor: 8,
                value: -64.5,
            },
        ),
        Message::new(
            ActorId::Node(1),
            7,
            0,
            Payload::ActivateThresholds {
                mask: BitMask::from_bytes(vec![0b1111, 0, 0, 0]),
                thresholds: vec![1.5, 12.25, 40.0],
            },
        ),
        Message::new(
            ActorId::Node(3),
            7,
            4,
            Payload::LocationConsensus {
                chunk: 2,
                values: std::array::from_fn(|i| -1000.0 + i as f64),
            },
        ),
        Message::new(
            ActorId::Node(0),
            4,
            0,
            Payload::ActivateSlots {
                slots: 6,
                columns: vec![
                    SlotColumn {
                        sensor: 3,
                        slots: 0b10_0101,
                        negative: 0b00_0100,
                    },
                    SlotColumn {
                        sensor: 12,
                        slots: 0b01_0000,
                        negative: 0,
                    },
                ],
            },
        ),
        Message::new(
            ActorId::Sensor(3),
            4,
            0,
            Payload::SlotValues {
                slots: 0b10_0101,
                values: vec![31.5, -31.5, 31.5],
            },
        ),
        Message::new(
            ActorId::Mac(0),
            4,
            0,
            Payload::MacOutput {
                values: vec![31.9, 2.0, -30.1, 0.2, 5.5, 30.8],
            },
        ),
    ]
}
