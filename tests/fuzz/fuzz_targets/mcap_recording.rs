//! `mcap_recording`: see `entry_points::mcap_recording`.
#![no_main]

#[path = "../entry_points.rs"]
mod entry_points;

libfuzzer_sys::fuzz_target!(|data: &[u8]| entry_points::mcap_recording(data));
