//! Real-time priority for the threads that answer a device's cycle (the FRI link).
//!
//! The LBR4+ drops out of command mode after five unanswered 1 ms measurements, so
//! the thread that answers them must not wait behind ordinary work. A thread asks
//! for `SCHED_FIFO`; where that is not permitted (no `CAP_SYS_NICE`, no
//! `LimitRTPRIO`) it keeps its normal priority and says so once in the log. On the
//! cell's machine the executor's systemd unit grants it (`CPUSchedulingPolicy=fifo`).

/// `SCHED_FIFO` priority of threads that answer a device cycle (1–99; the kernel's
/// interrupt threads run at 50, so this stays just above them).
pub const DEVICE_CYCLE_PRIORITY: i32 = 60;

/// `SCHED_FIFO` priority of the executor's control thread: below the device cycle,
/// above everything ordinary, so a control thread holding a driver's lock is never
/// preempted by ordinary work while the cycle thread waits for it.
pub const CONTROL_PRIORITY: i32 = 40;

/// Puts the calling thread under `SCHED_FIFO` at `priority`; the OS error when it
/// is not permitted or the priority is out of range.
pub fn set_fifo_priority(priority: i32) -> std::io::Result<()> {
    crate::sys::set_thread_fifo_priority(priority)
}

/// The calling thread's real-time priority: `Some(priority)` under `SCHED_FIFO` or
/// `SCHED_RR`, `None` under a normal policy.
pub fn current_realtime_priority() -> Option<i32> {
    crate::sys::thread_realtime_priority()
}

/// Lowers the calling thread to the lowest ordinary priority (`SCHED_OTHER`, nice
/// 19; a real-time policy inherited from its parent is dropped), for background
/// work beside a device's cycle (a simulator's physics); a failure only leaves it
/// where it was.
pub fn lower_thread_priority() {
    if let Err(e) = crate::sys::set_thread_background_priority() {
        tracing::debug!("cannot lower a background thread's priority: {e}");
    }
}

/// Asks for [`DEVICE_CYCLE_PRIORITY`] for thread `what` ([`request_priority`]).
pub fn request_device_cycle_priority(what: &str) {
    request_priority(what, DEVICE_CYCLE_PRIORITY);
}

/// Puts the calling thread (and the threads it starts later) under `SCHED_FIFO` at
/// `priority`, unless it already runs at a real-time priority at least as high
/// (e.g. set by its systemd unit); logs the outcome.
pub fn request_priority(what: &str, priority: i32) {
    if let Some(current) = current_realtime_priority().filter(|&p| p >= priority) {
        tracing::debug!("{what}: keeps its real-time priority {current}");
        return;
    }
    match set_fifo_priority(priority) {
        Ok(()) => tracing::debug!("{what}: SCHED_FIFO priority {priority}"),
        Err(e) => tracing::info!(
            "{what}: no real-time priority ({e}); cycles may be missed under load (grant CAP_SYS_NICE or run under the systemd unit)"
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn out_of_range_priorities_are_refused() {
        // Checked by the kernel before permissions, so this holds as root or not.
        let err = std::thread::spawn(|| set_fifo_priority(1000))
            .join()
            .unwrap()
            .unwrap_err();
        assert_eq!(err.raw_os_error(), Some(libc::EINVAL), "{err}");
    }

    #[test]
    fn a_thread_keeps_a_higher_priority_it_already_has() {
        std::thread::spawn(|| {
            if set_fifo_priority(DEVICE_CYCLE_PRIORITY + 10).is_err() {
                // Not permitted here: the thread stays normal and says so.
                assert_eq!(current_realtime_priority(), None);
                request_device_cycle_priority("test");
                assert_eq!(current_realtime_priority(), None);
                return;
            }
            request_device_cycle_priority("test");
            assert_eq!(
                current_realtime_priority(),
                Some(DEVICE_CYCLE_PRIORITY + 10)
            );
        })
        .join()
        .unwrap();
    }
}
