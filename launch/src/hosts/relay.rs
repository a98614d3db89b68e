//! A host's link shaped in user space: every connection of a host's Zenoh
//! session, in and out, passes through a relay of its own process that
//! holds what it carries for the link's delay (with its jitter) and lets
//! it go no faster than the link's rate. So `hosts[].link` works where the
//! kernel has no netem, on real machines as in namespaces.
//!
//! A connection between hosts `g` and `h` passes `g`'s relay and `h`'s, as
//! a packet between them passes both hosts' links: the delays add, as
//! they do with netem on both links.
//!
//! Two kinds, after the endpoint's transport:
//!
//! - **Datagrams** (`quic/`, the secured default): each UDP datagram is
//!   one packet, so the relay also drops a share `loss` of them, and QUIC
//!   pays for the loss as it would on a real link (retransmission,
//!   congestion window). This is netem's model, packet for packet.
//! - **A stream** (`tcp/`): the relay sits on a TCP stream, whose bytes
//!   all arrive, so it cannot stand for **loss**: a lost packet's cost
//!   only the kernel can show, and such a link needs netem.
//!
//! Neither reorders: a chunk never leaves before the one read before it,
//! so large jitter delays a little more than on netem, where later packets
//! may overtake.

use std::collections::HashMap;
use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use fusion_graph::hosts::HostLink;

/// What a relay does to the bytes it carries, each way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shaping {
    pub delay: Duration,
    /// Each chunk's delay is `delay ± jitter`, uniformly (netem's default).
    pub jitter: Duration,
    /// Bits per second; 0: no limit.
    pub rate_bits_per_s: f64,
    /// Share of datagrams dropped, 0 to 1 (a stream relay drops nothing).
    pub loss: f64,
}

impl Shaping {
    /// What a host's `link` asks of a relay; `None` if nothing (a link
    /// with only a cut, or none).
    pub fn from_link(link: &HostLink) -> Option<Self> {
        let s = Self {
            delay: Duration::from_secs_f64(link.delay_ms / 1e3),
            jitter: Duration::from_secs_f64(link.jitter_ms / 1e3),
            rate_bits_per_s: link.rate_mbit * 1e6,
            loss: link.loss,
        };
        (s.delay > Duration::ZERO
            || s.jitter > Duration::ZERO
            || s.rate_bits_per_s > 0.0
            || s.loss > 0.0)
            .then_some(s)
    }
}

/// When each chunk of one direction leaves: after the bytes before it
/// have been sent at the link's rate, after its delay, and never before
/// the chunk before it.
#[derive(Debug)]
pub struct Schedule {
    shaping: Shaping,
    sent_until: Option<Instant>,
    last_release: Option<Instant>,
    rng: u64,
}

impl Schedule {
    pub fn new(shaping: Shaping, seed: u64) -> Self {
        Self {
            shaping,
            sent_until: None,
            last_release: None,
            rng: seed | 1,
        }
    }

    /// The moment a chunk of `len` bytes read at `now` is released.
    pub fn release(&mut self, now: Instant, len: usize) -> Instant {
        let s = self.shaping;
        let mut sent = now.max(self.sent_until.unwrap_or(now));
        if s.rate_bits_per_s > 0.0 {
            sent += Duration::from_secs_f64(len as f64 * 8.0 / s.rate_bits_per_s);
        }
        self.sent_until = Some(sent);
        let spread = s.jitter.as_secs_f64() * (2.0 * self.uniform() - 1.0);
        let delay = (s.delay.as_secs_f64() + spread).max(0.0);
        let release = (sent + Duration::from_secs_f64(delay)).max(self.last_release.unwrap_or(now));
        self.last_release = Some(release);
        release
    }

    /// Whether the next datagram is lost.
    pub fn lost(&mut self) -> bool {
        self.shaping.loss > 0.0 && self.uniform() < self.shaping.loss
    }

    /// Uniform on [0, 1): xorshift64*, enough for jitter and loss.
    fn uniform(&mut self) -> f64 {
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        (self.rng.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// What a relay carries: the transport of the endpoint it stands in front of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Carrying {
    /// TCP connections (`tcp/`).
    Stream,
    /// UDP datagrams (`quic/`).
    Datagrams,
}

impl Carrying {
    /// The relay an endpoint's protocol needs.
    pub fn for_protocol(protocol: &str) -> Self {
        match protocol {
            "quic" | "udp" => Self::Datagrams,
            _ => Self::Stream,
        }
    }
}

/// A relay: listens on [`Relay::local`] and carries each connection (or
/// each peer's datagrams) to its upstream, shaped both ways. Stops
/// accepting when dropped; TCP connections already carried go on until
/// either end closes, datagram sessions end with it.
pub struct Relay {
    local: SocketAddr,
    stop: Arc<AtomicBool>,
}

impl Relay {
    /// Listens on `listen` (port 0: any) and relays to `upstream`.
    pub fn start(
        carrying: Carrying,
        listen: SocketAddr,
        upstream: SocketAddr,
        shaping: Shaping,
    ) -> std::io::Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let local = match carrying {
            Carrying::Stream => start_stream(listen, upstream, shaping, stop.clone())?,
            Carrying::Datagrams => start_datagrams(listen, upstream, shaping, stop.clone())?,
        };
        Ok(Self { local, stop })
    }

    /// Where it listens.
    pub fn local(&self) -> SocketAddr {
        self.local
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn start_stream(
    listen: SocketAddr,
    upstream: SocketAddr,
    shaping: Shaping,
    stopped: Arc<AtomicBool>,
) -> std::io::Result<SocketAddr> {
    let listener = TcpListener::bind(listen)?;
    let local = listener.local_addr()?;
    // Accepts are polled, so that a dropped relay's thread ends.
    listener.set_nonblocking(true)?;
    std::thread::Builder::new()
        .name(format!("relay-{local}"))
        .spawn(move || {
            let mut seed = 0x9e37_79b9_7f4a_7c15u64 ^ u64::from(local.port());
            while !stopped.load(Ordering::Relaxed) {
                match listener.accept() {
                    Ok((inbound, _)) => {
                        seed = seed.wrapping_add(0x9e37_79b9);
                        if let Err(e) = carry(inbound, upstream, shaping, seed) {
                            tracing::debug!(%upstream, error = %e, "relay: connection not carried");
                        }
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                        std::thread::sleep(Duration::from_millis(5));
                    }
                    Err(e) => {
                        tracing::warn!(%local, error = %e, "relay: accept failed");
                        std::thread::sleep(Duration::from_millis(50));
                    }
                }
            }
        })?;
    Ok(local)
}

/// How often a datagram relay's readers look whether the relay was dropped.
const DATAGRAM_POLL: Duration = Duration::from_millis(50);

/// A datagram relay: one front socket on `listen`; for each peer that
/// sends to it, a socket of its own towards `upstream`, so that the
/// upstream's answers find their way back to that peer.
fn start_datagrams(
    listen: SocketAddr,
    upstream: SocketAddr,
    shaping: Shaping,
    stopped: Arc<AtomicBool>,
) -> std::io::Result<SocketAddr> {
    let front = Arc::new(UdpSocket::bind(listen)?);
    let local = front.local_addr()?;
    front.set_read_timeout(Some(DATAGRAM_POLL))?;
    std::thread::Builder::new()
        .name(format!("relay-{local}"))
        .spawn(move || {
            let mut peers: HashMap<SocketAddr, Peer> = HashMap::new();
            let mut seed = 0x9e37_79b9_7f4a_7c15u64 ^ u64::from(local.port());
            let mut buf = vec![0u8; 64 << 10];
            while !stopped.load(Ordering::Relaxed) {
                let (n, from) = match front.recv_from(&mut buf) {
                    Ok(got) => got,
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) =>
                    {
                        continue
                    }
                    Err(e) => {
                        tracing::debug!(%local, error = %e, "relay: receive failed");
                        continue;
                    }
                };
                let peer = match peers.entry(from) {
                    std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
                    std::collections::hash_map::Entry::Vacant(e) => {
                        seed = seed.wrapping_add(0x9e37_79b9);
                        match Peer::open(&front, from, upstream, shaping, seed, stopped.clone()) {
                            Ok(p) => e.insert(p),
                            Err(err) => {
                                tracing::debug!(%upstream, error = %err, "relay: peer not carried");
                                continue;
                            }
                        }
                    }
                };
                peer.forward(&buf[..n]);
            }
        })?;
    Ok(local)
}

/// One peer of a datagram relay: its datagrams go upstream from a socket
/// of its own, and what comes back on that socket goes to it.
struct Peer {
    schedule: Schedule,
    upstream: mpsc::Sender<(Instant, Vec<u8>)>,
}

impl Peer {
    fn open(
        front: &Arc<UdpSocket>,
        peer: SocketAddr,
        upstream: SocketAddr,
        shaping: Shaping,
        seed: u64,
        stopped: Arc<AtomicBool>,
    ) -> std::io::Result<Self> {
        let any: SocketAddr = if upstream.is_ipv4() {
            "0.0.0.0:0".parse().expect("an address")
        } else {
            "[::]:0".parse().expect("an address")
        };
        let back = Arc::new(UdpSocket::bind(any)?);
        back.connect(upstream)?;
        back.set_read_timeout(Some(DATAGRAM_POLL))?;
        let to_upstream = {
            let back = back.clone();
            send_at_release(move |bytes| sent(back.send(bytes)), || {})?
        };
        let to_peer = {
            let front = front.clone();
            send_at_release(move |bytes| sent(front.send_to(bytes, peer)), || {})?
        };
        let mut schedule = Schedule::new(shaping, seed.rotate_left(17));
        std::thread::Builder::new()
            .name("relay-back".into())
            .spawn(move || {
                let mut buf = vec![0u8; 64 << 10];
                while !stopped.load(Ordering::Relaxed) {
                    match back.recv(&mut buf) {
                        Ok(n) => {
                            if schedule.lost() {
                                continue;
                            }
                            let at = schedule.release(Instant::now(), n);
                            if to_peer.send((at, buf[..n].to_vec())).is_err() {
                                break;
                            }
                        }
                        // A timeout, or an ICMP refusal from an upstream
                        // not listening yet: keep going.
                        Err(_) => continue,
                    }
                }
            })?;
        Ok(Self {
            schedule: Schedule::new(shaping, seed),
            upstream: to_upstream,
        })
    }

    /// Sends one datagram of the peer's upstream, unless the link loses it.
    fn forward(&mut self, bytes: &[u8]) {
        if self.schedule.lost() {
            return;
        }
        let at = self.schedule.release(Instant::now(), bytes.len());
        let _ = self.upstream.send((at, bytes.to_vec()));
    }
}

/// A thread that sends each chunk given it at its release time, while
/// `send` says to go on, and then calls `end`. It ends when the sender is
/// dropped. Both relays' sending sides.
fn send_at_release(
    mut send: impl FnMut(&[u8]) -> bool + Send + 'static,
    end: impl FnOnce() + Send + 'static,
) -> std::io::Result<mpsc::Sender<(Instant, Vec<u8>)>> {
    let (tx, rx) = mpsc::channel::<(Instant, Vec<u8>)>();
    std::thread::Builder::new()
        .name("relay-send".into())
        .spawn(move || {
            for (at, bytes) in rx {
                let now = Instant::now();
                if at > now {
                    std::thread::sleep(at - now);
                }
                if !send(&bytes) {
                    break;
                }
            }
            end();
        })?;
    Ok(tx)
}

/// Sends a datagram; a datagram not sent is as lost, and the next may go.
fn sent(result: std::io::Result<usize>) -> bool {
    if let Err(e) = result {
        tracing::debug!(error = %e, "relay: datagram not sent");
    }
    true
}

/// Connects `inbound` to `upstream`, a shaped pump each way.
fn carry(
    inbound: TcpStream,
    upstream: SocketAddr,
    shaping: Shaping,
    seed: u64,
) -> std::io::Result<()> {
    inbound.set_nonblocking(false)?;
    let outbound = TcpStream::connect_timeout(&upstream, Duration::from_secs(5))?;
    for s in [&inbound, &outbound] {
        s.set_nodelay(true)?;
    }
    pump(
        inbound.try_clone()?,
        outbound.try_clone()?,
        Schedule::new(shaping, seed),
    )?;
    pump(
        outbound,
        inbound,
        Schedule::new(shaping, seed.rotate_left(17)),
    )?;
    Ok(())
}

/// Reads `from` on one thread and writes to `to` on another, each chunk
/// at its release time. At the end of `from`, the chunks still held are
/// written, then `to`'s sending side is shut.
fn pump(mut from: TcpStream, to: TcpStream, mut schedule: Schedule) -> std::io::Result<()> {
    let ending = to.try_clone()?;
    let tx = send_at_release(
        move |bytes| (&to).write_all(bytes).is_ok(),
        move || {
            let _ = ending.shutdown(Shutdown::Write);
        },
    )?;
    std::thread::Builder::new()
        .name("relay-read".into())
        .spawn(move || {
            let mut buf = vec![0u8; 64 << 10];
            loop {
                match from.read(&mut buf) {
                    Ok(0) | Err(_) => break,
                    Ok(n) => {
                        let at = schedule.release(Instant::now(), n);
                        if tx.send((at, buf[..n].to_vec())).is_err() {
                            break;
                        }
                    }
                }
            }
        })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shaping(delay_ms: u64, jitter_ms: u64, rate: f64) -> Shaping {
        Shaping {
            delay: Duration::from_millis(delay_ms),
            jitter: Duration::from_millis(jitter_ms),
            rate_bits_per_s: rate,
            loss: 0.0,
        }
    }

    #[test]
    fn a_schedule_delays_keeps_order_and_keeps_to_the_rate() {
        let t0 = Instant::now();
        let mut s = Schedule::new(shaping(5, 0, 0.0), 1);
        assert_eq!(s.release(t0, 100), t0 + Duration::from_millis(5));
        // 1000 bytes at 80 kbit/s take 100 ms to send; the second chunk
        // waits for the first.
        let mut s = Schedule::new(shaping(5, 0, 80_000.0), 1);
        assert_eq!(s.release(t0, 1000), t0 + Duration::from_millis(105));
        assert_eq!(s.release(t0, 1000), t0 + Duration::from_millis(205));
        // Jitter stays within ±jitter and never reorders.
        let mut s = Schedule::new(shaping(10, 4, 0.0), 7);
        let mut last = t0;
        let mut spread = (Duration::MAX, Duration::ZERO);
        for i in 0..2000u64 {
            let now = t0 + Duration::from_millis(i);
            let at = s.release(now, 10);
            assert!(at >= last);
            last = at;
            let d = at - now;
            spread = (spread.0.min(d), spread.1.max(d));
        }
        assert!(spread.0 >= Duration::from_millis(6), "{spread:?}");
        assert!(spread.1 <= Duration::from_millis(14), "{spread:?}");
        assert!(
            spread.1 - spread.0 >= Duration::from_millis(6),
            "{spread:?}"
        );
    }

    #[test]
    fn nothing_to_do_is_no_relay() {
        assert_eq!(Shaping::from_link(&HostLink::default()), None);
        let l = HostLink {
            delay_ms: 5.0,
            ..Default::default()
        };
        assert_eq!(Shaping::from_link(&l), Some(shaping(5, 0, 0.0)));
    }

    /// Bytes through a relay come back in order, whole, and a round trip
    /// through it takes at least twice its delay.
    #[test]
    fn a_relay_carries_a_stream_with_its_delay() {
        let echo = TcpListener::bind("127.0.0.1:0").unwrap();
        let upstream = echo.local_addr().unwrap();
        std::thread::spawn(move || {
            let (mut c, _) = echo.accept().unwrap();
            let mut buf = [0u8; 4096];
            loop {
                match c.read(&mut buf) {
                    Ok(0) | Err(_) => break,
                    Ok(n) => c.write_all(&buf[..n]).unwrap(),
                }
            }
        });
        let relay = Relay::start(
            Carrying::Stream,
            "127.0.0.1:0".parse().unwrap(),
            upstream,
            shaping(20, 0, 0.0),
        )
        .unwrap();
        let mut c = TcpStream::connect(relay.local()).unwrap();
        c.set_nodelay(true).unwrap();
        let sent: Vec<u8> = (0..100_000u32).map(|i| (i % 251) as u8).collect();
        let started = Instant::now();
        let mut writer = c.try_clone().unwrap();
        let to_send = sent.clone();
        std::thread::spawn(move || writer.write_all(&to_send).unwrap());
        let mut got = vec![0u8; sent.len()];
        c.read_exact(&mut got).unwrap();
        assert!(started.elapsed() >= Duration::from_millis(40));
        assert_eq!(got, sent);
    }

    /// Datagrams through a relay come back whole, after twice its delay,
    /// and a lossy relay drops about its share of them each way.
    #[test]
    fn a_datagram_relay_delays_and_drops_its_share() {
        let echo = UdpSocket::bind("127.0.0.1:0").unwrap();
        let upstream = echo.local_addr().unwrap();
        std::thread::spawn(move || {
            let mut buf = [0u8; 2048];
            while let Ok((n, from)) = echo.recv_from(&mut buf) {
                echo.send_to(&buf[..n], from).unwrap();
            }
        });
        let relay = Relay::start(
            Carrying::Datagrams,
            "127.0.0.1:0".parse().unwrap(),
            upstream,
            shaping(20, 0, 0.0),
        )
        .unwrap();
        let c = UdpSocket::bind("127.0.0.1:0").unwrap();
        c.connect(relay.local()).unwrap();
        c.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        let started = Instant::now();
        c.send(b"one datagram").unwrap();
        let mut buf = [0u8; 64];
        let n = c.recv(&mut buf).unwrap();
        assert_eq!(&buf[..n], b"one datagram");
        assert!(started.elapsed() >= Duration::from_millis(40));

        // 20 % each way: about 64 % of round trips come back. With 2000
        // sent, the count's standard deviation is about 21.
        let lossy = Relay::start(
            Carrying::Datagrams,
            "127.0.0.1:0".parse().unwrap(),
            upstream,
            Shaping {
                loss: 0.2,
                ..shaping(0, 0, 0.0)
            },
        )
        .unwrap();
        let c = UdpSocket::bind("127.0.0.1:0").unwrap();
        c.connect(lossy.local()).unwrap();
        // Read as they come, so that no kernel buffer overflows and loses
        // what the relay did not.
        c.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        let reader = c.try_clone().unwrap();
        let counting = std::thread::spawn(move || {
            let mut buf = [0u8; 64];
            let mut back = 0u32;
            while reader.recv(&mut buf).is_ok() {
                back += 1;
            }
            back
        });
        let sent = 2000u32;
        for i in 0..sent {
            c.send(&i.to_le_bytes()).unwrap();
            // Paced, so that no kernel buffer on the way overflows.
            if i % 50 == 49 {
                std::thread::sleep(Duration::from_millis(5));
            }
        }
        let back = counting.join().unwrap();
        assert!((1140..=1420).contains(&back), "{back} of {sent} came back");
    }
}
