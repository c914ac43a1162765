//! What the binaries (`rigslam`, `rigslamd`, `rigslam-calibrate`) write on
//! stderr, the same way in each: the log, with colour codes only where a
//! person reads it.

use std::ffi::OsStr;
use std::io::IsTerminal;

/// Sends the log (`tracing`) to stderr, filtered by `RUST_LOG` (`info`
/// when unset or not understood), coloured only as [`colour_wanted`]
/// says. Call it once, first thing in `main`.
pub fn init_logging() {
    let no_color = std::env::var_os("NO_COLOR");
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .with_ansi(colour_wanted(
            std::io::stderr().is_terminal(),
            no_color.as_deref(),
        ))
        .init();
}

/// Whether log lines may carry ANSI colour codes: only when stderr is a
/// terminal and `NO_COLOR` (<https://no-color.org>) is unset or empty.
/// Under systemd stderr is the journal, which would keep the codes as
/// text (`journalctl` shows them as `ESC[2m` and the like), as would a log
/// file or a pipe.
pub fn colour_wanted(stderr_is_terminal: bool, no_color: Option<&OsStr>) -> bool {
    stderr_is_terminal && no_color.map_or(true, OsStr::is_empty)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_only_on_a_terminal_without_no_color() {
        let set = Some(OsStr::new("1"));
        let empty = Some(OsStr::new(""));
        assert!(colour_wanted(true, None));
        assert!(colour_wanted(true, empty), "an empty NO_COLOR is unset");
        assert!(!colour_wanted(true, set));
        assert!(!colour_wanted(false, None));
        assert!(!colour_wanted(false, empty));
        assert!(!colour_wanted(false, set));
    }
}
