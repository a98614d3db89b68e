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
        let mut scenario = default_scenario();
        scenario.steps = STEPS;
        scenario.sensors.per_cell = Some([3, 3]);
        scenario.hosts = ["a", "b", "c"]
            .iter()
            .enumerate()
            .map(|(h, name)| HostConfig {
                name: name.to_string(),
                nodes: (3 * h as u16..3 * h as u16 + 3).collect(),
                endpoint: String::new(),
            })
            .collect();
        hosts.place(&mut scenario);
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
