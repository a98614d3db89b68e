//! Progress on stderr that never goes silent for more than a second: an
//! indicatif bar on a terminal (redrawn by a steady tick, so its clock moves
//! even while the work does not), and on anything else a plain line once a
//! second, so that logs stay readable.

use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

use crate::results::TickRow;

/// The longest a plain-line progress stays silent.
const PLAIN_EVERY: Duration = Duration::from_secs(1);

/// One piece of long work: `label pos/total message`.
pub struct Progress {
    shared: Arc<Shared>,
    ticker: Option<JoinHandle<()>>,
}

struct Shared {
    label: String,
    started: Instant,
    bar: Option<ProgressBar>,
    state: Mutex<State>,
    finished: AtomicBool,
    wake: Condvar,
    sink: Sink,
}

/// Where plain lines go (stderr, but for tests).
type Sink = Box<dyn Fn(&str) + Send + Sync>;

#[derive(Default)]
struct State {
    pos: u64,
    total: u64,
    unit: &'static str,
    message: String,
}

impl Progress {
    /// A bar over `total` `unit`s, on a terminal; plain lines elsewhere.
    pub fn new(label: impl Into<String>, unit: &'static str, total: u64) -> Self {
        Self::with_terminal(label, unit, total, std::io::stderr().is_terminal())
    }

    fn with_terminal(
        label: impl Into<String>,
        unit: &'static str,
        total: u64,
        terminal: bool,
    ) -> Self {
        Self::build(
            label.into(),
            unit,
            total,
            terminal,
            Box::new(|line| eprintln!("{line}")),
        )
    }

    fn build(label: String, unit: &'static str, total: u64, terminal: bool, sink: Sink) -> Self {
        let bar = terminal.then(|| {
            let bar = ProgressBar::new(total);
            bar.set_style(
                ProgressStyle::with_template(
                    "{prefix} [{bar:24}] {pos}/{len} {msg} ({elapsed}, ETA {eta})",
                )
                .expect("a valid template")
                .progress_chars("=> "),
            );
            bar.set_prefix(label.clone());
            bar.set_message(unit);
            bar.enable_steady_tick(Duration::from_millis(200));
            bar
        });
        let shared = Arc::new(Shared {
            label,
            started: Instant::now(),
            bar,
            state: Mutex::new(State {
                total,
                unit,
                ..State::default()
            }),
            finished: AtomicBool::new(false),
            wake: Condvar::new(),
            sink,
        });
        let ticker = shared.bar.is_none().then(|| {
            let shared = shared.clone();
            std::thread::spawn(move || shared.print_plain_lines())
        });
        Self { shared, ticker }
    }

    /// Work done so far, and what to say about it (empty: nothing).
    pub fn set(&self, pos: u64, message: impl Into<String>) {
        let message = message.into();
        let mut s = self.shared.lock();
        if let Some(bar) = &self.shared.bar {
            bar.set_position(pos);
            bar.set_message(format!("{} {message}", s.unit));
        }
        s.pos = pos;
        s.message = message;
    }

    /// What is counted from now on (`steps` after `processes ready`).
    pub fn set_unit(&self, unit: &'static str) {
        self.shared.lock().unit = unit;
    }

    /// A new total (a later phase of the same work).
    pub fn set_total(&self, total: u64) {
        if let Some(bar) = &self.shared.bar {
            bar.set_length(total);
        }
        self.shared.lock().total = total;
    }

    /// Clears the bar, or prints the last plain line.
    pub fn finish(mut self) {
        self.stop();
    }

    fn stop(&mut self) {
        if self.shared.finished.swap(true, Ordering::SeqCst) {
            return;
        }
        // Taken so the ticker is either waiting (and is woken) or has not
        // yet checked `finished`.
        drop(self.shared.lock());
        if let Some(bar) = &self.shared.bar {
            bar.finish_and_clear();
        }
        self.shared.wake.notify_all();
        if let Some(t) = self.ticker.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.stop();
    }
}

impl Shared {
    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn line(&self) -> String {
        let s = self.lock();
        let mut line = format!(
            "{}: {}/{} {} ({:.0} s)",
            self.label,
            s.pos,
            s.total,
            s.unit,
            self.started.elapsed().as_secs_f64()
        );
        if !s.message.is_empty() {
            line.push_str(", ");
            line.push_str(&s.message);
        }
        line
    }

    /// A line a second until finished, and a last one then.
    fn print_plain_lines(&self) {
        let mut guard = self.lock();
        // `finished` is set under the lock, so no wake-up is missed.
        while !self.finished.load(Ordering::SeqCst) {
            guard = self
                .wake
                .wait_timeout(guard, PLAIN_EVERY)
                .unwrap_or_else(|p| p.into_inner())
                .0;
            if self.finished.load(Ordering::SeqCst) {
                break;
            }
            drop(guard);
            (self.sink)(&self.line());
            guard = self.lock();
        }
        drop(guard);
        (self.sink)(&self.line());
    }
}

/// A step's figures for a progress line: the nodes' position RMSE and their
/// mean CQ/dPCRLB (the centralized reference's row left out).
pub fn step_message(rows: &[TickRow]) -> String {
    let nodes: Vec<&TickRow> = rows.iter().filter(|r| r.node != "central").collect();
    if nodes.is_empty() {
        return String::new();
    }
    let rmse = (nodes.iter().map(|r| r.error().powi(2)).sum::<f64>() / nodes.len() as f64).sqrt();
    let bounds: Vec<f64> = nodes.iter().filter_map(|r| r.telemetry.bound).collect();
    if bounds.is_empty() {
        format!("RMSE {rmse:.2} m")
    } else {
        let bound = bounds.iter().sum::<f64>() / bounds.len() as f64;
        format!("RMSE {rmse:.2} m, bound {bound:.2} m")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn collecting(total: u64) -> (Progress, Arc<Mutex<Vec<String>>>) {
        let lines = Arc::new(Mutex::new(Vec::new()));
        let sink = lines.clone();
        let p = Progress::build(
            "step".into(),
            "steps",
            total,
            false,
            Box::new(move |l| sink.lock().unwrap().push(l.to_string())),
        );
        (p, lines)
    }

    #[test]
    fn plain_progress_prints_a_line_each_second_and_a_last_one_at_the_end() {
        let (p, lines) = collecting(10);
        p.set(3, "RMSE 1.00 m");
        // Some lines within 2.5 s: the ticker does not wait for a change.
        std::thread::sleep(Duration::from_millis(2500));
        let during = lines.lock().unwrap().len();
        assert!(during >= 1, "silent for 2.5 s");
        p.set(10, "");
        p.finish();
        let lines = lines.lock().unwrap();
        assert!(lines[0].starts_with("step: 3/10 steps"), "{}", lines[0]);
        assert!(lines[0].ends_with(", RMSE 1.00 m"), "{}", lines[0]);
        assert!(
            lines.last().unwrap().starts_with("step: 10/10 steps"),
            "{lines:?}"
        );
    }

    #[test]
    fn step_message_leaves_out_the_centralized_reference() {
        let row = |node: &str, x: f64, bound| {
            let mut telemetry = crate::sim::central_telemetry(Default::default(), bound);
            telemetry.estimate[0] = x;
            TickRow {
                step: 1,
                node: node.into(),
                truth: [0.0; 4],
                telemetry,
            }
        };
        let rows = [
            row("node-0", 3.0, Some(1.0)),
            row("node-1", 4.0, Some(2.0)),
            row("central", 100.0, None),
        ];
        assert_eq!(
            step_message(&rows),
            format!("RMSE {:.2} m, bound 1.50 m", 12.5f64.sqrt())
        );
    }
}
