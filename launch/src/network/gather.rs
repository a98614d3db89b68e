//! What the run leaves behind, gathered from every process: the byte
//! counts of every ledger, the hosts' report, the children's memory, and
//! the live view's traffic.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use fusion_graph::hosts::Placement;
use fusion_graph::{ActorId, Topology};
use transport::accounting::read_ledger;
use transport::accounting::Accounting;
use transport::ledger::LedgerError;

use crate::actor_process::{ledger_path, memory_path};
use crate::feed::{link_bytes_per_step, Hub, ViewEvent};
use crate::results::write_atomically;
use crate::summary::{ChildrenCpu, ChildrenMemory};
use crate::supervisor::HostFiles;

/// `hosts.json`: the bytes of cqnet's messages between hosts, by pair of
/// hosts (from the actors' own counts), and what each bridge moved and its
/// TCP sockets carried.
pub(super) fn write_hosts_report(
    out: &Path,
    placement: &Placement,
    accounting: &Accounting,
    bridges: &[(String, fusion_graph::hosts::BridgeCounts)],
    homes: &[(String, HostFiles)],
) -> anyhow::Result<()> {
    let mut pairs = Vec::new();
    let name = |a: ActorId| placement.hosts()[placement.host_of(a)].name.clone();
    let mut by_pair: BTreeMap<(String, String), [u64; 4]> = BTreeMap::new();
    for ((from, to, _), c) in accounting.iter() {
        if placement.crosses(*from, *to) {
            let e = by_pair.entry((name(*from), name(*to))).or_default();
            e[0] += c.sent_messages;
            e[1] += c.sent_bytes;
            e[2] += c.received_messages;
            e[3] += c.received_bytes;
        }
    }
    for ((from, to), [sm, sb, rm, rb]) in by_pair {
        pairs.push(serde_json::json!({
            "from": from, "to": to,
            "sent_messages": sm, "sent_bytes": sb,
            "received_messages": rm, "received_bytes": rb,
        }));
    }
    let cpu = |name: &str| {
        homes
            .iter()
            .find(|(h, _)| h == name)
            .and_then(|(_, f)| f.cpu_seconds)
    };
    let report = serde_json::json!({
        "hosts": placement.hosts().iter().map(|h| serde_json::json!({
            "name": h.name, "endpoint": h.endpoint, "nodes": h.nodes,
            "cpu_seconds": cpu(&h.name),
        })).collect::<Vec<_>>(),
        "between_hosts": pairs,
        "bridges": bridges.iter().map(|(h, c)| serde_json::json!({ "host": h, "counts": c })).collect::<Vec<_>>(),
    });
    write_atomically(
        &out.join("hosts.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    Ok(())
}

/// Writes what each host sent home into the results folder, where a run
/// on one host leaves the same files (`logs/`, `accounting/`), so that the
/// summary's memory covers every host and every actor's log is here. A
/// path outside those two folders is refused and said.
pub(super) fn bring_home(out: &Path, homes: &[(String, HostFiles)]) {
    for (host, home) in homes {
        home.write_home(host, out);
    }
}

/// The children's memory, as each last wrote it, and what their CPU and
/// context switches were over the run, summed (see
/// [`memory_path`](crate::actor_process::memory_path)).
pub(super) fn children_usage(
    out: &Path,
    topology: &Topology,
) -> (Option<ChildrenMemory>, Option<ChildrenCpu>) {
    let read = |a| -> Option<Vec<u64>> {
        let text = std::fs::read_to_string(memory_path(out, a)).ok()?;
        text.split_whitespace().map(|v| v.parse().ok()).collect()
    };
    let all: Vec<Vec<u64>> = topology
        .actors()
        .filter_map(read)
        .filter(|f| f.len() >= 2)
        .collect();
    let memory = (!all.is_empty()).then(|| ChildrenMemory {
        largest_peak_rss: all.iter().map(|m| m[0]).max().unwrap_or(0),
        total_pss: all.iter().map(|m| m[1]).sum(),
    });
    let cpu: Vec<&[u64]> = all.iter().filter_map(|f| f.get(2..6)).collect();
    let sum = |i: usize| cpu.iter().map(|c| c[i]).sum::<u64>();
    let cpu = (!cpu.is_empty()).then(|| ChildrenCpu {
        actors: cpu.len(),
        user_seconds: sum(0) as f64 / 1e6,
        system_seconds: sum(1) as f64 / 1e6,
        voluntary_switches: sum(2),
        involuntary_switches: sum(3),
    });
    (memory, cpu)
}

/// Every actor's byte counts, from the ledgers they leave (whatever ended
/// them), plus the launcher's own. An actor that never started has none; a
/// ledger that cannot be read is said, not silently dropped.
pub(super) fn merge_accounting(
    out: &Path,
    topology: &Topology,
    launcher: &Accounting,
) -> Accounting {
    let mut total = launcher.clone();
    for a in topology.actors() {
        let path = ledger_path(out, a);
        match read_ledger(&path, topology.payloads) {
            Ok(acc) => total.merge(&acc),
            Err(LedgerError::Io { source, .. })
                if source.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => tracing::warn!(actor = %a, error = %e, "byte counts lost"),
        }
    }
    total
}

/// Where a run over several hosts keeps every host's byte counts as they
/// stand, for the live view: the ledgers are on the hosts.
pub(super) fn hosts_traffic_path(out: &Path) -> PathBuf {
    out.join("accounting").join("hosts-traffic.csv")
}

/// The live view's once-a-second look at the link traffic: each node's
/// ledger as it stands (on several hosts, what the hosts last sent), over
/// the steps run so far.
pub fn traffic_poller(hub: Arc<Hub>, topology: Topology, out: PathBuf) -> crate::feed::Poll {
    Box::new(move || {
        let mut accounting = Accounting::default();
        for n in 0..topology.nodes() as u16 {
            if let Ok(acc) = read_ledger(&ledger_path(&out, ActorId::Node(n)), topology.payloads) {
                accounting.merge(&acc);
            }
        }
        let from_hosts = std::fs::read_to_string(hosts_traffic_path(&out)).ok();
        if let Some(acc) = from_hosts
            .as_deref()
            .and_then(|csv| Accounting::from_csv(csv, topology.payloads))
        {
            accounting.merge(&acc);
        }
        let steps = hub.latest_step().max(1) as f64;
        let bytes_per_step = link_bytes_per_step(&topology, &accounting, |_| steps);
        if bytes_per_step.iter().any(|b| *b > 0.0) {
            hub.publish(&ViewEvent::Traffic {
                step: hub.latest_step(),
                bytes_per_step,
            });
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A host's files land where a one-host run leaves them; a path that
    /// would leave `logs/` or `accounting/` is dropped, whatever the host
    /// says.
    #[test]
    fn files_from_hosts_stay_inside_the_results_folder() {
        let out = std::env::temp_dir().join(format!("cqnet-bring-home-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let files = [
            "logs/node-3.log",
            "accounting/node-3.memory",
            "../escaped",
            "logs/../../escaped",
            "logs/",
            "summary.json",
            "accounting/..",
            "/etc/passwd",
        ];
        let home = HostFiles {
            files: files
                .iter()
                .map(|p| (p.to_string(), p.as_bytes().to_vec()))
                .collect(),
            cpu_seconds: Some(1.0),
        };
        bring_home(&out, &[("b".into(), home)]);
        assert_eq!(
            std::fs::read(out.join("logs/node-3.log")).unwrap(),
            b"logs/node-3.log"
        );
        assert!(out.join("accounting/node-3.memory").is_file());
        assert!(!out.join("summary.json").exists());
        assert!(!out.parent().unwrap().join("escaped").exists());
        let mut written = 0;
        for dir in ["logs", "accounting"] {
            written += std::fs::read_dir(out.join(dir)).unwrap().count();
        }
        assert_eq!(written, 2);
        let _ = std::fs::remove_dir_all(&out);
    }

    /// Memory is read from every child that wrote it; CPU and context
    /// switches are summed over those that wrote them too, and a child
    /// that wrote half a line is left out rather than misread.
    #[test]
    fn the_childrens_usage_sums_what_each_wrote() {
        let out = std::env::temp_dir().join(format!("cqnet-usage-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        std::fs::create_dir_all(out.join("accounting")).unwrap();
        let topology =
            Topology::from_scenario(&fusion_graph::Scenario::default_scenario(), "d").unwrap();
        let write = |a: ActorId, line: &str| {
            std::fs::write(memory_path(&out, a), line).unwrap();
        };
        write(ActorId::Node(0), "2000 1000 1500000 250000 10 20");
        write(ActorId::Node(1), "3000 500 500000 750000 5 7");
        write(ActorId::Sensor(0), "1000 100");
        write(ActorId::Sensor(1), "1000 100 12");
        let (memory, cpu) = children_usage(&out, &topology);
        let memory = memory.unwrap();
        assert_eq!(memory.largest_peak_rss, 3000);
        assert_eq!(memory.total_pss, 1700);
        let cpu = cpu.unwrap();
        assert_eq!(cpu.actors, 2);
        assert!((cpu.user_seconds - 2.0).abs() < 1e-12);
        assert!((cpu.system_seconds - 1.0).abs() < 1e-12);
        assert_eq!((cpu.voluntary_switches, cpu.involuntary_switches), (15, 27));
        let _ = std::fs::remove_dir_all(&out);
    }
}
