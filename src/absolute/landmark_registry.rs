//! Which track is which map unknown. The relative stage names landmarks by
//! track id, and a landmark that leaves view and comes back gets a new
//! one; the map names its unknowns by map id, dense from 0, one per
//! landmark and one per frame node. The registry keeps both directions:
//! every track id mapped to its map id (several tracks may share one when
//! recognition says they are the same landmark), and for every map id the
//! track it entered the map under and its descriptor, for recognition and
//! for saving the map. With frame nodes, a track gets its map id when a
//! node is joined to it; until then a track fused in frames that add no
//! node is only known (so recognition leaves it alone, and its first
//! descriptor is kept) until it has been out of the fused frames for
//! [`FORGET_AFTER_FRAMES`]: a robot that keeps driving does not keep an
//! entry for every track it ever saw. A recognised track (an alias of a
//! map landmark) is dropped the same way once it has been out of the
//! fused frames for as long; its landmark keeps its map id under the
//! track it entered the map with. A run that checks its recognitions
//! afterwards asks for a log of every alias made
//! ([`LandmarkRegistry::keep_alias_log`]).

use std::collections::HashMap;

use crate::features::orb::Descriptor;
use crate::relative::types::LandmarkId;

/// The track id recorded for a frame node (no track has it).
const FRAME_NODE: LandmarkId = LandmarkId::MAX;

/// Track ids and map ids of the map's unknowns.
#[derive(Debug, Default)]
pub(super) struct LandmarkRegistry {
    /// Map id of every track id seen in a mapped frame, or recognised.
    map_ids: HashMap<LandmarkId, u32>,
    /// By map id: the track id it entered the map under ([`FRAME_NODE`]
    /// for a frame node).
    first_tracks: Vec<LandmarkId>,
    /// By map id: the landmark's descriptor (None for frame nodes and
    /// tracks that had none).
    descriptors: Vec<Option<Descriptor>>,
    /// Tracks fused without a map id yet: their first descriptor, and the
    /// fused frame they were last in.
    known_without_id: HashMap<LandmarkId, (Option<Descriptor>, u64)>,
    /// Recognised tracks (aliases) and the fused frame they were last in.
    alias_seen: HashMap<LandmarkId, u64>,
    /// Every alias made, (track, map id), when asked for.
    alias_log: Option<Vec<(LandmarkId, u32)>>,
    /// Frames fused ([`LandmarkRegistry::note_without_id`] calls).
    fused_frames: u64,
}

/// A track fused without a map id is forgotten after this many fused
/// frames without it (5 s at 20 Hz): a tracker's track that leaves the
/// view never comes back under its id. Checked every this many frames.
const FORGET_AFTER_FRAMES: u64 = 100;

/// Stands for the map id of a track known without one (never a map id:
/// they are handed out densely from 0).
pub(super) const NO_ID_YET: u32 = u32::MAX;

impl LandmarkRegistry {
    /// True before the first unknown.
    pub(super) fn is_empty(&self) -> bool {
        self.first_tracks.is_empty()
    }

    /// Map ids handed out (landmarks and frame nodes).
    pub(super) fn map_ids(&self) -> usize {
        self.first_tracks.len()
    }

    /// Track ids that have a map id.
    pub(super) fn tracks(&self) -> usize {
        self.map_ids.len()
    }

    /// The map id of a track; [`NO_ID_YET`] for one fused without an id
    /// yet; None for a track the map does not know (which recognition may
    /// look for).
    pub(super) fn known_as(&self, track: LandmarkId) -> Option<u32> {
        self.map_id_of(track).or_else(|| {
            self.known_without_id
                .contains_key(&track)
                .then_some(NO_ID_YET)
        })
    }

    /// The map id of a track, if it has one.
    pub(super) fn map_id_of(&self, track: LandmarkId) -> Option<u32> {
        self.map_ids.get(&track).copied()
    }

    /// True when the track has a map id, or was fused without one: it is
    /// a landmark of its own, recognition does not look for it.
    pub(super) fn contains(&self, track: LandmarkId) -> bool {
        self.map_ids.contains_key(&track) || self.known_without_id.contains_key(&track)
    }

    /// One fused frame: its tracks that have no map id (with their
    /// descriptors). Tracks without a map id and aliases out of the fused
    /// frames for [`FORGET_AFTER_FRAMES`] are forgotten.
    pub(super) fn note_without_id(
        &mut self,
        tracks: impl IntoIterator<Item = (LandmarkId, Option<Descriptor>)>,
    ) {
        self.fused_frames += 1;
        let now = self.fused_frames;
        for (track, descriptor) in tracks {
            let entry = self.known_without_id.entry(track).or_insert((None, now));
            entry.0 = entry.0.or(descriptor);
            entry.1 = now;
        }
        if now % FORGET_AFTER_FRAMES == 0 {
            self.known_without_id
                .retain(|_, (_, seen)| now - *seen < FORGET_AFTER_FRAMES);
            let map_ids = &mut self.map_ids;
            self.alias_seen.retain(|track, seen| {
                let keep = now - *seen < FORGET_AFTER_FRAMES;
                if !keep {
                    map_ids.remove(track);
                }
                keep
            });
        }
    }

    /// From now on every alias is logged for [`LandmarkRegistry::aliases`],
    /// also once its track is forgotten (a run that checks its
    /// recognitions against the ground truth at the end).
    pub(super) fn keep_alias_log(&mut self) {
        self.alias_log.get_or_insert_with(Vec::new);
    }

    /// Tracks fused without a map id that are still remembered.
    #[cfg(test)]
    fn known_without_id(&self) -> usize {
        self.known_without_id.len()
    }

    /// The map id of `track`, a new one if it has none. A landmark first
    /// seen without a descriptor takes the first one it is seen with.
    pub(super) fn assign(&mut self, track: LandmarkId, descriptor: Option<Descriptor>) -> u32 {
        // A track fused before without an id keeps the descriptor it was
        // first seen with.
        let descriptor = match self.known_without_id.remove(&track) {
            Some((first, _)) => first.or(descriptor),
            None => descriptor,
        };
        if let Some(seen) = self.alias_seen.get_mut(&track) {
            *seen = self.fused_frames;
        }
        let next = self.first_tracks.len() as u32;
        let map_id = *self.map_ids.entry(track).or_insert(next);
        if map_id == next {
            self.first_tracks.push(track);
            self.descriptors.push(descriptor);
        } else if let Some(slot @ None) = self.descriptors.get_mut(map_id as usize) {
            *slot = descriptor;
        }
        map_id
    }

    /// A new map id for a frame node.
    pub(super) fn add_frame_node(&mut self) -> u32 {
        self.first_tracks.push(FRAME_NODE);
        self.descriptors.push(None);
        self.first_tracks.len() as u32 - 1
    }

    /// Records that `track` is the landmark `map_id` (a recognition).
    pub(super) fn alias(&mut self, track: LandmarkId, map_id: u32) {
        self.map_ids.insert(track, map_id);
        self.alias_seen.insert(track, self.fused_frames);
        if let Some(log) = self.alias_log.as_mut() {
            log.push((track, map_id));
        }
    }

    /// The track a map landmark entered the map under; None for a frame
    /// node or an unknown map id.
    pub(super) fn first_track(&self, map_id: u32) -> Option<LandmarkId> {
        self.first_tracks
            .get(map_id as usize)
            .copied()
            .filter(|&track| track != FRAME_NODE)
    }

    /// True when `map_id` is a frame node.
    pub(super) fn is_frame_node(&self, map_id: u32) -> bool {
        self.first_tracks.get(map_id as usize) == Some(&FRAME_NODE)
    }

    /// Descriptors by map id.
    pub(super) fn descriptors(&self) -> &[Option<Descriptor>] {
        &self.descriptors
    }

    /// Track ids recognised as a landmark already in the map: (the track
    /// id, the id the landmark entered the map with). Every one made since
    /// [`LandmarkRegistry::keep_alias_log`], else those of tracks still
    /// remembered.
    pub(super) fn aliases(&self) -> Vec<(LandmarkId, LandmarkId)> {
        let with_first = |(track, map_id): (LandmarkId, u32)| {
            let first = self.first_tracks[map_id as usize];
            (first != track).then_some((track, first))
        };
        match &self.alias_log {
            Some(log) => log.iter().copied().filter_map(with_first).collect(),
            None => self
                .alias_seen
                .keys()
                .filter_map(|&track| with_first((track, *self.map_ids.get(&track)?)))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tracks_frame_nodes_and_aliases_get_the_ids_they_should() {
        let mut registry = LandmarkRegistry::default();
        assert!(registry.is_empty());
        assert_eq!(registry.add_frame_node(), 0);
        assert_eq!(registry.assign(7, None), 1);
        assert_eq!(registry.assign(9, Some([3; 4])), 2);
        // Seen again: the same id, and the first descriptor it has.
        assert_eq!(registry.assign(7, Some([5; 4])), 1);
        assert_eq!(registry.assign(9, Some([6; 4])), 2);
        assert_eq!(registry.descriptors()[1], Some([5; 4]));
        assert_eq!(registry.descriptors()[2], Some([3; 4]));
        registry.alias(12, 1);
        assert_eq!(registry.map_id_of(12), Some(1));
        assert_eq!(registry.first_track(1), Some(7));
        assert_eq!(registry.first_track(0), None);
        assert!(registry.is_frame_node(0) && !registry.is_frame_node(1));
        assert_eq!(registry.aliases(), vec![(12, 7)]);
        assert_eq!(registry.assign(13, None), 3);
        // Four ids (a node, three landmarks) for four tracks, one of them
        // (12) sharing 7's id and the node having none.
        assert_eq!((registry.map_ids(), registry.tracks()), (4, 4));
        // Tracks fused without an id are known (with their first
        // descriptor) until they have been out of the fused frames for
        // FORGET_AFTER_FRAMES.
        registry.note_without_id([(20, None), (21, Some([1; 4]))]);
        assert!(registry.contains(20) && registry.contains(21) && registry.contains(7));
        assert_eq!(registry.map_id_of(20), None);
        assert_eq!(registry.known_as(20), Some(NO_ID_YET));
        assert_eq!(registry.known_as(7), Some(1));
        assert_eq!(registry.known_as(99), None);
        for _ in 0..2 * FORGET_AFTER_FRAMES {
            registry.note_without_id([(21, Some([2; 4]))]);
        }
        assert!(!registry.contains(20) && registry.contains(21));
        assert_eq!(registry.known_without_id(), 1);
        // The alias 12, out of the fused frames as long, is forgotten too;
        // its landmark keeps its id under 7.
        assert_eq!(registry.map_id_of(12), None);
        assert!(registry.aliases().is_empty());
        assert_eq!((registry.map_ids(), registry.tracks()), (4, 3));
        assert_eq!(registry.map_id_of(7), Some(1));
        // Its id, when it gets one, comes with the first descriptor.
        assert_eq!(registry.assign(21, Some([3; 4])), 4);
        assert_eq!(registry.descriptors()[4], Some([1; 4]));
        assert_eq!(registry.known_without_id(), 0);
    }

    #[test]
    fn an_alias_in_view_is_kept_and_the_log_keeps_every_alias() {
        let mut registry = LandmarkRegistry::default();
        registry.add_frame_node();
        let landmark = registry.assign(7, None);
        registry.alias(12, landmark);
        registry.alias(13, landmark);
        registry.keep_alias_log();
        registry.alias(14, landmark);
        // 12 stays in the fused frames, 13 and 14 leave them.
        for _ in 0..2 * FORGET_AFTER_FRAMES {
            assert_eq!(registry.assign(12, None), landmark);
            registry.note_without_id([]);
        }
        assert_eq!(registry.map_id_of(12), Some(landmark));
        assert_eq!(registry.map_id_of(13), None);
        assert_eq!(registry.map_id_of(14), None);
        // Without the log only 12 is listed; with it every alias made
        // since the log was asked for is, forgotten or not.
        assert_eq!(registry.aliases(), vec![(14, 7)]);
        let mut quiet = LandmarkRegistry::default();
        quiet.add_frame_node();
        let id = quiet.assign(7, None);
        quiet.alias(12, id);
        quiet.alias(13, id);
        for _ in 0..2 * FORGET_AFTER_FRAMES {
            quiet.assign(12, None);
            quiet.note_without_id([]);
        }
        assert_eq!(quiet.aliases(), vec![(12, 7)]);
    }
}
