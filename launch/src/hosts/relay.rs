//! A host's link shaped in user space: every TCP connection of a host's
//! Zenoh session, in and out, passes through a relay of its own process
//! that holds each chunk of bytes for the link's delay (with its jitter)
//! and lets it go no faster than the link's rate. So `hosts[].link` works
//! where the kernel has no netem, on real machines as in namespaces.
//!
//! A connection between hosts `g` and `h` passes `g`'s relay and `h`'s, as
//! a packet between them passes both hosts' links: the delays add, as
//! they do with netem on both links.
//!
//! What a relay cannot stand for: **loss**. It sits on a TCP stream, whose
//! bytes all arrive; a lost packet's cost (a retransmission, a stalled
//! window) only the kernel can show. A link with `loss` needs netem. Its
//! jitter never reorders bytes (a stream has one order), so large jitter
//! on a relay delays more than on netem, where later packets may overtake.

use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
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
}

impl Shaping {
    /// What a host's `link` asks of a relay; `None` if nothing (a link
    /// with only a cut, or none).
    pub fn from_link(link: &HostLink) -> Option<Self> {
        let s = Self {
            delay: Duration::from_secs_f64(link.delay_ms / 1e3),
            jitter: Duration::from_secs_f64(link.jitter_ms / 1e3),
            rate_bits_per_s: link.rate_mbit * 1e6,
        };
        (s.delay > Duration::ZERO || s.jitter > Duration::ZERO || s.rate_bits_per_s > 0.0)
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

    /// Uniform on [0, 1): xorshift64*, enough for jitter.
    fn uniform(&mut self) -> f64 {
        self.rng ^= self.rng >> 12;
        self.rng ^= self.rng << 25;
        self.rng ^= self.rng >> 27;
        (self.rng.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A relay: listens on [`Relay::local`] and carries each connection to its
/// upstream, shaped both ways. Stops accepting when dropped; connections
/// already carried go on until either end closes.
pub struct Relay {
    local: SocketAddr,
    stop: Arc<AtomicBool>,
}

impl Relay {
    /// Listens on `listen` (port 0: any) and relays to `upstream`.
    pub fn start(
        listen: SocketAddr,
        upstream: SocketAddr,
        shaping: Shaping,
    ) -> std::io::Result<Self> {
        let listener = TcpListener::bind(listen)?;
        let local = listener.local_addr()?;
        // Accepts are polled, so that a dropped relay's thread ends.
        listener.set_nonblocking(true)?;
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
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
fn pump(mut from: TcpStream, mut to: TcpStream, mut schedule: Schedule) -> std::io::Result<()> {
    let (tx, rx) = mpsc::channel::<(Instant, Vec<u8>)>();
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
    std::thread::Builder::new()
        .name("relay-write".into())
        .spawn(move || {
            for (at, bytes) in rx {
                let now = Instant::now();
                if at > now {
                    std::thread::sleep(at - now);
                }
                if to.write_all(&bytes).is_err() {
                    break;
                }
            }
            let _ = to.shutdown(Shutdown::Write);
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
}
