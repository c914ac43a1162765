//! The absolute stage (paper eq. 41-71): consumes the relative stage's
//! [`RelativeOutput`] frame by frame, fuses its edges into the edge map
//! (by default a frame node joined to the frame's landmarks every 5
//! tracking frames, [`EdgePolicy::FrameNodes`]; or the paper's landmark
//! pairs), solves the map every K frames off the frame-rate path, and
//! corrects the robot position with the robot position Kalman filter.
//!
//! The map grows by one 3-vector unknown per frame node as well as per
//! landmark: in a bounded room with recognition the landmarks stop
//! growing but the frame nodes do not (4 per second at 20 Hz), so a run
//! of hours needs old frame nodes folded into their landmarks' edges,
//! which is not done yet.
//!
//! Per frame ([`AbsoluteStage::push`]):
//! 1. install a map solve that has finished, if any;
//! 2. predict the position with the relative stage's increment (eq. 60-62);
//! 3. correct it with the visible landmarks of the last solved map
//!    (eq. 63-71), their joint covariance from the map's factor (exact) or
//!    the paper's sub-matrix rule;
//! 4. fuse the frame's edges (eq. 41-43) *after* the correction, so that a
//!    frame's landmark noise is never in the map it is corrected against;
//! 5. every `solve_every_frames` frames, hand a snapshot of the edges to
//!    the map solve ([`SolveMode`]).
//!
//! The returned pose takes its orientation from the relative stage and its
//! position from the filter. Positions are in the relative stage's world
//! frame: the map is anchored at the first frame node, where the relative
//! stage put the robot in that frame ([`EdgePolicy::FrameNodes`]), or, with
//! landmark pairs, where it put the reference landmark (the first landmark
//! of the first frame with two or more). A robot position is exact in the
//! relative stage's frame; a landmark's is not (a monocular landmark's
//! depth at a static start is barely known), and the whole map would carry
//! its error.
//!
//! Use from the pipeline (`rigslam run`): one stage per run, one `push`
//! per relative-stage output, in order; the map solve runs on the stage's
//! own thread by default.
//!
//! ```no_run
//! use rigslam::absolute::{AbsoluteConfig, AbsoluteStage};
//! # fn relative_outputs() -> Vec<rigslam::relative::types::RelativeOutput> { Vec::new() }
//! let mut stage = AbsoluteStage::new(AbsoluteConfig::default());
//! for output in relative_outputs() {
//!     let corrected = stage.push(&output);
//!     // corrected.T_world_body -> `--trajectory`,
//!     // output.T_world_body    -> `--trajectory-relative`.
//!     let _ = (corrected.t_ns, corrected.T_world_body);
//! }
//! stage.wait_for_solve();
//! eprintln!("{:?}", stage.stats());
//! ```

use std::collections::HashMap;
use std::time::Instant;

use nalgebra::{DMatrix, Isometry3, Matrix3, Translation3, Vector3};

use super::map_worker::{MapSolveRequest, MapSolveWorker, RobustWeights, SolvedMap};
use super::position_filter::{LandmarkFix, PositionFilter};
use super::recognition::{
    consistent_recognitions, recognise_tracks, FramePlacement, LandmarkIndex, RecognitionConfig,
};
use super::solve_schedule::MapSolver;
use crate::edge_map::covariance::submatrix_covariance;
use crate::edge_map::edge::{EdgeMap, LandmarkObservation};
use crate::edge_map::ordering_reuse::SymbolicPath;
use crate::edge_map::policy::EdgePolicy;
use crate::edge_map::solve::SolverChoice;
use crate::edge_map::EdgeMapError;
use crate::features::orb::Descriptor;
use crate::relative::types::{BodyLandmark, LandmarkId, RelativeOutput, TrackingState};

/// How one frame's landmark pairs are weighted as edge measurements.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EdgeWeighting {
    /// The paper's eq. 42: each pair's edge gets `(Σ_yi + Σ_yj)^-1`,
    /// treating the pairs of one frame as independent. They are not (every
    /// landmark's noise is in m - 1 of them), so with all pairs the map
    /// information is about m/2 times too large and its covariance
    /// correspondingly too small.
    Paper,
    /// The information the frame really carries about the landmarks with
    /// its own (unknown) position marginalised out: `Λ = D - D W D`,
    /// `D = blockdiag(S_i)`, `W = (Σ_k S_k)^-1`, which is a block
    /// Laplacian over the complete graph with edge blocks `S_i W S_j`.
    /// Exact with [`EdgePolicy::AllPairs`] when the `S_i` commute
    /// (isotropic covariances), the symmetric part of `S_i W S_j`
    /// otherwise; with another policy it keeps only the chosen pairs'
    /// share. The map covariance `A^-1` is then the covariance of the
    /// map, which the filter relies on.
    FrameMarginal,
    /// The paper's edge `(Σ_yi + Σ_yj)^-1` scaled by `2 / m` for a frame
    /// of m landmarks: with all pairs and equal isotropic covariances that
    /// is exactly [`EdgeWeighting::FrameMarginal`] (each landmark's noise
    /// is counted once instead of m - 1 times), and unlike the
    /// frame-marginal blocks it is positive definite for any covariances.
    PaperScaled,
}

/// Which covariance of the visible landmarks the filter uses (eq. 59).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LandmarkCovariance {
    /// Exact blocks of `A^-1` from the map's Cholesky factor, plus the
    /// cross-covariance of the position error with the visible landmarks'
    /// map errors (consider terms). Falls back to the sub-matrix rule after
    /// a conjugate-gradient solve (no factor).
    Exact,
    /// The paper's approximation: the inverse of A's sub-matrix over the
    /// visible landmarks grown by `hops` rings; no consider terms.
    SubMatrix {
        /// Rings of neighbours added around the visible landmarks.
        hops: usize,
    },
}

pub use super::solve_schedule::SolveMode;

/// Configuration of the absolute stage.
#[derive(Clone, Debug)]
pub struct AbsoluteConfig {
    /// Which landmark pairs of a frame become edges [frame nodes every 5 frames].
    pub policy: EdgePolicy,
    /// How those edges are weighted as measurements [the paper's, scaled].
    pub weighting: EdgeWeighting,
    /// Map solve every this many frames (the paper: 5).
    pub solve_every_frames: usize,
    /// Where the map solve runs \[pipelined\].
    pub solve_mode: SolveMode,
    /// Direct sparse Cholesky or conjugate gradients [auto: CG above 200 000 landmarks].
    pub solver: SolverChoice,
    /// How the visible landmarks' covariance for the correction is computed \[exact\].
    pub covariance: LandmarkCovariance,
    /// Prediction noise: `Q = sigma^2 * |Δ| * I` (a random walk per metre
    /// travelled), sigma in m per sqrt(m).
    pub translation_sigma_per_sqrt_m: f64,
    /// Every landmark covariance the relative stage hands over is
    /// multiplied by this: its window covariances leave out what it does
    /// not model (tracking drift, calibration), and on real EuRoC frames
    /// the corrections' NIS says they are too small (bench/README.md).
    pub landmark_covariance_scale: f64,
    /// At most this many visible landmarks (the most precise) correct a
    /// frame.
    pub max_correction_landmarks: usize,
    /// Threads for the factorisation.
    pub solver_threads: usize,
    /// Recognise landmarks that come back under a new track id (None:
    /// every new id is a new landmark).
    pub recognition: Option<RecognitionConfig>,
    /// Down-weight map edges that disagree with the solved map (a wrong
    /// recognition) and solve again (None: plain least squares).
    pub robust: Option<RobustWeights>,
    /// Join consecutive frame nodes by the relative stage's translation
    /// between them ([`EdgePolicy::FrameNodes`] only): a frame whose
    /// landmarks are all new stays connected to the map.
    pub odometry_edges: bool,
}

impl Default for AbsoluteConfig {
    fn default() -> Self {
        Self {
            policy: EdgePolicy::FrameNodes { every: 5 },
            weighting: EdgeWeighting::PaperScaled,
            solve_every_frames: 5,
            solve_mode: SolveMode::Pipelined,
            solver: SolverChoice::Auto {
                cg_above_landmarks: 200_000,
            },
            covariance: LandmarkCovariance::Exact,
            translation_sigma_per_sqrt_m: 0.02,
            max_correction_landmarks: 30,
            landmark_covariance_scale: 1.0,
            solver_threads: 1,
            recognition: Some(RecognitionConfig::default()),
            robust: Some(RobustWeights::default()),
            odometry_edges: true,
        }
    }
}

/// The stage's answer for one frame.
#[allow(non_snake_case)]
#[derive(Clone, Debug, PartialEq)]
pub struct CorrectedPose {
    /// Frame stamp, ns.
    pub t_ns: i64,
    /// Position from the filter, orientation from the relative stage.
    pub T_world_body: Isometry3<f64>,
    /// The filter's position covariance (None before it starts).
    pub position_covariance_m2: Option<Matrix3<f64>>,
    /// Landmarks that corrected this frame.
    pub landmarks_used: usize,
    /// Version of the map used (0: none yet).
    pub map_version: u64,
    /// Normalised innovation squared of the correction (0 without one).
    pub nis: f64,
}

/// Counters and timings of a run.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct AbsoluteStats {
    /// Frames pushed.
    pub frames: usize,
    /// Frames the position filter corrected with landmarks.
    pub corrections: usize,
    /// Map solves installed.
    pub solves: usize,
    /// Solves whose sparsity pattern equalled the previous one's, so the
    /// symbolic factorisation was reused.
    pub symbolic_reused: usize,
    /// Solves whose pattern changed but whose landmark ordering was reused
    /// (new landmarks appended, no AMD).
    pub ordering_reused: usize,
    /// Solves with a fresh AMD ordering.
    pub fresh_orderings: usize,
    /// Solves done by conjugate gradients.
    pub pcg_solves: usize,
    /// Conjugate-gradient iterations over all of them.
    pub pcg_iterations: usize,
    /// Iterations a cold start would have needed (when measured).
    pub pcg_cold_iterations: usize,
    /// Background mode: requests put off because a solve was still
    /// running.
    pub deferred_solves: usize,
    /// Pipelined mode: time frames spent waiting for the solve they
    /// install (zero while solves take less than K frames), total and
    /// longest, ms.
    pub solve_wait_ms: f64,
    /// Longest of those waits, ms.
    pub solve_wait_max_ms: f64,
    /// Time spent in map solves in all, ms.
    pub solve_total_ms: f64,
    /// Parts of `solve_total_ms`: assembly of A, ordering + symbolic
    /// analysis, numeric factorisation, and the covariance blocks of the
    /// landmarks in view.
    pub solve_assemble_ms: f64,
    /// Ordering and symbolic analysis, ms.
    pub solve_symbolic_ms: f64,
    /// Numeric factorisation, ms.
    pub solve_factor_ms: f64,
    /// Covariance blocks of the landmarks in view, ms.
    pub solve_covariance_ms: f64,
    /// Entries of the last solve's Cholesky factor.
    pub last_factor_nnz: usize,
    /// Unknowns (3 per landmark or frame node) of the last solve.
    pub last_unknowns: usize,
    /// Robust reweighting: extra solves in all, and edges down-weighted
    /// in the last map.
    pub robust_solves: usize,
    /// Edges down-weighted in the last map.
    pub last_downweighted_edges: usize,
    /// Tracks recognised in some frames but not confirmed in the next
    /// (`RecognitionConfig::confirm_frames`): left as new landmarks.
    pub unconfirmed_recognitions: usize,
    /// Recognitions that put the robot elsewhere than the frame's
    /// landmarks already in the map do (`RecognitionConfig::consensus_gate_m`).
    pub inconsistent_recognitions: usize,
    /// Time spent in `push` over all frames, ms (inline solves included).
    pub frame_total_ms: f64,
    /// Longest time on one frame, ms.
    pub frame_max_ms: f64,
    /// Map solves that failed (the previous map was kept).
    pub solve_errors: usize,
    /// New track ids recognised as landmarks already in the map.
    pub recognised: usize,
    /// Landmarks (non-finite, or covariance not positive definite),
    /// increments and poses (non-finite) that were left out.
    pub rejected_inputs: usize,
    /// Landmarks in view and in the map left out of a correction that had
    /// room for them, because the map's covariance blocks were computed
    /// before they came into view (recognised since the last solve): they
    /// join after the next.
    pub uncached_landmarks: usize,
    /// Mean normalised innovation squared per degree of freedom of the
    /// corrections: about 1 when the covariances the filter is given are
    /// right, far above when they are overconfident.
    pub mean_nis_per_dof: f64,
    #[serde(skip)]
    nis_sum: f64,
    #[serde(skip)]
    nis_dof: usize,
}

/// The absolute stage.
pub struct AbsoluteStage {
    config: AbsoluteConfig,
    edges: EdgeMap,
    map_ids: HashMap<LandmarkId, u32>,
    /// Tracks recognised as a map landmark in fewer than
    /// `confirm_frames` consecutive frames: the landmark and the count.
    pending: HashMap<LandmarkId, (u32, u32)>,
    landmark_ids: Vec<LandmarkId>,
    /// Descriptor of each map landmark (by map id), for recognition.
    map_descriptors: Vec<Option<Descriptor>>,
    /// Solved map landmarks by world position, for recognition.
    index: LandmarkIndex,
    candidates: Vec<u32>,
    /// Reference landmark (map id 0) and where the relative stage put it.
    anchor_world_m: Option<Vector3<f64>>,
    /// Frames pushed before the one that anchored the map.
    anchor_frame: usize,
    filter: Option<PositionFilter>,
    map: Option<SolvedMap>,
    frames_since_solve: usize,
    /// Tracking frames offered to the map ([`EdgePolicy::FrameNodes`]).
    mapped_frames: usize,
    /// The last frame node and the relative stage's translation since it
    /// (world frame, m) with the distance travelled: the odometry edge to
    /// the next node. None after lost tracking (no edge across a gap).
    odometry: Option<(u32, Vector3<f64>, f64)>,
    next_version: u64,
    stats: AbsoluteStats,
    /// Where the map is solved, with what is in flight.
    solver: MapSolver,
    /// Map ids in view in the last tracking frame, the most precise
    /// first: the covariance blocks the next solve computes.
    in_view: Vec<u32>,
}

impl AbsoluteStage {
    /// A stage with `config`, starting its solve thread in the background and pipelined modes.
    pub fn new(config: AbsoluteConfig) -> Self {
        let solver = MapSolver::new(
            config.solve_mode,
            config.solver,
            config.solver_threads,
            config.robust,
        );
        let mut edges = EdgeMap::new();
        if solver.needs_edge_changes() {
            edges.track_changes();
        }
        Self {
            config,
            edges,
            map_ids: HashMap::new(),
            pending: HashMap::new(),
            landmark_ids: Vec::new(),
            map_descriptors: Vec::new(),
            index: LandmarkIndex::default(),
            candidates: Vec::new(),
            anchor_world_m: None,
            anchor_frame: 0,
            filter: None,
            map: None,
            frames_since_solve: 0,
            mapped_frames: 0,
            odometry: None,
            next_version: 1,
            stats: AbsoluteStats::default(),
            solver,
            in_view: Vec::new(),
        }
    }

    /// The inline worker (Inline mode only), e.g. to measure CG cold starts.
    pub fn worker_mut(&mut self) -> Option<&mut MapSolveWorker> {
        self.solver.inline_worker()
    }

    /// Counters and timings so far.
    pub fn stats(&self) -> &AbsoluteStats {
        &self.stats
    }

    /// The settings it was built with.
    pub fn config(&self) -> &AbsoluteConfig {
        &self.config
    }

    /// What map id 0 (the map's fixed unknown) is, and its world position
    /// (the map's anchor), once chosen.
    pub fn reference(&self) -> Option<(MapReference, Vector3<f64>)> {
        let anchor = self.anchor_world_m?;
        match *self.landmark_ids.first()? {
            FRAME_NODE => Some((
                MapReference::Frame {
                    index: self.anchor_frame,
                },
                anchor,
            )),
            track => Some((MapReference::Landmark(track), anchor)),
        }
    }

    /// Track ids recognised as a landmark already in the map: (the track
    /// id, the id the landmark entered the map with).
    pub fn aliases(&self) -> impl Iterator<Item = (LandmarkId, LandmarkId)> + '_ {
        self.map_ids.iter().filter_map(|(&id, &map_id)| {
            let first = self.landmark_ids[map_id as usize];
            (first != id).then_some((id, first))
        })
    }

    /// Solves the map with every edge fused so far (waiting for a running
    /// solve first) and returns its landmarks for saving: world position,
    /// covariance given the neighbours (inverse of the landmark's diagonal
    /// block of A, see [`super::map_file`]) and descriptor. None before any
    /// edge, and in [`SolveMode::Manual`] without a solved map.
    pub fn finish_map(&mut self) -> Option<super::map_file::SavedMap> {
        self.wait_for_solve();
        if self.frames_since_solve > 0 && self.edges.edge_count() > 0 {
            self.frames_since_solve = 0;
            self.request_solve();
            self.wait_for_solve();
        }
        let map = self.map.as_ref()?;
        let anchor = self.anchor_world_m?;
        let mut information = vec![Matrix3::zeros(); map.problem.landmark_count as usize];
        for e in &map.problem.edges {
            information[e.i as usize] += e.info;
            information[e.j as usize] += e.info;
        }
        let landmarks = map
            .positions_m
            .iter()
            .enumerate()
            .filter(|(map_id, _)| self.landmark_ids[*map_id] != FRAME_NODE)
            .filter_map(|(map_id, p)| {
                let local = (*map.local_id.get(map_id)?)? as usize;
                let covariance_m2 = information.get(local)?.try_inverse()?;
                Some(super::map_file::MapLandmark {
                    id: map_id as u32,
                    position_m: anchor + (*p)?,
                    covariance_m2: 0.5 * (covariance_m2 + covariance_m2.transpose()),
                    descriptor: self.map_descriptors.get(map_id).copied().flatten(),
                })
            })
            .collect();
        Some(super::map_file::SavedMap { landmarks })
    }

    /// The track id a map landmark was first seen under.
    pub fn landmark_track(&self, map_id: u32) -> Option<LandmarkId> {
        self.landmark_ids
            .get(map_id as usize)
            .copied()
            .filter(|&id| id != FRAME_NODE)
    }

    /// The last solved map, if any.
    pub fn map(&self) -> Option<&SolvedMap> {
        self.map.as_ref()
    }

    /// World position of a landmark in the last solved map.
    pub fn landmark_world_m(&self, id: LandmarkId) -> Option<Vector3<f64>> {
        let map_id = *self.map_ids.get(&id)?;
        let relative = (*self.map.as_ref()?.positions_m.get(map_id as usize)?)?;
        Some(self.anchor_world_m? + relative)
    }

    /// Processes one frame of the relative stage; returns the corrected pose.
    pub fn push(&mut self, output: &RelativeOutput) -> CorrectedPose {
        let start = Instant::now();
        match self.config.solve_mode {
            SolveMode::Background => self.poll_background(),
            SolveMode::Pipelined
                if self.frames_since_solve + 1 >= self.config.solve_every_frames =>
            {
                if self.solver.in_flight() {
                    let wait = Instant::now();
                    self.wait_for_solve();
                    let waited = wait.elapsed().as_secs_f64() * 1e3;
                    self.stats.solve_wait_ms += waited;
                    self.stats.solve_wait_max_ms = self.stats.solve_wait_max_ms.max(waited);
                }
            }
            _ => {}
        }
        let cleaned;
        let mut output = match sanitize(output) {
            Some((clean, rejected)) => {
                self.stats.rejected_inputs += rejected;
                cleaned = clean;
                &cleaned
            }
            None => output,
        };
        let scaled;
        if self.config.landmark_covariance_scale != 1.0 {
            let mut copy = output.clone();
            for l in &mut copy.landmarks {
                l.covariance_body_m2 *= self.config.landmark_covariance_scale;
            }
            scaled = copy;
            output = &scaled;
        }
        let rotation = *output.T_world_body.rotation.to_rotation_matrix().matrix();
        let tracking = output.state == TrackingState::Tracking;
        if tracking {
            if let Some((_, travelled, distance)) = self.odometry.as_mut() {
                *travelled += output.delta_translation_world_m;
                *distance += output.delta_translation_world_m.norm();
            }
        } else {
            self.odometry = None;
        }
        let mut report = None;
        match self.filter.as_mut() {
            Some(filter) => {
                let q = Matrix3::identity()
                    * self.config.translation_sigma_per_sqrt_m.powi(2)
                    * output.delta_translation_world_m.norm();
                filter.predict(&output.delta_translation_world_m, &q);
                if tracking {
                    self.recognise_new(output, &rotation);
                    report = self.correct(output, &rotation);
                }
            }
            None if tracking && output.landmarks.len() >= 2 => {
                // The first frame with edges anchors the map. Its node is
                // the reference where there are frame nodes: the robot is
                // exactly where the relative stage says. Otherwise its first
                // landmark is, and the robot is as uncertain as that
                // landmark's measurement.
                let first = &output.landmarks[0];
                let position = output.T_world_body.translation.vector;
                self.anchor_frame = self.stats.frames;
                if matches!(self.config.policy, EdgePolicy::FrameNodes { .. }) {
                    self.anchor_world_m = Some(position);
                    self.filter = Some(PositionFilter::new(
                        position,
                        Matrix3::identity() * ANCHOR_FRAME_VARIANCE_M2,
                    ));
                } else {
                    self.anchor_world_m = Some(position + rotation * first.position_body_m);
                    self.filter = Some(PositionFilter::new(
                        position,
                        rotation * first.covariance_body_m2 * rotation.transpose(),
                    ));
                }
            }
            None => {}
        }
        if tracking && self.filter.is_some() {
            self.fuse(output, &rotation);
            self.note_in_view(output);
        }
        self.frames_since_solve += 1;
        if self.frames_since_solve >= self.config.solve_every_frames && self.edges.edge_count() > 0
        {
            self.frames_since_solve = 0;
            self.request_solve();
        }
        let (translation, covariance) = match &self.filter {
            Some(f) => (f.position_world_m(), Some(f.covariance_m2())),
            None => (output.T_world_body.translation.vector, None),
        };
        let elapsed = start.elapsed().as_secs_f64() * 1e3;
        self.stats.frames += 1;
        self.stats.frame_total_ms += elapsed;
        self.stats.frame_max_ms = self.stats.frame_max_ms.max(elapsed);
        CorrectedPose {
            t_ns: output.t_ns,
            T_world_body: Isometry3::from_parts(
                Translation3::from(translation),
                output.T_world_body.rotation,
            ),
            position_covariance_m2: covariance,
            landmarks_used: report
                .map_or(0, |r: super::position_filter::CorrectionReport| r.landmarks),
            map_version: self.map.as_ref().map_or(0, |m| m.version),
            nis: report.map_or(0.0, |r| r.nis),
        }
    }

    /// Waits for a running background solve and installs it (end of a run,
    /// tests). Returns immediately in the other modes.
    pub fn wait_for_solve(&mut self) {
        if let Some((result, deferred)) = self.solver.finished(true) {
            self.install(result);
            if deferred {
                self.request_solve();
            }
        }
    }

    /// Manual mode: the request waiting to be solved, if any.
    pub fn take_solve_request(&mut self) -> Option<MapSolveRequest> {
        self.solver.take_request()
    }

    /// Manual mode: installs a solved map (ignored if older than the one
    /// in use).
    pub fn install_solved_map(&mut self, result: Result<SolvedMap, EdgeMapError>) {
        self.install(result);
    }

    fn poll_background(&mut self) {
        if let Some((result, deferred)) = self.solver.finished(false) {
            self.install(result);
            if deferred {
                self.request_solve();
            }
        }
    }

    fn install(&mut self, result: Result<SolvedMap, EdgeMapError>) {
        match result {
            Ok(map) => {
                if self.map.as_ref().is_some_and(|m| m.version > map.version) {
                    return;
                }
                self.stats.solves += 1;
                self.stats.solve_total_ms += map.report.total_ms;
                self.stats.solve_assemble_ms += map.report.assemble_ms;
                self.stats.solve_symbolic_ms += map.report.symbolic_ms;
                self.stats.solve_factor_ms += map.report.factor_ms - map.report.symbolic_ms;
                self.stats.solve_covariance_ms += map.report.covariance_ms;
                self.stats.last_factor_nnz = map.report.factor_nnz;
                self.stats.last_unknowns = map.laplacian.dim();
                self.stats.last_downweighted_edges = map.report.downweighted_edges;
                self.stats.robust_solves += map.report.robust_iterations;
                match map.symbolic_path {
                    Some(SymbolicPath::Reused) => self.stats.symbolic_reused += 1,
                    Some(SymbolicPath::OrderingReused) => self.stats.ordering_reused += 1,
                    Some(SymbolicPath::Fresh) => self.stats.fresh_orderings += 1,
                    None => {}
                }
                if map.report.method == "pcg" {
                    self.stats.pcg_solves += 1;
                    self.stats.pcg_iterations += map.report.cg_iterations;
                    self.stats.pcg_cold_iterations += map.cold_cg_iterations.unwrap_or(0);
                }
                if let Some(anchor) = self.anchor_world_m {
                    let world = map
                        .positions_m
                        .iter()
                        .zip(&self.landmark_ids)
                        .map(|(p, &id)| p.filter(|_| id != FRAME_NODE).map(|p| anchor + p))
                        .collect();
                    self.index = LandmarkIndex::build(world, INDEX_CELL_M);
                }
                self.map = Some(map);
            }
            Err(e) => {
                self.stats.solve_errors += 1;
                tracing::warn!("map solve failed: {e}");
            }
        }
    }

    fn request_solve(&mut self) {
        if self.solver.defer_if_busy() {
            self.stats.deferred_solves += 1;
            return;
        }
        let version = self.next_version;
        self.next_version += 1;
        let previous_m = self
            .map
            .as_ref()
            .map(|m| m.positions_m.clone())
            .unwrap_or_default();
        let covariance_of = match self.config.covariance {
            LandmarkCovariance::Exact => self.in_view.clone(),
            LandmarkCovariance::SubMatrix { .. } => Vec::new(),
        };
        if let Some(result) =
            self.solver
                .submit(version, &mut self.edges, previous_m, covariance_of)
        {
            self.install(result);
        }
    }

    fn note_in_view(&mut self, output: &RelativeOutput) {
        let mut ranked: Vec<(f64, u32)> = output
            .landmarks
            .iter()
            .filter_map(|l| Some((l.covariance_body_m2.trace(), *self.map_ids.get(&l.id)?)))
            .collect();
        ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
        self.in_view.clear();
        for (_, id) in ranked {
            if !self.in_view.contains(&id) {
                self.in_view.push(id);
            }
            if self.in_view.len() >= IN_VIEW_FACTOR * self.config.max_correction_landmarks {
                break;
            }
        }
    }

    fn map_id(&mut self, id: LandmarkId, descriptor: Option<Descriptor>) -> u32 {
        let next = self.landmark_ids.len() as u32;
        let map_id = *self.map_ids.entry(id).or_insert(next);
        if map_id == next {
            self.landmark_ids.push(id);
            self.map_descriptors.push(descriptor);
        } else if let Some(slot @ None) = self.map_descriptors.get_mut(map_id as usize) {
            *slot = descriptor;
        }
        map_id
    }

    /// Gives the frame's new track ids the map id of the landmark they
    /// are, where one passes the recognition gates.
    fn recognise_new(&mut self, output: &RelativeOutput, rotation: &Matrix3<f64>) {
        let (Some(config), Some(filter)) = (self.config.recognition, self.filter.as_ref()) else {
            return;
        };
        if self.index.is_empty() {
            return;
        }
        let placement = FramePlacement {
            rotation: *rotation,
            position_m: filter.position_world_m(),
            position_covariance_m2: filter.covariance_m2(),
            landmark_covariance_scale: 1.0,
        };
        let found = recognise_tracks(
            &self.index,
            &self.map_descriptors,
            &output.landmarks,
            &placement,
            |track| self.map_ids.get(&track).copied(),
            &config,
            &mut self.candidates,
        );
        // A recognition must place the robot where the frame's landmarks
        // already in the map place it.
        let (found, inconsistent) = consistent_recognitions(
            &self.index,
            &output.landmarks,
            rotation,
            |track| self.map_ids.get(&track).copied(),
            found,
            &config,
            1.0,
        );
        self.stats.inconsistent_recognitions += inconsistent;
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
                self.stats.recognised += 1;
                self.map_ids.insert(track, map_id);
            } else if count < config.max_pending_frames {
                pending.insert(track, (map_id, count));
            }
        }
        // A pending track not recognised as the same landmark again, or
        // gone from view, is dropped (and becomes a new landmark in fuse).
        self.stats.unconfirmed_recognitions += self
            .pending
            .keys()
            .filter(|track| !pending.contains_key(track) && !self.map_ids.contains_key(track))
            .count();
        self.pending = pending;
    }

    /// Edges of one frame (eq. 41-43) with the configured weighting.
    fn fuse(&mut self, output: &RelativeOutput, rotation: &Matrix3<f64>) {
        if output.landmarks.len() < 2 {
            return;
        }
        // The first frame node is the map's reference, id 0 (its frame
        // always has a node: the first of every `every`).
        let anchor_node = matches!(self.config.policy, EdgePolicy::FrameNodes { .. })
            && self.landmark_ids.is_empty();
        if anchor_node {
            self.landmark_ids.push(FRAME_NODE);
            self.map_descriptors.push(None);
        }
        let pending = std::mem::take(&mut self.pending);
        let mut observations: Vec<LandmarkObservation> = output
            .landmarks
            .iter()
            .filter(|l| !pending.contains_key(&l.id))
            .map(|l| LandmarkObservation {
                id: self.map_id(l.id, l.descriptor),
                p_body_m: l.position_body_m,
                cov_body_m2: l.covariance_body_m2,
            })
            .collect();
        self.pending = pending;
        // Two live tracks recognised as one landmark: keep the first.
        let mut seen = std::collections::HashSet::with_capacity(observations.len());
        observations.retain(|o| seen.insert(o.id));
        if observations.len() < 2 {
            return;
        }
        if let EdgePolicy::FrameNodes { every } = self.config.policy {
            self.mapped_frames += 1;
            if (self.mapped_frames - 1) % every != 0 {
                // Still give the frame's landmarks their map ids: they
                // may correct later frames once another frame maps them.
                return;
            }
            let node = if anchor_node {
                0
            } else {
                self.landmark_ids.push(FRAME_NODE);
                self.map_descriptors.push(None);
                self.landmark_ids.len() as u32 - 1
            };
            self.edges.add_frame_node(rotation, node, &observations);
            if let Some((previous, travelled, distance)) =
                self.odometry.filter(|_| self.config.odometry_edges)
            {
                // The relative stage's own motion between the two nodes,
                // a random walk of `translation_sigma_per_sqrt_m`: what
                // the frames say about each other besides their landmarks.
                let variance = self.config.translation_sigma_per_sqrt_m.powi(2)
                    * distance.max(MIN_ODOMETRY_DISTANCE_M);
                let info = Matrix3::identity() / variance;
                self.edges
                    .add_measurement(previous, node, &travelled, &info);
            }
            self.odometry = Some((node, Vector3::zeros(), 0.0));
            return;
        }
        let positions: Vec<Vector3<f64>> = observations.iter().map(|o| o.p_body_m).collect();
        let pairs = self.config.policy.pairs(&positions);
        match self.config.weighting {
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

    /// The correction (eq. 63-71) with the visible landmarks of the map.
    fn correct(
        &mut self,
        output: &RelativeOutput,
        rotation: &Matrix3<f64>,
    ) -> Option<super::position_filter::CorrectionReport> {
        let map = self.map.as_ref()?;
        let anchor = self.anchor_world_m?;
        // Visible landmarks in the solved map, the most precise first.
        let mut visible: Vec<(f64, u32, usize)> = output
            .landmarks
            .iter()
            .enumerate()
            .filter_map(|(k, l)| {
                let id = *self.map_ids.get(&l.id)?;
                map.positions_m.get(id as usize)?.as_ref()?;
                Some((l.covariance_body_m2.trace(), id, k))
            })
            .collect();
        visible.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut seen = std::collections::HashSet::with_capacity(visible.len());
        visible.retain(|v| seen.insert(v.1));
        // Exact covariance comes from the blocks the solve computed for
        // the landmarks then in view.
        let cached = match (self.config.covariance, &map.covariance) {
            (LandmarkCovariance::Exact, Some(blocks)) => Some(blocks),
            _ => None,
        };
        if let Some(blocks) = cached {
            // Counted only where they cost the correction a landmark.
            let cap = self.config.max_correction_landmarks;
            let before = visible.len().min(cap);
            visible.retain(|v| blocks.slot.contains_key(&v.1));
            self.stats.uncached_landmarks += before - visible.len().min(cap);
        }
        visible.truncate(self.config.max_correction_landmarks);
        if visible.is_empty() {
            return None;
        }
        let fixes: Vec<LandmarkFix> = visible
            .iter()
            .map(|&(_, id, k)| {
                let l = &output.landmarks[k];
                LandmarkFix {
                    landmark: id,
                    landmark_world_m: anchor
                        + map.positions_m[id as usize].expect("filtered to solved landmarks"),
                    offset_world_m: rotation * l.position_body_m,
                    offset_covariance_m2: rotation * l.covariance_body_m2 * rotation.transpose(),
                }
            })
            .collect();
        let ids: Vec<u32> = visible.iter().map(|v| v.1).collect();
        let filter = self.filter.as_mut()?;
        // Blocks exist whenever the map has a Cholesky factor; a PCG-solved
        // map has neither, and falls back to the sub-matrix rule.
        let (covariance, cross) = match (self.config.covariance, cached) {
            (LandmarkCovariance::Exact, Some(blocks)) => {
                let c = blocks.select(&ids)?;
                (c, Some(cross_covariance(map, &ids, filter)))
            }
            (LandmarkCovariance::Exact, None) => (submatrix_blocks(map, &ids, 2), None),
            (LandmarkCovariance::SubMatrix { hops }, _) => {
                (submatrix_blocks(map, &ids, hops), None)
            }
        };
        match filter.correct(&fixes, &covariance, cross.as_ref()) {
            Ok(report) => {
                self.stats.corrections += 1;
                self.stats.nis_sum += report.nis;
                self.stats.nis_dof += 3 * report.landmarks;
                self.stats.mean_nis_per_dof = self.stats.nis_sum / self.stats.nis_dof.max(1) as f64;
                Some(report)
            }
            Err(e) => {
                tracing::warn!("position correction skipped: {e}");
                None
            }
        }
    }
}

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

/// Smallest eigenvalue kept in an edge's information, relative to its
/// largest: keeps fused edges positive definite (see [`positive_part`]).
const POSITIVE_PART_FLOOR: f64 = 1e-6;

/// The solve computes covariance blocks for this many times the landmarks
/// a correction uses, so that tracks lost in the frames after it leave
/// others to use.
const IN_VIEW_FACTOR: usize = 2;

/// `Σ_k G_k Σ_L(k, V)` (3 x 3m): the cross-covariance of the position
/// error with the map errors of `ids`, from a three-column solve with the
/// factor (`A^-1 G^T`), without the `Σ_L(V, V)` columns.
fn cross_covariance(map: &SolvedMap, ids: &[u32], filter: &PositionFilter) -> DMatrix<f64> {
    let factor = map.factor.as_ref().expect("called with a factor");
    let dim = map.laplacian.dim();
    let mut rhs = vec![0.0; dim * 3];
    for (&id, g) in filter.map_sensitivity() {
        if let Some(u) = map.unknown_of(id) {
            for c in 0..3 {
                for r in 0..3 {
                    rhs[c * dim + 3 * u + r] = g[(c, r)];
                }
            }
        }
    }
    if dim > 0 {
        factor.solve_in_place(&mut rhs, 3);
    }
    let unknowns: Vec<Option<usize>> = ids.iter().map(|&id| map.unknown_of(id)).collect();
    DMatrix::from_fn(3, 3 * ids.len(), |r, c| {
        unknowns[c / 3].map_or(0.0, |u| rhs[r * dim + 3 * u + c % 3])
    })
}

/// Shortest distance an odometry edge's variance is computed for, m (a
/// robot at rest still gets a finite information).
const MIN_ODOMETRY_DISTANCE_M: f64 = 0.01;

/// Variance of the robot's position at the anchoring frame node, m² (it
/// defines the map's origin; not zero, to keep the filter well posed).
const ANCHOR_FRAME_VARIANCE_M2: f64 = 1e-8;

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

/// The track id recorded for a frame node of [`EdgePolicy::FrameNodes`]
/// (no track has it).
const FRAME_NODE: LandmarkId = LandmarkId::MAX;

/// Grid cell of the recognition index, m.
const INDEX_CELL_M: f64 = 1.0;

/// A copy of `output` without what would poison the map or the filter:
/// landmarks with a non-finite position or a covariance that is not
/// positive definite; a non-finite increment becomes zero; a non-finite
/// pose makes the frame `Lost`. None when everything is usable.
fn sanitize(output: &RelativeOutput) -> Option<(RelativeOutput, usize)> {
    let usable = |l: &BodyLandmark| {
        l.position_body_m.iter().all(|v| v.is_finite())
            && l.covariance_body_m2.iter().all(|v| v.is_finite())
            && l.covariance_body_m2.cholesky().is_some()
    };
    let pose_ok = output
        .T_world_body
        .translation
        .vector
        .iter()
        .all(|v| v.is_finite())
        && output
            .T_world_body
            .rotation
            .coords
            .iter()
            .all(|v| v.is_finite());
    let delta_ok = output
        .delta_translation_world_m
        .iter()
        .all(|v| v.is_finite());
    let bad_landmarks = output.landmarks.iter().filter(|l| !usable(l)).count();
    if pose_ok && delta_ok && bad_landmarks == 0 {
        return None;
    }
    let mut clean = output.clone();
    clean.landmarks.retain(usable);
    if !delta_ok {
        clean.delta_translation_world_m = Vector3::zeros();
    }
    if !pose_ok {
        clean.state = TrackingState::Lost;
        clean.T_world_body = Isometry3::identity();
        clean.landmarks.clear();
    }
    Some((
        clean,
        bad_landmarks + usize::from(!delta_ok) + usize::from(!pose_ok),
    ))
}

/// The paper's sub-matrix covariance of `ids` (zero for the reference).
fn submatrix_blocks(map: &SolvedMap, ids: &[u32], hops: usize) -> DMatrix<f64> {
    let m = ids.len();
    let locals: Vec<Option<u32>> = ids
        .iter()
        .map(|&id| map.local_id[id as usize].filter(|&l| map.problem.unknown_of(l).is_some()))
        .collect();
    let present: Vec<u32> = locals.iter().flatten().copied().collect();
    let mut covariance = DMatrix::zeros(3 * m, 3 * m);
    if present.is_empty() {
        return covariance;
    }
    let sub = submatrix_covariance(&map.laplacian, &map.problem, &present, hops);
    let slots: Vec<usize> = (0..m).filter(|&k| locals[k].is_some()).collect();
    for (a, &ka) in slots.iter().enumerate() {
        for (b, &kb) in slots.iter().enumerate() {
            covariance
                .fixed_view_mut::<3, 3>(3 * ka, 3 * kb)
                .copy_from(&sub.fixed_view::<3, 3>(3 * a, 3 * b));
        }
    }
    covariance
}

#[cfg(test)]
mod tests;
