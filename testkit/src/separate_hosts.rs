//! Hosts as separate as machines, on one machine: each host of a
//! multi-host scenario in a network namespace of its own, joined to the
//! others only by a veth pair to a bridge, and with a `/dev/shm` of its own
//! (a private tmpfs, in a mount namespace of its own), so that nothing but
//! the network joins them: no loopback, no shared memory, no iceoryx2
//! files. The link between a host and the bridge can be cut, restored, and
//! shaped by the kernel (`tc netem`: delay, jitter, loss, rate), as a real
//! network would be.
//!
//! It needs root and the `ip`, `tc` and `unshare` programs;
//! [`SeparateHosts::unavailable`] says why not, so that a test can say it
//! is skipped rather than fail.

use std::ffi::{OsStr, OsString};
use std::net::Ipv4Addr;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};

use fusion_graph::scenario::Scenario;

use crate::Error;

/// The port every host's agent listens on: each host has its own network
/// stack, so they can all use the same one.
pub const AGENT_PORT: u16 = 17447;

/// What mounts a host's private shared memory before its programs run:
/// iceoryx2 keeps everything of a run under `/dev/shm`.
const PRIVATE_SHM: &str = "mount -t tmpfs -o mode=1777 cqnet-host-shm /dev/shm || exit 97";

#[derive(Debug, Clone)]
struct Host {
    name: String,
    namespace: String,
    /// The veth end outside, on the bridge: cutting it cuts the host off.
    outside: String,
    /// The veth end inside the namespace.
    inside: String,
    address: Ipv4Addr,
}

/// Namespaces, a bridge and veth pairs, removed when dropped (with every
/// process still running in the namespaces).
#[derive(Debug)]
pub struct SeparateHosts {
    bridge: String,
    hosts: Vec<Host>,
}

impl SeparateHosts {
    /// Why hosts cannot be separated here, if they cannot: not root, or a
    /// program missing.
    pub fn unavailable() -> Option<String> {
        if !is_root() {
            return Some("creating network namespaces needs root".into());
        }
        for (program, arg) in [("ip", "-V"), ("tc", "-V"), ("unshare", "--version")] {
            let ran = Command::new(program)
                .arg(arg)
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status();
            if !ran.is_ok_and(|s| s.success()) {
                return Some(format!("`{program}` is not available"));
            }
        }
        None
    }

    /// A namespace per name, each with the address `10.213.<n>.<i + 1>`
    /// on a bridge of its own (`n` different for each call in this
    /// process and for each process, so that tests can run side by side).
    pub fn create(names: &[&str]) -> Result<Self, Error> {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let n = (std::process::id() * 7 + NEXT.fetch_add(1, Ordering::Relaxed)) % 250;
        // Interface names have at most 15 characters.
        let id = format!("{:x}", (std::process::id() % 0x10000) * 16 + n % 16);
        let mut made = Self {
            bridge: format!("cqbr{id}"),
            hosts: Vec::new(),
        };
        made.ip(&["link", "add", &made.bridge, "type", "bridge"])?;
        made.ip(&["link", "set", &made.bridge, "up"])?;
        for (i, name) in names.iter().enumerate() {
            let host = Host {
                name: name.to_string(),
                namespace: format!("cqnet-{id}-{name}"),
                outside: format!("cq{id}o{i}"),
                inside: format!("cq{id}i{i}"),
                address: Ipv4Addr::new(10, 213, n as u8, i as u8 + 1),
            };
            made.ip(&["netns", "add", &host.namespace])?;
            made.hosts.push(host.clone());
            made.ip(&[
                "link",
                "add",
                &host.outside,
                "type",
                "veth",
                "peer",
                "name",
                &host.inside,
            ])?;
            made.ip(&["link", "set", &host.inside, "netns", &host.namespace])?;
            made.ip(&["link", "set", &host.outside, "master", &made.bridge, "up"])?;
            let ns = &host.namespace;
            let cidr = format!("{}/24", host.address);
            made.ip(&["-n", ns, "addr", "add", &cidr, "dev", &host.inside])?;
            made.ip(&["-n", ns, "link", "set", &host.inside, "up"])?;
            made.ip(&["-n", ns, "link", "set", "lo", "up"])?;
        }
        Ok(made)
    }

    fn ip(&self, args: &[&str]) -> Result<(), Error> {
        run("ip", args)
    }

    fn host(&self, name: &str) -> &Host {
        self.hosts
            .iter()
            .find(|h| h.name == name)
            .unwrap_or_else(|| panic!("no separate host named {name:?}"))
    }

    /// Host `name`'s address.
    pub fn address(&self, name: &str) -> Ipv4Addr {
        self.host(name).address
    }

    /// Points each of the scenario's hosts at its namespace's address, on
    /// [`AGENT_PORT`]. Its hosts must be those this was created with.
    pub fn place(&self, scenario: &mut Scenario) {
        for h in &mut scenario.hosts {
            let protocol = match h.endpoint.split_once('/') {
                Some(("tcp", _)) => "tcp",
                _ => "quic",
            };
            h.endpoint = format!("{protocol}/{}:{AGENT_PORT}", self.address(&h.name));
        }
    }

    /// The namespaces' names, host by host, in the order created.
    pub fn hosts(&self) -> impl Iterator<Item = &str> {
        self.hosts.iter().map(|h| h.name.as_str())
    }

    /// `program` (with the arguments the caller adds) run in host
    /// `name`'s network namespace with a private `/dev/shm`.
    pub fn command(&self, name: &str, program: &OsStr) -> Command {
        self.in_host(name, &format!("{PRIVATE_SHM}; exec \"$@\""), program)
    }

    /// As [`command`](Self::command), with `program companion…` started
    /// first beside it, in the same namespaces (so that they share the
    /// host's `/dev/shm`), its output to `log`: a launcher and its own
    /// host's agent.
    pub fn command_with_companion(
        &self,
        name: &str,
        program: &OsStr,
        companion: &[OsString],
        log: &Path,
    ) -> Command {
        let mut line = quoted(program);
        for a in companion {
            line.push(' ');
            line.push_str(&quoted(a));
        }
        let log = quoted(log.as_os_str());
        let script = format!("{PRIVATE_SHM}; {line} >{log} 2>&1 & exec \"$@\"");
        self.in_host(name, &script, program)
    }

    fn in_host(&self, name: &str, script: &str, program: &OsStr) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", &self.host(name).namespace])
            .args(["unshare", "--mount", "--propagation", "private", "--"])
            .args(["sh", "-c", script, "sh"])
            .arg(program);
        c
    }

    /// Cuts host `name` off the bridge: nothing reaches it or leaves it
    /// until [`restore`](Self::restore).
    pub fn cut(&self, name: &str) -> Result<(), Error> {
        self.ip(&["link", "set", &self.host(name).outside, "down"])
    }

    /// Joins host `name` to the bridge again.
    pub fn restore(&self, name: &str) -> Result<(), Error> {
        self.ip(&["link", "set", &self.host(name).outside, "up"])
    }

    /// Shapes both directions of host `name`'s link with `tc netem`
    /// (`["delay", "5ms"]`, `["loss", "1%"]`, …). A kernel built without
    /// netem (`sch_netem`) refuses it: [`netem_unavailable`](Self::netem_unavailable)
    /// says so beforehand.
    pub fn shape(&self, name: &str, netem: &[&str]) -> Result<(), Error> {
        let mut qdisc = vec!["netem"];
        qdisc.extend(netem);
        self.qdisc(name, &qdisc)
    }

    /// Limits both directions of host `name`'s link to `rate` (`"10mbit"`)
    /// with a token bucket (`tc tbf`), which kernels without netem have.
    pub fn limit_rate(&self, name: &str, rate: &str) -> Result<(), Error> {
        self.qdisc(
            name,
            &["tbf", "rate", rate, "burst", "64kb", "latency", "400ms"],
        )
    }

    /// Removes the shaping of host `name`'s link.
    pub fn unshape(&self, name: &str) {
        let h = self.host(name);
        let _ = run("tc", &["qdisc", "del", "dev", &h.outside, "root"]);
        let _ = run(
            "tc",
            &["-n", &h.namespace, "qdisc", "del", "dev", &h.inside, "root"],
        );
    }

    fn qdisc(&self, name: &str, qdisc: &[&str]) -> Result<(), Error> {
        let h = self.host(name);
        for (ns, dev) in [(None, &h.outside), (Some(&h.namespace), &h.inside)] {
            let mut args: Vec<&str> = Vec::new();
            if let Some(ns) = ns {
                args.extend(["-n", ns]);
            }
            args.extend(["qdisc", "replace", "dev", dev, "root"]);
            args.extend(qdisc);
            run("tc", &args)?;
        }
        Ok(())
    }

    /// Applies what the scenario's hosts' `link` settings ask of their
    /// links from the start: netem's delay, jitter, loss (and rate, with
    /// them), or a token bucket's rate alone. Cuts come later, at their
    /// steps ([`Network::on_separate_hosts`](crate::Network::on_separate_hosts) applies them).
    pub fn apply_links(&self, scenario: &Scenario) -> Result<(), Error> {
        for h in &scenario.hosts {
            let Some(link) = &h.link else { continue };
            let (delay, jitter, loss, rate) = (
                format!("{}us", (link.delay_ms * 1e3).round()),
                format!("{}us", (link.jitter_ms * 1e3).round()),
                format!("{}%", link.loss * 100.0),
                format!("{}kbit", (link.rate_mbit * 1e3).round()),
            );
            if link.needs_netem() {
                let mut netem = vec!["delay", &delay, &jitter, "loss", &loss];
                if link.rate_mbit > 0.0 {
                    netem.extend(["rate", &rate]);
                }
                self.shape(&h.name, &netem)?;
            } else if link.rate_mbit > 0.0 {
                self.limit_rate(&h.name, &rate)?;
            }
        }
        Ok(())
    }

    /// Why this kernel cannot delay or drop packets with `tc netem`, if it
    /// cannot (found by trying it on a host's link).
    pub fn netem_unavailable(&self) -> Option<String> {
        let h = self.hosts.first()?;
        let tried = self.shape(&h.name, &["delay", "1ms"]);
        self.unshape(&h.name);
        tried.err().map(|e| e.to_string())
    }
}

impl Drop for SeparateHosts {
    fn drop(&mut self) {
        for h in &self.hosts {
            // Whatever still runs in the namespace goes with it.
            if let Ok(out) = Command::new("ip")
                .args(["netns", "pids", &h.namespace])
                .output()
            {
                for pid in String::from_utf8_lossy(&out.stdout).split_whitespace() {
                    let _ = Command::new("kill").args(["-9", pid]).status();
                }
            }
            let _ = run("ip", &["netns", "del", &h.namespace]);
        }
        let _ = run("ip", &["link", "del", &self.bridge]);
    }
}

/// `s` in single quotes for `sh`.
fn quoted(s: &OsStr) -> String {
    format!("'{}'", s.to_string_lossy().replace('\'', "'\\''"))
}

/// Whether this process runs as root (creating namespaces needs it).
fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status").is_ok_and(|s| {
        s.lines()
            .find(|l| l.starts_with("Uid:"))
            .and_then(|l| l.split_whitespace().nth(2))
            == Some("0")
    })
}

/// Runs `program args…`, its failure an error naming the command.
fn run(program: &str, args: &[&str]) -> Result<(), Error> {
    let out = Command::new(program)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .map_err(|source| Error::Spawn {
            executable: program.into(),
            source,
        })?;
    if out.status.success() {
        Ok(())
    } else {
        Err(Error::Host(format!(
            "`{program} {}`: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        )))
    }
}
