//! `daemon_config`: see `entry_points::daemon_config`.
#![no_main]

#[path = "../entry_points.rs"]
mod entry_points;

libfuzzer_sys::fuzz_target!(|data: &[u8]| entry_points::daemon_config(data));
