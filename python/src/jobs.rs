//! Long work on a thread of its own: `sim`, `run` and experiments, each a
//! [`Job`] the Python side waits on a little at a time with the GIL
//! released, reading its progress between waits and cancelling it on
//! Ctrl-C. A cancelled job stops as the command line's Ctrl-C stops it:
//! a run's processes stopped and reaped and its shared memory removed, a
//! `sim` between two steps, the results so far written.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

use launch::network::RunProgress;
use launch::progress::step_message;
use launch::results::{write_atomically, ResultsWriter};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;

use crate::scenario::PyScenario;
use crate::to_py_err;

/// How far a job has come: `done` of `total` `unit`, and a line of detail.
#[derive(Clone, Default)]
struct Progress {
    done: u64,
    total: u64,
    unit: &'static str,
    message: String,
}

/// What the job's thread and its Python handle share.
#[derive(Default)]
pub(crate) struct Shared {
    progress: Mutex<Progress>,
    /// The job's outcome once it has one: JSON text, or the error.
    outcome: Mutex<Option<anyhow::Result<String>>>,
    finished: Condvar,
    pub(crate) stop: Arc<AtomicBool>,
}

impl Shared {
    fn set(&self, done: u64, total: u64, unit: &'static str, message: String) {
        *self.progress.lock().expect("progress lock") = Progress {
            done,
            total,
            unit,
            message,
        };
    }

    /// Experiments report runs done of runs in all.
    pub(crate) fn set_runs(&self, done: u64, total: u64, message: String) {
        self.set(done, total, "runs", message);
    }

    fn finish(&self, outcome: anyhow::Result<String>) {
        *self.outcome.lock().expect("outcome lock") = Some(outcome);
        self.finished.notify_all();
    }
}

/// A `sim`, a `run` or an experiment going on in the background.
#[pyclass(module = "cqnet._cqnet")]
pub struct Job {
    shared: Arc<Shared>,
    thread: Mutex<Option<std::thread::JoinHandle<()>>>,
    out: PathBuf,
}

impl Job {
    /// Starts `work` on its own thread; whatever it returns, or a panic,
    /// becomes the job's outcome.
    fn start(
        name: &str,
        out: PathBuf,
        work: impl FnOnce(&Arc<Shared>) -> anyhow::Result<String> + Send + 'static,
    ) -> PyResult<Self> {
        let shared = Arc::new(Shared::default());
        let theirs = shared.clone();
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                let outcome =
                    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| work(&theirs)))
                        .unwrap_or_else(|panic| {
                            let what = panic
                                .downcast_ref::<String>()
                                .cloned()
                                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                                .unwrap_or_default();
                            Err(anyhow::anyhow!("cqnet panicked: {what}"))
                        });
                theirs.finish(outcome);
            })
            .map_err(|e| PyRuntimeError::new_err(format!("could not start a thread: {e}")))?;
        Ok(Self {
            shared,
            thread: Mutex::new(Some(thread)),
            out,
        })
    }
}

#[pymethods]
impl Job {
    /// Waits up to `timeout` seconds, without the GIL; True once finished.
    fn wait(&self, py: Python<'_>, timeout: f64) -> bool {
        let shared = self.shared.clone();
        let timeout = Duration::from_secs_f64(timeout.clamp(0.0, 3600.0));
        let finished = py.detach(move || {
            let outcome = shared.outcome.lock().expect("outcome lock");
            let (outcome, _) = shared
                .finished
                .wait_timeout_while(outcome, timeout, |o| o.is_none())
                .expect("outcome lock");
            outcome.is_some()
        });
        if finished {
            if let Some(t) = self.thread.lock().expect("thread lock").take() {
                let _ = py.detach(move || t.join());
            }
        }
        finished
    }

    /// (done, total, unit, message): how far the job has come.
    fn progress(&self) -> (u64, u64, &'static str, String) {
        let p = self.shared.progress.lock().expect("progress lock").clone();
        (p.done, p.total, p.unit, p.message)
    }

    /// Asks the job to stop as Ctrl-C would; `wait` says when it has.
    fn cancel(&self) {
        self.shared.stop.store(true, Ordering::Release);
    }

    /// The outcome as JSON text, or the job's error raised; a job not yet
    /// finished is a `RuntimeError`.
    fn result(&self) -> PyResult<String> {
        match &*self.shared.outcome.lock().expect("outcome lock") {
            None => Err(PyRuntimeError::new_err("the job has not finished")),
            Some(Ok(json)) => Ok(json.clone()),
            Some(Err(e)) => Err(to_py_err(e)),
        }
    }

    /// The folder the job writes its results into.
    #[getter]
    fn out(&self) -> PathBuf {
        self.out.clone()
    }
}

/// Starts `cqnet sim`: one run in this process (`runs == 1`), or `runs`
/// seeds from the scenario's over `threads` threads, each in
/// `out/run-NNN`. The outcome is the summary as `summary.json` has it.
#[pyfunction]
#[pyo3(signature = (scenario, out, runs = 1, threads = None, centralized = None))]
fn start_sim(
    scenario: &PyScenario,
    out: PathBuf,
    runs: u32,
    threads: Option<usize>,
    centralized: Option<bool>,
) -> PyResult<Job> {
    if runs == 0 {
        return Err(pyo3::exceptions::PyValueError::new_err(
            "runs must be at least 1",
        ));
    }
    let topology = scenario.topology()?;
    let s = scenario.scenario.clone();
    let centralized = centralized.unwrap_or(s.reference.centralized);
    let threads = threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .max(1);
    let dir = out.clone();
    Job::start("cqnet-sim", out, move |shared| {
        if runs == 1 {
            let mut writer = ResultsWriter::create(&dir)?;
            let steps = s.steps as u64;
            shared.set(0, steps, "steps", String::new());
            let summary = launch::sim::run_in_process_until(
                &s,
                &topology,
                &mut writer,
                centralized,
                |step, rows| shared.set(step as u64, steps, "steps", step_message(rows)),
                &shared.stop,
            )?;
            Ok(serde_json::to_string(&summary)?)
        } else {
            shared.set(0, runs as u64, "runs", String::new());
            let mc = launch::montecarlo::run_monte_carlo_until(
                &s,
                &topology,
                &dir,
                runs,
                threads,
                centralized,
                &|done| shared.set(done as u64, runs as u64, "runs", String::new()),
                &shared.stop,
            )?;
            let json = serde_json::to_string_pretty(&mc)?;
            write_atomically(&dir.join("summary.json"), json.as_bytes())?;
            Ok(json)
        }
    })
}

/// Starts `cqnet run`: the network as real processes, each actor started
/// as [`set_actor_program`](crate::set_actor_program) said. The outcome is
/// the summary.
#[pyfunction]
#[pyo3(signature = (scenario, out, lockstep = false, centralized = None, run_id = None, cores = "auto"))]
fn start_run(
    scenario: &PyScenario,
    out: PathBuf,
    lockstep: bool,
    centralized: Option<bool>,
    run_id: Option<String>,
    cores: &str,
) -> PyResult<Job> {
    let cores = match cores {
        "auto" => launch::cores::Cores::Auto,
        "off" => launch::cores::Cores::Off,
        other => {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "cores: `{other}` is neither \"auto\" nor \"off\""
            )))
        }
    };
    let topology = scenario.topology()?;
    let s = scenario.scenario.clone();
    let run_id = match run_id {
        Some(id) => fusion_graph::RunId::new(&id).map_err(|e| to_py_err(&e.into()))?,
        None => fusion_graph::RunId::generate(),
    };
    let centralized = centralized.unwrap_or(s.reference.centralized);
    let dir = out.clone();
    Job::start("cqnet-run", out, move |shared| {
        let options = launch::network::RunOptions {
            out: dir,
            lockstep,
            run_id,
            centralized,
            view: None,
            local_agents: false,
            stop: Some(shared.stop.clone()),
            cores,
        };
        let steps = s.steps as u64;
        let reporter = shared.clone();
        let summary = launch::network::run_network(&s, &topology, options, move |p| match p {
            RunProgress::Starting { ready, of } => {
                reporter.set(ready as u64, of as u64, "processes ready", String::new())
            }
            RunProgress::Running => reporter.set(0, steps, "steps", String::new()),
            RunProgress::Step { step, rows } => {
                reporter.set(step as u64, steps, "steps", step_message(rows))
            }
        })?;
        Ok(serde_json::to_string(&summary)?)
    })
}

pub(crate) fn start_experiment_job(
    out: PathBuf,
    work: impl FnOnce(&Arc<Shared>) -> anyhow::Result<String> + Send + 'static,
) -> PyResult<Job> {
    Job::start("cqnet-experiment", out, work)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Job>()?;
    m.add_function(wrap_pyfunction!(start_sim, m)?)?;
    m.add_function(wrap_pyfunction!(start_run, m)?)?;
    Ok(())
}
