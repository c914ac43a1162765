//! `edges_file`: see `entry_points::edges_file`.
#![no_main]

#[path = "../entry_points.rs"]
mod entry_points;

libfuzzer_sys::fuzz_target!(|data: &[u8]| entry_points::edges_file(data));
