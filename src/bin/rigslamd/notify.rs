//! systemd's notification protocol (sd_notify(3)): one datagram of
//! `KEY=VALUE` lines to the unix socket named in `$NOTIFY_SOCKET` (a path,
//! or an abstract name when it starts with `@`). Without the variable
//! (not started by systemd) every call does nothing.

use std::os::unix::net::UnixDatagram;

pub struct Notifier {
    socket: Option<(UnixDatagram, std::os::unix::net::SocketAddr)>,
}

impl Notifier {
    /// Reads `$NOTIFY_SOCKET`; a bad value is logged and ignored.
    pub fn from_env() -> Notifier {
        let socket = std::env::var_os("NOTIFY_SOCKET").and_then(|name| {
            let address = address_of(&name).map_err(|e| {
                tracing::warn!("NOTIFY_SOCKET={name:?} is not usable: {e}");
            });
            let socket = UnixDatagram::unbound().map_err(|e| {
                tracing::warn!("cannot create a socket for NOTIFY_SOCKET: {e}");
            });
            Some((socket.ok()?, address.ok()?))
        });
        Notifier { socket }
    }

    /// Sends `state` (newline-separated assignments).
    pub fn send(&self, state: &str) {
        if let Some((socket, address)) = &self.socket {
            if let Err(e) = socket.send_to_addr(state.as_bytes(), address) {
                tracing::warn!("sd_notify {state:?}: {e}");
            }
        }
    }

    pub fn ready(&self, status: &str) {
        self.send(&format!("READY=1\nSTATUS={}", one_line(status)));
    }

    pub fn status(&self, status: &str) {
        self.send(&format!("STATUS={}", one_line(status)));
    }

    pub fn watchdog(&self) {
        self.send("WATCHDOG=1");
    }

    pub fn reloading(&self) {
        self.send("RELOADING=1");
    }

    pub fn stopping(&self) {
        self.send("STOPPING=1");
    }
}

fn one_line(s: &str) -> String {
    s.replace('\n', " ")
}

fn address_of(name: &std::ffi::OsStr) -> std::io::Result<std::os::unix::net::SocketAddr> {
    use std::os::unix::ffi::OsStrExt;
    let bytes = name.as_bytes();
    match bytes.first() {
        Some(b'@') => {
            use std::os::linux::net::SocketAddrExt;
            std::os::unix::net::SocketAddr::from_abstract_name(&bytes[1..])
        }
        Some(b'/') => std::os::unix::net::SocketAddr::from_pathname(std::path::Path::new(name)),
        _ => Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "expected an absolute path or an abstract name starting with @",
        )),
    }
}

/// The watchdog period systemd asks for (`$WATCHDOG_USEC`, for this
/// process per `$WATCHDOG_PID`), if any.
pub fn watchdog_period() -> Option<std::time::Duration> {
    let usec: u64 = std::env::var("WATCHDOG_USEC").ok()?.parse().ok()?;
    if let Ok(pid) = std::env::var("WATCHDOG_PID") {
        if pid.parse::<u32>().ok()? != std::process::id() {
            return None;
        }
    }
    (usec > 0).then(|| std::time::Duration::from_micros(usec))
}
