//! `pose_message`: see `entry_points::pose_message`.
#![no_main]

#[path = "../entry_points.rs"]
mod entry_points;

libfuzzer_sys::fuzz_target!(|data: &[u8]| entry_points::pose_message(data));
