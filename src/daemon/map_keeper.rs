//! The daemon's map on disk (`[map] path`): what the SLAM thread starts
//! from and what it leaves behind.
//!
//! At start a saved map is loaded and the robot localises in it; a file
//! that is not a whole rigslam map (cut, damaged, another program's) is
//! moved aside under a new name, never overwritten, and a fresh map is
//! built. A map being built is saved every `save_every_s` of sensor time
//! from the last solved map (on a thread of its own, so the frame path
//! never waits for the disk), and once more in full when the daemon stops
//! (SIGTERM) or reloads (SIGHUP). Every save is atomic
//! ([`crate::text_file::write_atomically`]).

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::thread::JoinHandle;

use crate::absolute::map_file::SavedMap;
use crate::slam_pipeline::{SecondStage, SlamPipeline};

use super::config::MapConfig;
use super::health::{Health, MAP_BUILDING, MAP_LOCALISING};

/// How much nicer the periodic map save thread is than the frame path
/// (see [`crate::absolute::solve_schedule::MAP_SOLVE_NICE`]).
const MAP_SAVE_NICE: i32 = 10;

/// The map file and its saves.
pub struct MapKeeper {
    path: PathBuf,
    save_every_ns: i64,
    last_save_ns: Option<i64>,
    /// A periodic save still writing.
    writer: Option<JoinHandle<()>>,
    /// False when an unusable map could not be moved aside: it is never
    /// overwritten.
    saving: bool,
    health: Arc<Health>,
}

impl MapKeeper {
    /// The keeper for `config` (None without a `[map] path`) and what the
    /// pipeline starts with: localising in the saved map, or building one.
    pub fn open(config: &MapConfig, health: Arc<Health>) -> Option<(Self, SecondStage)> {
        let path = config.path.clone()?;
        crate::text_file::atomic::remove_stale_temporaries(&path);
        let (found, saving) = match start_from(&path) {
            Ok(found) => (found, true),
            Err(()) => (None, false),
        };
        let second = match found {
            Some(map) => {
                tracing::info!(
                    "localising in the saved map {} ({} landmarks)",
                    path.display(),
                    map.landmarks.len()
                );
                health
                    .map_landmarks
                    .store(map.landmarks.len() as u64, Ordering::Relaxed);
                health.map_mode.store(MAP_LOCALISING, Ordering::Relaxed);
                SecondStage::Localise(Arc::new(map))
            }
            None => {
                tracing::info!("building a new map, saved to {}", path.display());
                health.map_mode.store(MAP_BUILDING, Ordering::Relaxed);
                SecondStage::BuildMap
            }
        };
        let keeper = Self {
            path,
            save_every_ns: (config.save_every_s * 1e9) as i64,
            last_save_ns: None,
            writer: None,
            saving,
            health,
        };
        Some((keeper, second))
    }

    /// After each frame at `t_ns`: a periodic save of the last solved map
    /// when one is due and the previous one has finished.
    pub fn after_frame(&mut self, t_ns: i64, pipeline: &SlamPipeline) {
        if !self.saving {
            return;
        }
        let last = *self.last_save_ns.get_or_insert(t_ns);
        if t_ns - last < self.save_every_ns {
            return;
        }
        if self.writer.as_ref().is_some_and(|w| !w.is_finished()) {
            return;
        }
        let Some(map) = pipeline.solved_map() else {
            return;
        };
        self.last_save_ns = Some(t_ns);
        let (path, health) = (self.path.clone(), Arc::clone(&self.health));
        let spawned = std::thread::Builder::new()
            .name("map-save".into())
            .spawn(move || {
                crate::thread_priority::lower_this_threads_priority(MAP_SAVE_NICE);
                save(&path, &map, &health)
            });
        match spawned {
            Ok(handle) => self.writer = Some(handle),
            Err(e) => tracing::warn!("map not saved: cannot start its thread: {e}"),
        }
    }

    /// Saves the map being built in full (the daemon stops or reloads):
    /// the map solved with every edge so far.
    pub fn save_now(&mut self, pipeline: &mut SlamPipeline) {
        if let Some(writer) = self.writer.take() {
            let _ = writer.join();
        }
        if !self.saving {
            return;
        }
        let Some(map) = pipeline.finish_map() else {
            return;
        };
        save(&self.path, &map, &self.health);
    }

    /// What a pipeline started again (after a reload) begins with: the
    /// map just saved, or a new one.
    pub fn restart(&mut self) -> SecondStage {
        let found = match start_from(&self.path) {
            Ok(found) => found,
            Err(()) => {
                self.saving = false;
                None
            }
        };
        match found {
            Some(map) => {
                self.health
                    .map_mode
                    .store(MAP_LOCALISING, Ordering::Relaxed);
                SecondStage::Localise(Arc::new(map))
            }
            None => {
                self.health.map_mode.store(MAP_BUILDING, Ordering::Relaxed);
                SecondStage::BuildMap
            }
        }
    }
}

impl Drop for MapKeeper {
    fn drop(&mut self) {
        if let Some(writer) = self.writer.take() {
            let _ = writer.join();
        }
    }
}

/// Writes `map` atomically; counts it, or logs why not.
fn save(path: &Path, map: &SavedMap, health: &Health) {
    match map.write(path) {
        Ok(()) => {
            health.map_saves.fetch_add(1, Ordering::Relaxed);
            health
                .map_landmarks
                .store(map.landmarks.len() as u64, Ordering::Relaxed);
            tracing::info!(
                "map saved: {} landmarks to {} ({} unknowns in the last solve)",
                map.landmarks.len(),
                path.display(),
                health.map_unknowns.load(Ordering::Relaxed)
            );
        }
        Err(e) => tracing::error!("map not saved (the previous one is kept): {e}"),
    }
}

/// The saved map at `path`, if there is a whole one. A file that is not
/// is moved aside and the reason logged; Err when it could not be moved
/// (then nothing may be saved over it).
fn start_from(path: &Path) -> Result<Option<SavedMap>, ()> {
    if !path.exists() {
        return Ok(None);
    }
    match SavedMap::read(path) {
        Ok(map) => Ok(Some(map)),
        Err(e) => match set_aside(path) {
            Ok(aside) => {
                tracing::error!(
                    "the saved map cannot be used ({e}); kept as {} and a new map is built",
                    aside.display()
                );
                Ok(None)
            }
            Err(move_error) => {
                tracing::error!(
                    "the saved map cannot be used ({e}) nor moved aside ({move_error}); a new map is built but not saved, so that {} stays as it is",
                    path.display()
                );
                Err(())
            }
        },
    }
}

/// Renames `path` to `path.unusable-N` with the first N not taken.
fn set_aside(path: &Path) -> std::io::Result<PathBuf> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "map".into());
    for n in 1..10_000 {
        let aside = path.with_file_name(format!("{name}.unusable-{n}"));
        if !aside.exists() {
            std::fs::rename(path, &aside)?;
            return Ok(aside);
        }
    }
    Err(std::io::Error::other("10 000 maps set aside already"))
}
