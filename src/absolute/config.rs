//! What the absolute stage is built with: which edges a frame gives the
//! map and how they are weighted, how often and where the map is solved,
//! and the position filter's noise and covariance choices. The settings
//! file's `[absolute]` table becomes one of these in [`super::settings`].

use super::map_worker::RobustWeights;
use super::recognition::RecognitionConfig;
use super::solve_schedule::SolveMode;
use crate::edge_map::policy::EdgePolicy;
use crate::edge_map::solve::SolverChoice;

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

/// Frame nodes a landmark is joined to before it counts as mapped. At the
/// default of a node every 5 frames at 20 Hz, a landmark in view for 5 s.
pub const DEFAULT_FRAME_NODE_SATURATION: usize = 20;

/// Passes of the robot on which a place takes frame nodes: the first maps
/// it, the next two join the landmarks recognition finds again to those it
/// does not (a corner seen from elsewhere); later passes are corrected
/// against the map and add nothing to it.
pub const DEFAULT_NODE_PASSES_PER_PLACE: usize = 3;

/// How fast the orientation offset may wander, rad per sqrt(s): chosen on
/// the development renderings (5e-5 to 2e-4 give two-stage means within
/// 4 % of each other, 5e-5 the lowest mean and the smallest excess over
/// the relative stage; docs/results/), confirmed on the held-apart ones.
pub const DEFAULT_ORIENTATION_SIGMA_RAD_PER_SQRT_S: f64 = 5e-5;

/// How fast the scale of the map over the relative stage's window may
/// wander, per sqrt(s): off. On the monocular accuracy sets 3e-3 found a
/// wander of about 1 % RMS and changed the ATE by about 1 % either way
/// (worse on the held-apart starts in flight), the map-frame NEES by
/// 5-20 % (docs/results/map-scale-2026-12-03.md).
pub const DEFAULT_SCALE_SIGMA_PER_SQRT_S: f64 = 0.0;

/// How much the relative stage's motion between two frame nodes is
/// trusted in the map, m per sqrt(m): its error over the few frames
/// between two nodes (a quarter of a second at 20 Hz) is millimetres,
/// while the position filter's prediction noise
/// ([`AbsoluteConfig::translation_sigma_per_sqrt_m`], 0.02) stands for
/// everything the filter does not know over a whole run. Weighed at
/// that, the map's frame nodes followed their landmarks' window
/// estimates rather than the motion between them. Chosen on the
/// development renderings, confirmed on the held-apart ones
/// (docs/results/).
pub const DEFAULT_ODOMETRY_SIGMA_PER_SQRT_M: f64 = 0.003;

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
    /// Those edges' noise: `sigma^2 * |Δ| * I` over the way `Δ` between
    /// the two nodes, sigma in m per sqrt(m).
    pub odometry_sigma_per_sqrt_m: f64,
    /// Give a frame node's edge to a landmark only the share of the
    /// landmark's window estimate that is new since the landmark's last
    /// node ([`crate::relative::types::WindowSupport`]): the window's
    /// keyframes observing it that the last node's estimate did not rest
    /// on, over all that this one rests on ([`EdgePolicy::FrameNodes`]
    /// only). Without it, nodes between two keyframes hand the map the
    /// same estimate again, counted as new each time. The same rule sets
    /// the published position covariance: the filter's gain takes each
    /// frame's estimate as new, the covariance it publishes follows how
    /// much of each landmark's estimate repeats since its last correction
    /// ([`super::position_filter`]).
    pub count_window_once: bool,
    /// A landmark joined to this many frame nodes counts as mapped, and a
    /// frame whose landmarks are mostly mapped adds no node
    /// ([`EdgePolicy::FrameNodes`] only; 0: every frame adds one). A robot
    /// that keeps revisiting the same room then stops growing its map:
    /// its frames are still corrected against the map, they only stop
    /// adding measurements of what it already knows well.
    pub frame_node_saturation: usize,
    /// A place (a cube of [`super::node_places::PLACE_SIZE_M`] and a
    /// viewing direction) takes frame nodes on at most this many passes
    /// of the robot; later passes add none there
    /// ([`EdgePolicy::FrameNodes`] only; 0: no limit). Bounds the map when
    /// recognition misses landmarks seen again, which the saturation above
    /// cannot see.
    pub node_passes_per_place: usize,
    /// Correct the orientation too: the relative stage's orientation,
    /// turned by an offset the map's landmarks estimate, which wanders by
    /// this much, rad per sqrt(s) (0: the paper's filter, the orientation
    /// as the relative stage gives it).
    pub orientation_sigma_rad_per_sqrt_s: f64,
    /// Estimate the scale of the map over the relative stage's window
    /// with the position ([`super::position_filter`]), a random walk of
    /// this much per sqrt(s) (0: the window's lengths taken as the
    /// map's, the paper's filter).
    pub scale_sigma_per_sqrt_s: f64,
    /// Leave a landmark out of a position correction when its own
    /// innovation exceeds this chi-square (3 dof), as the localiser does;
    /// None: every landmark in view corrects. None here; the `[absolute]`
    /// settings turn it on in stereo-inertial (`correction_gate`).
    pub correction_gate_chi2: Option<f64>,
    /// Add to the published position covariance the error the relative
    /// stage's attitude puts in the robot's position: the landmarks were
    /// mapped through the attitude of their frames, the robot sees them
    /// through that of now (`mapping_attitude`; nothing where the
    /// relative stage gives no pose covariance).
    pub mapping_attitude_covariance: bool,
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
            odometry_sigma_per_sqrt_m: DEFAULT_ODOMETRY_SIGMA_PER_SQRT_M,
            count_window_once: true,
            frame_node_saturation: DEFAULT_FRAME_NODE_SATURATION,
            node_passes_per_place: DEFAULT_NODE_PASSES_PER_PLACE,
            orientation_sigma_rad_per_sqrt_s: DEFAULT_ORIENTATION_SIGMA_RAD_PER_SQRT_S,
            scale_sigma_per_sqrt_s: DEFAULT_SCALE_SIGMA_PER_SQRT_S,
            correction_gate_chi2: None,
            mapping_attitude_covariance: true,
        }
    }
}
