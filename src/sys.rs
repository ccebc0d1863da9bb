//! Every call into the C library, and every `unsafe` block outside a device's own
//! FFI module (`hw::kinect::ffi`, libfreenect loaded at run time), each with its
//! SAFETY note: signal handling (`sigaction`), signalling child processes (only
//! unreaped ones), thread scheduling, clocks and resource usage, file locks, and
//! receiving into uninitialised buffers. Callers get safe functions that return
//! `std::io::Result` or plain values.

use std::mem::MaybeUninit;
use std::process::Child;
use std::sync::atomic::{AtomicBool, Ordering};

/// The real user id of this process.
pub fn user_id() -> u32 {
    // SAFETY: getuid has no preconditions and cannot fail.
    unsafe { libc::getuid() }
}

static STOP_SIGNAL: AtomicBool = AtomicBool::new(false);

extern "C" fn on_stop_signal(_: libc::c_int) {
    // Async-signal-safe: a store to an atomic, nothing else.
    STOP_SIGNAL.store(true, Ordering::SeqCst);
}

/// Installs `handler` for `signal` with `sigaction` (`SA_RESTART`: interrupted
/// system calls resume; no signal is blocked while it runs besides itself).
fn install_handler(
    signal: libc::c_int,
    handler: extern "C" fn(libc::c_int),
) -> std::io::Result<()> {
    // SAFETY: an all-zero `sigaction` is a valid value of the plain C struct.
    let mut action: libc::sigaction = unsafe { std::mem::zeroed() };
    action.sa_sigaction = handler as usize as libc::sighandler_t;
    action.sa_flags = libc::SA_RESTART;
    // SAFETY: `action.sa_mask` is a valid, writable sigset_t.
    unsafe { libc::sigemptyset(&mut action.sa_mask) };
    // SAFETY: `action` is fully initialised and outlives the call; the old action is
    // not asked for (null). The handler only does async-signal-safe work.
    let rc = unsafe { libc::sigaction(signal, &action, std::ptr::null_mut()) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// Makes SIGTERM and SIGINT set a flag ([`stop_signal_received`]) instead of
/// ending the process.
pub fn install_stop_signal_handler() -> std::io::Result<()> {
    install_handler(libc::SIGTERM, on_stop_signal)?;
    install_handler(libc::SIGINT, on_stop_signal)
}

/// True once SIGTERM or SIGINT arrived (after [`install_stop_signal_handler`]).
pub fn stop_signal_received() -> bool {
    STOP_SIGNAL.load(Ordering::SeqCst)
}

/// Sends SIGTERM to `child` unless it has already been reaped; returns whether it
/// was sent. A child that has exited but was not yet waited for stays a zombie that
/// holds its PID, and only this process reaps it (through `child`), so the PID
/// signalled is never one the kernel has given to another process.
pub fn terminate_child(child: &mut Child) -> std::io::Result<bool> {
    if child.try_wait()?.is_some() {
        return Ok(false);
    }
    let pid = libc::pid_t::try_from(child.id())
        .map_err(|_| std::io::Error::other(format!("child id {} is not a pid", child.id())))?;
    // SAFETY: kill(2) with the PID of our own unreaped child (see above); no memory
    // is involved.
    if unsafe { libc::kill(pid, libc::SIGTERM) } == 0 {
        Ok(true)
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// Puts the calling thread under `SCHED_FIFO` at `priority`; the OS error when it
/// is not permitted or the priority is out of range.
pub fn set_thread_fifo_priority(priority: i32) -> std::io::Result<()> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pthread_self() is always a valid handle of the calling thread and
    // `param` outlives the call.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::from_raw_os_error(rc))
    }
}

/// The calling thread's real-time priority: `Some(priority)` under `SCHED_FIFO` or
/// `SCHED_RR`, `None` under a normal policy.
pub fn thread_realtime_priority() -> Option<i32> {
    let mut policy = 0;
    let mut param = libc::sched_param { sched_priority: 0 };
    // SAFETY: valid handle of the calling thread; both out-pointers are live locals.
    let rc = unsafe { libc::pthread_getschedparam(libc::pthread_self(), &mut policy, &mut param) };
    (rc == 0 && (policy == libc::SCHED_FIFO || policy == libc::SCHED_RR))
        .then_some(param.sched_priority)
}

/// Puts the calling thread under `SCHED_OTHER` at nice 19 (dropping a real-time
/// policy inherited from its parent).
pub fn set_thread_background_priority() -> std::io::Result<()> {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pthread_self() is the calling thread's valid handle and `param`
    // outlives the call; gettid has no preconditions, and setpriority on the
    // calling thread's own id only changes its nice value.
    let rc = unsafe {
        libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_OTHER, &param);
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        libc::setpriority(libc::PRIO_PROCESS, tid, 19)
    };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// The time of `clock` (ns); `None` if the clock does not exist.
fn clock_ns(clock: libc::clockid_t) -> Option<u64> {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec that outlives the call.
    let rc = unsafe { libc::clock_gettime(clock, &mut ts) };
    (rc == 0).then(|| ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64)
}

/// Nanoseconds of `CLOCK_MONOTONIC` (system-wide on Linux; 0 where it is missing,
/// which Linux never is).
pub fn monotonic_ns() -> u64 {
    clock_ns(libc::CLOCK_MONOTONIC).unwrap_or(0)
}

/// CPU time (ms) of the calling thread (`per_thread`) or of the whole process
/// (NaN where the clock is missing, which Linux never is).
pub fn cpu_time_ms(per_thread: bool) -> f64 {
    let clock = if per_thread {
        libc::CLOCK_THREAD_CPUTIME_ID
    } else {
        libc::CLOCK_PROCESS_CPUTIME_ID
    };
    clock_ns(clock).map_or(f64::NAN, |ns| ns as f64 * 1e-6)
}

/// What `getrusage(RUSAGE_SELF)` reports of this process.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResourceUsage {
    /// User plus system CPU time (ms).
    pub cpu_ms: f64,
    /// Minor page faults.
    pub minor_page_faults: u64,
}

/// This process's resource usage so far; `None` if `getrusage` fails.
pub fn resource_usage() -> Option<ResourceUsage> {
    // SAFETY: an all-zero rusage is a valid value of the plain C struct.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `usage` is a valid, writable rusage; getrusage only writes it.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return None;
    }
    let ms = |t: libc::timeval| t.tv_sec as f64 * 1e3 + t.tv_usec as f64 * 1e-3;
    Some(ResourceUsage {
        cpu_ms: ms(usage.ru_utime) + ms(usage.ru_stime),
        minor_page_faults: u64::try_from(usage.ru_minflt).unwrap_or(0),
    })
}

/// Takes an exclusive `flock` on `file` (waits for it; retried on EINTR).
pub fn lock_file_exclusive(file: &std::fs::File) -> std::io::Result<()> {
    use std::os::fd::AsRawFd;
    loop {
        // SAFETY: flock on a valid open descriptor has no other preconditions.
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX) } == 0 {
            return Ok(());
        }
        let err = std::io::Error::last_os_error();
        if err.kind() != std::io::ErrorKind::Interrupted {
            return Err(err);
        }
    }
}

/// Takes an exclusive `flock` on `file` if no one holds it; `Ok(false)` when
/// another open file description holds it.
pub fn try_lock_file_exclusive(file: &std::fs::File) -> std::io::Result<bool> {
    use std::os::fd::AsRawFd;
    loop {
        // SAFETY: flock on a valid open descriptor has no other preconditions.
        if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
            return Ok(true);
        }
        let err = std::io::Error::last_os_error();
        match err.kind() {
            std::io::ErrorKind::Interrupted => continue,
            std::io::ErrorKind::WouldBlock => return Ok(false),
            _ => return Err(err),
        }
    }
}

/// Releases a `flock` on `file` (closing the file would release it too).
pub fn unlock_file(file: &std::fs::File) {
    use std::os::fd::AsRawFd;
    // SAFETY: flock on a valid open descriptor has no other preconditions.
    unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_UN) };
}

/// Receives one packet from `socket` into `buf` with `flags` (`MSG_*`); returns its
/// length (0 at end of stream). A packet longer than `buf` is truncated.
pub fn recv_packet(
    socket: &socket2::Socket,
    buf: &mut [u8; 64],
    flags: libc::c_int,
) -> std::io::Result<usize> {
    let mut raw = [MaybeUninit::<u8>::uninit(); 64];
    let n = socket.recv_with_flags(&mut raw, flags)?;
    for (dst, src) in buf.iter_mut().zip(&raw[..n]) {
        // SAFETY: recv initialised the first n bytes.
        *dst = unsafe { src.assume_init() };
    }
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_contained_panic_is_an_error_with_its_message() {
        assert_eq!(contain_panic(|| 3), Ok(3));
        assert_eq!(
            contain_panic(|| -> u8 { panic!("boom") }),
            Err(Panicked {
                message: "boom".to_string()
            })
        );
        let n = 7;
        assert_eq!(
            contain_panic(|| -> u8 { panic!("boom {n}") }),
            Err(Panicked {
                message: "boom 7".to_string()
            })
        );
    }

    #[test]
    fn a_held_lock_is_not_taken_twice() {
        let dir = crate::fsio::TempDir::new("sys-lock").unwrap();
        let path = dir.join("lock");
        let a = std::fs::File::create(&path).unwrap();
        let b = std::fs::File::create(&path).unwrap();
        assert!(try_lock_file_exclusive(&a).unwrap());
        assert!(!try_lock_file_exclusive(&b).unwrap());
        drop(a);
        assert!(try_lock_file_exclusive(&b).unwrap());
    }

    static USR1: AtomicBool = AtomicBool::new(false);

    extern "C" fn on_usr1(_: libc::c_int) {
        USR1.store(true, Ordering::SeqCst);
    }

    #[test]
    fn a_sigaction_handler_runs_instead_of_the_default_action() {
        // SIGUSR1 (default: terminate) so the stop flag of the test process is left alone.
        install_handler(libc::SIGUSR1, on_usr1).unwrap();
        // SAFETY: raise has no preconditions; the handler above is installed.
        assert_eq!(unsafe { libc::raise(libc::SIGUSR1) }, 0);
        assert!(USR1.load(Ordering::SeqCst));
        // SAFETY: an all-zero sigaction is valid; only the old action is read back.
        let mut old: libc::sigaction = unsafe { std::mem::zeroed() };
        let rc = unsafe { libc::sigaction(libc::SIGUSR1, std::ptr::null(), &mut old) };
        assert_eq!(rc, 0);
        let handler: extern "C" fn(libc::c_int) = on_usr1;
        assert_eq!(old.sa_sigaction, handler as usize as libc::sighandler_t);
        assert_ne!(old.sa_flags & libc::SA_RESTART, 0);
    }

    #[test]
    fn only_an_unreaped_child_is_signalled() {
        use std::os::unix::process::ExitStatusExt;
        let mut child = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .unwrap();
        assert!(terminate_child(&mut child).unwrap());
        let status = child.wait().unwrap();
        assert_eq!(status.signal(), Some(libc::SIGTERM));
        // Reaped: its PID may belong to someone else now, so nothing is sent.
        assert!(!terminate_child(&mut child).unwrap());
    }

    #[test]
    fn clocks_and_usage_are_read() {
        assert!(cpu_time_ms(true).is_finite() && cpu_time_ms(true) >= 0.0);
        assert!(cpu_time_ms(false).is_finite() && cpu_time_ms(false) >= 0.0);
        assert!(resource_usage().unwrap().cpu_ms >= 0.0);
        let t = monotonic_ns();
        assert!(t > 0 && monotonic_ns() >= t);
    }
}

thread_local! {
    /// Whether a panic on this thread is being contained ([`contain_panic`]).
    static CONTAINING: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// A panic that [`contain_panic`] caught; shows as the panic's message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct Panicked {
    /// The panic's message ("a panic without a message" when it had none).
    pub message: String,
}

/// Runs `f`, turning a panic inside it into an error with the panic's message
/// instead of a crash, for a dependency known to panic on some inputs. The panic
/// hook stays silent for a contained panic (on this thread only); every other panic
/// prints as before.
pub fn contain_panic<T>(f: impl FnOnce() -> T) -> Result<T, Panicked> {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !CONTAINING.with(|c| c.get()) {
                previous(info);
            }
        }));
    });
    let was = CONTAINING.with(|c| c.replace(true));
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    CONTAINING.with(|c| c.set(was));
    outcome.map_err(|payload| Panicked {
        message: payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".to_string()),
    })
}
