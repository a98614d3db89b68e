//! The fuzzer in CI: the saved corpus replayed, then 10⁴ fresh inputs per
//! target, with no panic allowed. `cqnet fuzz` runs the 10⁷-input campaign
//! (see the README); this is its smoke test, on every commit.

use std::path::Path;

use cqnet::fuzz::{corpus_inputs, replay, run, Campaign, Target};

/// The corpus kept in the repository, grown by `cqnet fuzz`.
fn saved_corpus() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../fuzz/corpus"))
}

#[test]
fn the_saved_corpus_replays_without_a_panic() {
    for target in Target::ALL {
        let inputs = corpus_inputs(saved_corpus(), target).unwrap();
        assert!(
            !inputs.is_empty(),
            "no saved corpus for {} under {}",
            target.name(),
            saved_corpus().display()
        );
        let panics = replay(target, &inputs);
        assert!(panics.is_empty(), "{}: {panics:?}", target.name());
    }
}

#[test]
fn ten_thousand_fresh_inputs_per_target_without_a_panic() {
    for target in Target::ALL {
        let seed = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_secs();
        let report = run(
            &Campaign {
                target,
                inputs: 10_000,
                seed,
                threads: 2,
                corpus: Some(saved_corpus().to_path_buf()),
                save: false,
            },
            |_, _| {},
        )
        .unwrap();
        assert_eq!(report.inputs, 10_000);
        assert_eq!(
            report.panics,
            0,
            "{} (seed {seed}): {:?}",
            target.name(),
            report.panic_kinds
        );
        assert!(
            report.outcomes > 1,
            "{}: one outcome for every input",
            target.name()
        );
    }
}
