//! The calibration tool's fuzz target (`kalibr_yaml` in `tests/fuzz/`) on
//! the stable toolchain, like the core's `tests/fuzz_corpus.rs`: every
//! corpus file, the real YAML files read in place, and a seeded random
//! run of mutations (`tests/fuzz/corpus_run.rs` says how and what fails).

#[path = "../../tests/fuzz/calibration_entry_points.rs"]
mod calibration_entry_points;

#[path = "../../tests/fuzz/corpus_run.rs"]
mod corpus_run;

/// Where `corpus_run` finds the corpora and the real recordings.
const CORPUS_FROM_MANIFEST: &str = "../tests/fuzz/corpus";
const SHARED_DATA_FROM_MANIFEST: &str = "../../shared/data";

#[global_allocator]
static ALLOCATOR: corpus_run::Bounded = corpus_run::Bounded;

#[test]
fn every_corpus_file_and_mutation_parses_without_a_crash() {
    let real: Vec<_> = [
        "calib/euroc_imu_april/imu_april/sequence.yaml",
        "calib/euroc_imu_april/target.yaml",
        "calib/chessboard_9x6_25mm/left_intrinsics.yml",
        "euroc/V1_01_micro/mav0/cam0/sensor.yaml",
        "euroc/V1_01_micro/mav0/imu0/sensor.yaml",
    ]
    .iter()
    .filter_map(|f| corpus_run::real(f))
    .collect();
    let mut failures = Vec::new();
    for (name, target) in calibration_entry_points::TARGETS {
        failures.extend(corpus_run::run_target(name, *target, &real, 100_000, 4096));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}
