//! What a caller asks of a run (`RunOptions`), and what it hears while
//! the run goes on (`RunProgress`).

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use fusion_graph::RunId;

use crate::feed::Hub;
use crate::results::TickRow;

pub struct RunOptions {
    pub out: PathBuf,
    pub lockstep: bool,
    pub run_id: RunId,
    pub centralized: bool,
    /// Where to publish the live view's events, if it is served.
    pub view: Option<Arc<Hub>>,
    /// A scenario with `[[hosts]]`: start every host's agent here.
    pub local_agents: bool,
    /// Set by the caller to stop the run as Ctrl-C does: children stopped
    /// and reaped, shared memory removed, the results so far written.
    pub stop: Option<Arc<AtomicBool>>,
    /// Whether to place the processes on cores (see [`crate::cores`]).
    pub cores: crate::cores::Cores,
}

/// What the launcher tells its caller as the run goes.
pub enum RunProgress<'a> {
    /// `ready` of the `of` processes have started and said so.
    Starting { ready: usize, of: usize },
    /// Every process is up; the steps begin.
    Running,
    /// A step is over, with the reports that came in time for it.
    Step { step: u32, rows: &'a [TickRow] },
}
