//! Signals as ordinary events: SIGTERM, SIGINT and SIGHUP are blocked in
//! every thread (the mask is set before any thread starts and inherited),
//! and the main thread takes them with `sigtimedwait`, which is also its
//! timer. No handler runs in signal context, so nothing async-signal-
//! unsafe can happen.

use std::time::Duration;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Signal {
    /// SIGTERM or SIGINT: stop cleanly.
    Stop,
    /// SIGHUP: read the calibration again.
    Reload,
}

pub struct Signals {
    set: libc::sigset_t,
}

impl Signals {
    /// Blocks the signals in the calling thread (call before spawning).
    pub fn block() -> std::io::Result<Signals> {
        // SAFETY: sigemptyset/sigaddset fill a sigset_t we own;
        // pthread_sigmask reads it; all with valid pointers.
        unsafe {
            let mut set: libc::sigset_t = std::mem::zeroed();
            libc::sigemptyset(&mut set);
            for s in [libc::SIGTERM, libc::SIGINT, libc::SIGHUP] {
                libc::sigaddset(&mut set, s);
            }
            let rc = libc::pthread_sigmask(libc::SIG_BLOCK, &set, std::ptr::null_mut());
            if rc != 0 {
                return Err(std::io::Error::from_raw_os_error(rc));
            }
            Ok(Signals { set })
        }
    }

    /// The next signal within `timeout`, `None` when none came.
    pub fn wait(&self, timeout: Duration) -> Option<Signal> {
        let ts = libc::timespec {
            tv_sec: timeout.as_secs() as libc::time_t,
            tv_nsec: timeout.subsec_nanos() as libc::c_long,
        };
        // SAFETY: set and ts are valid for the call; info may be null.
        let s = unsafe { libc::sigtimedwait(&self.set, std::ptr::null_mut(), &ts) };
        match s {
            libc::SIGTERM | libc::SIGINT => Some(Signal::Stop),
            libc::SIGHUP => Some(Signal::Reload),
            // -1: timeout (EAGAIN) or interrupted (EINTR).
            _ => None,
        }
    }
}
