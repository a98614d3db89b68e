//! The bare Zenoh round trip between two hosts, as cqnet's agents open
//! their sessions (peer mode, TCP, no scouting): what a message between
//! hosts costs before cqnet adds anything, beside the bare iceoryx2 round
//! trip within a host (`cargo bench -p transport --bench roundtrip`).
//!
//! On one host (or namespace): `zenoh_ping pong tcp/10.213.0.2:17448`; on
//! the other: `zenoh_ping ping tcp/10.213.0.2:17448 [count]`, which prints
//! the round trip's p50 and p99 over `count` 64-byte messages (10,000).
//!
//! ```text
//! cargo run --release -p launch --features zenoh --example zenoh_ping -- pong tcp/127.0.0.1:17448
//! ```

use std::time::{Duration, Instant};

use zenoh::Wait;

fn session(listen: Option<&str>, connect: Option<&str>) -> zenoh::Session {
    let mut config = zenoh::Config::default();
    let mut set = |key: &str, value: String| {
        config
            .insert_json5(key, &value)
            .unwrap_or_else(|e| panic!("{key}: {e}"))
    };
    set("mode", "\"peer\"".into());
    set("scouting/multicast/enabled", "false".into());
    set(
        "listen/endpoints",
        serde_json::to_string(&listen.into_iter().collect::<Vec<_>>()).unwrap(),
    );
    set(
        "connect/endpoints",
        serde_json::to_string(&connect.into_iter().collect::<Vec<_>>()).unwrap(),
    );
    zenoh::open(config).wait().expect("a Zenoh session")
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("pong") => pong(&args[1]),
        Some("ping") => ping(
            &args[1],
            args.get(2).map_or(10_000, |n| n.parse().expect("a count")),
        ),
        _ => {
            eprintln!("usage: zenoh_ping pong <endpoint> | ping <endpoint> [count]");
            std::process::exit(2);
        }
    }
}

/// Answers every ping with its own bytes, until killed.
fn pong(endpoint: &str) {
    let s = session(Some(endpoint), None);
    let pings = s.declare_subscriber("cqnet/ping").wait().unwrap();
    let pong = s.declare_publisher("cqnet/pong").wait().unwrap();
    println!("answering on {endpoint}");
    while let Ok(sample) = pings.recv() {
        pong.put(sample.payload().to_bytes().into_owned())
            .wait()
            .unwrap();
    }
}

fn ping(endpoint: &str, count: usize) {
    let s = session(None, Some(endpoint));
    let pongs = s.declare_subscriber("cqnet/pong").wait().unwrap();
    let ping = s.declare_publisher("cqnet/ping").wait().unwrap();
    // Until the far side answers: declarations take a moment to propagate.
    let started = Instant::now();
    loop {
        ping.put(vec![0u8; 64]).wait().unwrap();
        if pongs
            .recv_timeout(Duration::from_millis(200))
            .ok()
            .flatten()
            .is_some()
        {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(30), "no answer");
    }
    while pongs.try_recv().ok().flatten().is_some() {}
    let mut times = Vec::with_capacity(count);
    for _ in 0..count {
        let t = Instant::now();
        ping.put(vec![0u8; 64]).wait().unwrap();
        pongs.recv().unwrap();
        times.push(t.elapsed());
    }
    times.sort();
    let at = |q: f64| times[((times.len() - 1) as f64 * q) as usize].as_secs_f64() * 1e6;
    println!(
        "Zenoh round trip over {count} messages of 64 bytes: p50 {:.1} µs, p99 {:.1} µs",
        at(0.5),
        at(0.99)
    );
}
