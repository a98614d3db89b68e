//! A static target's locator (`scenarios/location.toml`): four nodes, each
//! with 16 amplitude sensors, sum their log-likelihoods over shared grids
//! and their Fisher information by average consensus.
//!
//! - Under `sim`, every node's estimate is the ML estimate of all 64
//!   sensors' reports searched centrally over the same grids, and its
//!   bound is `sqrt(tr J⁻¹)` of `bounds`' exact CRLB (Theorem 6.2) of all
//!   the reports at that estimate: consensus gives the centralized sums.
//! - As real processes, in lockstep, the run reports `sim`'s ticks bit for
//!   bit and sends exactly the bytes its message sizes predict.

use std::time::Duration;

use bounds::location::{exact_information, log_likelihood, AmplitudeLaw, DecayLaw};
use bounds::Measurement;
use cqnet_testkit::{exclusive, MessageKind, Network, Run, Scenario};
use fusion_graph::world::StillTarget;
use fusion_graph::{ActorId, Topology};
use node::location::{sensor_quantizer, Grid, ThresholdDesign};
use sensor::SensorActor;
use wire::{BitMask, Message, Payload};

const CQNET: &str = env!("CARGO_BIN_EXE_cqnet-under-test");
const STEPS: u32 = 4;

fn scenario() -> Scenario {
    let mut s = Scenario::from_toml(
        fusion_graph::scenario::LOCATION_SCENARIO,
        "<built-in location>",
        &[],
    )
    .expect("the built-in scenario is valid");
    s.steps = STEPS;
    s
}

fn network(tag: &str) -> Network {
    Network::new(scenario())
        .executable(CQNET)
        .tag(tag)
        .lockstep()
        // No round may time out on a loaded machine: a timeout changes
        // what is summed (the listening window is as long).
        .set("consensus.round_timeout_ms", 5000)
        .set("clock.step_timeout_ms", 60000)
        .time_limit(Duration::from_secs(180))
}

/// Every report of every sensor in steps `1..=steps`, as its sensor
/// actor makes it from the truth and its node's activation: (sensor's
/// position, cell), in step and sensor order.
fn every_report(s: &Scenario, t: &Topology, steps: u32) -> Vec<([f64; 2], u32)> {
    let q = sensor_quantizer(s, ThresholdDesign::Designed).expect("quantized");
    let thresholds: Vec<f64> = (1..q.cells() as u32).map(|c| q.cell_edges(c).0).collect();
    let truth = bounds::State::new(s.target.position[0], s.target.position[1], 0.0, 0.0);
    let mut reports = Vec::new();
    for step in 1..=steps {
        for i in 0..t.sensors() as u16 {
            let mut sensor = SensorActor::new(s, t, i).unwrap();
            let owner = t.sensor_owner[i as usize];
            let own = &t.node_sensors[owner as usize];
            let activation = Message::new(
                ActorId::Node(owner),
                step,
                0,
                Payload::ActivateThresholds {
                    mask: BitMask::from_indices(0..own.len()),
                    thresholds: thresholds.clone(),
                },
            );
            let report = sensor
                .answer(&activation, &StillTarget(truth))
                .expect("the world holds every step")
                .expect("an active sensor reports");
            let Payload::Observation { cell } = report.payload else {
                panic!("a quantized report: {report:?}")
            };
            reports.push((t.sensor_positions[i as usize], cell));
        }
    }
    reports
}

/// The power law of the scenario's amplitude sensors (α = 1).
fn law(s: &Scenario) -> (DecayLaw, f64) {
    let a = AmplitudeLaw::of(s.observation.law()).expect("amplitude sensors");
    assert_eq!(a.alpha, 1.0);
    (a.law, a.sigma)
}

#[test]
fn consensus_gives_every_node_the_centralized_ml_estimate_and_crlb() {
    let r = network("location-sim").sim().unwrap();
    r.assert_success();
    let s = scenario();
    let t = Topology::from_scenario(&s, "s").unwrap();
    let (law, sigma) = law(&s);
    let q = sensor_quantizer(&s, ThresholdDesign::Designed).unwrap();
    assert_eq!(r.ticks().len(), 4 * STEPS as usize);
    for step in 1..=STEPS {
        let reports = every_report(&s, &t, step);
        let (positions, cells): (Vec<[f64; 2]>, Vec<u32>) = reports.into_iter().unzip();
        let central = |theta: [f64; 2]| log_likelihood(law, &q, sigma, &positions, &cells, theta);
        // The node's search, over the network's reports at once: the
        // region's 21 × 21 grid, then two grids, each ten times finer.
        let mut grid = Grid::over_region(&s, [21, 21]);
        let mut estimate = [0.0; 2];
        for level in 0..3 {
            if level > 0 {
                grid = grid.around(estimate);
            }
            let ll: Vec<f64> = (0..grid.len()).map(|k| central(grid.point(k))).collect();
            estimate = grid.best(&ll);
        }
        for tick in r.ticks().iter().filter(|t| t.step == step) {
            let off = (tick.estimate[0] - estimate[0]).hypot(tick.estimate[1] - estimate[1]);
            assert!(
                off < 1e-6,
                "step {step}, {}: {:?} against the centralized ML {estimate:?}",
                tick.node,
                tick.estimate
            );
            // Theorem 6.2's sum over every report, at the node's estimate.
            let j = exact_information(
                law,
                Measurement::Quantized(&q),
                sigma,
                &positions,
                tick.estimate,
            );
            let crlb = ((j[(0, 0)] + j[(1, 1)]) / j.determinant()).sqrt();
            let bound = tick.bound.expect("a bound");
            assert!(
                (bound / crlb - 1.0).abs() < 1e-6,
                "step {step}, {}: bound {bound} m against the centralized {crlb} m",
                tick.node
            );
        }
    }
}

/// Bytes of one message of each kind: a 13-byte header; an activation's
/// 2-byte mask, its count and 3 thresholds; a 2-bit cell in one byte; a
/// consensus piece's index and 32 numbers.
const ACTIVATION: u64 = 13 + 2 + 1 + 3 * 8;
const REPORT: u64 = 13 + 1;
const PIECE: u64 = 13 + 2 + 32 * 8;
/// A 21 × 21 grid's 441 numbers in 14 pieces, three grids, then the
/// information's 3 numbers in one.
const PIECES_PER_ROUND: u64 = 3 * 14 + 1;
const ROUNDS: u64 = 20;
/// The ring of four nodes.
const DIRECTED_LINKS: u64 = 8;

#[test]
fn as_processes_the_locator_reports_sims_ticks_and_sends_the_predicted_bytes() {
    let _guard = exclusive();
    let r: Run = network("location").run().unwrap();
    r.assert_success();
    let sim = network("location-twin").sim().unwrap();
    sim.assert_success();
    assert_eq!(r.sorted_tick_lines(), sim.sorted_tick_lines());
    assert!(r.ticks().iter().all(|t| !t.deadline_missed));
    let steps = u64::from(STEPS);
    for (kind, bytes) in [
        (MessageKind::ActivateThresholds, steps * 64 * ACTIVATION),
        (MessageKind::Observation, steps * 64 * REPORT),
        (
            MessageKind::LocationConsensus,
            steps * DIRECTED_LINKS * ROUNDS * PIECES_PER_ROUND * PIECE,
        ),
    ] {
        let c = r.counters(kind);
        assert_eq!(c.sent_bytes, bytes, "{kind:?}");
        assert_eq!(c.received_bytes, bytes, "{kind:?}");
        assert_eq!(sim.counters(kind).sent_bytes, bytes, "{kind:?} in sim");
    }
    // The bound falls as reports add up: by 1/sqrt(k) at a fixed point,
    // and the estimate barely moves.
    let bound = |step| r.mean_bound("node-0", step..=step).unwrap();
    assert!(
        bound(STEPS) < bound(1) / 1.5,
        "{} then {}",
        bound(1),
        bound(STEPS)
    );
    r.assert_clean();
}
