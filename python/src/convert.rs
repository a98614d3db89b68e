//! Python values to TOML values and back: what `Scenario.set`, `get` and
//! a run's `faults` pass through.

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

/// A Python bool, int, float, str, list, tuple or dict (with str keys) as
/// a TOML value; anything else is a `TypeError` naming its type.
pub fn to_toml(value: &Bound<'_, PyAny>) -> PyResult<toml::Value> {
    // bool before int: a Python bool is an int.
    if value.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(value.extract()?));
    }
    if value.is_instance_of::<PyInt>() {
        let i: i64 = value
            .extract()
            .map_err(|_| PyTypeError::new_err(format!("{value} does not fit a 64-bit integer")))?;
        return Ok(toml::Value::Integer(i));
    }
    if value.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(value.extract()?));
    }
    if value.is_instance_of::<PyString>() {
        return Ok(toml::Value::String(value.extract()?));
    }
    if value.is_instance_of::<PyList>() || value.is_instance_of::<PyTuple>() {
        let items = value
            .try_iter()?
            .map(|item| to_toml(&item?))
            .collect::<PyResult<Vec<_>>>()?;
        return Ok(toml::Value::Array(items));
    }
    if let Ok(dict) = value.cast::<PyDict>() {
        let mut table = toml::Table::new();
        for (k, v) in dict.iter() {
            let key: String = k
                .extract()
                .map_err(|_| PyTypeError::new_err(format!("a key {k} that is not a str")))?;
            table.insert(key, to_toml(&v)?);
        }
        return Ok(toml::Value::Table(table));
    }
    // NumPy scalars and other numbers: as a float if they say they are one.
    if let Ok(x) = value
        .call_method0("__float__")
        .and_then(|f| f.extract::<f64>())
    {
        return Ok(toml::Value::Float(x));
    }
    Err(PyTypeError::new_err(format!(
        "a scenario value must be a bool, int, float, str, list or dict, not {}",
        value.get_type().name()?
    )))
}

/// A TOML value as the Python value it reads as.
pub fn to_python<'py>(py: Python<'py>, value: &toml::Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match value {
        toml::Value::String(s) => s.into_pyobject(py)?.into_any(),
        toml::Value::Integer(i) => i.into_pyobject(py)?.into_any(),
        toml::Value::Float(x) => x.into_pyobject(py)?.into_any(),
        toml::Value::Boolean(b) => PyBool::new(py, *b).to_owned().into_any(),
        toml::Value::Datetime(d) => d.to_string().into_pyobject(py)?.into_any(),
        toml::Value::Array(items) => {
            let list = PyList::empty(py);
            for item in items {
                list.append(to_python(py, item)?)?;
            }
            list.into_any()
        }
        toml::Value::Table(table) => {
            let dict = PyDict::new(py);
            for (k, v) in table {
                dict.set_item(k, to_python(py, v)?)?;
            }
            dict.into_any()
        }
    })
}
