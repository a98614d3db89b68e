//! A fusion centre behind a multiple-access channel
//! (`scenarios/compressive.toml`): 25 sensors transmit at once in the
//! centre's slots, and the channel, an actor of its own, delivers each
//! slot's sum.
//!
//! - As real processes (centre, channel, 25 sensors, launcher), in
//!   lockstep: `sim`'s ticks bit for bit, and the bytes and energy the
//!   slots used predict, with each design: the chapter's, the one that
//!   counts a repeated sensor once, every sensor alike, random sensors,
//!   all.
//! - Under `sim`, the faults: a sensor that misses its slot leaves the
//!   sum without it and the centre goes on; a delivery lost on the way to
//!   the centre is a lost step, reported with no observation.

use std::time::Duration;

use cqnet_testkit::{exclusive, ActorId, MessageKind, Network, Run, Scenario};

const CQNET: &str = env!("CARGO_BIN_EXE_cqnet-under-test");
const STEPS: u32 = 8;
const HEADER: u64 = 13;

fn scenario(extra: &str) -> Scenario {
    let text = format!("{}\n{extra}", fusion_graph::scenario::COMPRESSIVE_SCENARIO);
    let mut s = Scenario::from_toml(&text, "<built-in compressive>", &[])
        .expect("the built-in scenario is valid");
    s.steps = STEPS;
    s
}

fn network(tag: &str, scenario: Scenario) -> Network {
    Network::new(scenario)
        .executable(CQNET)
        .tag(tag)
        .lockstep()
        // No slot may end by its timeout on a loaded machine: that would
        // change what is summed.
        .set("channel.slot_timeout_ms", 5000)
        .set("clock.step_timeout_ms", 60000)
        .time_limit(Duration::from_secs(180))
}

/// The counts the slots of `r`'s steps predict: the schedule to each
/// transmitter and the channel, a transmission message per transmitter, a
/// delivery per step; and from the transmissions' bytes, the energy.
fn assert_predicted_bytes(r: &Run, slots: u64) {
    let ticks = r.ticks();
    assert_eq!(ticks.len(), STEPS as usize);
    let transmitters: u64 = ticks.iter().map(|t| t.active.len() as u64).sum();
    let schedule: u64 = ticks
        .iter()
        .map(|t| {
            let active = t.active.len() as u64;
            (HEADER + 3 + 10 * active) * (active + 1)
        })
        .sum();
    let steps = u64::from(STEPS);
    let predicted = [
        (MessageKind::ActivateSlots, schedule),
        (MessageKind::MacOutput, steps * (HEADER + 1 + 8 * slots)),
    ];
    for (kind, bytes) in predicted {
        let c = r.counters(kind);
        assert_eq!(c.sent_bytes, bytes, "{kind:?}");
        assert_eq!(c.received_bytes, bytes, "{kind:?}");
    }
    let values = r.counters(MessageKind::SlotValues);
    assert_eq!(values.sent_messages, transmitters);
    assert_eq!(values.received_messages, transmitters);
    let energy = r
        .summary()
        .energy
        .expect("a channel's run reports its energy");
    assert_eq!(
        values.sent_bytes,
        transmitters * (HEADER + 4) + 8 * energy.transmissions,
        "a transmission message is a header, the slots' mask and a value a slot"
    );
    // Every delivery crossed the one link it has.
    assert_eq!(
        r.messages(ActorId::Mac(0), ActorId::Node(0), MessageKind::MacOutput),
        steps
    );
}

#[test]
fn as_processes_the_compressive_design_is_sims_and_spends_the_predicted_bytes_and_energy() {
    let _guard = exclusive();
    let s = scenario("");
    let r = network("cs-run", s.clone()).run().unwrap();
    r.assert_success();
    let sim = network("cs-twin", s).sim().unwrap();
    sim.assert_success();
    assert_eq!(r.sorted_tick_lines(), sim.sorted_tick_lines());
    assert_eq!(r.summary().energy, sim.summary().energy);
    assert!(r.ticks().iter().all(|t| !t.deadline_missed));
    assert_predicted_bytes(&r, 6);
    // The energy against the design's budget: each transmitter's slots are
    // Binomial(M, p_j), so their sum over the run is M Σ p within five of
    // its standard deviations (p as reported, to 10⁻⁴).
    let (mean, var) = r
        .ticks()
        .iter()
        .flat_map(|t| t.design.iter())
        .fold((0.0, 0.0), |(m, v), p| {
            (m + 6.0 * p, v + 6.0 * p * (1.0 - p))
        });
    let energy = r.summary().energy.unwrap().transmissions as f64;
    assert!(
        (energy - mean).abs() <= 5.0 * var.sqrt() + 0.01 * f64::from(STEPS),
        "{energy} transmissions against {mean} expected"
    );
    assert!(
        mean <= 6.0 * f64::from(STEPS) + 1e-2,
        "the design keeps M Σp within E = 6: {mean}"
    );
    r.assert_clean();
}

/// The design that counts a repeated sensor once, and every sensor alike
/// in the same slots: as processes, `sim`'s ticks bit for bit (the
/// sample matrices a design draws are the step's own stream), and the
/// bytes the slots predict.
#[test]
fn as_processes_the_counted_once_and_uniform_designs_are_sims() {
    let _guard = exclusive();
    for design in ["counted_once", "uniform"] {
        let n = network(&format!("cs-{design}"), scenario(""))
            .set("channel.design", format!("\"{design}\""));
        let r = n.clone().run().unwrap();
        r.assert_success();
        let sim = n.sim().unwrap();
        sim.assert_success();
        assert_eq!(r.sorted_tick_lines(), sim.sorted_tick_lines(), "{design}");
        assert_eq!(r.summary().energy, sim.summary().energy, "{design}");
        assert_predicted_bytes(&r, 6);
        r.assert_clean();
    }
}

#[test]
fn as_processes_random_and_all_sensors_spend_exactly_their_transmissions() {
    let _guard = exclusive();
    // (design, slots, transmitters a step): each sensor alone in a slot.
    for (design, slots, each_step) in [("random", 6, 6), ("all", 25, 25)] {
        let r = network(&format!("cs-{design}"), scenario(""))
            .set("channel.design", format!("\"{design}\""))
            .run()
            .unwrap();
        r.assert_success();
        assert_predicted_bytes(&r, slots);
        for t in r.ticks() {
            assert_eq!(
                t.active.len(),
                each_step,
                "{design}, step {}: {:?}",
                t.step,
                t.active
            );
        }
        let energy = r.summary().energy.unwrap();
        assert_eq!(
            energy.transmissions,
            each_step as u64 * u64::from(STEPS),
            "{design}"
        );
        r.assert_clean();
    }
}

/// The sensor the centre schedules at step 5 (read from a run without the
/// fault, which is the same up to there) drops out from step 5 on: the
/// centre still schedules it at step 5, the channel hears nothing from it
/// and delivers at the slots' end, the centre weighs that as if the
/// sensor were there, and every step is reported.
#[test]
fn a_sensor_that_misses_its_slot_is_absent_from_the_sum_and_the_centre_goes_on() {
    let clean = network("cs-clean", scenario("")).sim().unwrap();
    clean.assert_success();
    let at_5 = |r: &Run| -> Vec<u16> {
        r.ticks()
            .iter()
            .find(|t| t.step == 5)
            .map(|t| t.active.clone())
            .unwrap()
    };
    let chosen = at_5(&clean);
    assert!(!chosen.is_empty());
    let names: Vec<String> = chosen.iter().map(|s| format!("\"sensor-{s}\"")).collect();
    let fault = format!(
        "[[faults]]\nkind = \"sensor\"\nsensors = [{}]\nat_step = 5\nmode = \"dropout\"\n",
        names.join(", ")
    );
    let r = network("cs-dropout", scenario(&fault))
        .set("channel.slot_timeout_ms", 50)
        .sim()
        .unwrap();
    r.assert_success();
    assert_eq!(r.ticks().len(), STEPS as usize, "every step reported");
    for (a, b) in r.ticks().iter().zip(clean.ticks()).take(4) {
        assert_eq!(a.line, b.line, "up to the fault the runs are one");
    }
    assert_eq!(at_5(&r), chosen, "scheduled at step 5 as without the fault");
    for t in r.ticks() {
        assert_eq!(
            t.observations, 6,
            "step {}: the centre hears every slot",
            t.step
        );
        assert!(!t.deadline_missed, "step {}: delivered in time", t.step);
    }
    assert_eq!(
        r.counters(MessageKind::MacOutput).sent_messages,
        u64::from(STEPS)
    );
    for s in chosen {
        let before: u64 = r
            .ticks()
            .iter()
            .filter(|t| t.step < 5 && t.active.contains(&s))
            .count() as u64;
        let sent =
            |run: &Run| run.messages(ActorId::Sensor(s), ActorId::Mac(0), MessageKind::SlotValues);
        assert_eq!(sent(&r), before, "sensor-{s} is silent from step 5");
        assert!(
            sent(&clean) > before,
            "without the fault sensor-{s} transmits at step 5"
        );
    }
}

/// Every delivery from step 4 to 6 is lost between the channel and the
/// centre: those steps report no observation and the bound of the
/// prediction alone, wider than the step before; the centre tracks on.
#[test]
fn a_lost_delivery_is_a_lost_step() {
    let fault = "[[faults]]\nkind = \"loss\"\nlinks = [{ from = \"mac-0\", to = \"node-0\" }]\nat_step = 4\nduration = 3\nprobability = 1.0\n";
    let r = network("cs-lost", scenario(fault))
        .set("channel.slot_timeout_ms", 50)
        .sim()
        .unwrap();
    r.assert_success();
    assert_eq!(r.ticks().len(), STEPS as usize);
    for t in r.ticks() {
        let lost = (4..=6).contains(&t.step);
        assert_eq!(
            t.observations == 0,
            lost,
            "step {}: {}",
            t.step,
            t.observations
        );
    }
    // The centre ends a lost step by its own deadline, not the next
    // step's BeginStep overrunning it.
    assert!(r.ticks().iter().all(|t| !t.deadline_missed));
    let bound = |step: u32| r.mean_bound("node-0", step..=step).unwrap();
    assert!(bound(4) > bound(3), "{} then {}", bound(3), bound(4));
    assert!(bound(6) > bound(5), "{} then {}", bound(5), bound(6));
    assert!(
        bound(7) < bound(6),
        "heard again: {} then {}",
        bound(6),
        bound(7)
    );
    assert_eq!(r.dropped(MessageKind::MacOutput), 3);
}
