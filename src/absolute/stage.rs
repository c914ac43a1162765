//! The absolute stage (paper eq. 41-71): consumes the relative stage's
//! [`RelativeOutput`] frame by frame, fuses its edges into the edge map
//! (by default a frame node joined to the frame's landmarks every 5
//! tracking frames, [`EdgePolicy::FrameNodes`]; or the paper's landmark
//! pairs), solves the map every K frames off the frame-rate path, and
//! corrects the robot position with the robot position Kalman filter.
//!
//! The map grows by one 3-vector unknown per frame node as well as per
//! landmark: in a bounded room with recognition the landmarks stop
//! growing, and a frame whose landmarks are mostly joined to
//! `frame_node_saturation` nodes already adds no node of its own (it is
//! still corrected against the map), so the frame nodes stop growing too.
//! Where recognition misses landmarks seen again, a place (a cube of the
//! position and a viewing direction) that took nodes on
//! `node_passes_per_place` passes takes no more (`node_places`).
//!
//! Per frame ([`AbsoluteStage::push`]):
//! 1. install a map solve that has finished, if any;
//! 2. predict the position with the relative stage's increment (eq. 60-62),
//!    turned into the map's frame by the orientation offset;
//! 3. correct the orientation offset ([`super::orientation_filter`]), then
//!    the position (eq. 63-71), with the visible landmarks of the last
//!    solved map and their joint covariance from the map's factor (exact)
//!    or the paper's sub-matrix rule;
//! 4. fuse the frame's edges (eq. 41-43) *after* the correction, so that a
//!    frame's landmark noise is never in the map it is corrected against;
//! 5. every `solve_every_frames` frames, hand a snapshot of the edges to
//!    the map solve ([`SolveMode`]).
//!
//! The returned pose takes its orientation from the relative stage turned
//! by the offset filter's estimate (the paper's filter leaves it as the
//! relative stage gives it, which `orientation_sigma_rad_per_sqrt_s = 0`
//! restores) and its position from the position filter. The map's frame is
//! the relative stage's world frame at the anchor: the map is anchored at
//! the first frame node, where the relative stage put the robot in that
//! frame ([`EdgePolicy::FrameNodes`]), or, with
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
//!
//! [`EdgePolicy::FrameNodes`]: crate::edge_map::policy::EdgePolicy::FrameNodes

use std::time::Instant;

use nalgebra::{DMatrix, Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

pub use super::config::{AbsoluteConfig, EdgeWeighting, LandmarkCovariance};
pub use super::map_builder::MapReference;
pub use super::solve_schedule::SolveMode;

use super::map_builder::MapBuilder;
use super::map_cross_covariance::MapCrossCovariance;
use super::map_worker::{MapSolveRequest, MapSolveWorker, SolvedMap};
use super::mapping_attitude::MappingAttitude;
use super::orientation_filter::{OrientationFilter, OrientationUpdate};
use super::position_filter::{LandmarkFix, PositionFilter};
use super::recogniser::Recogniser;
use super::recognition::FramePlacement;
use super::solve_schedule::MapSolver;
use super::window_share::WindowShares;
use crate::edge_map::covariance::submatrix_covariance;
use crate::edge_map::ordering_reuse::SymbolicPath;
use crate::edge_map::EdgeMapError;
use crate::relative::types::{BodyLandmark, LandmarkId, RelativeOutput, TrackingState};

/// The stage's answer for one frame.
#[allow(non_snake_case)]
#[derive(Clone, Debug, PartialEq)]
pub struct CorrectedPose {
    /// Frame stamp, ns.
    pub t_ns: i64,
    /// Position from the position filter, orientation from the relative
    /// stage turned by the orientation offset.
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
    /// Pipelined mode on live frames ([`AbsoluteStage::never_wait_for_solves`]):
    /// solves not done by the frame due to install them, installed on a
    /// later frame instead of being waited for.
    pub late_solves: usize,
    /// Pipelined mode: time frames spent waiting for the solve they
    /// install (zero while solves take less than K frames), total and
    /// longest, ms.
    pub solve_wait_ms: f64,
    /// Longest of those waits, ms.
    pub solve_wait_max_ms: f64,
    /// Time spent in map solves in all, ms.
    pub solve_total_ms: f64,
    /// CPU time of the solving thread in map solves, ms: below
    /// `solve_total_ms` by the time the solve waited for its core.
    pub solve_cpu_ms: f64,
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
    /// Robust reweighting (weights and refill of A; not the
    /// factorisations), ms.
    pub solve_reweight_ms: f64,
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
    /// Landmarks left out of a position correction by the innovation gate
    /// ([`AbsoluteConfig::correction_gate_chi2`]).
    pub gated_out: usize,
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
    /// Frame nodes in the map ([`crate::edge_map::policy::EdgePolicy::FrameNodes`]).
    pub frame_nodes: usize,
    /// Frames whose turn it was to become a frame node, left out because
    /// their landmarks were mapped already
    /// ([`AbsoluteConfig::frame_node_saturation`]).
    pub frames_saturated: usize,
    /// Frames whose turn it was to become a frame node, left out because
    /// their place took nodes on enough passes already
    /// ([`AbsoluteConfig::node_passes_per_place`]).
    pub frames_place_full: usize,
    /// Places holding frame nodes.
    pub node_places: usize,
    /// Map ids handed out: one per landmark (with frame nodes, once a node
    /// joins it; recognised tracks share theirs) and one per frame node.
    pub map_ids: usize,
    /// Track ids that have a map id (a landmark's first track, and the
    /// tracks recognised as it).
    pub tracks_known: usize,
    /// Frames whose orientation offset the landmarks corrected.
    pub orientation_corrections: usize,
    /// Orientation corrections refused as too large for one frame
    /// ([`super::orientation_filter::MAX_ORIENTATION_STEP_RAD`]).
    pub orientation_refused: usize,
    /// The orientation offset at the last frame, degrees: how far the map
    /// has turned the relative stage's orientation.
    pub orientation_offset_deg: f64,
    /// Mean normalised innovation squared per degree of freedom of the
    /// corrections: about 1 when the covariances the filter is given are
    /// right, far above when they are overconfident.
    pub mean_nis_per_dof: f64,
    /// The map's lengths over the relative stage's at the last frame,
    /// less one, percent ([`AbsoluteConfig::scale_sigma_per_sqrt_s`]; 0
    /// when it is not estimated).
    pub map_scale_percent: f64,
    /// Its root mean square over the frames corrected, percent: how much
    /// the relative stage's scale wanders against the map's.
    pub map_scale_rms_percent: f64,
    #[serde(skip)]
    scale_sum_sq: f64,
    #[serde(skip)]
    nis_sum: f64,
    #[serde(skip)]
    nis_dof: usize,
}

impl AbsoluteStats {
    /// Adds an installed solve's counters and timings.
    fn count_solve(&mut self, map: &SolvedMap) {
        self.solves += 1;
        self.solve_total_ms += map.report.total_ms;
        self.solve_cpu_ms += map.report.cpu_ms;
        self.solve_assemble_ms += map.report.assemble_ms;
        self.solve_symbolic_ms += map.report.symbolic_ms;
        self.solve_factor_ms += map.report.factor_ms - map.report.symbolic_ms;
        self.solve_covariance_ms += map.report.covariance_ms;
        self.solve_reweight_ms += map.report.reweight_ms;
        self.last_factor_nnz = map.report.factor_nnz;
        self.last_unknowns = map.laplacian.dim();
        self.last_downweighted_edges = map.report.downweighted_edges;
        self.robust_solves += map.report.robust_iterations;
        match map.symbolic_path {
            Some(SymbolicPath::Reused) => self.symbolic_reused += 1,
            Some(SymbolicPath::OrderingReused) => self.ordering_reused += 1,
            Some(SymbolicPath::Fresh) => self.fresh_orderings += 1,
            None => {}
        }
        if map.report.method == "pcg" {
            self.pcg_solves += 1;
            self.pcg_iterations += map.report.cg_iterations;
            self.pcg_cold_iterations += map.cold_cg_iterations.unwrap_or(0);
        }
    }
}

/// The absolute stage: a thin owner of its parts. The map being built
/// (`MapBuilder`: edges, ids, anchor), the recognition of landmarks seen
/// before (`Recogniser`), the map solve (`MapSolver`, one state per
/// [`SolveMode`]) with the last solved map, and the position filter.
pub struct AbsoluteStage {
    config: AbsoluteConfig,
    builder: MapBuilder,
    /// None when recognition is off.
    recogniser: Option<Recogniser>,
    filter: Option<PositionFilter>,
    /// The relative stage's position covariance at the anchoring frame,
    /// m²: the filter's covariance is the robot's against the map's
    /// anchor, and the anchor itself is where the relative stage had
    /// drifted to by then, so the published map-frame covariance adds it
    /// (zero for a map anchored at the relative stage's origin).
    anchor_covariance_m2: Matrix3<f64>,
    /// The relative stage's attitude steps and where they were taken,
    /// as they stood when each map landmark was mapped
    /// ([`super::mapping_attitude`]).
    mapping_attitude: MappingAttitude,
    /// What those attitudes add to the position corrected against the
    /// last correction's landmarks, m² (zero when
    /// [`AbsoluteConfig::mapping_attitude_covariance`] is off).
    attitude_covariance_m2: Matrix3<f64>,
    /// None when the orientation is taken as the relative stage gives it.
    orientation: Option<OrientationFilter>,
    map: Option<SolvedMap>,
    /// The filter's cross-covariance with the errors of `map`'s
    /// covariance-block landmarks, followed from correction to correction.
    map_cross: Option<MapCrossCovariance>,
    /// Per map id: how much of its window estimate is new since its last
    /// correction (the published covariance counts repeated estimates).
    correction_shares: WindowShares,
    /// Where the map is solved, with what is in flight.
    solver: MapSolver,
    frames_since_solve: usize,
    /// Pipelined mode: whether the frame due to install a solve waits
    /// for it (false on live frames).
    wait_for_due_solves: bool,
    /// A solve missed the frame due to install it: installed as soon as
    /// it is done.
    solve_late: bool,
    next_version: u64,
    /// Map ids in view in the last tracking frame, the most precise
    /// first: the covariance blocks the next solve computes.
    in_view: Vec<u32>,
    /// The last frame's stamp (the scale's random walk), ns.
    last_t_ns: Option<i64>,
    stats: AbsoluteStats,
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
        Self {
            builder: MapBuilder::new(&config, solver.needs_edge_changes()),
            recogniser: config.recognition.map(Recogniser::new),
            orientation: (config.orientation_sigma_rad_per_sqrt_s > 0.0)
                .then(|| OrientationFilter::new(config.orientation_sigma_rad_per_sqrt_s)),
            config,
            filter: None,
            anchor_covariance_m2: Matrix3::zeros(),
            mapping_attitude: MappingAttitude::default(),
            attitude_covariance_m2: Matrix3::zeros(),
            map: None,
            map_cross: None,
            correction_shares: WindowShares::default(),
            solver,
            frames_since_solve: 0,
            wait_for_due_solves: true,
            solve_late: false,
            next_version: 1,
            in_view: Vec::new(),
            last_t_ns: None,
            stats: AbsoluteStats::default(),
        }
    }

    /// Live frames (a camera, a replay at its recorded pace): in
    /// [`SolveMode::Pipelined`] the frame due to install a solve no longer
    /// waits for it when it is late; it is installed on the first frame
    /// after it is done ([`AbsoluteStats::late_solves`]), and the solve
    /// that frame asked for starts then. A frame never waits for the map
    /// thread, which runs below the frame path's priority: on one busy
    /// core, waiting for it would hold the frame for as long as the
    /// solve's whole run. While solves keep their schedule the maps are
    /// the ones a repeatable run installs. The other modes are unchanged.
    pub fn never_wait_for_solves(&mut self) {
        self.wait_for_due_solves = false;
    }

    /// A pipelined stage whose every solve waits for a token on the
    /// returned channel before it starts (tests).
    #[cfg(test)]
    pub(crate) fn with_gated_solves(config: AbsoluteConfig) -> (Self, std::sync::mpsc::Sender<()>) {
        let config = AbsoluteConfig {
            solve_mode: SolveMode::Pipelined,
            ..config
        };
        let mut stage = Self::new(config);
        let (solver, gate) = MapSolver::gated(stage.config.solver, stage.config.robust);
        stage.solver = solver;
        (stage, gate)
    }

    /// The inline worker (Inline mode only), e.g. to measure CG cold starts.
    pub fn worker_mut(&mut self) -> Option<&mut MapSolveWorker> {
        self.solver.inline_worker()
    }

    /// The pose of a frame the stage has not taken yet (see
    /// [`crate::slam_pipeline::SlamPipeline::push_frame`]): the filter's
    /// position moved by the frame's relative motion and the orientation
    /// turned by the current offset, as `push` would before any
    /// correction; the stage itself is unchanged.
    pub fn carry(&self, output: &RelativeOutput) -> CorrectedPose {
        let offset = self.orientation_offset();
        let delta = offset * output.delta_translation_world_m;
        let delta = if delta.iter().all(|v| v.is_finite()) {
            delta
        } else {
            Vector3::zeros()
        };
        let (translation, covariance) = match &self.filter {
            Some(f) => {
                let q = Matrix3::identity()
                    * self.config.translation_sigma_per_sqrt_m.powi(2)
                    * delta.norm();
                (
                    f.position_world_m() + delta,
                    Some(self.map_frame_covariance_m2(f) + q),
                )
            }
            None => (output.T_world_body.translation.vector, None),
        };
        CorrectedPose {
            t_ns: output.t_ns,
            T_world_body: Isometry3::from_parts(
                Translation3::from(translation),
                offset * output.T_world_body.rotation,
            ),
            position_covariance_m2: covariance,
            landmarks_used: 0,
            map_version: self.map.as_ref().map_or(0, |m| m.version),
            nis: 0.0,
        }
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
        self.builder.reference()
    }

    /// Track ids recognised as a landmark already in the map: (the track
    /// id, the id the landmark entered the map with). Every one made
    /// since [`AbsoluteStage::keep_alias_log`]; without it only those of
    /// tracks still in view lately (a long run forgets ended tracks).
    pub fn aliases(&self) -> Vec<(LandmarkId, LandmarkId)> {
        self.builder.registry().aliases()
    }

    /// Logs every recognition from now on for [`AbsoluteStage::aliases`]
    /// (a run that checks them against the ground truth at its end; the
    /// log grows with every recognition).
    pub fn keep_alias_log(&mut self) {
        self.builder.registry_mut().keep_alias_log();
    }

    /// Solves the map with every edge fused so far (waiting for a running
    /// solve first) and returns its landmarks for saving: world position,
    /// covariance given the neighbours (inverse of the landmark's diagonal
    /// block of A, see [`super::map_file`]) and descriptor. None before any
    /// edge, and in [`SolveMode::Manual`] without a solved map.
    pub fn finish_map(&mut self) -> Option<super::map_file::SavedMap> {
        self.wait_for_solve();
        if self.frames_since_solve > 0 && self.builder.edge_count() > 0 {
            self.frames_since_solve = 0;
            self.request_solve();
            self.wait_for_solve();
        }
        self.solved_map()
    }

    /// The landmarks of the last solved map for saving, as
    /// [`Self::finish_map`] gives them but without solving again (so
    /// without the edges fused since that solve). None before a solve.
    pub fn solved_map(&self) -> Option<super::map_file::SavedMap> {
        let mut landmarks = self.builder.saved_landmarks(self.map.as_ref()?)?;
        if let Some(anchor) = self.builder.anchor_world_m() {
            // Each landmark keeps the attitude sums of its mapping frame,
            // about its own position.
            for l in &mut landmarks {
                l.attitude = self
                    .mapping_attitude
                    .mapped_moments(l.id)
                    .map(|m| m.about(&(l.position_m - anchor)));
            }
        }
        Some(super::map_file::SavedMap { landmarks })
    }

    /// The track id a map landmark was first seen under.
    pub fn landmark_track(&self, map_id: u32) -> Option<LandmarkId> {
        self.builder.registry().first_track(map_id)
    }

    /// The last solved map, if any.
    pub fn map(&self) -> Option<&SolvedMap> {
        self.map.as_ref()
    }

    /// World position of a landmark in the last solved map.
    pub fn landmark_world_m(&self, id: LandmarkId) -> Option<Vector3<f64>> {
        let map_id = self.builder.registry().map_id_of(id)?;
        let relative = (*self.map.as_ref()?.positions_m.get(map_id as usize)?)?;
        Some(self.builder.anchor_world_m()? + relative)
    }

    /// Processes one frame of the relative stage; returns the corrected pose.
    pub fn push(&mut self, output: &RelativeOutput) -> CorrectedPose {
        let start = Instant::now();
        self.install_due_solve();
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
        let offset = self.orientation_offset();
        let mut rotation = *(offset * output.T_world_body.rotation)
            .to_rotation_matrix()
            .matrix();
        let delta_world_m = offset * output.delta_translation_world_m;
        let tracking = output.state == TrackingState::Tracking;
        self.builder.note_motion(tracking, &delta_world_m);
        let mut report = None;
        match self.filter.as_mut() {
            Some(filter) => {
                let q = Matrix3::identity()
                    * self.config.translation_sigma_per_sqrt_m.powi(2)
                    * delta_world_m.norm();
                filter.predict(&delta_world_m, &q);
                if let Some(last) = self.last_t_ns {
                    let dt = output.t_ns.saturating_sub(last).max(0) as f64 * 1e-9;
                    filter.predict_scale(self.config.scale_sigma_per_sqrt_s.powi(2) * dt);
                }
                if let Some(orientation) = self.orientation.as_mut() {
                    orientation.predict(output.t_ns);
                }
                if tracking {
                    self.recognise_new(output, &rotation);
                    report = self.correct(output, &mut rotation);
                }
            }
            None if tracking && output.landmarks.len() >= 2 => self.anchor(output, &rotation),
            None => {}
        }
        self.last_t_ns = Some(output.t_ns);
        if let Some(filter) = self.filter.as_ref().filter(|_| tracking) {
            let recogniser = self.recogniser.as_ref();
            let position_m = filter.position_world_m();
            self.builder.fuse(output, &rotation, &position_m, |track| {
                recogniser.is_some_and(|r| r.is_pending(track))
            });
            self.note_mapping_attitude(output, &position_m);
            self.note_in_view(output);
            self.stats.frame_nodes = self.builder.frame_nodes();
            self.stats.frames_saturated = self.builder.frames_saturated();
            self.stats.frames_place_full = self.builder.frames_place_full();
            self.stats.node_places = self.builder.node_places();
            self.stats.map_ids = self.builder.registry().map_ids();
            self.stats.tracks_known = self.builder.registry().tracks();
        }
        self.frames_since_solve += 1;
        if self.frames_since_solve >= self.config.solve_every_frames
            && self.builder.edge_count() > 0
        {
            self.frames_since_solve = 0;
            self.request_solve();
        }
        let (translation, covariance) = match &self.filter {
            Some(f) => (f.position_world_m(), Some(self.map_frame_covariance_m2(f))),
            None => (output.T_world_body.translation.vector, None),
        };
        let offset = self.orientation_offset();
        let orientation = offset * output.T_world_body.rotation;
        self.stats.orientation_offset_deg = offset.angle().to_degrees();
        tracing::trace!(
            frame = self.stats.frames,
            landmarks = report.as_ref().map_or(0, |r| r.landmarks),
            nis = report.as_ref().map_or(0.0, |r| r.nis),
            correction_m = (translation - output.T_world_body.translation.vector).norm(),
            "corrected"
        );
        let elapsed = start.elapsed().as_secs_f64() * 1e3;
        self.stats.frames += 1;
        self.stats.frame_total_ms += elapsed;
        self.stats.frame_max_ms = self.stats.frame_max_ms.max(elapsed);
        CorrectedPose {
            t_ns: output.t_ns,
            T_world_body: Isometry3::from_parts(Translation3::from(translation), orientation),
            position_covariance_m2: covariance,
            landmarks_used: report.as_ref().map_or(0, |r| r.landmarks),
            map_version: self.map.as_ref().map_or(0, |m| m.version),
            nis: report.as_ref().map_or(0.0, |r| r.nis),
        }
    }

    /// The published position covariance, m²: the filter's (the robot
    /// against the map's anchor), the anchor's own, and what the mapping
    /// frames' attitude errors put in the landmarks it was corrected
    /// against.
    fn map_frame_covariance_m2(&self, filter: &PositionFilter) -> Matrix3<f64> {
        filter.published_covariance_m2() + self.anchor_covariance_m2 + self.attitude_covariance_m2
    }

    /// `R_o`: turns the relative stage's world frame into the map's
    /// (identity when the orientation is not corrected).
    pub fn orientation_offset(&self) -> UnitQuaternion<f64> {
        self.orientation
            .as_ref()
            .map_or(UnitQuaternion::identity(), OrientationFilter::offset)
    }

    /// Step 1 of a frame: picks up a finished background solve, or, in
    /// pipelined mode on the frame that requests the next solve, waits
    /// for the one in flight (on live frames: installs it if it is done,
    /// else on the first frame after it is).
    fn install_due_solve(&mut self) {
        match self.config.solve_mode {
            SolveMode::Background => {
                self.poll_background();
            }
            SolveMode::Pipelined if self.solve_late => {
                // Installing it may start the solve deferred meanwhile:
                // that one keeps the schedule.
                if self.poll_background() {
                    self.solve_late = false;
                }
            }
            SolveMode::Pipelined
                if self.frames_since_solve + 1 >= self.config.solve_every_frames =>
            {
                if !self.solver.in_flight() {
                    // Nothing to install.
                } else if !self.wait_for_due_solves {
                    if !self.poll_background() {
                        self.stats.late_solves += 1;
                        self.solve_late = true;
                    }
                } else {
                    let wait = Instant::now();
                    self.wait_for_solve();
                    let waited = wait.elapsed().as_secs_f64() * 1e3;
                    self.stats.solve_wait_ms += waited;
                    self.stats.solve_wait_max_ms = self.stats.solve_wait_max_ms.max(waited);
                }
            }
            _ => {}
        }
    }

    /// The first frame with edges anchors the map and starts the filter.
    /// Its node is the reference where there are frame nodes: the robot
    /// is exactly where the relative stage says. Otherwise its first
    /// landmark is, and the robot is as uncertain as that landmark's
    /// measurement.
    fn anchor(&mut self, output: &RelativeOutput, rotation: &Matrix3<f64>) {
        self.map_cross = None;
        self.anchor_covariance_m2 = output
            .pose_covariance
            .map(|c| c.matrix.fixed_view::<3, 3>(0, 0).into_owned())
            .filter(|c| c.iter().all(|v| v.is_finite()))
            .unwrap_or_else(Matrix3::zeros);
        let first = &output.landmarks[0];
        let position = output.T_world_body.translation.vector;
        if self.builder.has_frame_nodes() {
            self.builder.set_anchor(position, self.stats.frames);
            self.filter = Some(PositionFilter::new(
                position,
                Matrix3::identity() * ANCHOR_FRAME_VARIANCE_M2,
            ));
        } else {
            self.builder.set_anchor(
                position + rotation * first.position_body_m,
                self.stats.frames,
            );
            self.filter = Some(PositionFilter::new(
                position,
                rotation * first.covariance_body_m2 * rotation.transpose(),
            ));
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

    /// Installs a finished threaded solve, if one is; whether it did.
    fn poll_background(&mut self) -> bool {
        let Some((result, deferred)) = self.solver.finished(false) else {
            return false;
        };
        self.install(result);
        if deferred {
            self.request_solve();
        }
        true
    }

    fn install(&mut self, result: Result<SolvedMap, EdgeMapError>) {
        match result {
            Ok(map) => {
                if self.map.as_ref().is_some_and(|m| m.version > map.version) {
                    return;
                }
                self.stats.count_solve(&map);
                if tracing::enabled!(tracing::Level::TRACE) {
                    if let Some(old) = self.map.as_ref() {
                        let moved: Vec<f64> = self
                            .in_view
                            .iter()
                            .filter_map(|&id| {
                                let a = old.positions_m.get(id as usize).copied().flatten()?;
                                let b = map.positions_m.get(id as usize).copied().flatten()?;
                                Some((b - a).norm())
                            })
                            .collect();
                        let mean = moved.iter().sum::<f64>() / moved.len().max(1) as f64;
                        let max = moved.iter().copied().fold(0.0, f64::max);
                        tracing::trace!(
                            frame = self.stats.frames,
                            version = map.version,
                            in_view = moved.len(),
                            mean_moved_mm = mean * 1e3,
                            max_moved_mm = max * 1e3,
                            "map installed"
                        );
                    }
                }
                if let (Some(recogniser), Some(world)) = (
                    self.recogniser.as_mut(),
                    self.builder.landmark_world_positions(&map),
                ) {
                    recogniser.set_map(world);
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
                .submit(version, self.builder.edges_mut(), previous_m, covariance_of)
        {
            self.install(result);
        }
    }

    /// Takes the frame's attitude covariance into the mapping attitude's
    /// sums and notes the landmarks it mapped first (see
    /// [`super::mapping_attitude`]).
    fn note_mapping_attitude(&mut self, output: &RelativeOutput, position_m: &Vector3<f64>) {
        if !self.config.mapping_attitude_covariance {
            return;
        }
        let (Some(pose), Some(anchor)) = (
            output.pose_covariance.as_ref(),
            self.builder.anchor_world_m(),
        ) else {
            return;
        };
        let robot = position_m - anchor;
        self.mapping_attitude.advance(
            &pose.matrix.fixed_view::<3, 3>(3, 3).into_owned(),
            pose.origin_t_ns,
            &robot,
        );
        let registry = self.builder.registry();
        for l in &output.landmarks {
            if let Some(id) = registry.map_id_of(l.id) {
                self.mapping_attitude.note_mapped(id);
            }
        }
    }

    fn note_in_view(&mut self, output: &RelativeOutput) {
        let registry = self.builder.registry();
        // The budget counts every track the map knows, those no frame
        // node joined yet (no map id, so no block to ask for) included:
        // the blocks go to the most precise of the frame's known tracks
        // that are mapped.
        let mut ranked: Vec<(f64, Option<u32>)> = output
            .landmarks
            .iter()
            .filter(|l| registry.contains(l.id))
            .map(|l| (l.covariance_body_m2.trace(), registry.map_id_of(l.id)))
            .collect();
        ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
        self.in_view.clear();
        let mut unmapped = 0;
        for (_, id) in ranked {
            match id {
                Some(id) if !self.in_view.contains(&id) => self.in_view.push(id),
                Some(_) => {}
                None => unmapped += 1,
            }
            if self.in_view.len() + unmapped
                >= IN_VIEW_FACTOR * self.config.max_correction_landmarks
            {
                break;
            }
        }
    }

    /// Gives the frame's new track ids the map id of the landmark they
    /// are, where one passes the recognition gates.
    fn recognise_new(&mut self, output: &RelativeOutput, rotation: &Matrix3<f64>) {
        let (Some(recogniser), Some(filter)) = (self.recogniser.as_mut(), self.filter.as_ref())
        else {
            return;
        };
        let placement = FramePlacement {
            rotation: *rotation,
            position_m: filter.position_world_m(),
            position_covariance_m2: filter.covariance_m2(),
            landmark_covariance_scale: 1.0,
        };
        let counts = recogniser.recognise(output, &placement, self.builder.registry_mut());
        self.stats.recognised += counts.recognised;
        self.stats.inconsistent_recognitions += counts.inconsistent;
        self.stats.unconfirmed_recognitions += counts.unconfirmed;
    }

    /// The correction with the visible landmarks of the map: the
    /// orientation offset first (`rotation`, the frame's world-from-body
    /// rotation, is turned with it), then the position (eq. 63-71).
    fn correct(
        &mut self,
        output: &RelativeOutput,
        rotation: &mut Matrix3<f64>,
    ) -> Option<super::position_filter::CorrectionReport> {
        let map = self.map.as_ref()?;
        let anchor = self.builder.anchor_world_m()?;
        let registry = self.builder.registry();
        // Visible landmarks in the solved map, the most precise first.
        let mut visible: Vec<(f64, u32, usize)> = output
            .landmarks
            .iter()
            .enumerate()
            .filter_map(|(k, l)| {
                let id = registry.map_id_of(l.id)?;
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
        let mut supports: Vec<_> = visible
            .iter()
            .map(|&(_, _, k)| output.landmarks[k].support)
            .collect();
        let mut fixes: Vec<LandmarkFix> = visible
            .iter()
            .map(|&(_, id, k)| {
                let l = &output.landmarks[k];
                let offset_new_share = if self.config.count_window_once {
                    self.correction_shares.share(id, l.support)
                } else {
                    1.0
                };
                LandmarkFix {
                    landmark: id,
                    landmark_world_m: anchor
                        + map.positions_m[id as usize].expect("filtered to solved landmarks"),
                    offset_world_m: *rotation * l.position_body_m,
                    offset_covariance_m2: *rotation * l.covariance_body_m2 * rotation.transpose(),
                    offset_new_share,
                }
            })
            .collect();
        let mut ids: Vec<u32> = visible.iter().map(|v| v.1).collect();
        let filter = self.filter.as_mut()?;
        // Blocks exist whenever the map has a Cholesky factor; a PCG-solved
        // map has neither, and falls back to the sub-matrix rule.
        let (mut covariance, mut cross) = match (self.config.covariance, cached) {
            (LandmarkCovariance::Exact, Some(blocks)) => {
                let c = blocks.select(&ids)?;
                // Solved once per map, then followed (module docs of
                // `map_cross_covariance`).
                let kept = self.map_cross.take().filter(|k| k.is_for(map));
                let kept = kept.unwrap_or_else(|| MapCrossCovariance::solve(map, blocks, filter));
                let cross = kept.select(blocks, &ids)?;
                self.map_cross = Some(kept);
                (c, Some(cross))
            }
            (LandmarkCovariance::Exact, None) => (submatrix_blocks(map, &ids, 2), None),
            (LandmarkCovariance::SubMatrix { hops }, _) => {
                (submatrix_blocks(map, &ids, hops), None)
            }
        };
        // With the gate on, a landmark the map, the relative stage and the
        // filter disagree on (a wrong association, a landmark the last
        // solve moved by decimetres) is left out, as the localiser does:
        // on the accuracy sets one such landmark among thirty often
        // carried most of the correction's NIS.
        let kept: Option<Vec<usize>> = self.config.correction_gate_chi2.map(|gate| {
            let nis = filter.landmark_nis(&fixes, &covariance, cross.as_ref());
            (0..fixes.len()).filter(|&k| nis[k] <= gate).collect()
        });
        if let Some(kept) = kept.filter(|kept| kept.len() < fixes.len()) {
            self.stats.gated_out += fixes.len() - kept.len();
            if kept.is_empty() {
                return None;
            }
            fixes = kept.iter().map(|&k| fixes[k]).collect();
            ids = kept.iter().map(|&k| ids[k]).collect();
            supports = kept.iter().map(|&k| supports[k]).collect();
            covariance = DMatrix::from_fn(3 * kept.len(), 3 * kept.len(), |r, c| {
                covariance[(3 * kept[r / 3] + r % 3, 3 * kept[c / 3] + c % 3)]
            });
            cross = cross.map(|x| {
                DMatrix::from_fn(x.nrows(), 3 * kept.len(), |r, c| {
                    x[(r, 3 * kept[c / 3] + c % 3)]
                })
            });
        }
        if let Some(orientation) = self.orientation.as_mut() {
            let position = filter.position_world_m();
            match orientation.correct_with(&mut fixes, &covariance, &position) {
                OrientationUpdate::Applied(step) => {
                    let turn = *UnitQuaternion::from_scaled_axis(step)
                        .to_rotation_matrix()
                        .matrix();
                    *rotation = turn * *rotation;
                    self.stats.orientation_corrections += 1;
                }
                OrientationUpdate::TooLarge(_) => self.stats.orientation_refused += 1,
                OrientationUpdate::TooFewLandmarks | OrientationUpdate::Singular => {}
            }
        }
        match filter.correct(&fixes, &covariance, cross.as_ref()) {
            Ok(report) => {
                if let (Some(kept), Some(blocks)) = (self.map_cross.as_mut(), cached) {
                    if kept
                        .follow(blocks, &ids, &report.keep, &report.gain)
                        .is_none()
                    {
                        self.map_cross = None;
                    }
                }
                for (&id, &support) in ids.iter().zip(&supports) {
                    self.correction_shares.note_used(id, support);
                }
                if self.config.mapping_attitude_covariance {
                    let landmarks = ids
                        .iter()
                        .zip(&fixes)
                        .map(|(&id, fix)| (id, fix.offset_world_m));
                    self.attitude_covariance_m2 = self
                        .mapping_attitude
                        .position_covariance_m2(landmarks, &(filter.position_world_m() - anchor));
                }
                self.stats.corrections += 1;
                self.stats.nis_sum += report.nis;
                self.stats.nis_dof += 3 * report.landmarks;
                self.stats.mean_nis_per_dof = self.stats.nis_sum / self.stats.nis_dof.max(1) as f64;
                let scale_percent = 100.0 * filter.scale();
                self.stats.map_scale_percent = scale_percent;
                self.stats.scale_sum_sq += scale_percent * scale_percent;
                self.stats.map_scale_rms_percent =
                    (self.stats.scale_sum_sq / self.stats.corrections as f64).sqrt();
                Some(report)
            }
            Err(e) => {
                tracing::warn!("position correction skipped: {e}");
                None
            }
        }
    }
}

/// The solve computes covariance blocks for this many times the landmarks
/// a correction uses, so that tracks lost in the frames after it leave
/// others to use.
const IN_VIEW_FACTOR: usize = 2;

/// Variance of the robot's position at the anchoring frame node, m² (it
/// defines the map's origin; not zero, to keep the filter well posed).
const ANCHOR_FRAME_VARIANCE_M2: f64 = 1e-8;

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
