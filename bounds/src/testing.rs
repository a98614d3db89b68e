//! Helpers shared by the unit tests: random states and central differences.

use rand::Rng;

use crate::{Mat4, State};

/// A state uniform over `[0, extent]²` with velocity components uniform in
/// `±speed`.
pub fn random_state<R: Rng>(rng: &mut R, extent: f64, speed: f64) -> State {
    State::new(
        rng.random_range(0.0..extent),
        rng.random_range(0.0..extent),
        rng.random_range(-speed..speed),
        rng.random_range(-speed..speed),
    )
}

/// Central-difference Jacobian of a map from states to states.
pub fn central_jacobian(f: impl Fn(&State) -> State, x: &State, rel_step: f64) -> Mat4 {
    let mut jac = Mat4::zeros();
    for k in 0..4 {
        let h = rel_step * x[k].abs().max(1.0);
        let (mut up, mut down) = (*x, *x);
        up[k] += h;
        down[k] -= h;
        jac.set_column(k, &((f(&up) - f(&down)) / (2.0 * h)));
    }
    jac
}

pub(crate) use crate::observation::central_gradient;

/// Zeroed memory aligned to a cache line, that lives as long as the test
/// process, as a mapping of the shared tables does.
pub fn line_aligned_memory(bytes: usize) -> *mut u8 {
    let layout = std::alloc::Layout::from_size_align(bytes, crate::shared_rows::LINE).unwrap();
    // SAFETY: a non-zero size; never freed, like a mapping kept for good.
    let p = unsafe { std::alloc::alloc_zeroed(layout) };
    assert!(!p.is_null());
    p
}
