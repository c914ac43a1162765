//! Threads that must yield to the frame path (map solves, map saves)
//! lower their own scheduling priority as they start.

/// Makes the calling thread `steps` nicer than it is, up to 19 (Linux
/// keeps a nice value per thread; a new thread inherits its creator's).
/// Only ever lowers the priority, which needs no privilege. A failure is
/// logged and the thread runs on at its priority.
pub fn lower_this_threads_priority(steps: i32) {
    // SAFETY: gettid has no preconditions; getpriority and setpriority
    // with PRIO_PROCESS and a thread id read and change only that thread.
    let failed = unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        // getpriority returns -1 for nice -1 too; errno tells them apart.
        *libc::__errno_location() = 0;
        let now = libc::getpriority(libc::PRIO_PROCESS, tid);
        if now == -1 && *libc::__errno_location() != 0 {
            true
        } else {
            libc::setpriority(libc::PRIO_PROCESS, tid, (now + steps.max(0)).min(19)) != 0
        }
    };
    if failed {
        tracing::warn!(
            "could not lower this thread's priority: {}",
            std::io::Error::last_os_error()
        );
    }
}
