//! cqnet's own observation laws: bearing, received signal strength,
//! amplitude and linear Gaussian, each with its gradients written out.

use std::f64::consts::LN_10;

use crate::batch::{Positions, CHUNK};
use crate::State;

use super::{Evaluation, Evaluations, ObservationLaw, MIN_DISTANCE};

/// `g = atan2(p_x − X_s, p_y − Y_s)` (from north, clockwise), wrapped to
/// (−π, π]; `R = σ_θ² (1 + (d/d_0)²)`, with d no nearer than the near
/// field in `∇g` and `R`, so that the information `≈ 1/(σ_θ² d²)` stops
/// growing there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bearing {
    pub sigma_theta: f64,
    pub d0: f64,
    /// Metres, [`MIN_DISTANCE`] at least.
    pub near_field: f64,
}

/// Received signal strength in dBm: `g = P_0 − 5 ζ log10((d² + h²)/d_0²)`,
/// `R = σ_r²`, with `h` the near field: the sensor's antenna stands `h`
/// off the plane the target moves in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rss {
    pub p0: f64,
    pub zeta: f64,
    pub d0: f64,
    pub sigma: f64,
    /// `h`, metres.
    pub near_field: f64,
}

/// Amplitude, power law: `g = sqrt(P_0 / (1 + α dⁿ))`, `R = σ²`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Amplitude {
    pub p0: f64,
    pub alpha: f64,
    pub exponent: f64,
    pub sigma: f64,
}

/// Linear Gaussian: `g = hᵀx`, `R = r`; the sensor's position plays no
/// part. The limiting case in which the PCRLB must reproduce the Kalman
/// filter's information matrix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Linear {
    pub h: [f64; 4],
    pub r: f64,
}

impl ObservationLaw for Bearing {
    #[inline]
    fn evaluate(&self, sensor: [f64; 2], x: &State) -> Evaluation {
        let (dx, dy, d2) = offset(x, sensor);
        let d2 = d2.max(self.near_field.powi(2));
        let (s2, d0) = (self.sigma_theta * self.sigma_theta, self.d0);
        Evaluation {
            g: bearing(dx, dy),
            grad_g: State::new(dy / d2, -dx / d2, 0.0, 0.0),
            r: bearing_variance(self.sigma_theta, d0, d2),
            grad_r: State::new(
                2.0 * s2 * dx / (d0 * d0),
                2.0 * s2 * dy / (d0 * d0),
                0.0,
                0.0,
            ),
        }
    }

    #[inline]
    fn mean_and_variance(&self, sensor: [f64; 2], x: &State) -> (f64, f64) {
        let (dx, dy, d2) = offset(x, sensor);
        let d2 = d2.max(self.near_field.powi(2));
        (
            bearing(dx, dy),
            bearing_variance(self.sigma_theta, self.d0, d2),
        )
    }

    /// Vectorised ([`crate::batch::atan2`]), bit for bit `evaluate`'s.
    #[inline(always)]
    fn evaluate_batch(
        &self,
        sensor: [f64; 2],
        _states: &[State],
        at: &Positions,
        out: &mut Evaluations,
    ) {
        let (mut dx, mut dy, mut d2) = ([0.0; CHUNK], [0.0; CHUNK], [0.0; CHUNK]);
        let h = self.near_field;
        for i in 0..CHUNK {
            dx[i] = at.x[i] - sensor[0];
            dy[i] = at.y[i] - sensor[1];
            d2[i] = (dx[i] * dx[i] + dy[i] * dy[i]).max(h * h);
        }
        crate::batch::atan2(&dx, &dy, &mut out.g);
        let (sigma_theta, d0) = (self.sigma_theta, self.d0);
        let s2 = sigma_theta * sigma_theta;
        for i in 0..CHUNK {
            out.gx[i] = dy[i] / d2[i];
            out.gy[i] = -dx[i] / d2[i];
            out.r[i] = bearing_variance(sigma_theta, d0, d2[i]);
            out.rx[i] = 2.0 * s2 * dx[i] / (d0 * d0);
            out.ry[i] = 2.0 * s2 * dy[i] / (d0 * d0);
        }
    }

    fn is_angular(&self) -> bool {
        true
    }
}

impl ObservationLaw for Rss {
    #[inline]
    fn evaluate(&self, sensor: [f64; 2], x: &State) -> Evaluation {
        let (dx, dy, _) = offset(x, sensor);
        let (h, d0, zeta) = (self.near_field, self.d0, self.zeta);
        let d2 = dx * dx + dy * dy + h * h;
        // g = P0 − 5ζ log10((d² + h²)/d0²); ∂g/∂p = −10ζ/ln10 · (p − X)/(d² + h²)
        let k = -10.0 * zeta / LN_10 / d2;
        Evaluation {
            g: self.p0 - 5.0 * zeta * (d2 / (d0 * d0)).log10(),
            grad_g: State::new(k * dx, k * dy, 0.0, 0.0),
            r: self.sigma * self.sigma,
            grad_r: State::zeros(),
        }
    }
}

impl Amplitude {
    /// `dⁿ` from `d²`. A whole exponent (the decay laws' 1 to 4, and any
    /// up to 16) is products of `d²` and at most one square root: a third
    /// of the time of `powf`, which the compressive and censoring
    /// experiments spent most of their sensor model in.
    #[inline]
    fn distance_power(&self, d2: f64) -> f64 {
        let n = self.exponent;
        if n.fract() == 0.0 && (1.0..=16.0).contains(&n) {
            let whole = n as i32;
            let even = d2.powi(whole / 2);
            if whole % 2 == 0 {
                even
            } else {
                even * d2.sqrt()
            }
        } else {
            d2.sqrt().powf(n)
        }
    }

    /// `g`, `dⁿ` and `1 + α dⁿ`.
    #[inline]
    fn amplitude(&self, d2: f64) -> (f64, f64, f64) {
        let dn = self.distance_power(d2);
        let denom = 1.0 + self.alpha * dn;
        ((self.p0 / denom).sqrt(), dn, denom)
    }
}

impl ObservationLaw for Amplitude {
    #[inline]
    fn evaluate(&self, sensor: [f64; 2], x: &State) -> Evaluation {
        let (dx, dy, d2) = offset(x, sensor);
        let (g, dn, denom) = self.amplitude(d2);
        // ∂g/∂p = ∂g/∂d · (p − X)/d, ∂g/∂d = −g α n d^{n−1} / (2 (1 + α dⁿ)):
        // together −g α n dⁿ / (2 (1 + α dⁿ) d²) · (p − X).
        let k = -g * self.alpha * self.exponent * dn / (2.0 * denom * d2);
        Evaluation {
            g,
            grad_g: State::new(k * dx, k * dy, 0.0, 0.0),
            r: self.sigma * self.sigma,
            grad_r: State::zeros(),
        }
    }

    /// `evaluate`'s g and R without its gradient.
    #[inline]
    fn mean_and_variance(&self, sensor: [f64; 2], x: &State) -> (f64, f64) {
        let (_, _, d2) = offset(x, sensor);
        (self.amplitude(d2).0, self.sigma * self.sigma)
    }
}

impl ObservationLaw for Linear {
    #[inline]
    fn evaluate(&self, _sensor: [f64; 2], x: &State) -> Evaluation {
        let h = self.h;
        Evaluation {
            g: h[0] * x[0] + h[1] * x[1] + h[2] * x[2] + h[3] * x[3],
            grad_g: State::from(h),
            r: self.r,
            grad_r: State::zeros(),
        }
    }

    fn depends_on_position_only(&self) -> bool {
        self.h[2] == 0.0 && self.h[3] == 0.0
    }

    fn is_placed(&self) -> bool {
        false
    }
}

/// The bearing from north, clockwise, of the offset `(dx, dy)`: fdlibm's
/// atan2 (the `libm` crate), within an ulp as glibc's is, and a third
/// fewer instructions (callgrind).
#[inline]
fn bearing(dx: f64, dy: f64) -> f64 {
    libm::atan2(dx, dy)
}

/// `R(d) = σ_θ² (1 + d²/d_0²)`.
#[inline]
fn bearing_variance(sigma_theta: f64, d0: f64, d2: f64) -> f64 {
    sigma_theta * sigma_theta * (1.0 + d2 / (d0 * d0))
}

/// `(p_x − X, p_y − Y, d²)` with d floored at [`MIN_DISTANCE`].
#[inline]
fn offset(x: &State, sensor: [f64; 2]) -> (f64, f64, f64) {
    let dx = x[0] - sensor[0];
    let dy = x[1] - sensor[1];
    (dx, dy, (dx * dx + dy * dy).max(MIN_DISTANCE * MIN_DISTANCE))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// `dⁿ` by products is `d²^(n/2)` to n ulps (a rounding a product)
    /// for every whole exponent, over distances from centimetres to a
    /// hundred kilometres, and is `powf`'s own for a fractional one.
    #[test]
    fn a_whole_exponent_is_powf_to_rounding() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for n in [1.0, 2.0, 3.0, 4.0, 5.0, 7.0, 16.0, 2.5, 0.5] {
            let law = Amplitude {
                p0: 1.0,
                alpha: 1.0,
                exponent: n,
                sigma: 1.0,
            };
            for _ in 0..20_000 {
                let d = 10f64.powf(rng.random_range(-2.0..5.0));
                let d2 = d * d;
                let got = law.distance_power(d2);
                if n.fract() == 0.0 {
                    let want = d2.powf(n / 2.0);
                    let error = (got - want).abs() / want;
                    assert!(
                        error <= n * f64::EPSILON,
                        "n = {n}, d² = {d2}: {got} vs {want}"
                    );
                } else {
                    let want = d2.sqrt().powf(n);
                    assert_eq!(got.to_bits(), want.to_bits(), "n = {n}, d² = {d2}");
                }
            }
        }
    }

    /// At d = 10 with α = 0.01, n = 2: `g = sqrt(P0 / 2)`, and its gradient
    /// along the offset `−g α n dⁿ / (2 (1 + α dⁿ) d²) · d = −g/20`.
    #[test]
    fn the_amplitude_at_a_known_distance() {
        let law = Amplitude {
            p0: 8.0,
            alpha: 0.01,
            exponent: 2.0,
            sigma: 1.0,
        };
        let e = law.evaluate([0.0, 0.0], &State::new(6.0, 8.0, 0.0, 0.0));
        assert!((e.g - 2.0).abs() < 1e-15);
        let along = (e.grad_g[0] * 6.0 + e.grad_g[1] * 8.0) / 10.0;
        assert!((along + 0.1).abs() < 1e-15, "{along}");
    }
}
