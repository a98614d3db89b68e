//! Runs one part of the `node_step` bench's workload N times, for an
//! instruction count that does not drift with the machine's speed:
//!
//! ```text
//! cargo build --release -p node --example step_instructions
//! valgrind --tool=callgrind --callgrind-out-file=/dev/null \
//!     target/release/examples/step_instructions local 100
//! ```
//!
//! and the same with 0 for the setup alone; the difference over 100 is one
//! step's instructions. Parts: `local` (local filter + local bound),
//! `fusion` (fusion filter + CQ/dPCRLB), `filter` (the particle filter
//! alone), `delta-l` (the fusion filter's prediction and the node's ΔL
//! over it), `predict` (that prediction alone).

use std::hint::black_box;
use std::process::ExitCode;

use bounds::chacha::WideChaCha8;
use rand::SeedableRng;

#[path = "../benches/common/workload.rs"]
mod workload;
use workload::Workload;

const PARTS: [&str; 5] = ["local", "fusion", "filter", "delta-l", "predict"];

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (part, times) = match args.as_slice() {
        [part, times] => match times.parse::<usize>() {
            Ok(times) if PARTS.contains(&part.as_str()) => (part.clone(), times),
            _ => return usage(),
        },
        _ => return usage(),
    };
    let w = Workload::new();
    let model = &w.model;
    let evidence = Workload::evidence(&w.observations);
    let mut rng = WideChaCha8::seed_from_u64(4);
    for _ in 0..times {
        match part.as_str() {
            "local" => {
                black_box(w.local.clone().update(model, &evidence, false).unwrap());
            }
            "fusion" => {
                black_box(w.fusion.clone().step(model, &w.sums).unwrap());
            }
            "filter" => {
                let mut f = w.filter.clone();
                Workload::filter_step(model, &w.observations, &mut f, &mut rng);
                black_box(f);
            }
            "delta-l" => {
                let mut f = w.fusion.clone();
                f.predict(model).unwrap();
                black_box(
                    f.observation_information(model, &Workload::evidence(&w.observations))
                        .unwrap(),
                );
            }
            "predict" => {
                black_box(w.fusion.clone().predict(model).unwrap().len());
            }
            _ => unreachable!("parts are checked above"),
        }
    }
    ExitCode::SUCCESS
}

fn usage() -> ExitCode {
    eprintln!(
        "usage: step_instructions PART TIMES (PART: one of {}; TIMES: a count)",
        PARTS.join(", ")
    );
    ExitCode::from(2)
}
