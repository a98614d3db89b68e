//! Measures the default network on three hosts as separate as machines
//! (each in a network and mount namespace of its own; root only), with the
//! kernel shaping every host's link as each argument says: `none`, a delay
//! (`5ms`, with `tc netem`) or a rate (`10mbit`, with `tc tbf`). It prints
//! steps per second, the consensus round latency, and the bytes between
//! hosts. `--features zenoh`.
//!
//! ```text
//! cargo run --release -p cqnet-testkit --features zenoh --example separate_hosts -- none 5ms 10mbit
//! ```
//!
//! With the argument `cut` it measures instead what losing a host costs
//! the others: the same real-time run twice (same seed), once with host b's
//! link cut for 15 s from step 30, and the RMSE and bound of the other
//! hosts' nodes over the steps b's nodes were away, against the same steps
//! of the run without the cut.

use std::sync::Arc;

use cqnet_testkit::{default_scenario, Network, SeparateHosts};
use fusion_graph::hosts::HostConfig;

const STEPS: u32 = 200;

fn main() {
    if let Some(why) = SeparateHosts::unavailable() {
        eprintln!("cannot separate hosts here: {why}");
        std::process::exit(2);
    }
    let shapes: Vec<String> = std::env::args().skip(1).collect();
    if shapes.iter().any(|s| s == "cut") {
        return cut_cost();
    }
    let shapes = if shapes.is_empty() {
        vec!["none".to_string(), "5ms".to_string()]
    } else {
        shapes
    };
    println!("| between hosts | steps/s | round p50 / p99, µs | bytes between hosts per step | deadline misses |");
    println!("|---|---|---|---|---|");
    for shape in &shapes {
        let hosts = Arc::new(SeparateHosts::create(&["a", "b", "c"]).expect("namespaces"));
        for h in ["a", "b", "c"] {
            let shaped = if shape == "none" {
                Ok(())
            } else if shape.ends_with("ms") {
                // Each host's link delays both ways: a packet between two
                // hosts crosses two links, one out and one in, so each
                // link delays it half.
                hosts.shape(h, &["delay", &half_of(shape)])
            } else {
                hosts.limit_rate(h, shape)
            };
            if let Err(e) = shaped {
                eprintln!("{shape}: {e}");
                std::process::exit(2);
            }
        }
        let scenario = three_hosts(&hosts, STEPS);
        let run = Network::new(scenario)
            .tag("apart")
            .no_central()
            .lockstep()
            .on_separate_hosts(&hosts)
            .run()
            .expect("the run");
        run.assert_success();
        let s = run.summary();
        let rounds = s
            .round_latency_micros
            .as_ref()
            .map_or("-".into(), |p| format!("{:.0} / {:.0}", p.p50, p.p99));
        println!(
            "| {shape} | {:.1} | {rounds} | {:.0} | {} |",
            s.steps_per_second,
            between_hosts(&run) as f64 / f64::from(STEPS),
            s.deadline_misses
        );
    }
}

/// The default network, 3 × 3 sensors a node, a row of nodes on each of
/// hosts a, b and c.
fn three_hosts(hosts: &SeparateHosts, steps: u32) -> cqnet_testkit::Scenario {
    let mut scenario = default_scenario();
    scenario.steps = steps;
    scenario.sensors.per_cell = Some([3, 3]);
    scenario.hosts = ["a", "b", "c"]
        .iter()
        .enumerate()
        .map(|(h, name)| HostConfig {
            name: name.to_string(),
            nodes: (3 * h as u16..3 * h as u16 + 3).collect(),
            endpoint: String::new(),
            link: None,
        })
        .collect();
    hosts.place(&mut scenario);
    scenario
}

/// What losing host b costs nodes 0–2 and 6–8 (see the file's head).
fn cut_cost() {
    let steps = 100;
    let run = |cut: bool| {
        let hosts = Arc::new(SeparateHosts::create(&["a", "b", "c"]).expect("namespaces"));
        let mut running = Network::new(three_hosts(&hosts, steps))
            .tag("apart-cut")
            .set("clock.step_period_ms", 250)
            .on_separate_hosts(&hosts)
            .start()
            .expect("the run");
        if cut {
            assert!(running.wait_for_step(30, std::time::Duration::from_secs(120)));
            hosts.cut("b").expect("cut");
            std::thread::sleep(std::time::Duration::from_secs(15));
            hosts.restore("b").expect("restore");
        }
        let r = running.wait().expect("the run");
        r.assert_success();
        r
    };
    let whole = run(false);
    let cut = run(true);
    let away: Vec<u32> = (1..=steps)
        .filter(|s| cut.ticks_of("node-3").all(|t| t.step != *s))
        .collect();
    let others = ["node-0", "node-1", "node-2", "node-6", "node-7", "node-8"];
    let over_away = |r: &cqnet_testkit::Run| {
        let rows: Vec<_> = r
            .ticks()
            .iter()
            .filter(|t| others.contains(&t.node.as_str()) && away.contains(&t.step))
            .collect();
        let rmse = (rows.iter().map(|t| t.error * t.error).sum::<f64>() / rows.len() as f64).sqrt();
        let bounds: Vec<f64> = rows.iter().filter_map(|t| t.bound).collect();
        (
            rmse,
            bounds.iter().sum::<f64>() / bounds.len() as f64,
            rows.len(),
        )
    };
    let (first, last) = (
        away.first().copied().unwrap_or(0),
        away.last().copied().unwrap_or(0),
    );
    println!(
        "host b's nodes away for {} steps ({first} to {last})",
        away.len()
    );
    println!("| nodes 0–2 and 6–8, over those steps | RMSE, m | mean bound, m | rows |");
    println!("|---|---|---|---|");
    for (name, r) in [("without the cut", &whole), ("host b cut off", &cut)] {
        let (rmse, bound, rows) = over_away(r);
        println!("| {name} | {rmse:.3} | {bound:.3} | {rows} |");
    }
}

/// Half of a netem delay such as `5ms`.
fn half_of(delay: &str) -> String {
    let ms: f64 = delay
        .trim_end_matches("ms")
        .parse()
        .expect("a delay in ms, such as 5ms");
    format!("{}us", (ms * 500.0).round())
}

/// Bytes of cqnet's messages sent between hosts, from `hosts.json`.
fn between_hosts(run: &cqnet_testkit::Run) -> u64 {
    let text = std::fs::read_to_string(run.out_dir().join("hosts.json")).expect("hosts.json");
    let json: serde_json::Value = serde_json::from_str(&text).expect("json");
    json["between_hosts"]
        .as_array()
        .expect("between_hosts")
        .iter()
        .map(|p| p["sent_bytes"].as_u64().unwrap_or(0))
        .sum()
}
