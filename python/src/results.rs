//! A run's result files as columns: each numeric column parsed once, into
//! a `Vec` that becomes a NumPy array without a copy; text columns as
//! lists of str. `ticks.csv` and `links.csv` have their columns' types
//! here; a column this version does not know is read as numbers if every
//! value is one, else as text.

use std::path::Path;

use numpy::PyArray1;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::CqnetError;

/// What a column holds.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    /// Floats; an empty field is NaN (a bound a node could not give).
    Float,
    /// Non-negative integers (steps, counts, bytes).
    Count,
    Text,
}

fn kind_of(column: &str) -> Option<Kind> {
    Some(match column {
        "node" | "active" | "design" | "from" | "to" | "kind" => Kind::Text,
        "step" | "rounds" | "live_neighbours" | "observations" | "deadline_missed"
        | "short_rounds" => Kind::Count,
        c if c.ends_with("_messages") || c.ends_with("_bytes") => Kind::Count,
        "true_x" | "true_y" | "est_x" | "est_y" | "error" | "bound" | "local_bound"
        | "aux_bound" | "spread" | "disagreement" => Kind::Float,
        _ => return None,
    })
}

/// Reads a CSV file of cqnet's into a dict of column name to array or
/// list, in file order.
#[pyfunction]
fn read_columns<'py>(py: Python<'py>, path: std::path::PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let text = std::fs::read_to_string(&path)
        .map_err(|e| CqnetError::new_err(format!("{}: cannot read: {e}", path.display())))?;
    let columns = py.detach(|| parse(&text, &path))?;
    let dict = PyDict::new(py);
    for (name, column) in columns {
        match column {
            Column::Float(v) => dict.set_item(name, PyArray1::from_vec(py, v))?,
            Column::Count(v) => dict.set_item(name, PyArray1::from_vec(py, v))?,
            Column::Text(v) => dict.set_item(name, v)?,
        }
    }
    Ok(dict)
}

enum Column {
    Float(Vec<f64>),
    Count(Vec<u64>),
    Text(Vec<String>),
}

fn parse(text: &str, path: &Path) -> PyResult<Vec<(String, Column)>> {
    let mut lines = text.lines();
    let first = lines
        .next()
        .ok_or_else(|| CqnetError::new_err(format!("{}: empty file", path.display())))?;
    let header = fields(first);
    let rows: Vec<Vec<String>> = lines.filter(|l| !l.is_empty()).map(fields).collect();
    let bad = |row: usize, what: String| {
        CqnetError::new_err(format!("{}: line {}: {what}", path.display(), row + 2))
    };
    for (i, r) in rows.iter().enumerate() {
        if r.len() != header.len() {
            return Err(bad(
                i,
                format!("{} fields, the header has {}", r.len(), header.len()),
            ));
        }
    }
    header
        .iter()
        .enumerate()
        .map(|(c, name)| {
            let kind = kind_of(name).unwrap_or_else(|| {
                let numeric = rows
                    .iter()
                    .all(|r| r[c].is_empty() || r[c].parse::<f64>().is_ok());
                if numeric {
                    Kind::Float
                } else {
                    Kind::Text
                }
            });
            let column = match kind {
                Kind::Text => Column::Text(rows.iter().map(|r| r[c].clone()).collect()),
                Kind::Float => Column::Float(
                    rows.iter()
                        .enumerate()
                        .map(|(i, r)| match r[c].as_str() {
                            "" => Ok(f64::NAN),
                            v => v
                                .parse()
                                .map_err(|_| bad(i, format!("`{name}` = {v:?} is not a number"))),
                        })
                        .collect::<PyResult<_>>()?,
                ),
                Kind::Count => Column::Count(
                    rows.iter()
                        .enumerate()
                        .map(|(i, r)| {
                            r[c].parse().map_err(|_| {
                                bad(i, format!("`{name}` = {:?} is not a count", r[c]))
                            })
                        })
                        .collect::<PyResult<_>>()?,
                ),
            };
            Ok((name.to_string(), column))
        })
        .collect()
}

/// A line's fields: split at commas outside double quotes, a quoted
/// field's `""` read as one quote (what the experiments' column names
/// need; ticks and links have no quotes).
fn fields(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut field = String::new();
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                field.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => out.push(std::mem::take(&mut field)),
            (c, _) => field.push(c),
        }
    }
    out.push(field);
    out
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_columns, m)?)
}
