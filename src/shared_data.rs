//! Where the real recordings by others live (`../shared/data` beside the
//! repository; see its README), for tests, benchmarks and the demo.

use std::path::PathBuf;

/// `../shared/data` relative to the repository, or `$RIGSLAM_SHARED_DATA`
/// when set (a checkout elsewhere). `None` when it is missing, so a test
/// can skip; but when `CI` is set a missing folder panics, because CI must
/// run the real-data tests, not skip them.
pub fn shared_data_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("RIGSLAM_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data")));
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI is set but the shared data folder {} is missing",
        dir.display()
    );
    eprintln!("skipping: {} is missing", dir.display());
    None
}

/// `relative` inside [`shared_data_dir`], when the folder and it exist
/// (same CI rule: a missing folder fails there instead of skipping).
pub fn path_or_skip(relative: &str) -> Option<PathBuf> {
    let path = shared_data_dir()?.join(relative);
    if path.exists() {
        return Some(path);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI is set but {} is missing",
        path.display()
    );
    eprintln!("skipping: {} is missing", path.display());
    None
}
