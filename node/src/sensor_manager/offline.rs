//! The conventional PCRLB manager of the selection paper's comparison:
//! greedy selection on the offline (non-conditional) PCRLB, which averages
//! over trajectories drawn from the prior and uses no data.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use bounds::selection::offline_schedule;
use bounds::{BoundError, SensorTerm, State};
use fusion_graph::{Scenario, ScenarioError, Topology};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::{SelectionContext, SensorManager};
use crate::estimator::SensingModel;

/// Trajectories the offline bound's expectations take (N_T).
pub const OFFLINE_TRAJECTORIES: usize = 1000;

/// The schedule's own random stream: the same in every run and at every
/// node, since the offline bound depends on the prior alone.
const SCHEDULE_SEED: u64 = 0x0ff1_1e5c;

/// Each step's choice, (node, sensor), for steps 1, 2, …
type Schedule = Vec<Vec<(u16, u16)>>;

/// Greedy on the offline PCRLB: a schedule of sensors, computed once
/// before the run from the prior `N(target state, P_0)`, the dynamics and
/// the sensors' models. Every node computes the same schedule and
/// activates its own sensors in it, so no message is needed. A process
/// computes a scenario's schedule once (a Monte Carlo run's nodes share it).
#[derive(Debug, Clone)]
pub struct OfflinePcrlb {
    schedule: Arc<Schedule>,
}

#[derive(Debug, thiserror::Error)]
pub enum OfflineError {
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error("the offline PCRLB: {0}")]
    Bound(#[from] BoundError),
}

impl OfflinePcrlb {
    pub fn for_scenario(scenario: &Scenario, topology: &Topology) -> Result<Self, OfflineError> {
        static SCHEDULES: OnceLock<Mutex<HashMap<String, Arc<Schedule>>>> = OnceLock::new();
        let per_node = scenario.sensors.active_per_node as usize;
        let max_total = scenario
            .sensors
            .max_active_total
            .map_or(per_node * topology.nodes(), |m| m as usize);
        // What the schedule depends on: nothing of the run's seed.
        let key = format!(
            "{:?}",
            (
                scenario.target.initial_state(),
                scenario.filter.prior_std,
                &scenario.dynamics,
                &scenario.observation,
                &scenario.quantizer,
                &topology.sensor_positions,
                &topology.sensor_owner,
                per_node,
                max_total,
                scenario.steps,
            )
        );
        let cache = SCHEDULES.get_or_init(Default::default);
        if let Some(schedule) = cache.lock().unwrap_or_else(|p| p.into_inner()).get(&key) {
            return Ok(Self {
                schedule: schedule.clone(),
            });
        }
        let schedule = Arc::new(compute(scenario, topology, per_node, max_total)?);
        cache
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .insert(key, schedule.clone());
        Ok(Self { schedule })
    }
}

fn compute(
    scenario: &Scenario,
    topology: &Topology,
    per_node: usize,
    max_total: usize,
) -> Result<Schedule, OfflineError> {
    let models = scenario.models()?;
    let sensing = SensingModel::new(&models, topology);
    let candidates: Vec<(u16, u16, SensorTerm)> = sensing
        .sensor_terms()
        .into_iter()
        .enumerate()
        .map(|(s, term)| (topology.sensor_owner[s], s as u16, term))
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(SCHEDULE_SEED);
    Ok(offline_schedule(
        &models.dynamics,
        &candidates,
        &State::from(scenario.target.initial_state()),
        &models.prior_cov,
        scenario.steps as usize,
        OFFLINE_TRAJECTORIES,
        per_node,
        max_total,
        &mut rng,
    )?)
}

impl SensorManager for OfflinePcrlb {
    fn choose(&mut self, context: &SelectionContext<'_>) -> Vec<usize> {
        let Some(chosen) = (context.step as usize)
            .checked_sub(1)
            .and_then(|k| self.schedule.get(k))
        else {
            return Vec::new();
        };
        let mut own: Vec<usize> = chosen
            .iter()
            .filter(|(node, _)| *node == context.node)
            .filter_map(|(_, sensor)| context.own_sensors.iter().position(|s| s == sensor))
            .collect();
        own.sort_unstable();
        own
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fusion_graph::scenario::SENSOR_SELECTION_SCENARIO;

    /// Every node reads the same schedule: together they activate the
    /// schedule's sensors, at most the cap per node and N_max in all, and
    /// a second manager for the scenario shares the first one's schedule.
    #[test]
    fn the_nodes_share_one_schedule_within_the_caps() {
        let scenario =
            Scenario::from_toml(SENSOR_SELECTION_SCENARIO, "s", &["steps=5".into()]).unwrap();
        let topology = Topology::from_scenario(&scenario, "s").unwrap();
        let first = OfflinePcrlb::for_scenario(&scenario, &topology).unwrap();
        let second = OfflinePcrlb::for_scenario(&scenario, &topology).unwrap();
        assert!(Arc::ptr_eq(&first.schedule, &second.schedule));
        let view = vec![true; topology.nodes()];
        for step in 1..=5u32 {
            let mut total = 0;
            for node in 0..topology.nodes() as u16 {
                let own = &topology.node_sensors[node as usize];
                let context = SelectionContext {
                    step,
                    node,
                    own_sensors: own,
                    view: &view,
                    predicted: None,
                    sensor_positions: &topology.sensor_positions,
                    node_sensors: &topology.node_sensors,
                };
                let picks = first.clone().choose(&context);
                assert!(picks.len() <= scenario.sensors.active_per_node as usize);
                total += picks.len();
            }
            assert_eq!(total, 18, "step {step}");
            assert_eq!(first.schedule[step as usize - 1].len(), 18);
        }
    }
}
