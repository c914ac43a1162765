//! `dataset_dir`: see `entry_points::dataset_dir`.
#![no_main]

#[path = "../entry_points.rs"]
mod entry_points;

libfuzzer_sys::fuzz_target!(|data: &[u8]| entry_points::dataset_dir(data));
