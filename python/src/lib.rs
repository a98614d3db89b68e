//! `cqnet._cqnet`: the native half of cqnet's Python package. Each file
//! wraps one part of cqnet for Python; the package's Python half
//! (`python/cqnet/`) turns what these return into NumPy arrays, DataFrames,
//! progress bars and plots.
//!
//! Long work (a `sim`, a `run`, an experiment) runs on a thread of its own
//! as a [`jobs::Job`]: the Python side waits on it with the GIL released,
//! a little at a time, so that it can draw progress and hear Ctrl-C.

mod bounds_api;
mod convert;
mod experiments_api;
mod jobs;
mod results;
mod scenario;

use pyo3::prelude::*;

pyo3::create_exception!(
    cqnet,
    CqnetError,
    pyo3::exceptions::PyException,
    "An error from cqnet: a run that failed, a file that could not be read."
);
pyo3::create_exception!(
    cqnet,
    ScenarioError,
    CqnetError,
    "A scenario value cqnet refuses. `key` names it (`filter.particles`), \
     or is None when the error is not about one key."
);

/// An error of cqnet's as the Python exception it is: a scenario's with
/// its key, any other as `CqnetError` with its whole chain of causes.
pub(crate) fn to_py_err(e: &anyhow::Error) -> PyErr {
    match e.downcast_ref::<fusion_graph::ScenarioError>() {
        Some(s) => scenario_error(s),
        None => CqnetError::new_err(format!("{e:#}")),
    }
}

pub(crate) fn scenario_error(e: &fusion_graph::ScenarioError) -> PyErr {
    let err = ScenarioError::new_err(e.to_string());
    Python::attach(|py| {
        // Setting an attribute on a fresh exception object cannot fail
        // short of memory; the message still says the key if it does.
        let _ = err.value(py).setattr("key", e.key());
    });
    err
}

/// The parts the package's scenarios and bounds are read in: cqnet's own
/// (the laws `bearing`, `rss`, `amplitude`, `linear`, and the motion model
/// `coordinated_turn`).
pub(crate) fn vocabulary() -> fusion_graph::vocabulary::Vocabulary {
    fusion_graph::vocabulary::Vocabulary::BUILT_IN
}

#[pymodule]
fn _cqnet(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("CqnetError", m.py().get_type::<CqnetError>())?;
    m.add("ScenarioError", m.py().get_type::<ScenarioError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    scenario::register(m)?;
    jobs::register(m)?;
    results::register(m)?;
    bounds_api::register(m)?;
    experiments_api::register(m)?;
    m.add_function(wrap_pyfunction!(cli_main, m)?)?;
    m.add_function(wrap_pyfunction!(set_actor_program, m)?)?;
    m.add_function(wrap_pyfunction!(leftover_shared_memory, m)?)?;
    Ok(())
}

/// The files of a run's shared memory that still exist: none once the
/// run has ended, whether it finished, failed or was interrupted.
#[pyfunction]
fn leftover_shared_memory(run_id: &str) -> PyResult<Vec<std::path::PathBuf>> {
    let run = fusion_graph::RunId::new(run_id).map_err(|e| to_py_err(&e.into()))?;
    Ok(transport::iceoryx::run_resources(&run))
}

/// Runs the `cqnet` command with these arguments (the first is the
/// program's name) and returns its exit status: the package's `cqnet`
/// command, and how each actor of a `run` started from Python runs.
#[pyfunction]
fn cli_main(py: Python<'_>, args: Vec<String>) -> i32 {
    let code = py.detach(|| cqnet::App::new().main_with(args));
    if code == std::process::ExitCode::SUCCESS {
        0
    } else {
        1
    }
}

/// Says how this process starts a run's actors: `program` with
/// `leading_args` before `actor …`. This process's executable is Python's,
/// not cqnet's, so the package says it before its first run; the first
/// call holds for the process.
#[pyfunction]
fn set_actor_program(program: std::path::PathBuf, leading_args: Vec<String>) {
    launch::supervisor::ActorProgram {
        program,
        leading_args: leading_args.into_iter().map(Into::into).collect(),
    }
    .set_for_this_process();
}
