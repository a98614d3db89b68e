//! Paired comparisons of two arms over the same runs: the arms of an
//! experiment share their seeds, so run k of each tracks the same target
//! through the same noise, and the difference of their per-run figures
//! has far less spread than either figure.

/// The mean of per-run differences `a − b`, with its 95 % interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Paired {
    pub runs: usize,
    pub mean: f64,
    /// Half the width of the 95 % interval (Student's t on runs − 1
    /// degrees of freedom).
    pub half_width: f64,
}

/// Where a paired difference puts `a` against `b`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Order {
    /// The whole interval is below zero: `a` is lower.
    Lower,
    /// The whole interval is above zero: `a` is higher.
    Higher,
    /// The interval holds zero: not resolved at this many runs.
    Unresolved,
}

impl Paired {
    /// The paired difference of the runs both arms have a figure for;
    /// `None` with fewer than two such runs.
    pub fn of(a: &[Option<f64>], b: &[Option<f64>]) -> Option<Self> {
        let d: Vec<f64> = a
            .iter()
            .zip(b)
            .filter_map(|(a, b)| Some((*a)? - (*b)?))
            .collect();
        let n = d.len();
        if n < 2 {
            return None;
        }
        let mean = d.iter().sum::<f64>() / n as f64;
        let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        Some(Self {
            runs: n,
            mean,
            half_width: t95(n - 1) * (var / n as f64).sqrt(),
        })
    }

    pub fn order(&self) -> Order {
        if self.mean + self.half_width < 0.0 {
            Order::Lower
        } else if self.mean - self.half_width > 0.0 {
            Order::Higher
        } else {
            Order::Unresolved
        }
    }

    /// `−0.058 ± 0.041`.
    pub fn text(&self, digits: usize) -> String {
        format!("{:+.digits$} ± {:.digits$}", self.mean, self.half_width)
    }
}

/// The two-sided 95 % quantile of Student's t with `dof` degrees of
/// freedom: tabulated to 30, then the normal's with the first correction
/// term of its expansion (within 0.1 % from 30 on).
fn t95(dof: usize) -> f64 {
    const TABLE: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
        2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
        2.052, 2.048, 2.045, 2.042,
    ];
    match dof {
        0 => f64::INFINITY,
        1..=30 => TABLE[dof - 1],
        _ => {
            let z: f64 = 1.959_964;
            z + (z.powi(3) + z) / (4.0 * dof as f64)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_t_quantile_meets_the_normal_one() {
        assert_eq!(t95(1), 12.706);
        // Tabulated values at 40 and 120 degrees of freedom.
        assert!((t95(40) - 2.021).abs() < 0.002, "{}", t95(40));
        assert!((t95(120) - 1.980).abs() < 0.001, "{}", t95(120));
    }

    #[test]
    fn a_shared_noise_cancels_in_the_pairs() {
        // Each run's figure is a large common part plus a small offset of
        // the arm: unpaired, the spread would hide the offset.
        let common = [3.0, 9.0, 1.0, 7.0, 5.0, 2.0, 8.0, 4.0];
        let a: Vec<Option<f64>> = common
            .iter()
            .enumerate()
            .map(|(i, c)| Some(c - 0.1 + 0.01 * (i % 2) as f64))
            .collect();
        let b: Vec<Option<f64>> = common.iter().map(|c| Some(*c)).collect();
        let p = Paired::of(&a, &b).unwrap();
        assert_eq!(p.runs, 8);
        assert!((p.mean + 0.095).abs() < 1e-12);
        assert_eq!(p.order(), Order::Lower);
        assert_eq!(Paired::of(&b, &a).unwrap().order(), Order::Higher);
        let noisy: Vec<Option<f64>> = common.iter().map(|c| Some(10.0 - c)).collect();
        assert_eq!(Paired::of(&noisy, &b).unwrap().order(), Order::Unresolved);
        // A run missing from either arm is left out of the pairs.
        let mut gap = a.clone();
        gap[0] = None;
        assert_eq!(Paired::of(&gap, &b).unwrap().runs, 7);
        assert!(Paired::of(&[Some(1.0)], &[Some(2.0)]).is_none());
    }
}
