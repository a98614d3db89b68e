//! The wake-up service's trigger: a futex word in the event's own shared
//! memory, in place of the Unix datagram socket of iceoryx2's `ipc`
//! service.
//!
//! Why: a consensus round wakes every node once per neighbour's message,
//! and through a socket each wake-up costs a `sendto` in the notifier and,
//! in the listener, a `setsockopt`, a blocking `recvfrom` and a draining one
//! (iceoryx2's `UnixDatagramWaiter`). Notifying and waiting were a seventh
//! of a node process's CPU in `cqnet run` (perf). A futex costs one system call to
//! sleep and one to wake, and none at all when the notified actor is awake
//! (it finds the word set before it would sleep), which is the common case
//! in a round on two busy cores.
//!
//! iceoryx2 builds its events from a bit set of event ids and a trigger
//! (`iceoryx2_cal::event::common::EventImpl`); its own semaphore trigger
//! would do, but its timed wait polls with `nanosleep` under a monotonic
//! clock. This module is only the trigger; the ids, the notification state
//! and the shared memory stay iceoryx2's. [`Service`] is iceoryx2's `ipc`
//! service with this event and nothing else changed.
//!
//! The protocol is the usual pair of flags: the notifier sets `pending`
//! and then looks for sleepers; the listener counts itself among the
//! sleepers and then looks at `pending` (both sequentially consistent, so
//! at least one of the two sees the other). `FUTEX_WAIT` sleeps only while
//! the word still reads 0, so a notification between the look and the
//! sleep is not lost.

use core::fmt::Debug;
use core::mem::MaybeUninit;
use core::ptr::NonNull;
use core::sync::atomic::{AtomicU32, Ordering::SeqCst};
use std::time::Duration;

use iceoryx2_bb_elementary_traits::testing::abandonable::Abandonable;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use iceoryx2_bb_lock_free::mpmc::counting_bit_set::RelocatableCountingBitSet;
use iceoryx2_bb_system_types::file_name::FileName;
use iceoryx2_bb_system_types::path::Path;
use iceoryx2_cal::dynamic_storage::{self, DynamicStorage};
use iceoryx2_cal::event::common::EventImpl;
use iceoryx2_cal::event::event_state::EventState;
use iceoryx2_cal::event::trigger::{Configuration, HandlerInterface, State, WaiterInterface};
use iceoryx2_cal::event::{
    ListenerCreateError, ListenerWaitError, NotifierNotifyError, NotifierOpenError,
};
use iceoryx2_cal::named_concept::{NamedConceptPathHintRemoveError, NamedConceptRemoveError};
use iceoryx2_cal::shm_allocator::bump_allocator::BumpAllocator;
use iceoryx2_cal::shm_allocator::pool_allocator::PoolAllocator;

/// The trigger's state, in the event's shared memory beside the bit set.
#[derive(Debug)]
#[repr(C)]
pub struct FutexWord {
    /// 1 from a notification until the listener empties its buffer.
    pending: AtomicU32,
    /// Listeners in, or on their way into, `FUTEX_WAIT`.
    sleepers: AtomicU32,
}

// SAFETY: two atomics and no pointer, the same layout in every process of
// the build.
unsafe impl ZeroCopySend for FutexWord {}

type Bits = RelocatableCountingBitSet;
type Storage = dynamic_storage::posix_shared_memory::Storage<State<Bits, FutexWord>>;

/// iceoryx2's event with the futex trigger.
pub type FutexEvent = EventImpl<Bits, FutexWord, Storage, FutexNotifier, FutexListener>;

/// A pointer to the word in shared memory the event keeps mapped: the
/// notifier and listener live inside iceoryx2's handle and waiter, which own
/// that mapping, so the word outlives them.
#[derive(Debug)]
struct Word(NonNull<FutexWord>);

// SAFETY: the word is atomics only, shared between processes already.
unsafe impl Send for Word {}
// SAFETY: as above.
unsafe impl Sync for Word {}

impl Word {
    fn get(&self) -> &FutexWord {
        // SAFETY: see the type's doc: the mapping outlives `self`.
        unsafe { self.0.as_ref() }
    }
}

#[derive(Debug)]
pub struct FutexNotifier {
    word: Word,
}

impl Abandonable for FutexNotifier {
    unsafe fn abandon_in_place(_this: NonNull<Self>) {}
}

impl<E: EventState, S: DynamicStorage<State<E, FutexWord>>> HandlerInterface<E, FutexWord, S>
    for FutexNotifier
{
    fn open(
        _name: &FileName,
        _config: &Configuration,
        mgmt: &FutexWord,
    ) -> Result<Self, NotifierOpenError> {
        Ok(Self {
            word: Word(NonNull::from(mgmt)),
        })
    }

    fn notify(&self) -> Result<(), NotifierNotifyError> {
        let w = self.word.get();
        w.pending.store(1, SeqCst);
        if w.sleepers.load(SeqCst) != 0 {
            futex_wake(&w.pending).map_err(|_| NotifierNotifyError::InternalFailure)?;
        }
        Ok(())
    }
}

#[derive(Debug)]
pub struct FutexListener {
    word: Word,
}

impl Abandonable for FutexListener {
    unsafe fn abandon_in_place(_this: NonNull<Self>) {}
}

impl FutexListener {
    /// Sleeps while nothing is pending, at most `timeout` (`None`: forever).
    fn sleep(&self, timeout: Option<Duration>) -> Result<(), ListenerWaitError> {
        let w = self.word.get();
        if w.pending.load(SeqCst) != 0 {
            return Ok(());
        }
        w.sleepers.fetch_add(1, SeqCst);
        let slept = if w.pending.load(SeqCst) == 0 {
            futex_wait(&w.pending, timeout)
        } else {
            Ok(())
        };
        w.sleepers.fetch_sub(1, SeqCst);
        slept
    }
}

impl<E: EventState, S: DynamicStorage<State<E, FutexWord>>> WaiterInterface<E, FutexWord, S>
    for FutexListener
{
    const IS_FILE_DESCRIPTOR_BASED: bool = false;

    unsafe fn remove(
        _name: &FileName,
        _config: &Configuration,
    ) -> Result<bool, NamedConceptRemoveError> {
        // Nothing outside the event's shared memory.
        Ok(true)
    }

    fn remove_path_hint(_value: &Path) -> Result<(), NamedConceptPathHintRemoveError> {
        Ok(())
    }

    fn create(
        _name: &FileName,
        _config: &Configuration,
        mgmt: &mut MaybeUninit<FutexWord>,
    ) -> Result<Self, ListenerCreateError> {
        let word = mgmt.write(FutexWord {
            pending: AtomicU32::new(0),
            sleepers: AtomicU32::new(0),
        });
        Ok(Self {
            word: Word(NonNull::from(&*word)),
        })
    }

    fn try_wait(&self) -> Result<(), ListenerWaitError> {
        // The event drains its bit set after this whatever it returns.
        Ok(())
    }

    fn timed_wait(&self, timeout: Duration) -> Result<(), ListenerWaitError> {
        self.sleep(Some(timeout))
    }

    fn blocking_wait(&self) -> Result<(), ListenerWaitError> {
        self.sleep(None)
    }

    fn empty_buffer(&self) -> Result<(), ListenerWaitError> {
        self.word.get().pending.store(0, SeqCst);
        Ok(())
    }
}

/// `FUTEX_WAIT` on a word other processes map too (so not the private
/// variant), while it reads 0. A timeout and a changed word both return
/// `Ok`: the caller looks at the bit set either way.
fn futex_wait(word: &AtomicU32, timeout: Option<Duration>) -> Result<(), ListenerWaitError> {
    let ts = timeout.map(|t| libc::timespec {
        tv_sec: t.as_secs().min(i64::MAX as u64) as libc::time_t,
        tv_nsec: t.subsec_nanos() as libc::c_long,
    });
    let ts_ptr = ts
        .as_ref()
        .map_or(core::ptr::null(), |t| t as *const libc::timespec);
    // SAFETY: the word is a live atomic; the kernel reads it and the
    // timespec only during the call.
    let r = unsafe {
        libc::syscall(
            libc::SYS_futex,
            word.as_ptr(),
            libc::FUTEX_WAIT,
            0u32,
            ts_ptr,
            core::ptr::null::<u32>(),
            0u32,
        )
    };
    if r == 0 {
        return Ok(());
    }
    match std::io::Error::last_os_error().raw_os_error() {
        Some(libc::EAGAIN) | Some(libc::ETIMEDOUT) => Ok(()),
        Some(libc::EINTR) => Err(ListenerWaitError::InterruptSignal),
        _ => Err(ListenerWaitError::InternalFailure),
    }
}

/// Wakes every process sleeping on `word`.
fn futex_wake(word: &AtomicU32) -> std::io::Result<()> {
    // SAFETY: as in `futex_wait`; FUTEX_WAKE only reads the address.
    let r = unsafe {
        libc::syscall(
            libc::SYS_futex,
            word.as_ptr(),
            libc::FUTEX_WAKE,
            i32::MAX,
            core::ptr::null::<libc::timespec>(),
            core::ptr::null::<u32>(),
            0u32,
        )
    };
    if r < 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// iceoryx2's `ipc` service, every part the same but the event.
#[derive(Debug, Clone)]
pub struct Service {}

impl iceoryx2::service::Service for Service {
    type StaticStorage = iceoryx2_cal::static_storage::recommended::Ipc;
    type ConfigSerializer = iceoryx2_cal::serialize::recommended::Recommended;
    type PersistentDynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
        dynamic_storage::recommended::PersistentIpc<T>;
    type Bag = iceoryx2_cal::bag::recommended::Recommended;
    type DynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
        dynamic_storage::recommended::Ipc<T>;
    type ServiceNameHasher = iceoryx2_cal::hash::recommended::Recommended;
    type SharedMemory = iceoryx2_cal::shared_memory::recommended::Ipc<PoolAllocator>;
    type ResizableSharedMemory =
        iceoryx2_cal::resizable_shared_memory::recommended::Ipc<PoolAllocator>;
    type Connection = iceoryx2_cal::zero_copy_connection::recommended::Ipc;
    type Event = FutexEvent;
    type Monitoring = iceoryx2_cal::monitoring::recommended::Ipc;
    type Reactor = iceoryx2_cal::reactor::recommended::Ipc;
    type ArcThreadSafetyPolicy<T: Send + Debug + Abandonable> =
        iceoryx2_cal::arc_sync_policy::single_threaded::SingleThreaded<T>;
    type BlackboardMgmt<KeyType: Send + Sync + Debug + ZeroCopySend + 'static> =
        dynamic_storage::recommended::Ipc<KeyType>;
    type BlackboardPayload = iceoryx2_cal::shared_memory::recommended::Ipc<BumpAllocator>;
    type UniqueId = iceoryx2::unique_id_generator::unique_system_id::UniqueSystemId;
}

impl iceoryx2::service::internal::ServiceInternal<Service> for Service {}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use iceoryx2::prelude::*;

    use super::Service;
    use crate::iceoryx::{remove_run_resources, RunResources};
    use crate::{DeadNodeSweep, RunId};

    /// A node of this test's own run, configured as the transport's are,
    /// whose files `Cleanup` removes.
    fn test_node(run: &RunId) -> Node<Service> {
        let config = run.config(DeadNodeSweep::Off).unwrap();
        NodeBuilder::new()
            .config(&config)
            .create::<Service>()
            .unwrap()
    }

    struct Cleanup(RunId);

    impl Drop for Cleanup {
        fn drop(&mut self) {
            let _ = remove_run_resources(&self.0);
        }
    }

    fn event_name(run: &RunId) -> ServiceName {
        ServiceName::new(&format!("cqnet/{}/futex-test", run.as_str())).unwrap()
    }

    fn ids(
        listener: &iceoryx2::port::listener::Listener<Service>,
        timeout: Duration,
    ) -> Vec<usize> {
        let mut ids = Vec::new();
        listener
            .timed_wait(|e| ids.push(e.id.as_value()), timeout)
            .unwrap();
        ids
    }

    /// A notification that comes before the wait is not lost, nor is one
    /// that comes while the listener sleeps; with none, the wait times out.
    #[test]
    fn notifications_before_and_during_a_wait_arrive_and_silence_times_out() {
        let run = RunId::new(&format!("futex-{}", std::process::id())).unwrap();
        let _cleanup = Cleanup(run.clone());
        let node = test_node(&run);
        let event = node
            .service_builder(&event_name(&run))
            .event()
            .event_id_max_value(8)
            .open_or_create()
            .unwrap();
        let listener = event.listener_builder().create().unwrap();
        let notifier = event.notifier_builder().create().unwrap();

        // Before the wait: returned at once, with its id.
        notifier
            .notify_with_custom_event_id(EventId::new(3))
            .unwrap();
        let started = Instant::now();
        assert_eq!(ids(&listener, Duration::from_secs(30)), vec![3]);
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "it did not sleep out the wait"
        );

        // Nothing pending: the wait lasts its timeout and brings nothing.
        let started = Instant::now();
        assert!(ids(&listener, Duration::from_millis(20)).is_empty());
        assert!(started.elapsed() >= Duration::from_millis(20));

        // From another thread, with its own node, while we sleep.
        let name = event_name(&run);
        let waker_run = run.clone();
        let waker = std::thread::spawn(move || {
            let node = test_node(&waker_run);
            let event = node.service_builder(&name).event().open().unwrap();
            let notifier = event.notifier_builder().create().unwrap();
            std::thread::sleep(Duration::from_millis(50));
            notifier
                .notify_with_custom_event_id(EventId::new(5))
                .unwrap();
        });
        let started = Instant::now();
        let mut heard = Vec::new();
        while heard.is_empty() && started.elapsed() < Duration::from_secs(30) {
            heard = ids(&listener, Duration::from_secs(30));
        }
        waker.join().unwrap();
        assert_eq!(heard, vec![5]);
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "woken by the notification, not by the timeout"
        );
    }
}
