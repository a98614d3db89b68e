//! A sensor manager: each node activates its first `k` sensors, every step.

use node::parts::{ParamError, Setup};
use node::sensor_manager::{Manager, SelectionContext, SensorManager};

pub struct FirstK {
    k: usize,
}

impl SensorManager for FirstK {
    fn choose(&mut self, context: &SelectionContext<'_>) -> Vec<usize> {
        (0..self.k.min(context.own_sensors.len())).collect()
    }
}

/// `sensors.manager_params.k`, by default the scenario's `active_per_node`.
pub fn build(setup: &Setup<'_>) -> Result<Manager, ParamError> {
    let params = setup.params;
    params.only(&["k"])?;
    let own = setup.topology.node_sensors[setup.node as usize].len() as i64;
    let default = i64::from(setup.scenario.sensors.active_per_node);
    let k = params.integer("k", 1..=own.max(1), default)?;
    Ok(Manager::Alone(Box::new(FirstK { k: k as usize })))
}
