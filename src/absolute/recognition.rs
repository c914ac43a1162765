//! Landmark identity: a landmark the relative stage
//! hands over under a new track id (its track was lost, or the robot came
//! back to a place) is recognised as a landmark already in the map, so its
//! new edges join the old ones and the map closes the loop.
//!
//! A candidate must pass two gates:
//! - geometry: the map landmark lies within the chi-square gate of where
//!   the filter predicts the new observation in the world, with covariance
//!   `R Σ_body R^T + P + σ_floor² I` (observation, robot position, and a
//!   floor for the map's own error near the robot);
//! - appearance: the Hamming distance of the ORB descriptors (taken at each
//!   track's birth) is at most `max_hamming`, and clearly below the second
//!   best gated candidate's (`ratio`, `margin_bits`), so that a repeated
//!   texture is left alone rather than guessed.
//!
//! Map landmarks are found through a uniform grid over their solved world
//! positions ([`LandmarkIndex`]), rebuilt when a new map is installed.

use std::collections::HashMap;

use nalgebra::{Matrix3, Vector3};

use crate::features::matching::hamming;
use crate::features::orb::Descriptor;
use crate::relative::types::{BodyLandmark, LandmarkId};

/// Gates of the recognition.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RecognitionConfig {
    /// Largest Hamming distance (of 256 bits) of a recognised landmark.
    pub max_hamming: u32,
    /// The best distance must be below `ratio` times the second best ...
    pub ratio: f64,
    /// ... and at least this many bits below it (the ratio alone accepts
    /// 1 against 2 bits: two lookalikes).
    pub margin_bits: u32,
    /// Chi-square gate on the position (3 dof; 16.27 = 99.9 %).
    pub gate_chi2: f64,
    /// Standard deviation added on each axis for the map's error, m.
    pub floor_sigma_m: f64,
    /// Never search farther than this from the prediction, m.
    pub max_search_radius_m: f64,
    /// Do not try to recognise a landmark whose own position (in the
    /// body, as measured in this frame) is less certain than this (largest
    /// standard deviation, m): its gate would hold many lookalikes and the
    /// descriptor alone then picks wrong ones (monocular depth along the
    /// ray, seen on rendered V1_02).
    pub max_landmark_sigma_m: f64,
    /// A track is joined to a map landmark only once it has been
    /// recognised as that same landmark in this many consecutive tracking
    /// frames (1: at once). Until then it adds no edges; a track that
    /// fails a confirmation becomes a new landmark.
    pub confirm_frames: u32,
    /// ... and only once the track's own position is at least this
    /// certain (largest standard deviation, m): a lookalike that fits a
    /// wide gate at a track's birth no longer fits once its depth is known.
    pub confirm_max_sigma_m: f64,
    /// A track still not confirmed after this many frames becomes a new
    /// landmark.
    pub max_pending_frames: u32,
    /// Once a map exists, a track that is not recognised waits this many
    /// frames before it becomes a new landmark (0 or 1: at once): a
    /// landmark seen again is often out of the gates at its track's birth
    /// (its depth not yet known, or the recognition not yet confirmed),
    /// and a new id given then is a duplicate for good.
    pub new_landmark_after_frames: u32,
    /// A recognition must put the robot where the frame's landmarks
    /// already in the map put it (their per-axis median), within this
    /// distance plus three of the track's standard deviations, m (along
    /// each of its axes or its largest: [`ConsensusGate`]).
    pub consensus_gate_m: f64,
}

impl Default for RecognitionConfig {
    fn default() -> Self {
        Self {
            max_hamming: 50,
            ratio: 0.8,
            margin_bits: 15,
            gate_chi2: 16.27,
            floor_sigma_m: 0.05,
            max_search_radius_m: 5.0,
            max_landmark_sigma_m: 0.5,
            confirm_frames: 5,
            confirm_max_sigma_m: 0.1,
            max_pending_frames: 40,
            new_landmark_after_frames: 10,
            consensus_gate_m: 0.1,
        }
    }
}

/// Map landmarks by grid cell of their world position.
#[derive(Clone, Debug, Default)]
pub struct LandmarkIndex {
    cell_m: f64,
    cells: HashMap<[i32; 3], Vec<u32>>,
    positions: Vec<Option<Vector3<f64>>>,
}

impl LandmarkIndex {
    /// Indexes `positions_world_m[id]` (None: not placed) with cubic cells
    /// of side `cell_m`.
    pub fn build(positions_world_m: Vec<Option<Vector3<f64>>>, cell_m: f64) -> Self {
        let cell_m = if cell_m.is_finite() && cell_m > 0.0 {
            cell_m
        } else {
            1.0
        };
        let mut cells: HashMap<[i32; 3], Vec<u32>> = HashMap::new();
        for (id, p) in positions_world_m.iter().enumerate() {
            if let Some(p) = p.filter(|p| p.iter().all(|v| v.is_finite())) {
                cells
                    .entry(cell_of(&p, cell_m))
                    .or_default()
                    .push(id as u32);
            }
        }
        Self {
            cell_m,
            cells,
            positions: positions_world_m,
        }
    }

    /// World position of landmark `id`, m, if it is indexed.
    pub fn position(&self, id: u32) -> Option<Vector3<f64>> {
        *self.positions.get(id as usize)?
    }

    /// Landmarks indexed.
    pub fn len(&self) -> usize {
        self.positions.iter().flatten().count()
    }

    /// Whether no landmark is indexed.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Ids whose position is within `radius_m` of `centre` (appended).
    pub fn within(&self, centre: &Vector3<f64>, radius_m: f64, out: &mut Vec<u32>) {
        if self.cells.is_empty() || !radius_m.is_finite() || radius_m < 0.0 {
            return;
        }
        let lo = cell_of(&centre.add_scalar(-radius_m), self.cell_m);
        let hi = cell_of(&centre.add_scalar(radius_m), self.cell_m);
        let cells_spanned = (0..3)
            .map(|k| i64::from(hi[k]) - i64::from(lo[k]) + 1)
            .product::<i64>();
        let r2 = radius_m * radius_m;
        let mut keep = |id: u32| {
            if let Some(p) = self.position(id) {
                if (p - centre).norm_squared() <= r2 {
                    out.push(id);
                }
            }
        };
        if cells_spanned > self.cells.len() as i64 {
            // A sphere larger than the occupied map: scan the cells.
            for ids in self.cells.values() {
                ids.iter().copied().for_each(&mut keep);
            }
            return;
        }
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    if let Some(ids) = self.cells.get(&[x, y, z]) {
                        ids.iter().copied().for_each(&mut keep);
                    }
                }
            }
        }
    }
}

fn cell_of(p: &Vector3<f64>, cell_m: f64) -> [i32; 3] {
    let c = |v: f64| (v / cell_m).floor().clamp(i32::MIN as f64, i32::MAX as f64) as i32;
    [c(p.x), c(p.y), c(p.z)]
}

/// One landmark to recognise.
#[derive(Clone, Copy, Debug)]
pub struct RecognitionQuery {
    /// Where the filter places the observation in the world, m.
    pub predicted_world_m: Vector3<f64>,
    /// Covariance of that prediction (observation + robot position), m².
    pub covariance_m2: Matrix3<f64>,
    /// The track's ORB descriptor.
    pub descriptor: Descriptor,
}

/// The recognised map landmark and its descriptor distance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Recognition {
    /// The map landmark's id.
    pub map_id: u32,
    /// Hamming distance between the two descriptors, bits (of 256).
    pub hamming: u32,
}

/// Finds the map landmark `query` is, if one passes both gates.
/// `descriptors[map_id]` are the map's descriptors; `taken(map_id)` says
/// a map landmark is already seen in this frame (one track each).
pub fn recognise(
    index: &LandmarkIndex,
    descriptors: &[Option<Descriptor>],
    query: &RecognitionQuery,
    taken: impl Fn(u32) -> bool,
    config: &RecognitionConfig,
    candidates: &mut Vec<u32>,
) -> Option<Recognition> {
    let s = query.covariance_m2 + Matrix3::identity() * config.floor_sigma_m.powi(2);
    let s = 0.5 * (s + s.transpose());
    let finite = s
        .iter()
        .chain(query.predicted_world_m.iter())
        .all(|v| v.is_finite());
    if !finite {
        return None;
    }
    let information = s.cholesky()?.inverse();
    let largest = s.symmetric_eigenvalues().max();
    let radius = (config.gate_chi2 * largest)
        .sqrt()
        .min(config.max_search_radius_m);
    candidates.clear();
    index.within(&query.predicted_world_m, radius, candidates);
    let mut best: Option<Recognition> = None;
    let mut second = u32::MAX;
    for &id in candidates.iter() {
        if taken(id) {
            continue;
        }
        let (Some(p), Some(Some(d))) = (index.position(id), descriptors.get(id as usize)) else {
            continue;
        };
        let e = p - query.predicted_world_m;
        if e.dot(&(information * e)) > config.gate_chi2 {
            continue;
        }
        let h = hamming(&query.descriptor, d);
        match best {
            Some(b) if h >= b.hamming => second = second.min(h),
            _ => {
                if let Some(b) = best {
                    second = second.min(b.hamming);
                }
                best = Some(Recognition {
                    map_id: id,
                    hamming: h,
                });
            }
        }
    }
    let best = best?;
    let distinct = second == u32::MAX
        || (f64::from(best.hamming) < config.ratio * f64::from(second)
            && best.hamming + config.margin_bits <= second);
    (best.hamming <= config.max_hamming && distinct).then_some(best)
}

/// Where the robot stands when a frame's tracks are recognised: its
/// position and covariance (the position filter's) and the body's
/// orientation in the map's frame.
pub struct FramePlacement {
    /// Body-to-map rotation.
    pub rotation: Matrix3<f64>,
    /// Body position in the map frame, m.
    pub position_m: Vector3<f64>,
    /// Covariance of that position, m^2.
    pub position_covariance_m2: Matrix3<f64>,
    /// Multiplies the tracks' body-frame covariances.
    pub landmark_covariance_scale: f64,
}

/// Recognises the frame's tracks that `known` does not already place
/// (it gives the map id of a track that has one): each is predicted in
/// the map from `placement` and passed to [`recognise`], one track per map
/// landmark per frame. Returns the new (track, map id) pairs.
pub fn recognise_tracks(
    index: &LandmarkIndex,
    descriptors: &[Option<Descriptor>],
    landmarks: &[BodyLandmark],
    placement: &FramePlacement,
    known: impl Fn(LandmarkId) -> Option<u32>,
    config: &RecognitionConfig,
    candidates: &mut Vec<u32>,
) -> Vec<(LandmarkId, u32)> {
    let mut taken: Vec<u32> = landmarks.iter().filter_map(|l| known(l.id)).collect();
    let mut found = Vec::new();
    let r = &placement.rotation;
    for l in landmarks {
        let Some(descriptor) = l.descriptor else {
            continue;
        };
        if known(l.id).is_some() {
            continue;
        }
        let own = l.covariance_body_m2 * placement.landmark_covariance_scale;
        if !(own.symmetric_eigenvalues().max() <= config.max_landmark_sigma_m.powi(2)) {
            continue;
        }
        let query = RecognitionQuery {
            predicted_world_m: placement.position_m + r * l.position_body_m,
            covariance_m2: r
                * (l.covariance_body_m2 * placement.landmark_covariance_scale)
                * r.transpose()
                + placement.position_covariance_m2,
            descriptor,
        };
        if let Some(hit) = recognise(
            index,
            descriptors,
            &query,
            |id| taken.contains(&id),
            config,
            candidates,
        ) {
            taken.push(hit.map_id);
            found.push((l.id, hit.map_id));
        }
    }
    found
}

/// Landmarks already associated a frame needs in view before a new
/// recognition is checked against where they place the robot.
pub const MIN_CONSENSUS_LANDMARKS: usize = 5;

/// How far from the frame's consensus a recognition may place the robot
/// ([`consistent_recognitions`]); `g` is `consensus_gate_m`, `C` the
/// track's covariance turned into the map (body covariance times the
/// scale given).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConsensusGate {
    /// Within `g` plus three of the track's standard deviations along each
    /// of its own axes: the difference `e` passes when
    /// `e^T (9 C + g^2 I)^-1 e <= 1`. A monocular track is uncertain along
    /// its ray and sure across it, so a lookalike off to the side of the
    /// ray is not excused by the ray's depth. The map's recognitions use
    /// it: on the monocular accuracy sets one such recognition, 0.14 m
    /// off with a largest sigma of 0.07 m, moved a run's map-frame pose by
    /// decimetres (docs/results/).
    TrackAxes,
    /// Within `g` plus three of the track's largest standard deviation,
    /// in any direction: what the localiser uses (in saved maps the
    /// axes' gate measured no better).
    LargestSigma,
}

/// Keeps the recognitions `found` (track, map id) that place the robot
/// where the frame's landmarks already associated with the map (`known`)
/// place it, their per-axis median, within `gate`. The robot position a
/// landmark implies is its map position minus its rotated body-frame
/// offset. With fewer than [`MIN_CONSENSUS_LANDMARKS`] known landmarks in
/// view all are kept. Returns the kept recognitions and how many were
/// dropped.
pub fn consistent_recognitions(
    index: &LandmarkIndex,
    landmarks: &[BodyLandmark],
    rotation: &Matrix3<f64>,
    known: impl Fn(LandmarkId) -> Option<u32>,
    found: Vec<(LandmarkId, u32)>,
    config: &RecognitionConfig,
    covariance_scale: f64,
    gate: ConsensusGate,
) -> (Vec<(LandmarkId, u32)>, usize) {
    if found.is_empty() {
        return (found, 0);
    }
    let implied = |l: &BodyLandmark, map_id: u32| {
        index
            .position(map_id)
            .map(|p| p - rotation * l.position_body_m)
    };
    let mut placed: Vec<Vector3<f64>> = landmarks
        .iter()
        .filter_map(|l| implied(l, known(l.id)?))
        .collect();
    if placed.len() < MIN_CONSENSUS_LANDMARKS {
        return (found, 0);
    }
    let consensus = Vector3::from_fn(|k, _| {
        placed.sort_by(|a, b| a[k].total_cmp(&b[k]));
        placed[placed.len() / 2][k]
    });
    let by_id: HashMap<LandmarkId, &BodyLandmark> = landmarks.iter().map(|l| (l.id, l)).collect();
    let before = found.len();
    let kept: Vec<(LandmarkId, u32)> = found
        .into_iter()
        .filter(|&(track, map_id)| {
            let Some(l) = by_id.get(&track) else {
                return false;
            };
            let Some(x) = implied(l, map_id) else {
                return false;
            };
            let e = x - consensus;
            let own = l.covariance_body_m2 * covariance_scale;
            if gate == ConsensusGate::LargestSigma {
                let gate2 =
                    config.consensus_gate_m.powi(2) + 9.0 * own.symmetric_eigenvalues().max();
                return e.norm_squared() <= gate2;
            }
            let own = rotation * own * rotation.transpose();
            let allowed = own * 9.0 + Matrix3::identity() * config.consensus_gate_m.powi(2);
            // Not positive definite only for a covariance that is not
            // finite (or singular, with a zero gate): dropped.
            allowed
                .cholesky()
                .is_some_and(|c| e.dot(&c.solve(&e)) <= 1.0)
        })
        .collect();
    let dropped = before - kept.len();
    (kept, dropped)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn descriptor(seed: u64) -> Descriptor {
        let mut z = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        [0; 4].map(|_| {
            z ^= z << 13;
            z ^= z >> 7;
            z ^= z << 17;
            z
        })
    }

    fn flip(mut d: Descriptor, bits: &[usize]) -> Descriptor {
        for &b in bits {
            d[b / 64] ^= 1 << (b % 64);
        }
        d
    }

    /// Ten landmarks on a line 1 m apart, each with its own descriptor.
    fn line_map() -> (LandmarkIndex, Vec<Option<Descriptor>>) {
        let positions = (0..10)
            .map(|k| Some(Vector3::new(k as f64, 0.0, 1.0)))
            .collect();
        let descriptors = (0..10).map(|k| Some(descriptor(k + 1))).collect();
        (LandmarkIndex::build(positions, 0.7), descriptors)
    }

    fn query(at: Vector3<f64>, sigma_m: f64, d: Descriptor) -> RecognitionQuery {
        RecognitionQuery {
            predicted_world_m: at,
            covariance_m2: Matrix3::identity() * sigma_m * sigma_m,
            descriptor: d,
        }
    }

    #[test]
    fn the_grid_finds_exactly_the_landmarks_inside_the_sphere() {
        let positions: Vec<Option<Vector3<f64>>> = (0..400)
            .map(|k| {
                let k = k as f64;
                Some(Vector3::new(
                    (k * 0.37).sin() * 9.0,
                    (k * 0.11).cos() * 7.0,
                    k * 0.01,
                ))
            })
            .chain([None])
            .collect();
        let index = LandmarkIndex::build(positions.clone(), 0.9);
        assert_eq!(index.len(), 400);
        for (centre, radius) in [
            (Vector3::new(0.0, 0.0, 1.0), 2.5),
            (Vector3::new(5.0, -3.0, 2.0), 0.4),
            (Vector3::zeros(), 1e3),
        ] {
            let mut found = Vec::new();
            index.within(&centre, radius, &mut found);
            found.sort_unstable();
            let brute: Vec<u32> = positions
                .iter()
                .enumerate()
                .filter_map(|(id, p)| {
                    ((p.as_ref()? - centre).norm() <= radius).then_some(id as u32)
                })
                .collect();
            assert_eq!(found, brute, "centre {centre:?} radius {radius}");
        }
    }

    #[test]
    fn a_landmark_is_recognised_by_position_and_descriptor() {
        let (index, descriptors) = line_map();
        let config = RecognitionConfig::default();
        let mut scratch = Vec::new();
        // Landmark 4 seen again, 0.2 m off, 20 bits changed.
        let d = flip(descriptor(5), &(0..20).map(|k| k * 11).collect::<Vec<_>>());
        let q = query(Vector3::new(4.2, 0.0, 1.0), 0.15, d);
        let found = recognise(&index, &descriptors, &q, |_| false, &config, &mut scratch);
        assert_eq!(
            found,
            Some(Recognition {
                map_id: 4,
                hamming: 20
            })
        );
        // Already seen in this frame under another track: not again.
        assert_eq!(
            recognise(
                &index,
                &descriptors,
                &q,
                |id| id == 4,
                &config,
                &mut scratch
            ),
            None
        );
    }

    #[test]
    fn either_gate_alone_rejects() {
        let (index, descriptors) = line_map();
        let config = RecognitionConfig::default();
        let mut scratch = Vec::new();
        // Right descriptor, but 1.5 m away with a 0.1 m uncertainty.
        let far = query(Vector3::new(4.0, 1.5, 1.0), 0.1, descriptor(5));
        assert_eq!(
            recognise(&index, &descriptors, &far, |_| false, &config, &mut scratch),
            None
        );
        // The same place with a 1 m uncertainty: inside the gate again.
        let unsure = query(Vector3::new(4.0, 1.5, 1.0), 1.0, descriptor(5));
        assert_eq!(
            recognise(
                &index,
                &descriptors,
                &unsure,
                |_| false,
                &config,
                &mut scratch
            )
            .map(|r| r.map_id),
            Some(4)
        );
        // Right place, unrelated descriptor.
        let stranger = query(Vector3::new(4.0, 0.0, 1.0), 0.1, descriptor(99));
        assert_eq!(
            recognise(
                &index,
                &descriptors,
                &stranger,
                |_| false,
                &config,
                &mut scratch
            ),
            None
        );
    }

    #[test]
    fn two_lookalikes_inside_the_gate_are_left_alone() {
        let positions = vec![
            Some(Vector3::new(0.0, 0.0, 0.0)),
            Some(Vector3::new(0.3, 0.0, 0.0)),
        ];
        let base = descriptor(7);
        let descriptors = vec![Some(base), Some(flip(base, &[3, 70, 140]))];
        let index = LandmarkIndex::build(positions, 1.0);
        let q = query(Vector3::new(0.15, 0.0, 0.0), 0.3, flip(base, &[200]));
        assert_eq!(
            recognise(
                &index,
                &descriptors,
                &q,
                |_| false,
                &RecognitionConfig::default(),
                &mut Vec::new()
            ),
            None
        );
    }

    #[test]
    fn recognitions_must_agree_with_the_known_landmarks() {
        // The robot at (0, -2, 0), turned by nothing, sees landmarks 0-5 of
        // the line map already associated (tracks 10-15) and two new
        // tracks: 20 at landmark 7's true offset, 21 claiming landmark 8
        // but seen 0.4 m from it.
        let (index, _) = line_map();
        let robot = Vector3::new(0.0, -2.0, 0.0);
        let seen = |track: u64, world: Vector3<f64>| BodyLandmark {
            id: track,
            position_body_m: world - robot,
            covariance_body_m2: Matrix3::identity() * 1e-4,
            descriptor: None,
            support: None,
        };
        let at = |k: u32| index.position(k).expect("placed");
        let mut landmarks: Vec<BodyLandmark> = (0..6).map(|k| seen(10 + k, at(k as u32))).collect();
        landmarks.push(seen(20, at(7)));
        landmarks.push(seen(21, at(8) + Vector3::new(0.0, 0.4, 0.0)));
        let known = |track: u64| (10..16).contains(&track).then(|| (track - 10) as u32);
        let config = RecognitionConfig::default();
        let (kept, dropped) = consistent_recognitions(
            &index,
            &landmarks,
            &Matrix3::identity(),
            known,
            vec![(20, 7), (21, 8)],
            &config,
            1.0,
            ConsensusGate::TrackAxes,
        );
        assert_eq!(kept, vec![(20, 7)]);
        assert_eq!(dropped, 1);
        // With fewer than five known landmarks in view nothing is judged.
        let (kept, dropped) = consistent_recognitions(
            &index,
            &landmarks[2..],
            &Matrix3::identity(),
            known,
            vec![(20, 7), (21, 8)],
            &config,
            1.0,
            ConsensusGate::TrackAxes,
        );
        assert_eq!((kept.len(), dropped), (2, 0));
    }

    #[test]
    fn a_recognition_off_the_side_of_a_tracks_ray_is_not_excused_by_its_depth() {
        // Six landmarks of the line map already associated place the robot
        // at (0, -2, 0). Two new monocular tracks, unsure along their ray
        // (y, sigma 0.1 m) and sure across it (5 mm), each claim a map
        // landmark seen 0.2 m from it: along the ray (kept) and across it
        // (dropped). Three times the largest sigma would excuse both.
        let (index, _) = line_map();
        let robot = Vector3::new(0.0, -2.0, 0.0);
        let ray = Matrix3::from_diagonal(&Vector3::new(
            0.005f64.powi(2),
            0.1f64.powi(2),
            0.005f64.powi(2),
        ));
        let seen = |track: u64, world: Vector3<f64>, covariance: Matrix3<f64>| BodyLandmark {
            id: track,
            position_body_m: world - robot,
            covariance_body_m2: covariance,
            descriptor: None,
            support: None,
        };
        let at = |k: u32| index.position(k).expect("placed");
        let mut landmarks: Vec<BodyLandmark> = (0..6)
            .map(|k| seen(10 + k, at(k as u32), Matrix3::identity() * 1e-4))
            .collect();
        landmarks.push(seen(20, at(7) + Vector3::new(0.0, 0.2, 0.0), ray));
        landmarks.push(seen(21, at(8) + Vector3::new(0.2, 0.0, 0.0), ray));
        let known = |track: u64| (10..16).contains(&track).then(|| (track - 10) as u32);
        let config = RecognitionConfig::default();
        let largest_gate = (config.consensus_gate_m.powi(2) + 9.0 * 0.1f64.powi(2)).sqrt();
        assert!(0.2 < largest_gate, "the old gate would have kept both");
        let judge = |landmarks: &[BodyLandmark], rotation: &Matrix3<f64>, gate| {
            consistent_recognitions(
                &index,
                landmarks,
                rotation,
                known,
                vec![(20, 7), (21, 8)],
                &config,
                1.0,
                gate,
            )
        };
        let (kept, dropped) = judge(&landmarks, &Matrix3::identity(), ConsensusGate::TrackAxes);
        assert_eq!((kept, dropped), (vec![(20, 7)], 1));
        // The body covariance is turned into the map: the same robot turned
        // a quarter turn about z sees the ray along the map's x, so the
        // same map offsets swap verdicts.
        let turn =
            *nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2)
                .matrix();
        let turned = |l: &BodyLandmark| BodyLandmark {
            position_body_m: turn.transpose() * l.position_body_m,
            ..*l
        };
        let mut landmarks: Vec<BodyLandmark> = landmarks.iter().map(turned).collect();
        landmarks[6].position_body_m =
            turn.transpose() * (at(7) + Vector3::new(0.2, 0.0, 0.0) - robot);
        landmarks[7].position_body_m =
            turn.transpose() * (at(8) + Vector3::new(0.0, 0.2, 0.0) - robot);
        let (kept, dropped) = judge(&landmarks, &turn, ConsensusGate::TrackAxes);
        assert_eq!((kept, dropped), (vec![(20, 7)], 1));
        // The largest sigma in any direction (the localiser's gate) keeps both.
        let (kept, dropped) = judge(&landmarks, &turn, ConsensusGate::LargestSigma);
        assert_eq!((kept.len(), dropped), (2, 0));
    }

    #[test]
    fn non_finite_queries_and_empty_maps_find_nothing() {
        let (index, descriptors) = line_map();
        let config = RecognitionConfig::default();
        let mut scratch = Vec::new();
        let nan = query(Vector3::new(f64::NAN, 0.0, 1.0), 0.1, descriptor(5));
        assert_eq!(
            recognise(&index, &descriptors, &nan, |_| false, &config, &mut scratch),
            None
        );
        let mut bad = query(Vector3::new(4.0, 0.0, 1.0), 0.1, descriptor(5));
        bad.covariance_m2[(0, 0)] = f64::NAN;
        assert_eq!(
            recognise(&index, &descriptors, &bad, |_| false, &config, &mut scratch),
            None
        );
        let empty = LandmarkIndex::build(Vec::new(), 1.0);
        let q = query(Vector3::new(4.0, 0.0, 1.0), 0.1, descriptor(5));
        assert_eq!(
            recognise(&empty, &[], &q, |_| false, &config, &mut scratch),
            None
        );
    }
}
