//! `kalibr_yaml`: see `calibration_entry_points::kalibr_yaml`.
#![no_main]

#[path = "../calibration_entry_points.rs"]
mod calibration_entry_points;

libfuzzer_sys::fuzz_target!(|data: &[u8]| calibration_entry_points::kalibr_yaml(data));
