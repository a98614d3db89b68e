//! Dissertation ch. 3, Tables 3.1–3.3: the average number of transmissions
//! l̄ of NIS censoring (CFwMD) for a budget of l, with the node feeding
//! back its predicted estimate (CFwMD) or the estimate and its covariance
//! (CFwMD2). Computed in-process, in the dissertation's own setups: a
//! fusion centre's particle filter that weights every particle with the
//! full likelihood, the received measurements' and the silent sensors'.
//!
//! The threshold assumes the innovation is `N(0, S)`. With CFwMD the
//! sensor's S comes from its own Kalman covariance recursion, which does
//! not know how good the fused estimate is, so l̄ drifts from l; CFwMD2
//! normalizes by the fed-back covariance and should hold l. That is the
//! tables' point, and the check.

mod network;
mod report;
mod setups;
mod trial;

use std::path::Path;

use bounds::censoring::CensoringRule;

use crate::{Computed, ComputedReport, Options};
pub use network::network_experiments;
use report::{check, draw, print, table_csv, Row};
use setups::{name, setups, SCHEMES};
use trial::measure;

pub fn experiments() -> Vec<Computed> {
    vec![Computed {
        name: "censoring-tables",
        source: "dissertation ch. 3, Tables 3.1-3.3",
        about: "NIS censoring at the sensor with the silent sensors' likelihood at the fusion centre: the average number of transmissions for a budget of l, CFwMD (estimate fed back) and CFwMD2 (estimate and covariance), in the dissertation's three setups",
        run,
    }]
}

fn run(options: &Options, dir: &Path) -> anyhow::Result<ComputedReport> {
    let threads = options.threads.max(1);
    let mut rows = Vec::new();
    for setup in setups() {
        for &(l, cfwmd, cfwmd2) in setup.theirs {
            let rule =
                CensoringRule::for_budget(l, setup.sensors.len(), setup.sensors[0].len() as u32)?;
            let ours = SCHEMES.map(|scheme| {
                let measured = measure(&setup, &rule, scheme, threads);
                eprintln!(
                    "  table {} l = {l}: {} l̄ = {:.4}",
                    setup.table,
                    name(scheme),
                    measured.mean
                );
                measured
            });
            rows.push(Row {
                table: setup.table,
                l,
                sensors: setup.sensors.len(),
                ours,
                theirs: [cfwmd, cfwmd2],
                trials: setup.trials,
            });
        }
    }
    ComputedReport::write(
        dir,
        "censoring-tables",
        &table_csv(&rows),
        |svg| draw(svg, &rows),
        check(&rows),
        print(&rows),
    )
}

#[cfg(test)]
mod tests {
    use super::setups::Feedback;
    use super::trial::{innovation_statistics, kalman_update};
    use super::*;
    use bounds::{Mat4, SensorLaw, State};

    /// A one-step check of the sensor-side statistics on the scalar line:
    /// S = P_xx + r, and the Kalman update shrinks the position variance to
    /// P r / (P + r).
    #[test]
    fn the_sensor_statistics_are_the_kalman_filters() {
        let sensor = vec![SensorLaw::Linear {
            h: [1.0, 0.0, 0.0, 0.0],
            r: 2.0,
        }
        .at([0.0, 0.0])];
        let cov = Mat4::from_diagonal(&State::new(3.0, 1.0, 5.0, 1.0));
        let (g, s, r) = innovation_statistics(&sensor, &State::new(4.0, 0.0, 1.0, 0.0), &cov);
        assert_eq!(g[0], 4.0);
        assert!((s[(0, 0)] - 5.0).abs() < 1e-12 && r[(0, 0)] == 2.0);
        let updated = kalman_update(&cov, &sensor, &State::zeros());
        assert!((updated[(0, 0)] - 3.0 * 2.0 / 5.0).abs() < 1e-12);
        assert!(
            (updated[(2, 2)] - 5.0).abs() < 1e-12,
            "uncorrelated velocity untouched"
        );
    }

    /// The experiment's filter with every sensor sending (η = 0) is a
    /// particle filter on a linear-Gaussian system: its position RMSE must
    /// be the Kalman filter's, whose covariance we iterate here for one
    /// sensor of r = 1/4 (four of r = 1).
    #[test]
    fn with_every_sensor_sending_the_filter_is_the_kalman_filter() {
        let mut setup = setups().remove(0);
        setup.trials = 40;
        setup.particles = 2000;
        let rule = CensoringRule { threshold: 0.0 };
        let m = measure(&setup, &rule, Feedback::Estimate, 2);
        assert!(
            (m.mean - 4.0).abs() < 1e-12,
            "every sensor sends: {}",
            m.mean
        );
        let one = vec![SensorLaw::Linear {
            h: [1.0, 0.0, 0.0, 0.0],
            r: 0.25,
        }
        .at([0.0, 0.0])];
        let f = setup.dynamics.jacobian(&State::zeros());
        let (q, _) = setup.process_noise();
        let mut p = setup.prior_cov;
        let mut mse = 0.0;
        for _ in 0..setup.steps {
            p = kalman_update(&(f * p * f.transpose() + q), &one, &State::zeros());
            mse += p[(0, 0)];
        }
        let kalman = (mse / setup.steps as f64).sqrt();
        assert!(
            (m.rmse / kalman - 1.0).abs() < 0.15,
            "particle filter {} m vs Kalman {kalman} m",
            m.rmse
        );
    }
}
