//! Independent computations spread over threads, returned in index order:
//! each item's randomness comes from its index alone, so a result does not
//! depend on how many threads ran it, or which ran what.

use std::sync::atomic::{AtomicUsize, Ordering};

/// `f(0), …, f(count − 1)`, computed on up to `threads` threads.
pub(crate) fn indexed<T: Send>(
    count: usize,
    threads: usize,
    f: impl Fn(usize) -> T + Sync,
) -> Vec<T> {
    indexed_with(count, threads, || (), |_, i| f(i))
}

/// The same, each thread with a workspace of its own made by `init` and
/// handed to every `f` it runs (a filter reused over trials, say, so that
/// a trial allocates little). What `f` returns must not depend on what
/// the workspace held before.
pub(crate) fn indexed_with<S, T: Send>(
    count: usize,
    threads: usize,
    init: impl Fn() -> S + Sync,
    f: impl Fn(&mut S, usize) -> T + Sync,
) -> Vec<T> {
    let next = AtomicUsize::new(0);
    let (f, init, next) = (&f, &init, &next);
    let workers = threads.clamp(1, count.max(1));
    let mut done: Vec<(usize, T)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(move || {
                    let mut workspace = init();
                    let mut mine = Vec::new();
                    loop {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        if i >= count {
                            break mine;
                        }
                        mine.push((i, f(&mut workspace, i)));
                    }
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().expect("a worker panicked"))
            .collect()
    });
    done.sort_by_key(|(i, _)| *i);
    done.into_iter().map(|(_, t)| t).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_come_in_index_order_whatever_the_threads() {
        let one = indexed(100, 1, |i| i * i);
        let three = indexed(100, 3, |i| i * i);
        assert_eq!(one, three);
        assert_eq!(one[7], 49);
        assert!(indexed(0, 2, |i| i).is_empty());
    }
}
