//! The `bounds` crate for Python: sensors, quantizers and dynamics as
//! classes, the Fisher information and the conditional bound's recursion
//! as functions over NumPy arrays, vectorized over particles. Each
//! docstring states its equation; `docs/equations.md` derives them.

use bounds::pcrlb::{dynamics_terms as terms_over, information_update, observation_information};
use bounds::selection::{greedy, selection_cost as cost_of, Candidate};
use bounds::{Dynamics, Mat4, Measurement, ObservationModel, Quantizer, State};
use fusion_graph::scenario::ObservationConfig;
use numpy::ndarray::ArrayViewD;
use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyReadonlyArray1, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::{to_python, to_toml};

/// Two 4×4 matrices, as (B11, B12) or (L(k+1|k), L(k+1)).
type MatrixPair<'py> = (
    Bound<'py, numpy::PyArray2<f64>>,
    Bound<'py, numpy::PyArray2<f64>>,
);

fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// A 4×4 matrix as a NumPy array.
pub fn mat4_to_py<'py>(py: Python<'py>, m: &Mat4) -> Bound<'py, numpy::PyArray2<f64>> {
    // nalgebra is column-major; NumPy's default order is row-major.
    let rows: Vec<f64> = (0..4)
        .flat_map(|i| (0..4).map(move |j| m[(i, j)]))
        .collect();
    PyArray1::from_vec(py, rows)
        .reshape([4, 4])
        .expect("16 values make a 4×4 matrix")
}

/// A (4, 4) array as a matrix.
fn mat4_from(a: &PyReadonlyArrayDyn<'_, f64>, what: &str) -> PyResult<Mat4> {
    let v = a.as_array();
    if v.shape() != [4, 4] {
        return Err(value_error(format!(
            "{what} must be 4×4, got shape {:?}",
            v.shape()
        )));
    }
    Ok(Mat4::from_fn(|i, j| v[[i, j]]))
}

/// States from a (4,) or (n, 4) array; whether it was one state.
fn states_from(a: &ArrayViewD<'_, f64>, what: &str) -> PyResult<(Vec<State>, bool)> {
    match a.shape() {
        [4] => Ok((vec![State::from_fn(|i, _| a[[i]])], true)),
        [n, 4] => Ok((
            (0..*n).map(|k| State::from_fn(|i, _| a[[k, i]])).collect(),
            false,
        )),
        s => Err(value_error(format!(
            "{what} must have shape (4,) or (n, 4) [x, y, vx, vy], got {s:?}"
        ))),
    }
}

/// The weights of `n` particles: as given, or uniform.
fn weights_for(n: usize, weights: Option<PyReadonlyArray1<'_, f64>>) -> PyResult<Vec<f64>> {
    match weights {
        None => Ok(vec![1.0 / n.max(1) as f64; n]),
        Some(w) => {
            let w = w.as_array().to_vec();
            if w.len() != n {
                return Err(value_error(format!(
                    "{n} particles but {} weights",
                    w.len()
                )));
            }
            if w.iter().any(|x| !x.is_finite() || *x < 0.0) {
                return Err(value_error("weights must be finite and non-negative"));
            }
            Ok(w)
        }
    }
}

/// Matrices as a (4, 4) array, or an (n, 4, 4) one.
fn mats_to_py<'py>(
    py: Python<'py>,
    ms: &[Mat4],
    one: bool,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let flat: Vec<f64> = ms
        .iter()
        .flat_map(|m| (0..4).flat_map(move |i| (0..4).map(move |j| m[(i, j)])))
        .collect();
    let shape: Vec<usize> = if one {
        vec![4, 4]
    } else {
        vec![ms.len(), 4, 4]
    };
    PyArray1::from_vec(py, flat).reshape(shape)
}

/// A sensor's quantizer: `2^bits` cells over `[lo, hi]`, the outer two
/// open to ±∞, or (wrapped) a circle of `2^bits` equal cells, for
/// bearings; or cells between given thresholds.
#[pyclass(name = "Quantizer", module = "cqnet.bounds", frozen)]
#[derive(Clone)]
pub struct PyQuantizer {
    pub quantizer: Quantizer,
}

impl PyQuantizer {
    /// The indices as cells, each checked to be one of this quantizer's.
    fn cell_indices(&self, index: &PyReadonlyArrayDyn<'_, u32>) -> PyResult<Vec<u32>> {
        let cells: Vec<u32> = index.as_array().iter().copied().collect();
        match cells
            .iter()
            .find(|i| **i as usize >= self.quantizer.cells())
        {
            Some(bad) => Err(value_error(format!(
                "cell {bad} of a quantizer of {} cells",
                self.quantizer.cells()
            ))),
            None => Ok(cells),
        }
    }
}

/// The shape that arrays of these shapes broadcast to, as NumPy's rule says.
fn broadcast_shape(shapes: &[&[usize]]) -> PyResult<Vec<usize>> {
    let n = shapes.iter().map(|s| s.len()).max().unwrap_or(0);
    (0..n)
        .map(|k| {
            let dims = shapes.iter().map(|s| {
                if k + s.len() >= n {
                    s[k + s.len() - n]
                } else {
                    1
                }
            });
            dims.clone().try_fold(1usize, |acc, d| match (acc, d) {
                (a, 1) => Ok(a),
                (1, d) => Ok(d),
                (a, d) if a == d => Ok(a),
                _ => Err(value_error(format!("shapes {shapes:?} do not broadcast"))),
            })
        })
        .collect()
}

#[pymethods]
impl PyQuantizer {
    #[staticmethod]
    fn uniform(bits: u8, lo: f64, hi: f64) -> PyResult<Self> {
        Quantizer::uniform(bits, lo, hi)
            .map(|quantizer| Self { quantizer })
            .map_err(value_error)
    }

    /// Cells of equal width around the circle [lo, hi): bearings.
    #[staticmethod]
    fn uniform_wrapped(bits: u8, lo: f64, hi: f64) -> PyResult<Self> {
        Quantizer::uniform_wrapped(bits, lo, hi)
            .map(|quantizer| Self { quantizer })
            .map_err(value_error)
    }

    /// Cells between strictly increasing finite thresholds τ_1 < … < τ_{L−1}.
    #[staticmethod]
    fn from_thresholds(thresholds: Vec<f64>) -> PyResult<Self> {
        Quantizer::from_thresholds(&thresholds)
            .map(|quantizer| Self { quantizer })
            .map_err(value_error)
    }

    #[getter]
    fn bits(&self) -> u8 {
        self.quantizer.bits()
    }

    #[getter]
    fn cells(&self) -> usize {
        self.quantizer.cells()
    }

    /// The cell index of each value.
    fn encode<'py>(
        &self,
        py: Python<'py>,
        z: PyReadonlyArrayDyn<'py, f64>,
    ) -> Bound<'py, PyArrayDyn<u32>> {
        let shape = z.as_array().shape().to_vec();
        let cells: Vec<u32> = z
            .as_array()
            .iter()
            .map(|v| self.quantizer.encode(*v))
            .collect();
        PyArray1::from_vec(py, cells)
            .reshape(shape)
            .expect("as many cells as values")
    }

    /// A value inside each cell: its midpoint, or the finite edge of an
    /// unbounded outer cell.
    fn representative<'py>(
        &self,
        py: Python<'py>,
        index: PyReadonlyArrayDyn<'py, u32>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let cells = self.cell_indices(&index)?;
        let values: Vec<f64> = cells
            .iter()
            .map(|i| self.quantizer.representative(*i))
            .collect();
        PyArray1::from_vec(py, values).reshape(index.as_array().shape().to_vec())
    }

    /// ln h_i = ln P(Y = i) for Z ~ N(mean, variance), elementwise over
    /// arrays that broadcast as NumPy's do: the log-likelihood of a
    /// quantized observation the particle filters weigh with (a wrapped
    /// quantizer sums the cell's copies a period apart). Finite far into
    /// the tails.
    fn ln_probability<'py>(
        &self,
        py: Python<'py>,
        index: PyReadonlyArrayDyn<'py, u32>,
        mean: PyReadonlyArrayDyn<'py, f64>,
        variance: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        self.cell_indices(&index)?;
        let (i, m, v) = (index.as_array(), mean.as_array(), variance.as_array());
        let shape = broadcast_shape(&[i.shape(), m.shape(), v.shape()])?;
        let (i, m, v) = (
            i.broadcast(shape.clone()).expect("checked"),
            m.broadcast(shape.clone()).expect("checked"),
            v.broadcast(shape.clone()).expect("checked"),
        );
        if v.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
            return Err(value_error("variance must be finite and > 0"));
        }
        let values: Vec<f64> = i
            .iter()
            .zip(m.iter())
            .zip(v.iter())
            .map(|((i, m), v)| self.quantizer.ln_probability(*i, *m, *v))
            .collect();
        PyArray1::from_vec(py, values).reshape(shape)
    }

    /// The Fisher information of one quantized observation of a scalar
    /// Z ~ N(mean, σ²) about its mean, at each mean:
    /// Σ_i (φ(a_i) − φ(b_i))² / (σ² h_i), with a_i, b_i the cell's edges in
    /// standard units and h_i its probability. Exact (every cell summed).
    fn fisher_information<'py>(
        &self,
        py: Python<'py>,
        mean: PyReadonlyArrayDyn<'py, f64>,
        sigma: f64,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        if !(sigma.is_finite() && sigma > 0.0) {
            return Err(value_error(format!(
                "sigma must be finite and > 0, got {sigma}"
            )));
        }
        let shape = mean.as_array().shape().to_vec();
        let values: Vec<f64> = mean
            .as_array()
            .iter()
            .map(|m| {
                self.quantizer
                    .fisher_scalars_all_cells(*m, sigma * sigma)
                    .gg
            })
            .collect();
        PyArray1::from_vec(py, values).reshape(shape)
    }

    fn __repr__(&self) -> String {
        format!(
            "Quantizer(bits={}, cells={})",
            self.quantizer.bits(),
            self.quantizer.cells()
        )
    }
}

/// A sensor as the bounds see it: an observation law at a position, and
/// a quantizer (None: it sends the raw value).
///
/// `law` is a dict as a scenario's `[observation]` table writes it:
/// `{"kind": "bearing", "sigma_theta": 0.05, "d0": 10.0}`,
/// `{"kind": "rss", "p0": .., "zeta": .., "d0": .., "sigma": ..}`,
/// `{"kind": "amplitude", "p0": .., "alpha": .., "exponent": .., "sigma": ..}`
/// or `{"kind": "linear", "h": [..4], "r": ..}`.
#[pyclass(name = "Sensor", module = "cqnet.bounds", frozen)]
#[derive(Clone)]
pub struct PySensor {
    model: ObservationModel,
    /// The law's table, as given.
    law: toml::Table,
    quantizer: Option<Quantizer>,
}

impl PySensor {
    pub fn new(law: &ObservationConfig, position: [f64; 2], quantizer: Option<Quantizer>) -> Self {
        Self {
            model: law.law().at(position),
            law: law.table().clone(),
            quantizer,
        }
    }

    fn measurement(&self) -> Measurement<'_> {
        match &self.quantizer {
            Some(q) => Measurement::Quantized(q),
            None => Measurement::Raw,
        }
    }
}

#[pymethods]
impl PySensor {
    #[new]
    #[pyo3(signature = (law, position = (0.0, 0.0), quantizer = None))]
    fn py_new(
        law: &Bound<'_, PyAny>,
        position: (f64, f64),
        quantizer: Option<PyRef<'_, PyQuantizer>>,
    ) -> PyResult<Self> {
        let toml::Value::Table(table) = to_toml(law)? else {
            return Err(value_error("law: expected a dict with a \"kind\""));
        };
        let law = ObservationConfig::read(table, crate::vocabulary())
            .map_err(|e| value_error(format!("law: {e}")))?;
        Ok(Self::new(
            &law,
            [position.0, position.1],
            quantizer.map(|q| q.quantizer.clone()),
        ))
    }

    #[getter]
    fn position(&self) -> (f64, f64) {
        (self.model.sensor[0], self.model.sensor[1])
    }

    #[getter]
    fn law<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_python(py, &toml::Value::Table(self.law.clone()))
    }

    #[getter]
    fn quantizer(&self) -> Option<PyQuantizer> {
        self.quantizer
            .clone()
            .map(|quantizer| PyQuantizer { quantizer })
    }

    /// The expected Fisher information of one observation about the state
    /// at each state: J_Y(x) = Σ_i ∇h_i ∇h_iᵀ / h_i quantized, or
    /// J_Z(x) = ∇g∇gᵀ/R + ∇R∇Rᵀ/(2R²) raw. States (4,) give (4, 4); (n, 4)
    /// give (n, 4, 4).
    fn information<'py>(
        &self,
        py: Python<'py>,
        states: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let (states, one) = states_from(&states.as_array(), "states")?;
        let m = self.measurement();
        let js: Vec<Mat4> = py.detach(|| {
            states
                .iter()
                .map(|x| bounds::expected_information(&self.model, m, x))
                .collect()
        });
        mats_to_py(py, &js, one)
    }

    /// The observation's mean g(x) and variance R(x) at each state, two
    /// arrays of the states' leading shape.
    fn mean_and_variance<'py>(
        &self,
        py: Python<'py>,
        states: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let (states, one) = states_from(&states.as_array(), "states")?;
        let (g, r): (Vec<f64>, Vec<f64>) = states
            .iter()
            .map(|x| self.model.mean_and_variance(x))
            .unzip();
        if one {
            Ok((
                g[0].into_pyobject(py)?.into_any(),
                r[0].into_pyobject(py)?.into_any(),
            ))
        } else {
            Ok((
                PyArray1::from_vec(py, g).into_any(),
                PyArray1::from_vec(py, r).into_any(),
            ))
        }
    }

    fn __repr__(&self) -> String {
        format!(
            "Sensor(law={:?}, position=({}, {}), quantizer={})",
            self.model.law,
            self.model.sensor[0],
            self.model.sensor[1],
            self.quantizer
                .as_ref()
                .map_or("None".to_string(), |q| format!("{} bits", q.bits()))
        )
    }
}

/// The target's motion: the coordinated turn x(k) = F(Ω(x)) x(k−1) + ξ,
/// Ω(x) = −a_m / max(‖v‖, v_min), ξ ~ N(0, Q); with `maneuver_accel = 0`
/// the constant-velocity model. `process_noise` is "continuous"
/// (σ_v²[[T³/3, T²/2], [T²/2, T]] per axis) or "discrete".
#[pyclass(name = "Dynamics", module = "cqnet.bounds", frozen)]
#[derive(Clone)]
pub struct PyDynamics {
    pub dynamics: Dynamics,
}

#[pymethods]
impl PyDynamics {
    #[new]
    #[pyo3(signature = (period, sigma_v, maneuver_accel = 0.0, min_speed = 1.0, process_noise = "continuous"))]
    fn py_new(
        period: f64,
        sigma_v: f64,
        maneuver_accel: f64,
        min_speed: f64,
        process_noise: &str,
    ) -> PyResult<Self> {
        let process_noise = match process_noise {
            "continuous" => bounds::ProcessNoise::Continuous,
            "discrete" => bounds::ProcessNoise::Discrete,
            other => {
                return Err(value_error(format!(
                    "process_noise must be \"continuous\" or \"discrete\", got {other:?}"
                )))
            }
        };
        let dynamics = Dynamics::new(bounds::CoordinatedTurn {
            period,
            maneuver_accel,
            min_speed,
            sigma_v,
            process_noise,
        })
        .map_err(|e| {
            value_error(format!(
                "`{}` must be {}, got {}",
                e.parameter, e.expected, e.value
            ))
        })?;
        Ok(Self { dynamics })
    }

    /// Any motion model the package knows, by its table as a scenario's
    /// `[dynamics]` gives it: `{"kind": "coordinated_turn", "period": 1.0,
    /// "maneuver_accel": 0.1, "sigma_v": 0.05}` (a table without `kind` is
    /// the coordinated turn). `motion_models()` lists the kinds.
    #[staticmethod]
    fn of(model: &Bound<'_, PyAny>) -> PyResult<Self> {
        let toml::Value::Table(table) = to_toml(model)? else {
            return Err(value_error("model: expected a dict"));
        };
        let (_, dynamics) =
            fusion_graph::scenario::DynamicsConfig::read(table, crate::vocabulary())
                .map_err(|e| value_error(format!("model: {e}")))?;
        Ok(Self { dynamics })
    }

    /// Q, 4×4.
    #[getter]
    fn q<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray2<f64>> {
        mat4_to_py(py, self.dynamics.q())
    }

    /// Q⁻¹, 4×4.
    #[getter]
    fn q_inv<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray2<f64>> {
        mat4_to_py(py, self.dynamics.q_inv())
    }

    /// The noiseless transition f(x) of each state.
    fn transition<'py>(
        &self,
        py: Python<'py>,
        states: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let shape = states.as_array().shape().to_vec();
        let (states, _) = states_from(&states.as_array(), "states")?;
        let flat: Vec<f64> = states
            .iter()
            .flat_map(|x| {
                self.dynamics
                    .transition(x)
                    .iter()
                    .copied()
                    .collect::<Vec<_>>()
            })
            .collect();
        PyArray1::from_vec(py, flat).reshape(shape)
    }

    /// The Jacobian F̃(x) = ∂f/∂x of each state: (4, 4) or (n, 4, 4).
    fn jacobian<'py>(
        &self,
        py: Python<'py>,
        states: PyReadonlyArrayDyn<'py, f64>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let (states, one) = states_from(&states.as_array(), "states")?;
        let js: Vec<Mat4> = states.iter().map(|x| self.dynamics.jacobian(x)).collect();
        mats_to_py(py, &js, one)
    }

    fn __repr__(&self) -> String {
        format!("Dynamics({:?})", self.dynamics.model)
    }
}

/// The expected observation information of the sensors over a weighted
/// particle cloud: Σ_j w_j Σ_s J_s(x_j), 4×4 (the conditional bound's
/// ΔL over the predicted particles). Uniform weights when none are given.
#[pyfunction]
#[pyo3(signature = (sensors, particles, weights = None))]
fn expected_information<'py>(
    py: Python<'py>,
    sensors: Vec<PyRef<'py, PySensor>>,
    particles: PyReadonlyArrayDyn<'py, f64>,
    weights: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
    let (particles, _) = states_from(&particles.as_array(), "particles")?;
    let weights = weights_for(particles.len(), weights)?;
    let terms: Vec<bounds::SensorTerm<'_>> = sensors
        .iter()
        .map(|s| bounds::SensorTerm {
            model: &s.model,
            measurement: s.measurement(),
        })
        .collect();
    let j = py
        .detach(|| observation_information(&terms, &particles, &weights))
        .map_err(value_error)?;
    Ok(mat4_to_py(py, &j))
}

/// The dynamics terms over the posterior particles at k:
/// B11 = E[F̃ᵀ Q⁻¹ F̃] and B12 = −E[F̃ᵀ] Q⁻¹ (B22 = Q⁻¹, B21 = B12ᵀ).
/// Returns (B11, B12).
#[pyfunction]
#[pyo3(signature = (dynamics, particles, weights = None))]
fn dynamics_terms<'py>(
    py: Python<'py>,
    dynamics: &PyDynamics,
    particles: PyReadonlyArrayDyn<'py, f64>,
    weights: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<MatrixPair<'py>> {
    let (particles, _) = states_from(&particles.as_array(), "particles")?;
    let weights = weights_for(particles.len(), weights)?;
    let t = terms_over(&dynamics.dynamics, &particles, &weights).map_err(value_error)?;
    Ok((mat4_to_py(py, &t.b11), mat4_to_py(py, &t.b12)))
}

/// One step of the conditional PCRLB's recursion, from the posterior
/// particles at k:
/// L(k+1|k) = Q⁻¹ − B21 (L(k) + ΔL_late + B11)⁻¹ B12 and
/// L(k+1) = L(k+1|k) + ΔL(k+1), with ΔL(k+1) the observation information
/// over the predicted particles (`expected_information`). Returns
/// (L(k+1|k), L(k+1)); the position bound is `position_bound(L(k+1))`.
#[pyfunction]
#[pyo3(signature = (information, dynamics, particles, observation_information, weights = None, late = None))]
fn conditional_bound_step<'py>(
    py: Python<'py>,
    information: PyReadonlyArrayDyn<'py, f64>,
    dynamics: &PyDynamics,
    particles: PyReadonlyArrayDyn<'py, f64>,
    observation_information: PyReadonlyArrayDyn<'py, f64>,
    weights: Option<PyReadonlyArray1<'py, f64>>,
    late: Option<PyReadonlyArrayDyn<'py, f64>>,
) -> PyResult<MatrixPair<'py>> {
    let l = mat4_from(&information, "information")?;
    let obs = mat4_from(&observation_information, "observation_information")?;
    let late = late
        .map(|m| mat4_from(&m, "late"))
        .transpose()?
        .unwrap_or_else(Mat4::zeros);
    let (particles, _) = states_from(&particles.as_array(), "particles")?;
    let weights = weights_for(particles.len(), weights)?;
    let d = &dynamics.dynamics;
    let terms = terms_over(d, &particles, &weights).map_err(value_error)?;
    let step = information_update(&(l + late), &terms, d.q_inv(), &obs).map_err(value_error)?;
    Ok((
        mat4_to_py(py, &step.predicted),
        mat4_to_py(py, &step.updated),
    ))
}

/// The position bound in metres, sqrt(tr[L⁻¹]_pos): directly comparable
/// with an RMSE. None if L is not positive definite.
#[pyfunction]
fn position_bound(information: PyReadonlyArrayDyn<'_, f64>) -> PyResult<Option<f64>> {
    Ok(bounds::position_bound(&mat4_from(
        &information,
        "information",
    )?))
}

/// The selection cost of adding `candidate` to the chosen sensors:
/// C(A ∪ {s}) = tr_pos[(L(k+1|k) + Σ_{a∈A} J̄_a + J̄_s)⁻¹], with `chosen`
/// the sum Σ_{a∈A} J̄_a. None if the sum is not positive definite.
#[pyfunction]
fn selection_cost(
    predicted: PyReadonlyArrayDyn<'_, f64>,
    chosen: PyReadonlyArrayDyn<'_, f64>,
    candidate: PyReadonlyArrayDyn<'_, f64>,
) -> PyResult<Option<f64>> {
    Ok(cost_of(
        &mat4_from(&predicted, "predicted")?,
        &mat4_from(&chosen, "chosen")?,
        &mat4_from(&candidate, "candidate")?,
    ))
}

/// Greedy sensor selection: one sensor per iteration, the candidate of
/// least `selection_cost` given those already chosen (ties to the smaller
/// node, then sensor), until `n_max` are chosen or every node has
/// `per_node_cap`. `candidates` are (node, sensor, J̄ 4×4) triples.
/// Returns the chosen (node, sensor) pairs in the order chosen.
#[pyfunction]
fn greedy_selection(
    predicted: PyReadonlyArrayDyn<'_, f64>,
    candidates: Vec<(u16, u16, PyReadonlyArrayDyn<'_, f64>)>,
    per_node_cap: usize,
    n_max: usize,
) -> PyResult<Vec<(u16, u16)>> {
    let candidates = candidates
        .iter()
        .map(|(node, sensor, j)| {
            Ok(Candidate {
                node: *node,
                sensor: *sensor,
                information: mat4_from(j, "a candidate's information")?,
            })
        })
        .collect::<PyResult<Vec<_>>>()?;
    Ok(greedy(
        &mat4_from(&predicted, "predicted")?,
        &candidates,
        per_node_cap,
        n_max,
    ))
}

/// The Fisher information of one quantized observation of a scalar
/// Z ~ N(mean, σ²) about its mean, Σ_i (φ(a_i) − φ(b_i))² / (σ² h_i), for
/// cells between the thresholds; vectorized over `mean`. It tends to the
/// unquantized 1/σ² as the cells narrow.
#[pyfunction]
fn quantized_fisher_information<'py>(
    py: Python<'py>,
    thresholds: Vec<f64>,
    mean: PyReadonlyArrayDyn<'py, f64>,
    sigma: f64,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    PyQuantizer::from_thresholds(thresholds)?.fisher_information(py, mean, sigma)
}

/// The observation laws a `Sensor`'s `law` may name by `kind`.
#[pyfunction]
fn observation_laws() -> Vec<&'static str> {
    bounds::SensorLaw::KINDS
        .into_iter()
        .chain(crate::vocabulary().law_names())
        .collect()
}

/// The motion models `Dynamics.of` may name by `kind`.
#[pyfunction]
fn motion_models() -> Vec<&'static str> {
    [bounds::CoordinatedTurn::KIND]
        .into_iter()
        .chain(crate::vocabulary().motion_names())
        .collect()
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(observation_laws, m)?)?;
    m.add_function(wrap_pyfunction!(motion_models, m)?)?;
    m.add_class::<PyQuantizer>()?;
    m.add_class::<PySensor>()?;
    m.add_class::<PyDynamics>()?;
    m.add_function(wrap_pyfunction!(expected_information, m)?)?;
    m.add_function(wrap_pyfunction!(dynamics_terms, m)?)?;
    m.add_function(wrap_pyfunction!(conditional_bound_step, m)?)?;
    m.add_function(wrap_pyfunction!(position_bound, m)?)?;
    m.add_function(wrap_pyfunction!(selection_cost, m)?)?;
    m.add_function(wrap_pyfunction!(greedy_selection, m)?)?;
    m.add_function(wrap_pyfunction!(quantized_fisher_information, m)?)?;
    Ok(())
}
