//! The daemon's library side: what `rigslamd` runs, so that tests can
//! run it too.
//!
//! Follow the data: [`config`] says where it comes from; [`sources`] are
//! the driver (or replay) threads that feed the bounded [`queue`]s;
//! [`slam_stage`] is the thread that runs the SLAM pipeline on them and
//! publishes a pose per frame and, through [`fast_pose`], one per IMU
//! sample; [`map_keeper`] loads and saves its map (`[map]`); [`health`]
//! collects what the threads report into the status;
//! [`recorder`] writes the streams to MCAP; [`pipeline`] starts, watches
//! and stops all of it.
//!
//! Threads, not an async runtime: every source is a blocking driver read
//! and the SLAM stage is CPU-bound, so each gets a thread; the supervisor
//! (the binary's main thread) waits for signals with `sigtimedwait`,
//! which doubles as its timer. Nothing is left for tokio to do.

pub mod config;
pub mod fast_pose;
pub mod health;
pub mod map_keeper;
pub mod pipeline;
pub mod queue;
pub mod recorder;
pub mod slam_stage;
pub mod sources;
pub mod viewer;

use std::sync::{Condvar, Mutex};
use std::time::Duration;

pub use config::{check, DaemonConfig, DaemonConfigError, Problem};
pub use pipeline::{IpcSink, Pipeline, PipelineError, PipelineReport};
pub use slam_stage::{FrameItem, PoseSink};

/// Wakes the SLAM stage when any of its queues gets an item, so that it
/// sleeps on one condition variable for several queues.
#[derive(Default)]
pub struct Doorbell {
    rings: Mutex<u64>,
    rung: Condvar,
}

impl Doorbell {
    /// Counts one ring and wakes every thread waiting on the bell.
    pub fn ring(&self) {
        *self.rings.lock().unwrap_or_else(|e| e.into_inner()) += 1;
        self.rung.notify_all();
    }

    /// The ring count, to wait for a change from.
    pub fn rung(&self) -> u64 {
        *self.rings.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Waits until the count differs from `seen`, at most `timeout`.
    pub fn wait(&self, seen: u64, timeout: Duration) {
        let rings = self.rings.lock().unwrap_or_else(|e| e.into_inner());
        let _ = self
            .rung
            .wait_timeout_while(rings, timeout, |r| *r == seen)
            .unwrap_or_else(|e| e.into_inner());
    }
}
