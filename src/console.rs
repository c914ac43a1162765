//! What the binaries (`rigslam`, `rigslamd`, `rigslam-calibrate`) write on
//! stderr, the same way in each: the log, with colour codes only where a
//! person reads it, and the error that ends a command, said once.

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

/// An error and its causes on one line, joined by ": ", for the user:
/// the file and the line, never a debug dump. A cause whose text the
/// line already carries is left out: many errors print their source
/// inline ("X: No such file or directory (os error 2)") and give it as
/// their source too, which anyhow's `{:#}` would print a second time.
pub fn error_chain(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if !out.contains(&text) {
            if !out.is_empty() {
                out.push_str(": ");
            }
            out.push_str(&text);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An error that prints its source inline and gives it as its source.
    #[derive(Debug)]
    struct Unreadable(std::io::Error);

    impl std::fmt::Display for Unreadable {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            write!(f, "cannot read rig.toml: {}", self.0)
        }
    }

    impl std::error::Error for Unreadable {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            Some(&self.0)
        }
    }

    #[test]
    fn each_cause_is_said_once() {
        let io = || std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = anyhow::Error::new(Unreadable(io())).context("loading the config");
        assert_eq!(
            error_chain(&e),
            "loading the config: cannot read rig.toml: no such file"
        );
        // What the binaries printed before: the cause twice.
        assert_eq!(format!("{e:#}").matches("no such file").count(), 2);
        // A cause not said yet is kept.
        let e = anyhow::Error::new(io()).context("reading the map");
        assert_eq!(error_chain(&e), "reading the map: no such file");
    }

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
