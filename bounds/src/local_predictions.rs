//! Censoring without feedback (dissertation ch. 3, Props. 3.3 and 3.8):
//! each sensor runs its own Kalman filter on its own measurements and
//! censors against its own prediction `x̂ⁱ(k|k−1)`, which its fusion
//! centre never sees. The centre weighs a silence by integrating over what
//! the sensors' predictions could have been:
//!
//! ```text
//! p(m, z_obs | x) ∝ ∫ p(x̂¹…x̂ᴺ | x) Π_silent P(νʲᵀ Sʲ⁻¹ νʲ < η | x, x̂ʲ) dx̂      (3.21, 3.53)
//! ```
//!
//! The dissertation takes `p(x̂¹…x̂ᴺ | x) = N(x ⊗ 1, Σ)` with Σ the
//! predictions' error covariances (eqs. 3.26–3.28). Read literally that
//! makes the integral the same at every x: with `x̂ʲ = x − eʲ` and `e`
//! independent of x, the innovation `νʲ = Hʲ eʲ + nʲ` does not involve x,
//! so silence would carry no information and the scheme would weigh the
//! particles as if the silence were ignored. [`LocalPredictions::silence_as_printed`]
//! builds that factor, to show it.
//!
//! In a linear-Gaussian system the sensors' filters are linear in the
//! measurements with gains fixed in advance, so the state and every
//! sensor's estimate are jointly Gaussian, and `p(x̂ | x)` is the exact
//! conditional of that joint law: its mean `c + G x` moves with x (by less
//! than x does), which is what lets a silence say something.
//! [`LocalPredictions`] carries the joint law step by step and
//! [`LocalPredictions::silence`] conditions it.

use nalgebra::{DMatrix, DVector};
use rand::Rng;
use rand_distr::StandardNormal;

use crate::censoring::CensoringRule;
use crate::normal;

/// The joint Gaussian law of the state and every sensor's own Kalman
/// estimate, `y = [x; x̂¹; …; x̂ᴺ]`, in a linear-Gaussian system
/// `x(k) = F x(k−1) + u`, `zⁱ = Hⁱ x + nⁱ`. Between [`Self::predict`] and
/// [`Self::update`] the estimates are the predictions `x̂ⁱ(k|k−1)`.
#[derive(Debug, Clone)]
pub struct LocalPredictions {
    d: usize,
    f: DMatrix<f64>,
    q: DMatrix<f64>,
    sensors: Vec<LocalSensor>,
    mean: DVector<f64>,
    cov: DMatrix<f64>,
}

/// One sensor's measurement model and its filter's covariance.
#[derive(Debug, Clone)]
struct LocalSensor {
    h: DMatrix<f64>,
    r: DMatrix<f64>,
    /// `Pⁱ(k−1|k−1)`, then `Pⁱ(k|k−1)` after a prediction.
    own: DMatrix<f64>,
}

impl LocalPredictions {
    /// The law at step 0: `x(0) ~ N(m₀, P₀)` and every sensor's estimate
    /// `x̂ⁱ(0|0) = m₀` with covariance `P₀`. `sensors` are `(Hⁱ, Rⁱ)`.
    pub fn new(
        f: DMatrix<f64>,
        q: DMatrix<f64>,
        sensors: Vec<(DMatrix<f64>, DMatrix<f64>)>,
        prior_mean: DVector<f64>,
        prior_cov: DMatrix<f64>,
    ) -> Self {
        let d = f.nrows();
        let n = sensors.len();
        let mut mean = DVector::zeros(d * (n + 1));
        let mut cov = DMatrix::zeros(d * (n + 1), d * (n + 1));
        for block in 0..=n {
            mean.rows_mut(block * d, d).copy_from(&prior_mean);
        }
        cov.view_mut((0, 0), (d, d)).copy_from(&prior_cov);
        Self {
            d,
            f,
            q,
            sensors: sensors
                .into_iter()
                .map(|(h, r)| LocalSensor {
                    h,
                    r,
                    own: prior_cov.clone(),
                })
                .collect(),
            mean,
            cov,
        }
    }

    pub fn sensors(&self) -> usize {
        self.sensors.len()
    }

    /// One step of the motion: the state moves with its noise, every
    /// estimate becomes its prediction `F x̂ⁱ`.
    pub fn predict(&mut self) {
        let (d, blocks) = (self.d, self.sensors.len() + 1);
        let mut transition = DMatrix::zeros(d * blocks, d * blocks);
        for b in 0..blocks {
            transition
                .view_mut((b * d, b * d), (d, d))
                .copy_from(&self.f);
        }
        self.mean = &transition * &self.mean;
        self.cov = &transition * &self.cov * transition.transpose();
        let mut x_block = self.cov.view_mut((0, 0), (d, d));
        x_block += &self.q;
        for s in &mut self.sensors {
            s.own = &self.f * &s.own * self.f.transpose() + &self.q;
        }
    }

    /// Sensor i's innovation covariance `Sⁱ = Hⁱ Pⁱ(k|k−1) Hⁱᵀ + Rⁱ`: what
    /// it normalizes its innovation by.
    pub fn innovation_covariance(&self, i: usize) -> DMatrix<f64> {
        let s = &self.sensors[i];
        &s.h * &s.own * s.h.transpose() + &s.r
    }

    /// Sensor i's Kalman gain this step, `Kⁱ = Pⁱ Hⁱᵀ Sⁱ⁻¹`.
    pub fn gain(&self, i: usize) -> DMatrix<f64> {
        let s = &self.sensors[i];
        let inverse = self
            .innovation_covariance(i)
            .try_inverse()
            .expect("S = H P Hᵀ + R with R > 0 is invertible");
        &s.own * s.h.transpose() * inverse
    }

    /// Sensor i's own predicted covariance `Pⁱ(k|k−1)` (after a prediction).
    pub fn own_covariance(&self, i: usize) -> &DMatrix<f64> {
        &self.sensors[i].own
    }

    /// `P̃ⁱʲ = E[(x − x̂ⁱ)(x − x̂ʲ)ᵀ]`, the predictions' error
    /// cross-covariance of eq. 3.27, from the joint law.
    pub fn error_cross_covariance(&self, i: usize, j: usize) -> DMatrix<f64> {
        let d = self.d;
        let block = |a: usize, b: usize| self.cov.view((a * d, b * d), (d, d)).into_owned();
        let (a, b) = (i + 1, j + 1);
        block(0, 0) - block(0, b) - block(a, 0) + block(a, b)
    }

    /// Every sensor updates with its own measurement, in law:
    /// `x̂ⁱ ← (I − KⁱHⁱ) x̂ⁱ + KⁱHⁱ x + Kⁱ nⁱ`.
    pub fn update(&mut self) {
        let (d, blocks) = (self.d, self.sensors.len() + 1);
        let mut m = DMatrix::identity(d * blocks, d * blocks);
        let mut noise = DMatrix::zeros(d * blocks, d * blocks);
        let gains: Vec<DMatrix<f64>> = (0..self.sensors.len()).map(|i| self.gain(i)).collect();
        for (i, (s, k)) in self.sensors.iter_mut().zip(&gains).enumerate() {
            let b = (i + 1) * d;
            let kh = k * &s.h;
            m.view_mut((b, 0), (d, d)).copy_from(&kh);
            m.view_mut((b, b), (d, d))
                .copy_from(&(DMatrix::identity(d, d) - &kh));
            noise
                .view_mut((b, b), (d, d))
                .copy_from(&(k * &s.r * k.transpose()));
            let own = (DMatrix::identity(d, d) - &kh) * &s.own;
            s.own = 0.5 * (&own + own.transpose());
        }
        self.mean = &m * &self.mean;
        self.cov = &m * &self.cov * m.transpose() + noise;
        self.cov = 0.5 * (&self.cov + self.cov.transpose());
    }

    /// The law of the silent sensors' innovations given the state, from
    /// the exact conditional `x̂ | x ~ N(c + G x, Σ_c)` of the joint law
    /// (call between [`Self::predict`] and [`Self::update`]).
    pub fn silence<G: Rng + ?Sized>(
        &self,
        silent: &[usize],
        rule: &CensoringRule,
        draws: usize,
        rng: &mut G,
    ) -> Option<JointSilence> {
        let d = self.d;
        let cxx = self.cov.view((0, 0), (d, d)).into_owned();
        let cxx_inv = cxx.try_inverse()?;
        let m = silent.len();
        let mut cpx = DMatrix::zeros(m * d, d);
        let mut cpp = DMatrix::zeros(m * d, m * d);
        let mut mp = DVector::zeros(m * d);
        for (a, &i) in silent.iter().enumerate() {
            let bi = (i + 1) * d;
            cpx.view_mut((a * d, 0), (d, d))
                .copy_from(&self.cov.view((bi, 0), (d, d)));
            mp.rows_mut(a * d, d).copy_from(&self.mean.rows(bi, d));
            for (b, &j) in silent.iter().enumerate() {
                let bj = (j + 1) * d;
                cpp.view_mut((a * d, b * d), (d, d))
                    .copy_from(&self.cov.view((bi, bj), (d, d)));
            }
        }
        let gain = &cpx * &cxx_inv;
        let offset = &mp - &gain * self.mean.rows(0, d);
        let conditional = &cpp - &gain * cpx.transpose();
        self.joint_silence(silent, rule, &gain, &offset, &conditional, draws, rng)
    }

    /// The same, with the dissertation's `x̂ | x ~ N(x ⊗ 1, Σ)` (eq. 3.26):
    /// `G` stacks identities, `c = 0`, `Σ_c` the error covariances. Its
    /// probability is the same at every state.
    pub fn silence_as_printed<G: Rng + ?Sized>(
        &self,
        silent: &[usize],
        rule: &CensoringRule,
        draws: usize,
        rng: &mut G,
    ) -> Option<JointSilence> {
        let d = self.d;
        let m = silent.len();
        let mut errors = DMatrix::zeros(m * d, m * d);
        for (a, &i) in silent.iter().enumerate() {
            for (b, &j) in silent.iter().enumerate() {
                errors
                    .view_mut((a * d, b * d), (d, d))
                    .copy_from(&self.error_cross_covariance(i, j));
            }
        }
        self.joint_silence(
            silent,
            rule,
            &stacked_identities(m, d),
            &DVector::zeros(m * d),
            &errors,
            draws,
            rng,
        )
    }

    /// With `x̂_M | x ~ N(c + G x, Σ_c)`, the silent sensors' innovations
    /// `νʲ = Hʲ(x − x̂ʲ) + nʲ` are `N(A x − b, T)`, `A = H_M(1 ⊗ I − G)`,
    /// `b = H_M c`, `T = H_M Σ_c H_Mᵀ + R_M`.
    #[allow(clippy::too_many_arguments)]
    fn joint_silence<G: Rng + ?Sized>(
        &self,
        silent: &[usize],
        rule: &CensoringRule,
        gain: &DMatrix<f64>,
        offset: &DVector<f64>,
        conditional: &DMatrix<f64>,
        draws: usize,
        rng: &mut G,
    ) -> Option<JointSilence> {
        let d = self.d;
        let rows: usize = silent.iter().map(|&i| self.sensors[i].h.nrows()).sum();
        if rows > MAX_ROWS {
            return None;
        }
        let mut h = DMatrix::zeros(rows, silent.len() * d);
        let mut r = DMatrix::zeros(rows, rows);
        let mut regions = Vec::with_capacity(silent.len());
        let mut row = 0;
        for (a, &i) in silent.iter().enumerate() {
            let s = &self.sensors[i];
            let k = s.h.nrows();
            h.view_mut((row, a * d), (k, d)).copy_from(&s.h);
            r.view_mut((row, row), (k, k)).copy_from(&s.r);
            let s_inv = self.innovation_covariance(i).try_inverse()?;
            regions.push(Region {
                first: row,
                rows: k,
                s_inv: s_inv.as_slice().to_vec(),
            });
            row += k;
        }
        let a = &h * (stacked_identities(silent.len(), d) - gain);
        let b = &h * offset;
        let t = &h * conditional * h.transpose() + r;
        let t = 0.5 * (&t + t.transpose());
        let factor = t.clone().cholesky()?.l();
        let draws = if rows == 1 { 0 } else { draws };
        let padded = draws.next_multiple_of(LANES);
        // Component by component, each padded with NaN, which no region
        // holds: the count goes a block of draws at a time.
        let mut columns = vec![f64::NAN; rows * padded];
        for d in 0..draws {
            let z = DVector::<f64>::from_fn(rows, |_, _| rng.sample(StandardNormal));
            for (k, w) in (&factor * z).iter().enumerate() {
                columns[k * padded + d] = *w;
            }
        }
        Some(JointSilence {
            threshold: rule.threshold,
            a,
            b,
            noise_sd: t[(0, 0)].sqrt(),
            regions,
            columns,
            draws,
            padded,
            rows,
        })
    }
}

/// `1 ⊗ I`: m identities of size d, one above the other.
fn stacked_identities(m: usize, d: usize) -> DMatrix<f64> {
    DMatrix::from_fn(m * d, d, |i, j| if i % d == j { 1.0 } else { 0.0 })
}

/// The most innovation components one joint silence handles (four silent
/// two-component sensors); more would need a larger stack buffer.
pub const MAX_ROWS: usize = 8;

/// One silent sensor's region `νᵀ S⁻¹ ν < η`, its rows in the stacked ν.
#[derive(Debug, Clone)]
struct Region {
    first: usize,
    rows: usize,
    /// `S⁻¹` column by column (`S⁻¹[i, j]` at `i + j·rows`), as a slice:
    /// every particle asks about every draw, and a matrix's indexing
    /// costs more than the arithmetic.
    s_inv: Vec<f64>,
}

/// Draws a region is asked about at once: a block the compiler keeps in
/// vector registers.
const LANES: usize = 16;

impl Region {
    /// Which of a block of draws put `ν = μ + w` (this region's rows of
    /// them) inside, `Σ_i Σ_j ν_i S⁻¹[i, j] ν_j < η` summed in that order,
    /// cleared in `inside`. `columns` holds each component's draws,
    /// `padded` apart, and the block starts at `at`.
    #[inline(always)]
    fn keep_inside(
        &self,
        mu: &[f64],
        columns: &[f64],
        padded: usize,
        at: usize,
        threshold: f64,
        inside: &mut [bool; LANES],
    ) {
        let (f, n, s) = (self.first, self.rows, &self.s_inv[..]);
        let column = |k: usize| -> &[f64; LANES] {
            let start = (f + k) * padded + at;
            columns[start..start + LANES]
                .try_into()
                .expect("a block is LANES draws")
        };
        let mut q = [0.0; LANES];
        for i in 0..n {
            let (wi, mi) = (column(i), mu[f + i]);
            for j in 0..n {
                let (wj, mj, sij) = (column(j), mu[f + j], s[i + j * n]);
                for l in 0..LANES {
                    q[l] += (mi + wi[l]) * sij * (mj + wj[l]);
                }
            }
        }
        for l in 0..LANES {
            inside[l] &= q[l] < threshold;
        }
    }
}

/// `P(every silent sensor stays silent | x)`, the silent sensors'
/// innovations being `N(A x − b, T)`. One scalar innovation has the closed
/// form `Φ((√(ηs) − μ)/√T) − Φ((−√(ηs) − μ)/√T)`; more are counted over
/// draws of `N(0, T)` shared by every state (common random numbers, so the
/// estimate is smooth in x), as the dissertation does for vectors (§3.7.2).
#[derive(Debug, Clone)]
pub struct JointSilence {
    threshold: f64,
    a: DMatrix<f64>,
    b: DVector<f64>,
    noise_sd: f64,
    regions: Vec<Region>,
    /// Draws of `N(0, T)`, component by component: component k of draw d
    /// at `k·padded + d`, and each component's last `padded − draws`
    /// entries NaN.
    columns: Vec<f64>,
    draws: usize,
    padded: usize,
    rows: usize,
}

impl JointSilence {
    /// `ln P(silent | x)` at a state `x` (d numbers). Allocates nothing.
    pub fn ln_probability(&self, x: &[f64]) -> f64 {
        let mut mu = [0.0; MAX_ROWS];
        for (row, m) in mu.iter_mut().enumerate().take(self.rows) {
            *m = (0..x.len()).map(|c| self.a[(row, c)] * x[c]).sum::<f64>() - self.b[row];
        }
        if self.rows == 1 {
            let region = &self.regions[0];
            let half = (self.threshold / region.s_inv[0]).sqrt();
            let sd = self.noise_sd;
            return normal::ln_interval_mass((-half - mu[0]) / sd, (half - mu[0]) / sd);
        }
        let count = self.count_inside(&mu);
        // Half a draw keeps a state no draw supports from a weight of zero.
        ((count as f64 + 0.5) / (self.draws as f64 + 1.0)).ln()
    }

    /// The draws that every region holds, with the innovations' mean `mu`.
    fn count_inside(&self, mu: &[f64; MAX_ROWS]) -> usize {
        #[cfg_attr(target_arch = "x86_64", target_feature(enable = "avx2"))]
        unsafe fn avx2(s: &JointSilence, mu: &[f64; MAX_ROWS]) -> usize {
            s.count_blocks(mu)
        }
        if crate::batch::has_avx2() {
            // SAFETY: the CPU has AVX2.
            unsafe { avx2(self, mu) }
        } else {
            self.count_blocks(mu)
        }
    }

    #[inline(always)]
    fn count_blocks(&self, mu: &[f64; MAX_ROWS]) -> usize {
        let mut count = 0;
        for at in (0..self.padded).step_by(LANES) {
            let mut inside = [true; LANES];
            for region in &self.regions {
                region.keep_inside(
                    mu,
                    &self.columns,
                    self.padded,
                    at,
                    self.threshold,
                    &mut inside,
                );
            }
            count += inside.iter().filter(|&&b| b).count();
        }
        count
    }
}

/// `D(N(m₀, P₀) ‖ N(m₁, P₁))` (eq. 3.30):
/// `½ [tr(P₁⁻¹P₀) − ln(|P₀|/|P₁|) − d + (m₁ − m₀)ᵀ P₁⁻¹ (m₁ − m₀)]`.
/// `None` when a covariance is not positive definite.
pub fn gaussian_kl(
    m0: &DVector<f64>,
    p0: &DMatrix<f64>,
    m1: &DVector<f64>,
    p1: &DMatrix<f64>,
) -> Option<f64> {
    let c0 = p0.clone().cholesky()?;
    let c1 = p1.clone().cholesky()?;
    let ln_det = |c: &nalgebra::Cholesky<f64, nalgebra::Dyn>| {
        2.0 * c.l().diagonal().iter().map(|v| v.ln()).sum::<f64>()
    };
    let dm = m1 - m0;
    let trace = c1.solve(p0).trace();
    let quadratic = dm.dot(&c1.solve(&dm));
    Some(0.5 * (trace - (ln_det(&c0) - ln_det(&c1)) - p0.nrows() as f64 + quadratic))
}

/// The prior-to-posterior divergence of one Kalman update, the
/// information-theoretic censoring metric of §3.4 (eq. 3.29): the sensor
/// sends when `D(p(x|z₁..ₖ₋₁) ‖ p(x|z₁..ₖ))` (or, `symmetric`, its sum with
/// the reverse, eq. 3.35) reaches its threshold. `h`, `r`, the prior
/// `(m, p)` and the measurement `z`.
pub fn update_divergence(
    m: &DVector<f64>,
    p: &DMatrix<f64>,
    h: &DMatrix<f64>,
    r: &DMatrix<f64>,
    z: &DVector<f64>,
    symmetric: bool,
) -> Option<f64> {
    let s = h * p * h.transpose() + r;
    let k = p * h.transpose() * s.try_inverse()?;
    let posterior_mean = m + &k * (z - h * m);
    let posterior = (DMatrix::identity(p.nrows(), p.nrows()) - &k * h) * p;
    let posterior = 0.5 * (&posterior + posterior.transpose());
    let forward = gaussian_kl(m, p, &posterior_mean, &posterior)?;
    if symmetric {
        Some(forward + gaussian_kl(&posterior_mean, &posterior, m, p)?)
    } else {
        Some(forward)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// The dissertation's 1-D line: constant velocity, D = 1 s, σ² = 4,
    /// sensors measuring position with r = 1.
    fn line(n: usize) -> LocalPredictions {
        let f = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]);
        let q = 4.0 * DMatrix::from_row_slice(2, 2, &[0.25, 0.5, 0.5, 1.0]);
        let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
        let r = DMatrix::from_element(1, 1, 1.0);
        LocalPredictions::new(
            f,
            q,
            vec![(h, r); n],
            DVector::from_vec(vec![0.0, 10.0]),
            DMatrix::identity(2, 2),
        )
    }

    #[test]
    fn the_closed_form_divergence_is_the_scalar_one() {
        let (m0, s0, m1, s1) = (0.3, 1.7_f64, -1.1, 0.6_f64);
        let kl = gaussian_kl(
            &DVector::from_element(1, m0),
            &DMatrix::from_element(1, 1, s0 * s0),
            &DVector::from_element(1, m1),
            &DMatrix::from_element(1, 1, s1 * s1),
        )
        .unwrap();
        let scalar = (s1 / s0).ln() + (s0 * s0 + (m0 - m1).powi(2)) / (2.0 * s1 * s1) - 0.5;
        assert!((kl - scalar).abs() < 1e-12, "{kl} vs {scalar}");
    }

    /// Theorem 3.4 and Corollary 3.5: for a scalar measurement, the update's
    /// divergence grows with |ν| alone, so thresholding it at the value it
    /// takes on the NIS boundary sends exactly what NIS sends.
    #[test]
    fn censoring_by_divergence_sends_what_nis_sends() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let m = DVector::from_vec(vec![1.0, -2.0]);
        let p = DMatrix::from_row_slice(2, 2, &[2.0, 0.7, 0.7, 1.5]);
        let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
        let r = DMatrix::from_element(1, 1, 0.8);
        let s = 2.0 + 0.8;
        let rule = CensoringRule::for_budget(1.0, 4, 1).unwrap();
        for symmetric in [false, true] {
            let at = |nu: f64| {
                let z = DVector::from_element(1, m[0] + nu);
                update_divergence(&m, &p, &h, &r, &z, symmetric).unwrap()
            };
            let boundary = at((rule.threshold * s).sqrt());
            assert!((at(-(rule.threshold * s).sqrt()) - boundary).abs() < 1e-12);
            for _ in 0..2000 {
                let nu: f64 = 3.0 * rng.sample::<f64, _>(StandardNormal);
                assert_eq!(at(nu) >= boundary, rule.sends(nu * nu / s), "ν = {nu}");
            }
        }
    }

    /// Eqs. 3.27–3.28: the cross-covariance of two sensors' prediction
    /// errors follows `P̃ = F P Fᵀ + Q`, `P = (I − KⁱH)P̃(I − KʲH)ᵀ`, from
    /// `P(0|0) = 0`; the joint law must give the same, and on the diagonal
    /// each sensor's own Kalman covariance.
    #[test]
    fn the_joint_law_has_the_cross_covariance_recursion() {
        let mut law = line(2);
        let f = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]);
        let q = 4.0 * DMatrix::from_row_slice(2, 2, &[0.25, 0.5, 0.5, 1.0]);
        let h = DMatrix::from_row_slice(1, 2, &[1.0, 0.0]);
        // The prior's error is shared by both sensors (both start at m₀).
        let mut cross = DMatrix::identity(2, 2);
        for _ in 0..8 {
            law.predict();
            cross = &f * &cross * f.transpose() + &q;
            let got = law.error_cross_covariance(0, 1);
            assert!((&got - &cross).norm() < 1e-9, "{got} vs {cross}");
            let own = law.error_cross_covariance(0, 0);
            assert!((&own - law.own_covariance(0)).norm() < 1e-9);
            let (k0, k1) = (law.gain(0), law.gain(1));
            let i = DMatrix::identity(2, 2);
            cross = (&i - &k0 * &h) * &cross * (&i - &k1 * &h).transpose();
            law.update();
        }
    }

    /// The conditional law `x̂ | x` against simulation: regressing the
    /// simulated sensors' predictions on the simulated state gives the
    /// slope G and the residual spread Σ_c the joint law says.
    #[test]
    fn the_conditional_law_of_the_predictions_matches_simulation() {
        let mut law = line(2);
        let steps = 4;
        for _ in 0..steps - 1 {
            law.predict();
            law.update();
        }
        law.predict();
        // Simulate the same system: truth, two Kalman filters.
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut gains_law = line(2);
        let mut gains = Vec::new();
        for _ in 0..steps {
            gains_law.predict();
            gains.push(gains_law.gain(0));
            gains_law.update();
        }
        let f = nalgebra::Matrix2::new(1.0, 1.0, 0.0, 1.0);
        let q_factor = nalgebra::Matrix2::new(1.0, 0.0, 2.0, 0.0); // Q = 4 [¼ ½; ½ 1] = L Lᵀ
        let runs = 40_000;
        let (mut sxx, mut sxp, mut spp) = (0.0, 0.0, 0.0);
        let (mut mx, mut mp) = (0.0, 0.0);
        let mut samples = Vec::with_capacity(runs);
        for _ in 0..runs {
            let n = |rng: &mut ChaCha8Rng| rng.sample::<f64, _>(StandardNormal);
            let mut x = nalgebra::Vector2::new(n(&mut rng), 10.0 + n(&mut rng));
            let mut est = [nalgebra::Vector2::new(0.0, 10.0); 2];
            for (k, gain) in gains.iter().enumerate() {
                x = f * x + q_factor * nalgebra::Vector2::new(n(&mut rng), 0.0);
                for e in &mut est {
                    *e = f * *e;
                }
                if k + 1 == steps {
                    break;
                }
                for e in &mut est {
                    let z = x[0] + n(&mut rng);
                    *e += nalgebra::Vector2::new(gain[(0, 0)], gain[(1, 0)]) * (z - e[0]);
                }
            }
            samples.push((x[0], est[0][0]));
        }
        for (x, p) in &samples {
            mx += x;
            mp += p;
        }
        mx /= runs as f64;
        mp /= runs as f64;
        for (x, p) in &samples {
            sxx += (x - mx).powi(2);
            sxp += (x - mx) * (p - mp);
            spp += (p - mp).powi(2);
        }
        // Regress the first sensor's predicted position on the position alone
        // (the law, marginalized likewise).
        let slope = sxp / sxx;
        let residual = (spp - sxp * sxp / sxx) / runs as f64;
        let d = 2;
        let cov = &law.cov;
        let (cxx, cxp, cpp) = (cov[(0, 0)], cov[(d, 0)], cov[(d, d)]);
        let (want_slope, want_residual) = (cxp / cxx, cpp - cxp * cxp / cxx);
        assert!(
            (slope - want_slope).abs() < 0.01,
            "slope {slope} vs {want_slope}"
        );
        assert!(
            (residual / want_residual - 1.0).abs() < 0.05,
            "residual {residual} vs {want_residual}"
        );
        assert!(want_slope > 0.5 && want_slope < 1.0, "{want_slope}");
    }

    #[test]
    fn the_printed_silence_is_the_same_at_every_state() {
        let mut law = line(2);
        law.predict();
        law.update();
        law.predict();
        let rule = CensoringRule::for_budget(1.0, 2, 1).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for silent in [vec![0], vec![0, 1]] {
            let printed = law
                .silence_as_printed(&silent, &rule, 500, &mut rng)
                .unwrap();
            let exact = law.silence(&silent, &rule, 500, &mut rng).unwrap();
            let at = |s: &JointSilence, x: f64| s.ln_probability(&[x, 10.0]);
            assert!((at(&printed, -30.0) - at(&printed, 40.0)).abs() < 1e-12);
            // The predictions are centred on 20 m after two steps.
            assert!(
                at(&exact, 20.0) - at(&exact, 80.0) > 0.1,
                "a silence favours states near where the sensors predict"
            );
        }
    }

    /// The closed form for one scalar innovation and the draws for two
    /// agree where the second sensor's region holds everything.
    #[test]
    fn one_silent_sensor_in_closed_form_is_the_count_over_draws() {
        let mut law = line(2);
        law.predict();
        let rule = CensoringRule::for_budget(1.0, 2, 1).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let closed = law.silence(&[0], &rule, 0, &mut rng).unwrap();
        let mut counted = law.silence(&[0, 1], &rule, 40_000, &mut rng).unwrap();
        // The second sensor's region widened to hold every draw.
        counted.regions[1].s_inv.fill(0.0);
        for x in [-3.0, 0.0, 2.0] {
            let (a, b) = (
                closed.ln_probability(&[x, 10.0]).exp(),
                counted.ln_probability(&[x, 10.0]).exp(),
            );
            assert!((a - b).abs() < 0.01, "x = {x}: {a} vs {b}");
        }
    }

    /// The count a block of draws at a time is the count draw by draw, for
    /// silent sensors of one and of two components and a number of draws
    /// that does not fill the last block.
    #[test]
    fn the_blocked_count_is_the_count_draw_by_draw() {
        let f = DMatrix::from_row_slice(2, 2, &[1.0, 1.0, 0.0, 1.0]);
        let q = 4.0 * DMatrix::from_row_slice(2, 2, &[0.25, 0.5, 0.5, 1.0]);
        let scalar = (
            DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
            DMatrix::from_element(1, 1, 1.0),
        );
        let pair = (
            DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 0.5, 1.0]),
            DMatrix::from_row_slice(2, 2, &[1.0, 0.3, 0.3, 2.0]),
        );
        let mut law = LocalPredictions::new(
            f,
            q,
            vec![scalar.clone(), pair, scalar],
            DVector::from_vec(vec![0.0, 10.0]),
            DMatrix::identity(2, 2),
        );
        law.predict();
        let rule = CensoringRule::for_budget(1.5, 3, 1).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let silence = law.silence(&[0, 1, 2], &rule, 1003, &mut rng).unwrap();
        let (rows, padded) = (silence.rows, silence.padded);
        let mut partial = 0;
        for x in [-4.0, 0.0, 3.0, 6.0, 8.0, 10.0, 12.0, 14.0, 25.0] {
            let state = [x, 10.0];
            let mut mu = [0.0; MAX_ROWS];
            for (row, m) in mu.iter_mut().enumerate().take(rows) {
                *m = (0..2).map(|c| silence.a[(row, c)] * state[c]).sum::<f64>() - silence.b[row];
            }
            let by_draw = (0..silence.draws)
                .filter(|&d| {
                    silence.regions.iter().all(|region| {
                        let n = region.rows;
                        let nu = |k: usize| {
                            mu[region.first + k] + silence.columns[(region.first + k) * padded + d]
                        };
                        let mut q = 0.0;
                        for i in 0..n {
                            for j in 0..n {
                                q += nu(i) * region.s_inv[i + j * n] * nu(j);
                            }
                        }
                        q < silence.threshold
                    })
                })
                .count();
            let blocked = silence.count_inside(&mu);
            assert_eq!(blocked, by_draw, "x = {x}");
            partial += usize::from(by_draw > 0 && by_draw < silence.draws);
        }
        assert!(partial >= 3, "the states hold some draws and not others");
    }
}
