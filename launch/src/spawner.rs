//! Starting children from a thread whose descriptor table holds almost
//! nothing.
//!
//! A child starts with a copy of its parent's descriptor table and closes,
//! at exec, every descriptor marked close-on-exec. The supervisor holds a
//! pipe and a pidfd for each child it has started, so the k-th child copied
//! and closed 2k descriptors: 6.8 million closes for a network of 2,601
//! processes, the square of the network. The spawner is a thread with a
//! table of its own (`unshare(CLONE_FILES)`) that holds standard input and
//! output and one end of a socket; for each child it makes the pipe, starts
//! the child, opens its pidfd, and hands both descriptors to the supervisor
//! over the socket (`SCM_RIGHTS`), keeping none.
//!
//! The thread lives until the spawner is dropped: a child's parent-death
//! signal (`PR_SET_PDEATHSIG`) follows the thread that started it.

use std::ffi::OsString;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::path::PathBuf;
use std::process::Stdio;
use std::sync::mpsc;
use std::thread::JoinHandle;

/// A started child: its pid, the read end of its output (stdout and stderr
/// in one pipe) and a pidfd that becomes readable when it exits.
#[derive(Debug)]
pub struct Spawned {
    pub pid: u32,
    pub output: OwnedFd,
    pub pidfd: OwnedFd,
}

struct Request {
    program: PathBuf,
    args: Vec<OsString>,
}

/// The spawner thread and the supervisor's end of its socket.
pub struct Spawner {
    requests: Option<mpsc::Sender<Request>>,
    replies: OwnedFd,
    thread: Option<JoinHandle<()>>,
}

/// What one reply carries besides its descriptors: 0 or an errno, and the
/// child's pid.
const REPLY_LEN: usize = 8;

impl Spawner {
    pub fn start() -> io::Result<Self> {
        let (mine, theirs) = socket_pair()?;
        let (requests, incoming) = mpsc::channel::<Request>();
        let thread = std::thread::Builder::new()
            .name("spawner".into())
            .spawn(move || serve(incoming, theirs))?;
        Ok(Self {
            requests: Some(requests),
            replies: mine,
            thread: Some(thread),
        })
    }

    /// Starts `program` with `args`, standard input from `/dev/null`.
    pub fn spawn(&self, program: PathBuf, args: Vec<OsString>) -> io::Result<Spawned> {
        self.requests
            .as_ref()
            .expect("the sender lives as long as the spawner")
            .send(Request { program, args })
            .map_err(|_| io::Error::other("the spawner thread has stopped"))?;
        receive_reply(&self.replies)
    }
}

impl Drop for Spawner {
    fn drop(&mut self) {
        self.requests.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The spawner thread: one reply per request, until the spawner is dropped.
fn serve(requests: mpsc::Receiver<Request>, socket: OwnedFd) {
    own_a_small_table(socket.as_raw_fd());
    for Request { program, args } in requests {
        let reply = start_child(program, args);
        if send_reply(&socket, reply).is_err() {
            return;
        }
    }
}

/// Gives this thread a descriptor table of its own with nothing in it but
/// standard input, output and error and `keep`. Signals are blocked first:
/// a handler that ran here would write to descriptor numbers that mean
/// something else in this table (tokio's signal pipe). Where the kernel
/// refuses, the thread keeps sharing the process's table, which only costs
/// time.
fn own_a_small_table(keep: RawFd) {
    use nix::sys::signal::{pthread_sigmask, SigSet, SigmaskHow};
    if pthread_sigmask(SigmaskHow::SIG_BLOCK, Some(&SigSet::all()), None).is_err() {
        return;
    }
    // SAFETY: unshare(CLONE_FILES) copies the calling thread's table; every
    // descriptor stays valid in both copies.
    if unsafe { libc::unshare(libc::CLONE_FILES) } != 0 {
        tracing::debug!(
            error = %io::Error::last_os_error(),
            "the spawner shares the process's descriptor table"
        );
        return;
    }
    let keep = keep as u32;
    // SAFETY: this table is this thread's alone now, and it uses none of the
    // descriptors it closes (only `keep` and 0-2). Errors (a kernel before
    // close_range) leave them open, which only costs time.
    unsafe {
        if keep > 3 {
            libc::syscall(libc::SYS_close_range, 3u32, keep - 1, 0u32);
        }
        libc::syscall(libc::SYS_close_range, keep + 1, u32::MAX, 0u32);
    }
}

fn start_child(program: PathBuf, args: Vec<OsString>) -> io::Result<(u32, OwnedFd, OwnedFd)> {
    let (output, child_output) = io::pipe()?;
    let mut command = std::process::Command::new(program);
    command
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::from(child_output.try_clone()?))
        .stderr(Stdio::from(child_output));
    let child = command.spawn()?;
    // The write ends close with the command, here: the reader must see the
    // end when the child exits.
    drop(command);
    let pid = child.id();
    match pidfd_open(pid) {
        Ok(pidfd) => Ok((pid, output.into(), pidfd)),
        Err(e) => {
            // Unwatchable: not left running.
            // SAFETY: the child is ours and not yet reaped, so the pid is its.
            unsafe {
                libc::kill(pid as i32, libc::SIGKILL);
                libc::waitpid(pid as i32, std::ptr::null_mut(), 0);
            }
            Err(e)
        }
    }
}

fn pidfd_open(pid: u32) -> io::Result<OwnedFd> {
    // SAFETY: pidfd_open takes a pid and flags and returns a new descriptor.
    let fd = unsafe { libc::syscall(libc::SYS_pidfd_open, pid as libc::pid_t, 0u32) };
    if fd < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: the kernel just gave us this descriptor.
    Ok(unsafe { OwnedFd::from_raw_fd(fd as RawFd) })
}

fn socket_pair() -> io::Result<(OwnedFd, OwnedFd)> {
    let mut fds = [0 as RawFd; 2];
    // SAFETY: socketpair writes two descriptors into the array on success.
    let r = unsafe {
        libc::socketpair(
            libc::AF_UNIX,
            libc::SOCK_SEQPACKET | libc::SOCK_CLOEXEC,
            0,
            fds.as_mut_ptr(),
        )
    };
    if r != 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: both are new descriptors that nothing else owns.
    Ok(unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) })
}

/// The control-message buffer for two descriptors, aligned as `cmsghdr`.
#[repr(C)]
union Control {
    header: libc::cmsghdr,
    bytes: [u8; 64],
}

fn send_reply(socket: &OwnedFd, reply: io::Result<(u32, OwnedFd, OwnedFd)>) -> io::Result<()> {
    let (code, pid, fds) = match &reply {
        Ok((pid, output, pidfd)) => (0i32, *pid, vec![output.as_raw_fd(), pidfd.as_raw_fd()]),
        Err(e) => (e.raw_os_error().unwrap_or(libc::EIO), 0, Vec::new()),
    };
    let mut data = [0u8; REPLY_LEN];
    data[..4].copy_from_slice(&code.to_ne_bytes());
    data[4..].copy_from_slice(&pid.to_ne_bytes());
    let mut iov = buffer(&mut data);
    // SAFETY: all-zero is a valid control buffer.
    let mut control: Control = unsafe { std::mem::zeroed() };
    let fd_bytes = std::mem::size_of_val(fds.as_slice());
    // SAFETY: CMSG_SPACE is arithmetic.
    let space = if fds.is_empty() {
        0
    } else {
        unsafe { libc::CMSG_SPACE(fd_bytes as u32) as usize }
    };
    assert!(space <= std::mem::size_of::<Control>());
    let msg = header(&mut iov, &mut control, space);
    if !fds.is_empty() {
        // SAFETY: the control buffer holds CMSG_SPACE of the descriptors
        // (checked), and CMSG_FIRSTHDR points into it because
        // msg_controllen says so.
        unsafe {
            let header = libc::CMSG_FIRSTHDR(&msg);
            (*header).cmsg_level = libc::SOL_SOCKET;
            (*header).cmsg_type = libc::SCM_RIGHTS;
            (*header).cmsg_len = libc::CMSG_LEN(fd_bytes as u32) as usize;
            std::ptr::copy_nonoverlapping(
                fds.as_ptr().cast::<u8>(),
                libc::CMSG_DATA(header),
                fd_bytes,
            );
        }
    }
    // SAFETY: msg points at live buffers for the duration of the call.
    retrying(|| unsafe { libc::sendmsg(socket.as_raw_fd(), &msg, libc::MSG_NOSIGNAL) })?;
    // The descriptors now travel in the message; ours close here.
    drop(reply);
    Ok(())
}

fn receive_reply(socket: &OwnedFd) -> io::Result<Spawned> {
    let mut data = [0u8; REPLY_LEN];
    let mut iov = buffer(&mut data);
    // SAFETY: all-zero is a valid control buffer.
    let mut control: Control = unsafe { std::mem::zeroed() };
    let mut msg = header(&mut iov, &mut control, std::mem::size_of::<Control>());
    // SAFETY: msg points at live buffers for the duration of the call.
    let received = retrying(|| unsafe {
        libc::recvmsg(socket.as_raw_fd(), &mut msg, libc::MSG_CMSG_CLOEXEC)
    })?;
    let mut fds = Vec::new();
    // SAFETY: the kernel filled the control buffer up to msg_controllen;
    // CMSG_FIRSTHDR/NXTHDR walk only that.
    unsafe {
        let mut header = libc::CMSG_FIRSTHDR(&msg);
        while !header.is_null() {
            if (*header).cmsg_level == libc::SOL_SOCKET && (*header).cmsg_type == libc::SCM_RIGHTS {
                let bytes = (*header).cmsg_len as usize - libc::CMSG_LEN(0) as usize;
                let data = libc::CMSG_DATA(header).cast::<RawFd>();
                for k in 0..bytes / std::mem::size_of::<RawFd>() {
                    fds.push(OwnedFd::from_raw_fd(data.add(k).read_unaligned()));
                }
            }
            header = libc::CMSG_NXTHDR(&msg, header);
        }
    }
    if received != REPLY_LEN {
        return Err(io::Error::other("the spawner's reply was cut short"));
    }
    let code = i32::from_ne_bytes(data[..4].try_into().expect("4 bytes"));
    let pid = u32::from_ne_bytes(data[4..].try_into().expect("4 bytes"));
    if code != 0 {
        return Err(io::Error::from_raw_os_error(code));
    }
    let mut fds = fds.into_iter();
    match (fds.next(), fds.next()) {
        (Some(output), Some(pidfd)) => Ok(Spawned { pid, output, pidfd }),
        _ => Err(io::Error::other(
            "the spawner's reply came without its descriptors",
        )),
    }
}

fn buffer(data: &mut [u8]) -> libc::iovec {
    libc::iovec {
        iov_base: data.as_mut_ptr().cast(),
        iov_len: data.len(),
    }
}

/// A message header over one buffer and the first `control_len` bytes of
/// `control`.
fn header(iov: &mut libc::iovec, control: &mut Control, control_len: usize) -> libc::msghdr {
    // SAFETY: all-zero is a valid msghdr.
    let mut msg: libc::msghdr = unsafe { std::mem::zeroed() };
    msg.msg_iov = iov;
    msg.msg_iovlen = 1;
    if control_len > 0 {
        msg.msg_control = (control as *mut Control).cast();
        msg.msg_controllen = control_len;
    }
    msg
}

/// Makes a system call until a signal does not interrupt it.
fn retrying(mut call: impl FnMut() -> isize) -> io::Result<usize> {
    loop {
        let n = call();
        if n >= 0 {
            return Ok(n as usize);
        }
        let e = io::Error::last_os_error();
        if e.kind() != io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    /// A child started by the spawner writes to the pipe it was handed and
    /// is reaped with its exit code; it inherits only standard input and
    /// output, whatever the process holds, and none of the spawner
    /// thread's blocked signals.
    #[test]
    fn a_child_from_the_spawner_reports_through_its_descriptors() {
        // Descriptors the process holds that the spawner must not pass on.
        let held: Vec<std::fs::File> = (0..50)
            .map(|_| std::fs::File::open("/dev/null").unwrap())
            .collect();
        let spawner = Spawner::start().unwrap();
        let child = spawner
            .spawn(
                "/bin/sh".into(),
                vec![
                    "-c".into(),
                    "echo ready; ls /proc/self/fd | wc -l; grep SigBlk /proc/self/status; \
                     echo oops >&2; exit 3"
                        .into(),
                ],
            )
            .unwrap();
        let mut output = String::new();
        std::fs::File::from(child.output)
            .read_to_string(&mut output)
            .unwrap();
        let lines: Vec<&str> = output.lines().collect();
        assert_eq!(lines[0], "ready");
        // 0, 1, 2 and the one `ls` opens to read the directory: nothing of
        // the 50 (or of the test harness's).
        let open: usize = lines[1].trim().parse().unwrap();
        assert!(open <= 4, "the child inherited {open} descriptors");
        // The spawner thread blocks every signal; its children must not.
        assert_eq!(
            lines[2].split_whitespace().collect::<Vec<_>>(),
            ["SigBlk:", "0000000000000000"]
        );
        assert_eq!(lines[3], "oops");
        let mut status = 0;
        // SAFETY: the child is ours; its output ended, so it is exiting.
        let reaped = unsafe { libc::waitpid(child.pid as i32, &mut status, 0) };
        assert_eq!(reaped, child.pid as i32);
        assert!(libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 3);
        drop(held);
    }

    #[test]
    fn a_program_that_does_not_exist_is_not_found() {
        let spawner = Spawner::start().unwrap();
        let e = spawner
            .spawn("/nonexistent/cqnet-test-program".into(), Vec::new())
            .unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::NotFound);
    }
}
