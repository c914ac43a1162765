//! The map as it is built, before it is solved: the edges fused so far
//! (paper eq. 41-43), which track is which unknown
//! ([`LandmarkRegistry`]), where the map is anchored in the relative
//! stage's world frame, and the odometry that joins consecutive frame
//! nodes. One frame's edges go in through [`MapBuilder::fuse`]; the map
//! solve takes the edges from [`MapBuilder::edges_mut`].

use nalgebra::{Matrix3, Vector3};

use super::config::{AbsoluteConfig, EdgeWeighting};
use super::landmark_registry::{LandmarkRegistry, NO_ID_YET};
use super::map_file::MapLandmark;
use super::map_worker::SolvedMap;
use super::node_places::NodePlaces;
use super::window_share::WindowShares;
use crate::edge_map::edge::{EdgeMap, LandmarkObservation};
use crate::edge_map::policy::EdgePolicy;
use crate::features::orb::Descriptor;
use crate::relative::types::{LandmarkId, RelativeOutput, WindowSupport};

/// What the map's reference (map id 0, fixed at the anchor) is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapReference {
    /// A landmark, by the track id it entered the map with.
    Landmark(LandmarkId),
    /// The robot's position in a frame, by the number of frames pushed
    /// before it.
    Frame {
        /// Frames pushed before it.
        index: usize,
    },
}

/// The map's anchor: the world position of map id 0, and the frame (by
/// the number of frames pushed before it) that chose it.
#[derive(Clone, Copy, Debug)]
struct Anchor {
    world_m: Vector3<f64>,
    frame: usize,
}

/// The last frame node, and the relative stage's translation since it
/// (world frame, m) with the distance travelled: the odometry edge to the
/// next node.
#[derive(Clone, Copy, Debug)]
struct OdometrySinceNode {
    node: u32,
    travelled_m: Vector3<f64>,
    distance_m: f64,
}

/// The edges, the ids and the anchor of the map being built.
pub(super) struct MapBuilder {
    edges: EdgeMap,
    registry: LandmarkRegistry,
    anchor: Option<Anchor>,
    /// None after lost tracking (no odometry edge across a gap).
    odometry: Option<OdometrySinceNode>,
    /// Tracking frames offered to the map ([`EdgePolicy::FrameNodes`]).
    mapped_frames: usize,
    policy: EdgePolicy,
    weighting: EdgeWeighting,
    /// Random walk of the odometry edges, m per sqrt(m); None without them.
    odometry_sigma_per_sqrt_m: Option<f64>,
    /// Frame nodes added.
    frame_nodes: usize,
    /// Frames whose turn it was to become a node, left out because their
    /// landmarks were mapped already.
    frames_saturated: usize,
    /// Per map id: the frame nodes it is joined to (saturating).
    nodes_per_landmark: Vec<u16>,
    /// See [`AbsoluteConfig::frame_node_saturation`] (0: off).
    saturation: usize,
    /// Where the frame nodes were taken.
    places: NodePlaces,
    /// See [`AbsoluteConfig::node_passes_per_place`] (0: off).
    passes_per_place: usize,
    /// Frames whose turn it was to become a node, left out because their
    /// place took nodes on `passes_per_place` passes already.
    frames_place_full: usize,
    /// See [`AbsoluteConfig::count_window_once`].
    count_window_once: bool,
    /// Per map id: how much of its window estimate is new since it was
    /// last joined to a frame node.
    window_shares: WindowShares,
}

impl MapBuilder {
    /// An empty map with the edge choices of `config`; `track_changes`
    /// when the solve reuses its previous factorisation.
    pub(super) fn new(config: &AbsoluteConfig, track_changes: bool) -> Self {
        let mut edges = EdgeMap::new();
        if track_changes {
            edges.track_changes();
        }
        let frame_nodes = matches!(config.policy, EdgePolicy::FrameNodes { .. });
        Self {
            edges,
            registry: LandmarkRegistry::default(),
            anchor: None,
            odometry: None,
            mapped_frames: 0,
            policy: config.policy,
            weighting: config.weighting,
            odometry_sigma_per_sqrt_m: (frame_nodes && config.odometry_edges)
                .then_some(config.odometry_sigma_per_sqrt_m),
            frame_nodes: 0,
            frames_saturated: 0,
            nodes_per_landmark: Vec::new(),
            saturation: config.frame_node_saturation,
            places: NodePlaces::default(),
            passes_per_place: config.node_passes_per_place,
            frames_place_full: 0,
            count_window_once: config.count_window_once,
            window_shares: WindowShares::default(),
        }
    }

    /// Frames left out of the map because their landmarks were mapped
    /// already ([`AbsoluteConfig::frame_node_saturation`]).
    pub(super) fn frames_saturated(&self) -> usize {
        self.frames_saturated
    }

    /// Frames left out of the map because their place was mapped on
    /// enough passes already ([`AbsoluteConfig::node_passes_per_place`]).
    pub(super) fn frames_place_full(&self) -> usize {
        self.frames_place_full
    }

    /// Places holding frame nodes.
    pub(super) fn node_places(&self) -> usize {
        self.places.len()
    }

    /// Whether most of a frame's landmarks (more than
    /// [`MAPPED_SHARE_TO_SKIP`]) are joined to `saturation` frame nodes
    /// already.
    fn mostly_mapped(&self, observations: &[LandmarkObservation]) -> bool {
        if self.saturation == 0 {
            return false;
        }
        let mapped = observations
            .iter()
            .filter(|o| {
                self.nodes_per_landmark
                    .get(o.id as usize)
                    .is_some_and(|&n| n as usize >= self.saturation)
            })
            .count();
        mapped as f64 > MAPPED_SHARE_TO_SKIP * observations.len() as f64
    }

    /// Frame nodes in the map.
    pub(super) fn frame_nodes(&self) -> usize {
        self.frame_nodes
    }

    /// The edges fused so far, for the map solve.
    pub(super) fn edges_mut(&mut self) -> &mut EdgeMap {
        &mut self.edges
    }

    /// Edges fused so far.
    pub(super) fn edge_count(&self) -> usize {
        self.edges.edge_count()
    }

    /// Track ids and map ids.
    pub(super) fn registry(&self) -> &LandmarkRegistry {
        &self.registry
    }

    /// Track ids and map ids, for recognition to add aliases.
    pub(super) fn registry_mut(&mut self) -> &mut LandmarkRegistry {
        &mut self.registry
    }

    /// True when a frame node is map id 0.
    pub(super) fn has_frame_nodes(&self) -> bool {
        matches!(self.policy, EdgePolicy::FrameNodes { .. })
    }

    /// Fixes map id 0 at `world_m`, chosen in the frame with `frame`
    /// frames pushed before it.
    pub(super) fn set_anchor(&mut self, world_m: Vector3<f64>, frame: usize) {
        self.anchor = Some(Anchor { world_m, frame });
    }

    /// World position of map id 0, once chosen.
    pub(super) fn anchor_world_m(&self) -> Option<Vector3<f64>> {
        self.anchor.map(|a| a.world_m)
    }

    /// What map id 0 is, and its world position, once chosen.
    pub(super) fn reference(&self) -> Option<(MapReference, Vector3<f64>)> {
        let anchor = self.anchor?;
        if self.registry.is_empty() {
            return None;
        }
        let reference = match self.registry.first_track(0) {
            Some(track) => MapReference::Landmark(track),
            None => MapReference::Frame {
                index: anchor.frame,
            },
        };
        Some((reference, anchor.world_m))
    }

    /// Adds the relative stage's increment to the odometry since the last
    /// frame node while tracking; forgets it otherwise.
    pub(super) fn note_motion(&mut self, tracking: bool, delta_world_m: &Vector3<f64>) {
        if !tracking {
            self.odometry = None;
        } else if let Some(odometry) = self.odometry.as_mut() {
            odometry.travelled_m += delta_world_m;
            odometry.distance_m += delta_world_m.norm();
        }
    }

    /// World positions of the solved map's landmarks by map id (None for
    /// frame nodes and unsolved ids), once anchored.
    pub(super) fn landmark_world_positions(
        &self,
        map: &SolvedMap,
    ) -> Option<Vec<Option<Vector3<f64>>>> {
        let anchor = self.anchor?.world_m;
        Some(
            map.positions_m
                .iter()
                .enumerate()
                .map(|(map_id, p)| {
                    p.filter(|_| !self.registry.is_frame_node(map_id as u32))
                        .map(|p| anchor + p)
                })
                .collect(),
        )
    }

    /// The solved map's landmarks for saving: world position, covariance
    /// given the neighbours (inverse of the landmark's diagonal block of
    /// A, see [`super::map_file`]) and descriptor. None before the anchor.
    pub(super) fn saved_landmarks(&self, map: &SolvedMap) -> Option<Vec<MapLandmark>> {
        let anchor = self.anchor?.world_m;
        let mut information = vec![Matrix3::zeros(); map.problem.landmark_count as usize];
        for e in &map.problem.edges {
            information[e.i as usize] += e.info;
            information[e.j as usize] += e.info;
        }
        let descriptors = self.registry.descriptors();
        Some(
            map.positions_m
                .iter()
                .enumerate()
                .filter(|(map_id, _)| !self.registry.is_frame_node(*map_id as u32))
                .filter_map(|(map_id, p)| {
                    let local = (*map.local_id.get(map_id)?)? as usize;
                    let covariance_m2 = information.get(local)?.try_inverse()?;
                    Some(MapLandmark {
                        id: map_id as u32,
                        position_m: anchor + (*p)?,
                        covariance_m2: 0.5 * (covariance_m2 + covariance_m2.transpose()),
                        descriptor: descriptors.get(map_id).copied().flatten(),
                        attitude: None,
                    })
                })
                .collect(),
        )
    }

    /// Edges of one tracking frame (eq. 41-43) with the configured policy
    /// and weighting; `position_m` is the robot's corrected world
    /// position (the place a frame node is taken at). Tracks for which
    /// `pending` holds (a recognition not yet confirmed) are left out:
    /// they get a map id once they are confirmed or given up.
    pub(super) fn fuse(
        &mut self,
        output: &RelativeOutput,
        rotation: &Matrix3<f64>,
        position_m: &Vector3<f64>,
        pending: impl Fn(LandmarkId) -> bool,
    ) {
        if output.landmarks.len() < 2 {
            return;
        }
        // The first frame node is the map's reference, id 0 (its frame
        // always has a node: the first of every `every`).
        let anchor_node = self.has_frame_nodes() && self.registry.is_empty();
        if anchor_node {
            self.registry.add_frame_node();
        }
        // With frame nodes a track gets its map id when a node is joined
        // to it: (index in `observations`, track, descriptor) of those
        // that have none yet.
        let frame_nodes = self.has_frame_nodes();
        let mut without_id = Vec::new();
        let mut observations: Vec<LandmarkObservation> = Vec::with_capacity(output.landmarks.len());
        let mut supports: Vec<Option<WindowSupport>> = Vec::with_capacity(output.landmarks.len());
        // Two live tracks recognised as one landmark: keep the first.
        let mut seen = std::collections::HashSet::with_capacity(output.landmarks.len());
        for l in output.landmarks.iter().filter(|l| !pending(l.id)) {
            let id = if frame_nodes && self.registry.map_id_of(l.id).is_none() {
                without_id.push((observations.len(), l.id, l.descriptor));
                NO_ID_YET
            } else {
                let id = self.registry.assign(l.id, l.descriptor);
                if !seen.insert(id) {
                    continue;
                }
                id
            };
            observations.push(LandmarkObservation {
                id,
                p_body_m: l.position_body_m,
                cov_body_m2: l.covariance_body_m2,
            });
            supports.push(l.support);
        }
        if let EdgePolicy::FrameNodes { every } = self.policy {
            let node = observations.len() >= 2
                && self.fuse_frame_node(
                    rotation,
                    position_m,
                    &mut observations,
                    &supports,
                    &without_id,
                    every,
                    anchor_node,
                );
            let still_without = if node { Vec::new() } else { without_id };
            self.registry.note_without_id(
                still_without
                    .into_iter()
                    .map(|(_, track, descriptor)| (track, descriptor)),
            );
            return;
        }
        if observations.len() < 2 {
            return;
        }
        let positions: Vec<Vector3<f64>> = observations.iter().map(|o| o.p_body_m).collect();
        let pairs = self.policy.pairs(&positions);
        match self.weighting {
            EdgeWeighting::Paper => self.edges.add_frame(rotation, &observations, &pairs),
            EdgeWeighting::PaperScaled => {
                let scale = 2.0 / observations.len() as f64;
                for &(a, b) in &pairs {
                    let (oa, ob) = (&observations[a], &observations[b]);
                    let covariance =
                        rotation * (oa.cov_body_m2 + ob.cov_body_m2) * rotation.transpose();
                    let Some(info) = covariance.try_inverse() else {
                        continue;
                    };
                    let info = (0.5 * scale) * (info + info.transpose());
                    let y = rotation * (ob.p_body_m - oa.p_body_m);
                    self.edges.add_measurement(oa.id, ob.id, &y, &info);
                }
            }
            EdgeWeighting::FrameMarginal => {
                let infos: Option<Vec<Matrix3<f64>>> = observations
                    .iter()
                    .map(|o| (rotation * o.cov_body_m2 * rotation.transpose()).try_inverse())
                    .collect();
                let Some(infos) = infos else { return };
                let Some(w) = infos.iter().sum::<Matrix3<f64>>().try_inverse() else {
                    return;
                };
                for &(a, b) in &pairs {
                    let Some(info) = positive_part(&(infos[a] * w * infos[b])) else {
                        continue;
                    };
                    let y = rotation * (observations[b].p_body_m - observations[a].p_body_m);
                    self.edges
                        .add_measurement(observations[a].id, observations[b].id, &y, &info);
                }
            }
        }
    }

    /// [`EdgePolicy::FrameNodes`]: every `every`-th mapped frame becomes a
    /// node joined to its landmarks, and to the previous node by the
    /// odometry between them. The tracks of `without_id` (index in
    /// `observations`, track, descriptor) get their map ids when the node
    /// is added. True when it is.
    fn fuse_frame_node(
        &mut self,
        rotation: &Matrix3<f64>,
        position_m: &Vector3<f64>,
        observations: &mut [LandmarkObservation],
        supports: &[Option<WindowSupport>],
        without_id: &[(usize, LandmarkId, Option<Descriptor>)],
        every: usize,
        anchor_node: bool,
    ) -> bool {
        self.mapped_frames += 1;
        if (self.mapped_frames - 1) % every != 0 {
            return false;
        }
        // Where the frame looks: the mean direction of its landmarks.
        let looking = rotation
            * observations
                .iter()
                .filter_map(|o| o.p_body_m.try_normalize(0.0))
                .sum::<Vector3<f64>>();
        let place = self.places.turn(position_m, &looking);
        if !anchor_node && self.mostly_mapped(observations) {
            // The odometry since the last node goes on accumulating: the
            // next node's edge spans both.
            self.frames_saturated += 1;
            return false;
        }
        if let Some(place) = place {
            if !anchor_node
                && self.passes_per_place > 0
                && self.places.is_full(place, self.passes_per_place)
            {
                // Mapped from here on enough passes already (with landmarks
                // recognition did not find again): the odometry goes on
                // accumulating.
                self.frames_place_full += 1;
                return false;
            }
            self.places.add_node(place);
        }
        for &(k, track, descriptor) in without_id {
            observations[k].id = self.registry.assign(track, descriptor);
        }
        let node = if anchor_node {
            0
        } else {
            self.registry.add_frame_node()
        };
        self.frame_nodes += 1;
        for o in observations.iter() {
            let k = o.id as usize;
            if self.nodes_per_landmark.len() <= k {
                self.nodes_per_landmark.resize(k + 1, 0);
            }
            self.nodes_per_landmark[k] = self.nodes_per_landmark[k].saturating_add(1);
        }
        if self.count_window_once {
            for (o, support) in observations.iter_mut().zip(supports) {
                let share = self
                    .window_shares
                    .use_estimate(o.id, *support)
                    .max(MIN_NEW_SHARE);
                o.cov_body_m2 /= share;
            }
        }
        self.edges.add_frame_node(rotation, node, observations);
        if let (Some(odometry), Some(sigma)) = (self.odometry, self.odometry_sigma_per_sqrt_m) {
            // The relative stage's own motion between the two nodes, a
            // random walk of `sigma`: what the frames say about each
            // other besides their landmarks.
            let variance = sigma.powi(2) * odometry.distance_m.max(MIN_ODOMETRY_DISTANCE_M);
            let info = Matrix3::identity() / variance;
            self.edges
                .add_measurement(odometry.node, node, &odometry.travelled_m, &info);
        }
        self.odometry = Some(OdometrySinceNode {
            node,
            travelled_m: Vector3::zeros(),
            distance_m: 0.0,
        });
        true
    }
}

/// Share of a landmark's window estimate a frame node is given when
/// nothing in it is new (no keyframe since the landmark's last node):
/// small, so that the node still has a position in the map.
const MIN_NEW_SHARE: f64 = 1e-2;

/// The symmetric part of an edge block `S_i W S_j`, with eigenvalues below
/// a small fraction of the largest raised to it. With anisotropic
/// covariances (stereo depth along different rays) the symmetric part is
/// often indefinite; an indefinite edge would make its fused information
/// singular and the edge unusable, so the direction it is negative in is
/// given (almost) no weight instead. None when nothing is positive.
fn positive_part(block: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let symmetric = 0.5 * (block + block.transpose());
    let eigen = symmetric.symmetric_eigen();
    let largest = eigen.eigenvalues.max();
    if !(largest > 0.0) || !largest.is_finite() {
        return None;
    }
    let floor = largest * POSITIVE_PART_FLOOR;
    let clamped = eigen.eigenvalues.map(|v| v.max(floor));
    let q = eigen.eigenvectors;
    let info = q * Matrix3::from_diagonal(&clamped) * q.transpose();
    Some(0.5 * (info + info.transpose()))
}

/// A frame adds no node when more than this share of its landmarks are
/// mapped ([`AbsoluteConfig::frame_node_saturation`]): a frame that sees
/// half new or little-seen landmarks still extends the map. Each node it
/// adds counts for at least half its landmarks, so a room of `L`
/// landmarks seen `m` at a time gets at most `2 L saturation / m` nodes.
const MAPPED_SHARE_TO_SKIP: f64 = 0.5;

/// Smallest eigenvalue kept in an edge's information, relative to its
/// largest: keeps fused edges positive definite (see [`positive_part`]).
const POSITIVE_PART_FLOOR: f64 = 1e-6;

/// Shortest distance an odometry edge's variance is computed for, m (a
/// robot at rest still gets a finite information).
const MIN_ODOMETRY_DISTANCE_M: f64 = 0.01;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::relative::types::BodyLandmark;

    /// Four landmarks 3 m ahead, sigma 1 cm, whose window estimate rests
    /// on ten keyframes up to `newest` (None: no window).
    fn landmarks(newest: Option<u64>) -> Vec<BodyLandmark> {
        (0..4)
            .map(|k| BodyLandmark {
                id: k,
                position_body_m: Vector3::new(k as f64 - 1.5, 0.5, 3.0),
                covariance_body_m2: Matrix3::identity() * 1e-4,
                descriptor: None,
                support: newest.map(|n| WindowSupport {
                    keyframes: 10,
                    newest_keyframe: n,
                }),
            })
            .collect()
    }

    /// Ten frames at the origin, each a frame node; the information (trace)
    /// the map holds about track 2 over all its edges, over one frame's.
    fn information_gathered(count_window_once: bool, newest: impl Fn(u64) -> Option<u64>) -> f64 {
        let config = AbsoluteConfig {
            policy: EdgePolicy::FrameNodes { every: 1 },
            frame_node_saturation: 0,
            node_passes_per_place: 0,
            count_window_once,
            ..AbsoluteConfig::default()
        };
        let mut builder = MapBuilder::new(&config, false);
        for frame in 0..10u64 {
            let output = RelativeOutput::tracking_at_origin(
                frame as i64 * 50_000_000,
                landmarks(newest(frame)),
            );
            builder.fuse(&output, &Matrix3::identity(), &Vector3::zeros(), |_| false);
        }
        assert_eq!(builder.frame_nodes(), 10);
        let id = builder.registry().map_id_of(2).expect("mapped");
        let total: f64 = builder
            .edges
            .sorted_edges()
            .iter()
            .filter(|((i, j), _)| *i == id || *j == id)
            .map(|(_, e)| e.info.trace())
            .sum();
        total / (3.0 / 1e-4)
    }

    #[test]
    fn an_estimate_handed_on_again_adds_almost_nothing() {
        // Ten frames between the same two keyframes: the same estimate.
        let once = information_gathered(true, |_| Some(5));
        let each = information_gathered(false, |_| Some(5));
        assert!((each - 10.0).abs() < 1e-9, "{each}");
        assert!((once - (1.0 + 9.0 * MIN_NEW_SHARE)).abs() < 1e-9, "{once}");
    }

    #[test]
    fn each_node_adds_the_share_of_new_keyframes() {
        // A keyframe per frame: each later node adds a tenth.
        let once = information_gathered(true, |frame| Some(5 + frame));
        assert!((once - 1.9).abs() < 1e-9, "{once}");
        // Two per frame: a fifth.
        let once = information_gathered(true, |frame| Some(5 + 2 * frame));
        assert!((once - 2.8).abs() < 1e-9, "{once}");
        // Eleven per frame (more than it rests on): all of it again.
        let once = information_gathered(true, |frame| Some(5 + 11 * frame));
        assert!((once - 10.0).abs() < 1e-9, "{once}");
    }

    #[test]
    fn without_a_window_every_node_counts_whole() {
        let once = information_gathered(true, |_| None);
        assert!((once - 10.0).abs() < 1e-9, "{once}");
    }
}
