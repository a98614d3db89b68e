//! `cqnet.Scenario`: a validated scenario, edited the way `--set` edits
//! one, with the same keyed errors.

use std::path::PathBuf;

use fusion_graph::scenario::{
    Scenario, COMPRESSIVE_SCENARIO, DEFAULT_SCENARIO, LOCATION_SCENARIO, RANDOM_EXCHANGE_SCENARIO,
    SENSOR_SELECTION_SCENARIO,
};
use fusion_graph::Topology;
use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::exceptions::{PyKeyError, PyValueError};
use pyo3::prelude::*;

use crate::bounds_api::{PyDynamics, PySensor};
use crate::convert::{to_python, to_toml};
use crate::scenario_error;

/// The scenarios cqnet carries, by the names `Scenario.builtin` takes.
const BUILTIN: [(&str, &str, &str); 5] = [
    ("default", "<built-in default>", DEFAULT_SCENARIO),
    (
        "sensor-selection",
        "<built-in sensor-selection>",
        SENSOR_SELECTION_SCENARIO,
    ),
    (
        "random-exchange",
        "<built-in random-exchange>",
        RANDOM_EXCHANGE_SCENARIO,
    ),
    ("location", "<built-in location>", LOCATION_SCENARIO),
    (
        "compressive",
        "<built-in compressive>",
        COMPRESSIVE_SCENARIO,
    ),
];

/// A scenario, validated as `cqnet` validates a file: every key checked,
/// the topology built. Change values with `set`, which checks them as
/// `--set` does; `to_toml` gives the file.
#[pyclass(name = "Scenario", module = "cqnet", eq)]
#[derive(Clone)]
pub struct PyScenario {
    pub scenario: Scenario,
    /// Where it came from, as errors name it.
    pub source: String,
}

/// Two scenarios are equal when their values are, wherever they came from.
impl PartialEq for PyScenario {
    fn eq(&self, other: &Self) -> bool {
        self.scenario == other.scenario
    }
}

impl PyScenario {
    fn parse(text: &str, source: &str, overrides: &[String]) -> PyResult<Self> {
        let scenario =
            Scenario::from_toml(text, source, overrides).map_err(|e| scenario_error(&e))?;
        Topology::from_scenario(&scenario, source).map_err(|e| scenario_error(&e))?;
        Ok(Self {
            scenario,
            source: source.to_string(),
        })
    }

    pub fn topology(&self) -> PyResult<Topology> {
        Topology::from_scenario(&self.scenario, &self.source).map_err(|e| scenario_error(&e))
    }

    fn table(&self) -> toml::Table {
        toml::from_str(&self.scenario.to_toml()).expect("a scenario's TOML reads back")
    }

    /// This scenario with `faults` added to its own: each a dict as a
    /// `[[faults]]` table is written (`{"kind": "kill", "actor": "node-4",
    /// "at_step": 10, "signal": "SIGKILL"}`), checked as in a file.
    pub fn with_faults(&self, faults: &Bound<'_, PyAny>) -> PyResult<Self> {
        let added = match to_toml(faults)? {
            toml::Value::Array(items) => items,
            _ => return Err(PyValueError::new_err("faults must be a list of dicts")),
        };
        let mut table = self.table();
        let all = table
            .entry("faults")
            .or_insert_with(|| toml::Value::Array(Vec::new()));
        match all {
            toml::Value::Array(existing) => existing.extend(added),
            _ => unreachable!("a validated scenario's faults are a list"),
        }
        let text = toml::to_string(&table).expect("a table serializes");
        Self::parse(&text, &self.source, &[])
    }
}

#[pymethods]
impl PyScenario {
    /// The default scenario: 9 nodes on a 3×3 grid, 225 bearing sensors,
    /// 8-bit quantization, 1000 particles, 100 steps.
    #[staticmethod]
    fn default() -> PyResult<Self> {
        Self::builtin("default")
    }

    /// A scenario cqnet carries: "default", "sensor-selection" (25 bearing
    /// sensors a cell with PCRLB-based selection), "random-exchange" (a
    /// lattice of 25 RSS nodes for the random-exchange and KL trackers),
    /// "location" (a static target located from quantized amplitudes) or
    /// "compressive" (a fusion centre hearing its sensors through a
    /// multiple-access channel).
    #[staticmethod]
    fn builtin(name: &str) -> PyResult<Self> {
        match BUILTIN.iter().find(|(n, _, _)| *n == name) {
            Some((_, source, text)) => Self::parse(text, source, &[]),
            None => Err(PyValueError::new_err(format!(
                "no built-in scenario `{name}`; there are: {}",
                BUILTIN
                    .iter()
                    .map(|(n, _, _)| *n)
                    .collect::<Vec<_>>()
                    .join(", ")
            ))),
        }
    }

    /// A scenario file, read and checked.
    #[staticmethod]
    fn from_file(path: PathBuf) -> PyResult<Self> {
        let source = path.display().to_string();
        let text = std::fs::read_to_string(&path).map_err(|e| {
            scenario_error(&fusion_graph::ScenarioError::Read {
                file: source.clone(),
                message: e.to_string(),
            })
        })?;
        Self::parse(&text, &source, &[])
    }

    /// A scenario from TOML text.
    #[staticmethod]
    #[pyo3(signature = (text, source = "<string>"))]
    fn from_toml(text: &str, source: &str) -> PyResult<Self> {
        Self::parse(text, source, &[])
    }

    /// Sets `key` (dotted, as `--set` takes it: "filter.particles") to
    /// `value` and checks the scenario again; raises `ScenarioError` with
    /// the key on a value cqnet refuses, and leaves the scenario as it
    /// was. Returns the scenario, so that calls chain.
    fn set<'py>(
        mut slf: PyRefMut<'py, Self>,
        key: &str,
        value: &Bound<'py, PyAny>,
    ) -> PyResult<PyRefMut<'py, Self>> {
        let literal = to_toml(value)?.to_string();
        let assignment = format!("{key}={literal}");
        let changed = Self::parse(&slf.scenario.to_toml(), &slf.source, &[assignment])?;
        *slf = changed;
        Ok(slf)
    }

    /// Sets several keys at once, `{"nodes.grid": [2, 1],
    /// "fusion_graph.radius": 800.0}`, and checks the scenario once they
    /// all hold: for values that are only valid together. Returns the
    /// scenario.
    fn update<'py>(
        mut slf: PyRefMut<'py, Self>,
        values: &Bound<'py, pyo3::types::PyDict>,
    ) -> PyResult<PyRefMut<'py, Self>> {
        let assignments = values
            .iter()
            .map(|(k, v)| Ok(format!("{}={}", k.extract::<String>()?, to_toml(&v)?)))
            .collect::<PyResult<Vec<String>>>()?;
        let changed = Self::parse(&slf.scenario.to_toml(), &slf.source, &assignments)?;
        *slf = changed;
        Ok(slf)
    }

    /// The value at a dotted key ("quantizer.bits"); `KeyError` if the
    /// scenario has none there.
    fn get<'py>(&self, py: Python<'py>, key: &str) -> PyResult<Bound<'py, PyAny>> {
        let table = toml::Value::Table(self.table());
        let mut at = &table;
        for part in key.split('.') {
            at = at
                .get(part)
                .ok_or_else(|| PyKeyError::new_err(key.to_string()))?;
        }
        to_python(py, at)
    }

    /// This scenario with faults added, each a dict as a `[[faults]]` table.
    #[pyo3(name = "with_faults")]
    fn py_with_faults(&self, faults: &Bound<'_, PyAny>) -> PyResult<Self> {
        self.with_faults(faults)
    }

    /// The scenario as a TOML file.
    fn to_toml(&self) -> String {
        self.scenario.to_toml()
    }

    fn copy(&self) -> Self {
        self.clone()
    }

    fn __copy__(&self) -> Self {
        self.clone()
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.clone()
    }

    #[getter]
    fn name(&self) -> String {
        self.scenario.name.clone()
    }

    #[getter]
    fn steps(&self) -> u32 {
        self.scenario.steps
    }

    #[getter]
    fn seed(&self) -> u64 {
        self.scenario.seed
    }

    /// Where the scenario came from: a file's path, or a built-in's name.
    #[getter]
    fn source(&self) -> String {
        self.source.clone()
    }

    /// The processing nodes' positions, an (N, 2) array in metres.
    fn node_positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let t = self.topology()?;
        positions(py, &t.node_positions)
    }

    /// The sensors' positions, an (S, 2) array in metres.
    fn sensor_positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let t = self.topology()?;
        positions(py, &t.sensor_positions)
    }

    /// Each sensor's processing node, an (S,) array of node indices.
    fn sensor_owners<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<u16>>> {
        Ok(PyArray1::from_vec(
            py,
            self.topology()?.sensor_owner.to_vec(),
        ))
    }

    /// The fusion graph's edges, as (node, node) pairs with the smaller first.
    fn edges(&self) -> PyResult<Vec<(u16, u16)>> {
        let t = self.topology()?;
        Ok(t.neighbours
            .iter()
            .enumerate()
            .flat_map(|(i, ns)| {
                ns.iter()
                    .filter(move |j| **j as usize > i)
                    .map(move |j| (i as u16, *j))
            })
            .collect())
    }

    /// Every sensor as the bounds see it: its observation law at its
    /// position, and its quantizer (none when sensors send raw values).
    fn sensors(&self) -> PyResult<Vec<PySensor>> {
        let models = self.scenario.models().map_err(|e| scenario_error(&e))?;
        let t = self.topology()?;
        Ok(t.sensor_positions
            .iter()
            .map(|p| PySensor::new(&self.scenario.observation, *p, models.quantizer.clone()))
            .collect())
    }

    /// The target's dynamics as the filters and bounds use them.
    fn dynamics(&self) -> PyResult<PyDynamics> {
        let models = self.scenario.models().map_err(|e| scenario_error(&e))?;
        Ok(PyDynamics {
            dynamics: models.dynamics,
        })
    }

    /// The prior covariance P₀ every filter starts from, 4×4.
    fn prior_covariance<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let models = self.scenario.models().map_err(|e| scenario_error(&e))?;
        Ok(crate::bounds_api::mat4_to_py(py, &models.prior_cov))
    }

    /// The target's true state at step 0 for this scenario's seed, [x, y, vx, vy].
    fn initial_state<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_vec(py, self.scenario.true_initial_state().as_slice().to_vec())
    }

    fn __repr__(&self) -> String {
        format!(
            "Scenario(name={:?}, steps={}, seed={}, source={:?})",
            self.scenario.name, self.scenario.steps, self.scenario.seed, self.source
        )
    }
}

fn positions<'py>(py: Python<'py>, p: &[[f64; 2]]) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let flat: Vec<f64> = p.iter().flatten().copied().collect();
    PyArray1::from_vec(py, flat).reshape([p.len(), 2])
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyScenario>()
}
