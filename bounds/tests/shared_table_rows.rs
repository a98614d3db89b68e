//! The process-wide tables with their rows in shared memory read the same
//! numbers, to the bit, as tables whose rows are their own. Its own test
//! binary: sharing changes the process's tables for good.

use std::alloc::{alloc_zeroed, Layout};

use bounds::fisher_table::{self, FisherTable};
use bounds::mass_table::{self, LnMassTable};
use bounds::table_memory::{share_table_rows, shared_table_bytes};

#[test]
fn shared_rows_read_as_private_ones_do() {
    let len = shared_table_bytes();
    // SAFETY: a non-zero size; kept for the rest of the process.
    let memory = unsafe { alloc_zeroed(Layout::from_size_align(len, 64).unwrap()) };
    assert!(!memory.is_null());
    // SAFETY: zeroed, aligned, kept, and written only by the tables.
    unsafe { share_table_rows(memory, len) }.unwrap();
    let (own_mass, own_fisher) = (LnMassTable::default(), FisherTable::default());
    let (shared_mass, shared_fisher) = (mass_table::table(), fisher_table::table());
    let mut s = 0.51;
    while s < 63.0 {
        for i in 0..40 {
            let v = -11.9 + 0.6 * i as f64;
            let u = i as f64 / 40.0;
            let bits = |x: Option<f64>| x.map(f64::to_bits);
            assert_eq!(
                bits(shared_mass.lookup(v, s)),
                bits(own_mass.lookup(v, s)),
                "ln P at v = {v}, s = {s}"
            );
            let sums = |t: &FisherTable| t.lookup(u, s).map(|x| x.map(f64::to_bits));
            assert_eq!(
                sums(shared_fisher),
                sums(&own_fisher),
                "sums at u = {u}, s = {s}"
            );
        }
        s *= 1.07;
    }
    // The rows went into the shared memory: past its header, the first
    // table's state words are 2 (ready) for the rows read.
    // SAFETY: within the memory, read after every write above.
    let states = unsafe { std::slice::from_raw_parts(memory.add(64).cast::<u32>(), 64) };
    assert!(
        states.contains(&2),
        "no row was built into the shared memory"
    );
}
