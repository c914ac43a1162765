//! Simulated relative-stage outputs for the absolute stage: a robot drives
//! laps of an oval path inside a room whose walls carry landmarks, and each
//! frame hands over what the relative stage would: its
//! dead-reckoned pose (orientation exact unless it is made to drift,
//! position integrated from noisy increments), the noisy increment
//! itself, and the visible landmarks in the body frame with stereo-like
//! covariances, their noise drawn from those covariances. Ground truth
//! comes along, so the absolute stage's consistency (NEES) can be checked.

use std::collections::HashMap;

use nalgebra::{Isometry3, Matrix3, Matrix6, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::features::orb::Descriptor;
use crate::imu::ImuBiases;
use crate::relative::types::{
    BodyLandmark, LandmarkId, PoseCovariance, RelativeOutput, TrackingState, WindowSupport,
};

/// Parameters of a simulated run.
#[derive(Clone, Debug)]
pub struct RoomRunOptions {
    /// Room extent (x, y), m; landmarks on its four walls, 0-3 m high.
    pub room_m: (f64, f64),
    /// Landmarks placed on the walls.
    pub landmarks: usize,
    /// Laps of the oval path (semi-axes 35% of the room).
    pub laps: f64,
    /// Distance between frames, m.
    pub step_m: f64,
    /// Landmarks within this range and the field of view are seen.
    pub range_m: f64,
    /// Half of the horizontal field of view, rad.
    pub half_fov_rad: f64,
    /// At most this many (nearest) landmarks per frame.
    pub max_visible: usize,
    /// Transverse standard deviation per metre of depth.
    pub sigma_transverse_per_m: f64,
    /// Depth standard deviation per squared metre of depth.
    pub sigma_depth_per_m2: f64,
    /// Increment noise: standard deviation per sqrt(metre) travelled, per
    /// axis (a random walk, Q = sigma^2 * distance * I).
    pub sigma_translation_per_sqrt_m: f64,
    /// Give every landmark the isotropic covariance of its depth error
    /// instead of the stereo-like ellipsoid.
    pub isotropic_landmarks: bool,
    /// A landmark that leaves the view gets a new track id when it comes
    /// back, as a KLT tracker gives it (false: its index for the whole run).
    pub fresh_track_ids: bool,
    /// Give each track a descriptor: the landmark's own 256 bits with this
    /// many flipped at the track's birth (None: no descriptors).
    pub descriptor_bit_flips: Option<u32>,
    /// Share of tracks born without a descriptor (too near the image
    /// border for one), so recognition can never find them again.
    pub undescribed_share: f64,
    /// Systematic odometry drift, world frame, m per m travelled: added
    /// to every increment in proportion to its length, so (unlike a scale
    /// error on a closed path) it accumulates lap after lap.
    pub drift_per_m: Vector3<f64>,
    /// Systematic orientation drift, rad per m travelled (a rotation
    /// vector, world frame): the relative stage's world frame turns away
    /// from the true one by `Exp(rate · distance)`, and its orientation
    /// and increments with it, as a gyroscope's uncorrected bias turns a
    /// visual-inertial odometry's heading.
    pub rotation_drift_rad_per_m: Vector3<f64>,
    /// A random walk of the relative stage's heading (about the vertical),
    /// rad per sqrt(m) travelled, on top of `rotation_drift_rad_per_m`;
    /// when positive each frame also hands on the pose covariance a
    /// relative stage would publish for it: heading variance
    /// `walk² · distance`, exact roll and pitch, and position `sigma² ·
    /// distance · I` from the increments' noise alone (what the heading
    /// adds to the position is left out).
    pub heading_walk_rad_per_sqrt_m: f64,
    /// The room (landmarks and their appearance) comes from `seed`; the
    /// noise of the drive from this seed when given, so that two drives
    /// through the same room differ (a map made in one, localised in by
    /// the other).
    pub noise_seed: Option<u64>,
    /// Seed of the room (landmark positions and descriptors), and of the drive unless `noise_seed`
    /// is given.
    pub seed: u64,
    /// Body-frame landmark estimates as a sliding window hands them on
    /// (None: each frame's error drawn anew).
    pub window: Option<SimulatedWindow>,
    /// The relative stage's lengths (increments and landmark offsets) are
    /// the truth's over `1 + σ`, with `σ = amplitude · sin(2π d /
    /// period_m)` at `d` metres travelled: a monocular window's wandering
    /// scale. (0, _): none.
    pub scale_wander: (f64, f64),
}

/// A sliding window's landmark estimates: a keyframe every
/// `frames_per_keyframe` frames draws a new error for each landmark in
/// view, and a landmark's estimate carries the mean of its last
/// `keyframes` draws (scaled to the covariance it is given), with its
/// [`crate::relative::types::WindowSupport`]. Frames between two
/// keyframes hand on the same estimate.
#[derive(Clone, Copy, Debug)]
pub struct SimulatedWindow {
    /// Frames per keyframe.
    pub frames_per_keyframe: usize,
    /// Keyframes a window keeps.
    pub keyframes: usize,
}

impl Default for RoomRunOptions {
    fn default() -> Self {
        Self {
            room_m: (16.0, 10.0),
            landmarks: 200,
            laps: 2.0,
            step_m: 0.3,
            range_m: 8.0,
            half_fov_rad: 60f64.to_radians(),
            max_visible: 20,
            sigma_transverse_per_m: 0.003,
            sigma_depth_per_m2: 0.004,
            sigma_translation_per_sqrt_m: 0.02,
            isotropic_landmarks: false,
            fresh_track_ids: false,
            descriptor_bit_flips: None,
            undescribed_share: 0.0,
            drift_per_m: Vector3::zeros(),
            rotation_drift_rad_per_m: Vector3::zeros(),
            heading_walk_rad_per_sqrt_m: 0.0,
            noise_seed: None,
            seed: 0,
            window: None,
            scale_wander: (0.0, 1.0),
        }
    }
}

/// A simulated run with its ground truth.
pub struct RoomRun {
    /// What the relative stage would have output per frame (drifting odometry, tracks re-identified
    /// on re-entering the view).
    pub outputs: Vec<RelativeOutput>,
    /// True body position per frame, world frame, m.
    pub truth_position_m: Vec<Vector3<f64>>,
    /// True body orientation per frame, world frame.
    pub truth_orientation: Vec<UnitQuaternion<f64>>,
    /// True landmark positions by index, world frame, m.
    pub landmarks_m: Vec<Vector3<f64>>,
    /// The landmark index each track id belongs to.
    pub track_landmark: HashMap<LandmarkId, usize>,
}

impl RoomRun {
    /// True world position of the absolute stage's map reference: the
    /// landmark a track belongs to, or the robot in a frame.
    pub fn reference_truth_m(&self, reference: super::MapReference) -> Option<Vector3<f64>> {
        match reference {
            super::MapReference::Landmark(track) => {
                Some(self.landmarks_m[*self.track_landmark.get(&track)?])
            }
            super::MapReference::Frame { index } => self.truth_position_m.get(index).copied(),
        }
    }
}

fn normal3(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    Vector3::from_fn(|_, _| StandardNormal.sample(rng))
}

/// Orthonormal frame whose first column is the unit ray.
fn ray_frame(ray: &Vector3<f64>) -> Matrix3<f64> {
    let helper = if ray.z.abs() < 0.9 {
        Vector3::z()
    } else {
        Vector3::x()
    };
    let u = ray.cross(&helper).normalize();
    let v = ray.cross(&u);
    Matrix3::from_columns(&[*ray, u, v])
}

/// Runs the simulated drive.
pub fn simulate_room_run(options: &RoomRunOptions) -> RoomRun {
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let (w, h) = options.room_m;
    let perimeter = 2.0 * (w + h);
    let landmarks_m: Vec<Vector3<f64>> = (0..options.landmarks)
        .map(|_| {
            let s = rng.gen_range(0.0..perimeter);
            let z = rng.gen_range(0.0..3.0);
            if s < w {
                Vector3::new(s, 0.0, z)
            } else if s < w + h {
                Vector3::new(w, s - w, z)
            } else if s < 2.0 * w + h {
                Vector3::new(2.0 * w + h - s, h, z)
            } else {
                Vector3::new(0.0, perimeter - s, z)
            }
        })
        .collect();
    // Appearance draws from its own generator, so that the noise of runs
    // without descriptors is what it always was.
    let mut looks = ChaCha8Rng::seed_from_u64(options.seed ^ 0x6c6f_6f6b_7321);
    let appearance: Vec<Descriptor> = (0..options.landmarks)
        .map(|_| [0; 4].map(|_| looks.gen::<u64>()))
        .collect();
    if let Some(noise_seed) = options.noise_seed {
        rng = ChaCha8Rng::seed_from_u64(noise_seed);
        looks = ChaCha8Rng::seed_from_u64(noise_seed ^ 0x6c6f_6f6b_7321);
    }
    let mut live_tracks: HashMap<usize, (LandmarkId, Option<Descriptor>)> = HashMap::new();
    let mut track_landmark = HashMap::new();
    let mut next_track: LandmarkId = 0;
    let centre = Vector3::new(w / 2.0, h / 2.0, 1.2);
    let (a, b) = (0.35 * w, 0.35 * h);
    // Arc length per radian is at least min(a, b): step the angle so that
    // consecutive frames are about step_m apart.
    let mut angle: f64 = 0.0;
    let end_angle = options.laps * std::f64::consts::TAU;
    let position_at = |t: f64| centre + Vector3::new(a * t.cos(), b * t.sin(), 0.0);
    let mut outputs = Vec::new();
    let mut truth_position_m = Vec::new();
    let mut truth_orientation = Vec::new();
    let mut travelled_m = 0.0;
    let mut previous_truth: Option<Vector3<f64>> = None;
    let mut relative_position = position_at(0.0);
    let mut t_ns = 0i64;
    // Per landmark in view: its keyframes' standard-normal draws, oldest
    // first (window runs only).
    let mut window_draws: HashMap<usize, std::collections::VecDeque<Vector3<f64>>> = HashMap::new();
    let mut keyframe: u64 = 0;
    // The heading's random walk draws from its own generator, so that
    // runs without it are what they always were.
    let mut walk_rng =
        ChaCha8Rng::seed_from_u64(options.noise_seed.unwrap_or(options.seed) ^ 0x6865_6164_696e_67);
    let mut heading_rad = 0.0;
    let walking = options.heading_walk_rad_per_sqrt_m > 0.0;
    while angle <= end_angle {
        let frame_index = outputs.len();
        let p = position_at(angle);
        let tangent = Vector3::new(-a * angle.sin(), b * angle.cos(), 0.0);
        let yaw = tangent.y.atan2(tangent.x);
        let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw);
        let r = *rotation.matrix();
        let delta = match previous_truth {
            None => Vector3::zeros(),
            Some(prev) => {
                let true_delta: Vector3<f64> = p - prev;
                let sigma = options.sigma_translation_per_sqrt_m * true_delta.norm().sqrt();
                travelled_m += true_delta.norm();
                if walking {
                    let step: f64 = StandardNormal.sample(&mut walk_rng);
                    heading_rad +=
                        step * options.heading_walk_rad_per_sqrt_m * true_delta.norm().sqrt();
                }
                true_delta + options.drift_per_m * true_delta.norm() + normal3(&mut rng) * sigma
            }
        };
        // The relative stage's world frame, turned by its drift so far.
        let turned = (options.rotation_drift_rad_per_m != Vector3::zeros() || walking).then(|| {
            UnitQuaternion::from_scaled_axis(options.rotation_drift_rad_per_m * travelled_m)
                * UnitQuaternion::from_scaled_axis(Vector3::z() * heading_rad)
        });
        let pose_covariance = walking.then(|| {
            let mut matrix = Matrix6::zeros();
            matrix
                .fixed_view_mut::<3, 3>(0, 0)
                .fill_diagonal(options.sigma_translation_per_sqrt_m.powi(2) * travelled_m);
            matrix[(5, 5)] = options.heading_walk_rad_per_sqrt_m.powi(2) * travelled_m;
            PoseCovariance {
                matrix,
                origin_t_ns: 0,
                T_world_origin: Translation3::from(position_at(0.0)).into(),
            }
        });
        let (amplitude, period_m) = options.scale_wander;
        let window_scale =
            1.0 + amplitude * (std::f64::consts::TAU * travelled_m / period_m.max(1e-9)).sin();
        let delta = turned.map_or(delta, |d| d * delta) / window_scale;
        relative_position += delta;
        let mut candidates: Vec<(f64, usize)> = landmarks_m
            .iter()
            .enumerate()
            .filter_map(|(id, l)| {
                let body = r.transpose() * (l - p);
                let depth = body.norm();
                let bearing = body.y.atan2(body.x).abs();
                (depth <= options.range_m && body.x > 0.5 && bearing <= options.half_fov_rad)
                    .then_some((depth, id))
            })
            .collect();
        candidates.sort_by(|x, y| x.0.total_cmp(&y.0));
        candidates.truncate(options.max_visible);
        candidates.sort_by_key(|c| c.1);
        let mut tracks = HashMap::with_capacity(candidates.len());
        for &(_, index) in &candidates {
            let track = live_tracks.get(&index).copied().unwrap_or_else(|| {
                let id = if options.fresh_track_ids {
                    next_track += 1;
                    next_track - 1
                } else {
                    index as LandmarkId
                };
                let described = options.undescribed_share <= 0.0
                    || looks.gen::<f64>() >= options.undescribed_share;
                let descriptor = options
                    .descriptor_bit_flips
                    .filter(|_| described)
                    .map(|flips| {
                        let mut d = appearance[index];
                        for _ in 0..flips {
                            let bit = looks.gen_range(0..256usize);
                            d[bit / 64] ^= 1 << (bit % 64);
                        }
                        d
                    });
                (id, descriptor)
            });
            track_landmark.insert(track.0, index);
            tracks.insert(index, track);
        }
        live_tracks = tracks;
        if let Some(window) = options.window {
            let new_keyframe = frame_index % window.frames_per_keyframe.max(1) == 0;
            if new_keyframe && frame_index > 0 {
                keyframe += 1;
            }
            window_draws.retain(|index, _| live_tracks.contains_key(index));
            for &(_, index) in &candidates {
                let draws = window_draws.entry(index).or_default();
                if new_keyframe || draws.is_empty() {
                    draws.push_back(normal3(&mut rng));
                    if draws.len() > window.keyframes.max(1) {
                        draws.pop_front();
                    }
                }
            }
        }
        let landmarks = candidates
            .iter()
            .map(|&(depth, id)| {
                let body = r.transpose() * (landmarks_m[id] - p);
                let frame = ray_frame(&(body / depth));
                let sigma_t = options.sigma_transverse_per_m * depth;
                let sigma_d = options.sigma_depth_per_m2 * depth * depth;
                let sigmas = if options.isotropic_landmarks {
                    Vector3::repeat(sigma_d.max(sigma_t))
                } else {
                    Vector3::new(sigma_d, sigma_t, sigma_t)
                };
                let covariance = frame
                    * Matrix3::from_diagonal(&sigmas.component_mul(&sigmas))
                    * frame.transpose();
                let (draw, support) = match window_draws.get(&id) {
                    Some(draws) => {
                        let n = draws.len() as f64;
                        let support = WindowSupport {
                            keyframes: draws.len() as u16,
                            newest_keyframe: keyframe,
                        };
                        (draws.iter().sum::<Vector3<f64>>() / n.sqrt(), Some(support))
                    }
                    None => (normal3(&mut rng), None),
                };
                let noise = frame * draw.component_mul(&sigmas);
                let (track, descriptor) = live_tracks[&id];
                BodyLandmark {
                    id: track,
                    position_body_m: body / window_scale + noise,
                    covariance_body_m2: covariance,
                    descriptor,
                    support,
                }
            })
            .collect();
        outputs.push(RelativeOutput {
            t_ns,
            state: TrackingState::Tracking,
            T_world_body: Isometry3::from_parts(
                Translation3::from(relative_position),
                turned.map_or(UnitQuaternion::from_rotation_matrix(&rotation), |d| {
                    d * UnitQuaternion::from_rotation_matrix(&rotation)
                }),
            ),
            velocity_world_m_s: Vector3::zeros(),
            biases: ImuBiases::default(),
            delta_translation_world_m: delta,
            landmarks,
            pose_covariance,
        });
        truth_position_m.push(p);
        truth_orientation.push(UnitQuaternion::from_rotation_matrix(&rotation));
        previous_truth = Some(p);
        t_ns += 50_000_000;
        let speed = tangent.norm().max(1e-9);
        angle += options.step_m / speed;
    }
    RoomRun {
        outputs,
        truth_position_m,
        truth_orientation,
        landmarks_m,
        track_landmark,
    }
}
