//! The live view, seen as a user sees it: a real `cqnet run --view` opened
//! in headless Chromium (driven over the DevTools protocol), and a finished
//! run replayed by `cqnet view`. Chromium is Debian's `chromium` package,
//! which `.ci/run` installs where it can; without it the browser test says
//! it is skipped.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine;
use cqnet_testkit::{default_scenario, exclusive, Kill, Network, Partition, Signal};
use serde_json::{json, Value};

const CQNET: &str = env!("CARGO_BIN_EXE_cqnet-under-test");

fn chromium() -> Option<PathBuf> {
    std::env::var_os("CHROMIUM")
        .map(PathBuf::from)
        .into_iter()
        .chain(["/usr/bin/chromium", "/usr/bin/chromium-browser"].map(PathBuf::from))
        .find(|p| p.is_file())
}

/// Headless Chromium on a page, killed and its profile removed on drop.
struct Browser {
    child: Child,
    profile: PathBuf,
}

impl Browser {
    fn open(executable: &Path, url: &str, tag: &str) -> Self {
        let profile =
            std::env::temp_dir().join(format!("cqnet-chromium-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&profile);
        std::fs::create_dir_all(&profile).unwrap();
        let child = Command::new(executable)
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--remote-debugging-port=0",
                "--window-size=1400,900",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg(url)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start chromium");
        Self { child, profile }
    }

    /// The DevTools port, once Chromium has written it.
    fn devtools_port(&self) -> u16 {
        let file = self.profile.join("DevToolsActivePort");
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(30) {
            if let Some(port) = std::fs::read_to_string(&file)
                .ok()
                .and_then(|t| t.lines().next()?.parse().ok())
            {
                return port;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        panic!("chromium wrote no DevToolsActivePort");
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.profile);
    }
}

/// An HTTP/1.1 GET on 127.0.0.1, its body (read by its Content-Length:
/// DevTools keeps the connection open and answers HTTP/1.0 with nothing).
fn http_get(port: u16, path: &str) -> String {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(s, "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").unwrap();
    let mut bytes = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        if let Some(end) = bytes.windows(4).position(|w| w == b"\r\n\r\n") {
            let head = String::from_utf8_lossy(&bytes[..end]).to_ascii_lowercase();
            let length: usize = head
                .lines()
                .find_map(|l| l.strip_prefix("content-length:")?.trim().parse().ok())
                .unwrap_or(0);
            if bytes.len() >= end + 4 + length {
                return String::from_utf8_lossy(&bytes[end + 4..end + 4 + length]).into_owned();
            }
        }
        let n = s.read(&mut buf).unwrap_or(0);
        if n == 0 {
            return String::new();
        }
        bytes.extend_from_slice(&buf[..n]);
    }
}

/// One page's DevTools session.
struct Page {
    socket: tungstenite::WebSocket<TcpStream>,
    next_id: u64,
}

impl Page {
    fn attach(port: u16, url: &str) -> Self {
        let start = Instant::now();
        let ws = loop {
            let targets: Value =
                serde_json::from_str(&http_get(port, "/json/list")).unwrap_or(Value::Null);
            let found = targets.as_array().and_then(|ts| {
                ts.iter()
                    .find(|t| {
                        t["type"] == "page" && t["url"].as_str().is_some_and(|u| u.starts_with(url))
                    })
                    .and_then(|t| t["webSocketDebuggerUrl"].as_str().map(str::to_string))
            });
            if let Some(ws) = found {
                break ws;
            }
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "no page for {url}: {targets}"
            );
            std::thread::sleep(Duration::from_millis(100));
        };
        let stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
        let (socket, _) = tungstenite::client(ws.as_str(), stream).expect("DevTools websocket");
        Self { socket, next_id: 1 }
    }

    fn call(&mut self, method: &str, params: Value) -> Value {
        let id = self.next_id;
        self.next_id += 1;
        let request = json!({"id": id, "method": method, "params": params}).to_string();
        self.socket
            .send(tungstenite::Message::text(request))
            .unwrap();
        loop {
            let m = self.socket.read().expect("DevTools reply");
            let Ok(text) = m.to_text() else { continue };
            let v: Value = serde_json::from_str(text).unwrap_or(Value::Null);
            if v["id"] == id {
                assert!(v.get("error").is_none(), "{method}: {v}");
                return v["result"].clone();
            }
        }
    }

    fn eval(&mut self, expression: &str) -> Value {
        self.call(
            "Runtime.evaluate",
            json!({"expression": expression, "returnByValue": true}),
        )["result"]["value"]
            .clone()
    }

    /// Polls `expression` until `holds` says yes (or panics after `timeout`).
    fn wait_until(
        &mut self,
        expression: &str,
        timeout: Duration,
        holds: impl Fn(&Value) -> bool,
    ) -> Value {
        let start = Instant::now();
        loop {
            let v = self.eval(expression);
            if holds(&v) {
                return v;
            }
            assert!(start.elapsed() < timeout, "{expression} is still {v}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

const TRACK_POINTS: &str =
    "document.getElementById('truth').getAttribute('points').trim().split(/\\s+/).filter(Boolean).length";

/// During a real run, the page shows the nine nodes and a true track that
/// grows, and its screenshot is saved (`CQNET_VIEW_SCREENSHOT=path` copies
/// it, as for the README's).
#[test]
fn the_live_view_of_a_real_run_shows_the_nodes_and_a_growing_track() {
    let Some(chromium) = chromium() else {
        eprintln!("SKIPPED the_live_view_of_a_real_run_shows_the_nodes_and_a_growing_track: no chromium (apt-get install chromium)");
        return;
    };
    let _guard = exclusive();
    let mut s = default_scenario();
    s.steps = 80;
    let group = |names: &[&str]| names.iter().map(|n| n.to_string()).collect();
    let mut running = Network::new(s)
        .executable(CQNET)
        .tag("view")
        .arg("--view")
        // Faults for the page to show: a cut across the grid and a stopped node.
        .fault(Partition {
            groups: vec![
                group(&["node-0", "node-1", "node-3", "node-4"]),
                group(&["node-2", "node-5", "node-6", "node-7", "node-8"]),
            ],
            at_step: 3,
            duration: Some(40),
        })
        .fault(Kill {
            actor: "node-8".into(),
            at_step: 3,
            signal: Signal::Stop,
            restart_after: Some(40),
        })
        .start()
        .unwrap();
    let line = running
        .wait_for_stderr_line("live view of", Duration::from_secs(30))
        .unwrap_or_else(|| panic!("no view URL:\n{}", running.stderr_so_far()));
    let url = line.rsplit(' ').next().unwrap().to_string();
    assert!(url.starts_with("http://127.0.0.1:"), "{line}");
    assert!(
        running.wait_for_step(5, Duration::from_secs(120)),
        "no step 5"
    );

    let browser = Browser::open(&chromium, &url, "live");
    let mut page = Page::attach(browser.devtools_port(), &url);
    let nodes = page.wait_until(
        "document.querySelectorAll('#map .node').length",
        Duration::from_secs(20),
        |v| v.as_u64().is_some_and(|n| n > 0),
    );
    assert_eq!(nodes, 9, "nodes on the map");
    assert_eq!(
        page.eval("document.querySelectorAll('#map .sensor').length"),
        225
    );
    let first = page.wait_until(TRACK_POINTS, Duration::from_secs(20), |v| {
        v.as_u64().is_some_and(|n| n > 0)
    });
    let first = first.as_u64().unwrap();
    let later = page.wait_until(TRACK_POINTS, Duration::from_secs(20), |v| {
        v.as_u64().is_some_and(|n| n > first)
    });
    assert!(later.as_u64().unwrap() > first);
    assert_eq!(
        page.eval("document.querySelectorAll('#map .node.dead').length"),
        1,
        "node-8 stopped"
    );
    assert!(
        page.eval("document.querySelectorAll('#map .link.cut').length")
            .as_u64()
            .unwrap()
            >= 3
    );
    assert_eq!(
        page.eval("document.querySelectorAll('#timeline .fault').length"),
        2
    );
    // The chart has a series per node and the centralized reference, each
    // with its error and its bound.
    page.wait_until(
        "document.querySelectorAll('#chart .series').length",
        Duration::from_secs(10),
        |v| v.as_u64().is_some_and(|n| n >= 2 * 10),
    );
    // The status line says how far consensus got in the step drawn.
    page.wait_until(
        "document.getElementById('status').textContent",
        Duration::from_secs(20),
        |v| {
            v.as_str()
                .is_some_and(|s| s.contains("disagreement after consensus"))
        },
    );
    page.call(
        "Emulation.setDeviceMetricsOverride",
        json!({"width": 1400, "height": 820, "deviceScaleFactor": 1, "mobile": false}),
    );
    let shot = page.call("Page.captureScreenshot", json!({"format": "png"}));
    let png = base64::engine::general_purpose::STANDARD
        .decode(shot["data"].as_str().unwrap())
        .unwrap();
    assert!(png.starts_with(b"\x89PNG"));
    std::fs::write(running.out_dir().join("view.png"), &png).unwrap();
    if let Some(path) = std::env::var_os("CQNET_VIEW_SCREENSHOT") {
        std::fs::write(path, &png).unwrap();
    }
    drop(page);
    drop(browser);

    let r = running.wait().unwrap();
    r.assert_success().assert_clean();
}

/// `cqnet view OUT_DIR` replays a finished run: its event stream has the
/// map, every step and the end.
#[test]
fn a_finished_run_replays_in_the_view() {
    let mut s = default_scenario();
    s.steps = 12;
    let sim = Network::new(s)
        .executable(CQNET)
        .tag("replay")
        .sim()
        .unwrap();
    sim.assert_success();
    let mut view = Command::new(CQNET)
        .args(["view", "--speed", "1000"])
        .arg(sim.out_dir())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    struct Kill(Child);
    impl Drop for Kill {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let mut stdout = view.stdout.take().unwrap();
    let view = Kill(view);
    let mut first = Vec::new();
    let mut byte = [0u8];
    while stdout.read(&mut byte).unwrap() == 1 && byte[0] != b'\n' {
        first.push(byte[0]);
    }
    let first = String::from_utf8(first).unwrap();
    let port: u16 = first
        .split("http://127.0.0.1:")
        .nth(1)
        .and_then(|rest| rest.split('/').next()?.parse().ok())
        .unwrap_or_else(|| panic!("no URL in {first:?}"));

    let mut stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(30)))
        .unwrap();
    write!(stream, "GET /events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n").unwrap();
    let mut events = String::new();
    let mut buf = [0u8; 8192];
    while !events.contains("\"type\":\"end\"") {
        let n = stream
            .read(&mut buf)
            .expect("the stream goes on until the end event");
        assert!(n > 0, "the stream closed early:\n{events}");
        events.push_str(&String::from_utf8_lossy(&buf[..n]));
    }
    let count = |kind: &str| events.matches(&format!("\"type\":\"{kind}\"")).count();
    assert_eq!(count("setup"), 1);
    assert_eq!(count("step"), 12);
    assert_eq!(count("estimates"), 12);
    assert!(events.contains("\"mode\":\"replay\""));
    // Nine nodes and the centralized reference report each step.
    assert_eq!(events.matches("\"node\":\"node-").count(), 12 * 9);
    drop(view);
}
