//! The fuzz targets on the stable toolchain, for every test run: each
//! target's entry point gets every file of its corpus
//! (`tests/fuzz/corpus/<target>/`), the real recordings that fit it read
//! in place from `../shared/data`, and then a bounded random run: inputs
//! mutated from those seeds by a seeded generator (bit flips, truncation,
//! inserted and deleted bytes, numbers replaced by huge or odd values,
//! huge binary length fields, splices), the same every run.
//!
//! What fails the run, as the fuzzer would: a panic (with the input that
//! caused it, as the file name or the mutation's index and bytes); an
//! allocation over [`ALLOCATION_LIMIT`] (a length field trusted; the
//! process aborts, naming the input); an input running longer than
//! [`HANG_LIMIT`] (the process aborts, naming the input).
//!
//! Shared by `tests/fuzz_corpus.rs` (the core's targets) and
//! `calibration/tests/fuzz_corpus.rs` (the calibration tool's).

#![allow(dead_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write as _;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// No input may make a parser ask for more than this in one allocation.
pub const ALLOCATION_LIMIT: usize = 1 << 30;
/// No input may keep a parser busy for longer than this.
pub const HANG_LIMIT: Duration = Duration::from_secs(60);

/// The system allocator, refusing single allocations over
/// [`ALLOCATION_LIMIT`] after saying which input asked.
pub struct Bounded;

static CURRENT: Mutex<String> = Mutex::new(String::new());
/// The bytes of the input running, for the message of a refusal.
static CURRENT_DATA: AtomicUsize = AtomicUsize::new(0);
static CURRENT_LEN: AtomicUsize = AtomicUsize::new(0);
/// Milliseconds since [`EPOCH`] when the current input started; 0 when
/// none runs.
static STARTED_MS: AtomicU64 = AtomicU64::new(0);
static EPOCH: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();

fn refuse(size: usize) {
    let mut err = std::io::stderr().lock();
    let _ = write!(
        err,
        "\nallocation of {size} bytes refused (limit {ALLOCATION_LIMIT}): a length field trusted? input: "
    );
    if let Ok(current) = CURRENT.try_lock() {
        let _ = err.write_all(current.as_bytes());
    }
    // The input's bytes in hex (no allocation here: this is the allocator).
    let (ptr, len) = (
        CURRENT_DATA.load(Ordering::Relaxed),
        CURRENT_LEN.load(Ordering::Relaxed),
    );
    if ptr != 0 {
        let _ = write!(err, "\n{len} bytes: ");
        // SAFETY: run_one stores the slice it runs and clears it after.
        let data = unsafe { std::slice::from_raw_parts(ptr as *const u8, len) };
        for b in data {
            let _ = write!(err, "{b:02x}");
        }
    }
    let _ = err.write_all(b"\n");
}

unsafe impl GlobalAlloc for Bounded {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > ALLOCATION_LIMIT {
            refuse(layout.size());
            return std::ptr::null_mut();
        }
        System.alloc(layout)
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > ALLOCATION_LIMIT {
            refuse(layout.size());
            return std::ptr::null_mut();
        }
        System.alloc_zeroed(layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > ALLOCATION_LIMIT {
            refuse(new_size);
            return std::ptr::null_mut();
        }
        System.realloc(ptr, layout, new_size)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
}

fn now_ms() -> u64 {
    EPOCH.get_or_init(Instant::now).elapsed().as_millis() as u64 + 1
}

/// Aborts the process when one input runs longer than [`HANG_LIMIT`].
fn start_watchdog() {
    static STARTED: std::sync::Once = std::sync::Once::new();
    STARTED.call_once(|| {
        now_ms();
        std::thread::spawn(|| loop {
            std::thread::sleep(Duration::from_millis(500));
            let started = STARTED_MS.load(Ordering::Relaxed);
            if started != 0 && now_ms() - started > HANG_LIMIT.as_millis() as u64 {
                let current = CURRENT.lock().map(|c| c.clone()).unwrap_or_default();
                eprintln!("\nno answer after {HANG_LIMIT:?} (a hang?) on input: {current}");
                let (ptr, len) = (
                    CURRENT_DATA.load(Ordering::Relaxed),
                    CURRENT_LEN.load(Ordering::Relaxed),
                );
                if ptr != 0 {
                    // SAFETY: run_one stores the slice it runs and clears
                    // it after; the input is still running.
                    let data = unsafe { std::slice::from_raw_parts(ptr as *const u8, len) };
                    let hex: String = data.iter().map(|b| format!("{b:02x}")).collect();
                    eprintln!("{len} bytes: {hex}");
                }
                std::process::abort();
            }
        });
    });
}

/// Runs `target` on `data`; on a panic, the error names `what` and shows
/// the input.
fn run_one(target: fn(&[u8]), what: &str, data: &[u8]) -> Result<Duration, String> {
    if let Ok(mut current) = CURRENT.lock() {
        current.clear();
        current.push_str(what);
    }
    let started = Instant::now();
    CURRENT_DATA.store(data.as_ptr() as usize, Ordering::Relaxed);
    CURRENT_LEN.store(data.len(), Ordering::Relaxed);
    STARTED_MS.store(now_ms(), Ordering::Relaxed);
    let outcome = catch_unwind(AssertUnwindSafe(|| target(data)));
    STARTED_MS.store(0, Ordering::Relaxed);
    CURRENT_DATA.store(0, Ordering::Relaxed);
    match outcome {
        Ok(()) => Ok(started.elapsed()),
        Err(panic) => {
            let message = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            let shown: String = String::from_utf8_lossy(&data[..data.len().min(600)]).into();
            Err(format!(
                "{what}: panicked: {message}\n  input ({} bytes, first 600 as text): {shown:?}",
                data.len()
            ))
        }
    }
}

/// The corpus folder of `target`.
pub fn corpus_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(CORPUS_FROM_MANIFEST)
        .join(target)
}

/// Set by the including test file: the corpus root relative to its
/// crate's manifest folder.
const CORPUS_FROM_MANIFEST: &str = crate::CORPUS_FROM_MANIFEST;

/// Every file of a folder, sorted by name.
fn files_of(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("corpus folder {}: {e}", dir.display()))
        .map(|e| e.expect("a folder entry").path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    files
}

/// Numbers a mutation puts in place of one in the text.
const ODD_NUMBERS: [&str; 14] = [
    "1152921504606846976",
    "18446744073709551615",
    "18446744073709551616",
    "9223372036854775807",
    "-9223372036854775808",
    "4294967295",
    "-1",
    "0",
    "1e308",
    "-1e-320",
    "nan",
    "inf",
    "-0",
    "1e999",
];

/// Length fields a mutation writes into binary inputs.
const ODD_LENGTHS: [u64; 6] = [
    1 << 60,
    u64::MAX,
    u32::MAX as u64,
    (1 << 31) + 7,
    1 << 40,
    0,
];

/// One to four mutations of `seed`; `other` is another seed to splice from.
pub fn mutate(rng: &mut ChaCha8Rng, seed: &[u8], other: &[u8]) -> Vec<u8> {
    let mut data = seed.to_vec();
    for _ in 0..rng.gen_range(1..=4) {
        let len = data.len();
        match rng.gen_range(0..9) {
            0 if len > 0 => {
                let at = rng.gen_range(0..len);
                data[at] ^= 1 << rng.gen_range(0..8);
            }
            1 if len > 0 => {
                let at = rng.gen_range(0..len);
                data[at] = rng.gen();
            }
            2 => data.truncate(rng.gen_range(0..=len)),
            3 => {
                let at = rng.gen_range(0..=len);
                let n = rng.gen_range(1..=16);
                let bytes: Vec<u8> = (0..n)
                    .map(|_| {
                        if rng.gen_bool(0.5) {
                            *b"0123456789.-e ,:\n#[]{}\"'"
                                .get(rng.gen_range(0..24))
                                .expect("in range")
                        } else {
                            rng.gen()
                        }
                    })
                    .collect();
                data.splice(at..at, bytes);
            }
            4 if len > 0 => {
                let from = rng.gen_range(0..len);
                let to = rng.gen_range(from..=len.min(from + 64));
                data.drain(from..to);
            }
            5 => {
                // A number of the text (a run of digits) made odd.
                let starts: Vec<usize> = (0..len)
                    .filter(|&i| {
                        data[i].is_ascii_digit() && (i == 0 || !data[i - 1].is_ascii_digit())
                    })
                    .collect();
                if let Some(&at) = starts.get(rng.gen_range(0..starts.len().max(1))) {
                    let end = (at..len)
                        .find(|&i| !data[i].is_ascii_digit())
                        .unwrap_or(len);
                    let odd = ODD_NUMBERS[rng.gen_range(0..ODD_NUMBERS.len())];
                    data.splice(at..end, odd.bytes());
                }
            }
            6 if len >= 8 => {
                // A huge binary length field, little-endian, 4 or 8 bytes.
                let value = ODD_LENGTHS[rng.gen_range(0..ODD_LENGTHS.len())];
                let width = if rng.gen_bool(0.5) { 4 } else { 8 };
                let at = rng.gen_range(0..=len - width);
                data[at..at + width].copy_from_slice(&value.to_le_bytes()[..width]);
            }
            7 if len > 0 => {
                // A slice repeated.
                let from = rng.gen_range(0..len);
                let to = rng.gen_range(from..=len.min(from + 256));
                let copy = data[from..to].to_vec();
                let at = rng.gen_range(0..=len);
                data.splice(at..at, copy);
            }
            8 if !other.is_empty() => {
                // The head of this input and the tail of another.
                let cut = rng.gen_range(0..=len);
                let from = rng.gen_range(0..other.len());
                data.truncate(cut);
                data.extend_from_slice(&other[from..]);
            }
            _ => {}
        }
    }
    data
}

/// One target's corpus run: its corpus files, then `extra` inputs (real
/// files, each named), then `mutations` mutated inputs; the real inputs
/// are mutated from their first `mutate_prefix` bytes only, so that big
/// recordings stay cheap. Returns the failures, each naming its input.
pub fn run_target(
    name: &str,
    target: fn(&[u8]),
    extra: &[(String, Vec<u8>)],
    mutations: usize,
    mutate_prefix: usize,
) -> Vec<String> {
    start_watchdog();
    let started = Instant::now();
    let mut failures = Vec::new();
    let mut seeds: Vec<Vec<u8>> = Vec::new();
    let mut slowest = (Duration::ZERO, String::new());
    let mut run = |what: String, data: &[u8], failures: &mut Vec<String>| match run_one(
        target, &what, data,
    ) {
        Ok(took) => {
            if took > slowest.0 {
                slowest = (took, what);
            }
        }
        Err(e) => failures.push(e),
    };
    let files = files_of(&corpus_dir(name));
    assert!(!files.is_empty(), "the corpus of {name} is empty");
    for file in &files {
        let data = std::fs::read(file).expect("a corpus file");
        run(file.display().to_string(), &data, &mut failures);
        seeds.push(data);
    }
    for (what, data) in extra {
        run(what.clone(), data, &mut failures);
        seeds.push(data[..data.len().min(mutate_prefix)].to_vec());
    }
    let mut rng =
        ChaCha8Rng::seed_from_u64(name.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
        }));
    for k in 0..mutations {
        let seed = &seeds[rng.gen_range(0..seeds.len())];
        let other = &seeds[rng.gen_range(0..seeds.len())];
        let data = mutate(&mut rng, seed, other);
        run(format!("{name} mutation {k}"), &data, &mut failures);
        if failures.len() >= 5 {
            break;
        }
    }
    println!(
        "{name}: {} corpus files, {} real inputs, {mutations} mutations in {:.1} s; slowest input {:.0} ms ({})",
        files.len(),
        extra.len(),
        started.elapsed().as_secs_f64(),
        slowest.0.as_secs_f64() * 1e3,
        slowest.1
    );
    failures
}

/// `relative` in `../shared/data` read in place, when there (a missing
/// folder fails under CI, as for the other real-data tests).
pub fn real(relative: &str) -> Option<(String, Vec<u8>)> {
    let root = std::env::var_os("RIGSLAM_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join(crate::SHARED_DATA_FROM_MANIFEST)
        });
    if !root.is_dir() {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI is set but the shared data folder {} is missing",
            root.display()
        );
        return None;
    }
    let path = root.join(relative);
    let data = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    Some((path.display().to_string(), data))
}
