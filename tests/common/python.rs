//! The Python the readers' tests run: `RIGSLAM_PYTHON`, which
//! `scripts/test` points at the venv it makes in `target/py`.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// `RIGSLAM_PYTHON` when it imports `modules` (comma-separated, as in an
/// import line); `None` (skip, saying what to install: `packages`) outside
/// CI; a failure under CI.
pub fn python_with(modules: &str, packages: &str) -> Option<PathBuf> {
    let candidate = std::env::var_os("RIGSLAM_PYTHON").map(PathBuf::from);
    let usable = candidate.as_ref().is_some_and(|p| {
        Command::new(p)
            .args(["-c", &format!("import {modules}")])
            .status()
            .is_ok_and(|s| s.success())
    });
    if usable {
        return candidate;
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI is set but RIGSLAM_PYTHON ({candidate:?}) is not a Python with {packages} \
         (scripts/test makes one in target/py)"
    );
    eprintln!("skipping: set RIGSLAM_PYTHON to a Python with `pip install {packages}`");
    None
}

/// What the reader script `tests/readers/<script>` printed (JSON) for `file`.
pub fn script_json(python: &Path, script: &str, file: &Path) -> serde_json::Value {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/readers")
        .join(script);
    let out = Command::new(python)
        .arg(path)
        .arg(file)
        .output()
        .expect("run python");
    assert!(
        out.status.success(),
        "{script} failed on {}: {}",
        file.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("JSON from {script}: {e}"))
}

/// Reads a child's stdout to its end on a thread; the flag turns true
/// when it ended (the child wrote all it was asked for, or died).
pub fn read_lines(
    stdout: std::process::ChildStdout,
) -> (
    std::sync::Arc<std::sync::atomic::AtomicBool>,
    std::thread::JoinHandle<Vec<String>>,
) {
    use std::io::BufRead;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    let done = Arc::new(AtomicBool::new(false));
    let stop = Arc::clone(&done);
    let lines = std::thread::spawn(move || {
        let lines: Vec<String> = std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
            .collect();
        stop.store(true, Ordering::SeqCst);
        lines
    });
    (done, lines)
}
