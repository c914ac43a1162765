//! The absolute stage's recognition over frames: a new track that looks
//! like a landmark already in the map ([`super::recognition`]'s gates,
//! and the frame's consensus) becomes that landmark only when it is
//! recognised as the same one in `confirm_frames` consecutive frames and
//! is precise enough; until then it is pending and stays out of the map.
//! The landmarks it searches are those of the last solved map, by world
//! position.

use std::collections::HashMap;

use nalgebra::Vector3;

use super::landmark_registry::LandmarkRegistry;
use super::recognition::{
    consistent_recognitions, recognise_tracks, ConsensusGate, FramePlacement, LandmarkIndex,
    RecognitionConfig,
};
use crate::features::matching::hamming;
use crate::relative::types::{LandmarkId, RelativeOutput};

/// Grid cell of the recognition index, m.
const INDEX_CELL_M: f64 = 1.0;

/// How near a map landmark with a similar descriptor must be to a new
/// track for the track to wait (`new_landmark_after_frames`) before it
/// becomes a new landmark, m.
const LOOKALIKE_RADIUS_M: f64 = 0.5;

/// What one frame's recognition did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct RecognitionCounts {
    /// Tracks confirmed as a map landmark (now aliases in the registry).
    pub recognised: usize,
    /// Recognitions dropped because they placed the robot elsewhere than
    /// the frame's mapped landmarks do.
    pub inconsistent: usize,
    /// Pending tracks given up: not recognised again as the same landmark.
    pub unconfirmed: usize,
}

/// Pending recognitions and the index of the solved map's landmarks.
pub(super) struct Recogniser {
    config: RecognitionConfig,
    /// Tracks recognised as a map landmark in fewer than `confirm_frames`
    /// consecutive frames: the landmark's map id and the count.
    pending: HashMap<LandmarkId, (u32, u32)>,
    /// Tracks with no map id, and for how many frames they have been seen
    /// so (until `new_landmark_after_frames`): held out of the map while
    /// recognition may still find them.
    unmapped_age: HashMap<LandmarkId, u32>,
    /// Solved map landmarks by world position.
    index: LandmarkIndex,
    /// Scratch for the index's answers.
    candidates: Vec<u32>,
}

impl Recogniser {
    /// A recogniser with no map yet.
    pub(super) fn new(config: RecognitionConfig) -> Self {
        Self {
            config,
            pending: HashMap::new(),
            unmapped_age: HashMap::new(),
            index: LandmarkIndex::default(),
            candidates: Vec::new(),
        }
    }

    /// Searches these landmarks from now on: world positions by map id
    /// (None for frame nodes and unsolved ids).
    pub(super) fn set_map(&mut self, world_m: Vec<Option<Vector3<f64>>>) {
        self.index = LandmarkIndex::build(world_m, INDEX_CELL_M);
    }

    /// True while `track` waits for its recognition to be confirmed.
    pub(super) fn is_pending(&self, track: LandmarkId) -> bool {
        self.pending.contains_key(&track) || self.unmapped_age.contains_key(&track)
    }

    /// Recognises the frame's tracks that have no map id, with the robot
    /// at `placement`; confirmed ones become aliases in `registry`.
    pub(super) fn recognise(
        &mut self,
        output: &RelativeOutput,
        placement: &FramePlacement,
        registry: &mut LandmarkRegistry,
    ) -> RecognitionCounts {
        let mut counts = RecognitionCounts::default();
        if self.index.is_empty() {
            return counts;
        }
        let config = &self.config;
        let found = recognise_tracks(
            &self.index,
            registry.descriptors(),
            &output.landmarks,
            placement,
            // A track fused before is a landmark of its own, mapped or not
            // yet (no map id until a frame node joins it): not looked for.
            |track| registry.known_as(track),
            config,
            &mut self.candidates,
        );
        // A recognition must place the robot where the frame's landmarks
        // already in the map place it.
        let (found, inconsistent) = consistent_recognitions(
            &self.index,
            &output.landmarks,
            &placement.rotation,
            |track| registry.map_id_of(track),
            found,
            config,
            1.0,
            ConsensusGate::TrackAxes,
        );
        counts.inconsistent = inconsistent;
        let mut pending = HashMap::with_capacity(found.len());
        for (track, map_id) in found {
            let count = match self.pending.get(&track) {
                Some(&(earlier, count)) if earlier == map_id => count + 1,
                _ => 1,
            };
            let precise = output
                .landmarks
                .iter()
                .find(|l| l.id == track)
                .is_some_and(|l| {
                    l.covariance_body_m2.symmetric_eigenvalues().max()
                        <= config.confirm_max_sigma_m.powi(2)
                });
            if count >= config.confirm_frames && precise {
                counts.recognised += 1;
                registry.alias(track, map_id);
            } else if count < config.max_pending_frames {
                pending.insert(track, (map_id, count));
            }
        }
        // A pending track not recognised as the same landmark again, or
        // gone from view, is dropped (and becomes a new landmark when its
        // frame is fused).
        counts.unconfirmed = self
            .pending
            .keys()
            .filter(|&&track| !pending.contains_key(&track) && !registry.contains(track))
            .count();
        self.pending = pending;
        // Tracks still without a map id that look like a map landmark
        // near where they are wait before they become new landmarks;
        // those gone from view are forgotten.
        let mut ages = HashMap::with_capacity(self.unmapped_age.len());
        for l in &output.landmarks {
            if registry.contains(l.id) {
                continue;
            }
            let waited = self.unmapped_age.get(&l.id).copied();
            let age = waited.unwrap_or(0) + 1;
            if age >= config.new_landmark_after_frames {
                continue;
            }
            if waited.is_some() {
                // Already waiting: no need to look for a lookalike again.
                ages.insert(l.id, age);
                continue;
            }
            let Some(descriptor) = l.descriptor.as_ref() else {
                continue;
            };
            let world_m = placement.position_m + placement.rotation * l.position_body_m;
            self.candidates.clear();
            self.index
                .within(&world_m, LOOKALIKE_RADIUS_M, &mut self.candidates);
            let descriptors = registry.descriptors();
            let lookalike = self.candidates.iter().any(|&id| {
                descriptors
                    .get(id as usize)
                    .and_then(|d| d.as_ref())
                    .is_some_and(|d| hamming(d, descriptor) <= config.max_hamming)
            });
            if lookalike {
                ages.insert(l.id, age);
            }
        }
        self.unmapped_age = ages;
        counts
    }
}
