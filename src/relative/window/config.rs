//! The window's settings and its errors.

use super::camera_imu::CameraImuRefinementConfig;
use super::landmark_consistency::LandmarkTest;
use super::noise_adaptation::NoiseAdaptationConfig;
use super::reprojection::RobustKernel;

/// Settings of the window (defaults in brackets).
#[derive(Debug, Clone, PartialEq)]
pub struct WindowConfig {
    /// L: keyframes kept \[10\].
    pub keyframes_kept: usize,
    /// M: newest keyframes optimised \[7\]; the oldest L-M are held fixed.
    pub keyframes_free: usize,
    /// Standard deviation of a pixel measurement [1.0].
    pub pixel_sigma: f64,
    /// Loss applied to each whitened reprojection error \[Huber\].
    pub robust_kernel: RobustKernel,
    /// Kernel threshold in pixels [1.5].
    pub huber_px: f64,
    /// Squared whitened error above which an observation is flagged an
    /// outlier after an optimisation [5.991, chi-square 2 DoF at 95%].
    pub outlier_chi2: f64,
    /// A landmark whose inlier observations together fail a chi-square
    /// test in the pixel noise the features show is taken out with its
    /// track ([`LandmarkTest`]); None: no such test.
    pub landmark_test: Option<LandmarkTest>,
    /// LM iterations per optimisation \[10\].
    pub max_iterations: usize,
    /// Inertial terms on [false]; see [`super::Window::enable_imu`].
    pub use_imu: bool,
    /// Smallest ray angle to triangulate from two keyframes [1 deg].
    pub min_parallax_deg: f64,
    /// Smallest ray angle to triangulate from a stereo pair [0.25 deg].
    pub stereo_min_parallax_deg: f64,
    /// Depth range of a new landmark in either camera, window units [0.05, 200].
    pub min_depth_m: f64,
    /// Largest depth of a new landmark in either camera, window units.
    pub max_depth_m: f64,
    /// Largest reprojection error of a new landmark in the two views it
    /// is triangulated from, px [5.0].
    pub init_max_error_px: f64,
    /// Gravity prior before any solve, rad [0.02].
    pub gravity_prior_sigma_rad: f64,
    /// Prior on the oldest free keyframe when no marginal is known yet:
    /// velocity m/s [0.5], gyro bias rad/s [0.01], accel bias m/s^2 [0.2].
    pub velocity_prior_sigma_m_s: f64,
    /// Prior sigma of the gyro bias, rad/s.
    pub gyro_bias_prior_sigma_rad_s: f64,
    /// Prior sigma of the accel bias, m/s^2.
    pub accel_bias_prior_sigma_m_s2: f64,
    /// Share of the previous solve's marginal information kept as the
    /// prior on the boundary keyframe's velocity and biases [0.5].
    pub prior_weight: f64,
    /// Carry the boundary prior forward by marginalising the departing
    /// inertial link (the private `marginalise` module) [true]; false: `prior_weight` times
    /// the last solve's marginal, the paper's reading of eq. 34.
    pub marginalise_boundary: bool,
    /// Factor on the new boundary's pose covariance in that
    /// marginalisation \[4\]. The pose's marginal already holds the departing
    /// link's information, and the visual errors of neighbouring keyframes
    /// are correlated: taken at face value (1) the prior grows
    /// overconfident (errors of 2-3 sigma on the YEI rendering) and locks
    /// in the error the biases had when the chain started (the
    /// mono-inertial sliding test then drifts 0.046 m over 7 m; 0.035 at
    /// 2, 0.026 at 4).
    pub boundary_pose_covariance_scale: f64,
    /// Memory of that prior, s \[10\]: its information is multiplied by
    /// `exp(-dt / memory)` per link, so what the biases were thought to be
    /// when the chain started (an in-flight initialisation's gyro bias is
    /// 1-3 mrad/s off) fades instead of holding them there; `inf` keeps
    /// everything. Measured on the real-IMU renderings, seeds 0-5 (mean
    /// ATE stereo-inertial / mono-inertial): inf 0.021 / 0.048 m, 15 s
    /// 0.022 / 0.047, 10 s 0.020 / 0.045, 5 s 0.020 / 0.047; the in-flight
    /// start 0.039 / 0.063, 0.030 / 0.053, 0.026 / 0.048, 0.017 / 0.039.
    pub boundary_prior_memory_s: f64,
    /// The same for gravity [0.5]: the marginal counts measurements still
    /// in the window, so the information converges to `w / (1 - w)`
    /// windows' worth. Gravity is a constant of the run, but an early
    /// tilt locked in by that sum stays in every later pose. Development
    /// set, seeds 0-5 from rest (stereo-inertial / mono-inertial mean
    /// ATE): 0.3: 0.0222 / 0.0459 m, 0.5: 0.0211 / 0.0408, 0.7: 0.0209 /
    /// 0.0440 (bench/accuracy/README.md).
    pub gravity_prior_weight: f64,
    /// Carry the published covariance with the measurements consecutive
    /// solves share ([`super::propagated_covariance`]) and the gravity
    /// prior's sensitivity read from the prior the solve weighed \[true\].
    /// Off, the sensitivity is read from the next, tighter prior, which
    /// inflates the carried gravity covariance about as much as counting
    /// shared measurements as new shrinks it.
    pub covariance_shared_measurements: bool,
    /// The pixel sigma the published covariance of an inertial mode is
    /// computed with, on the declared `pixel_sigma`: `max(gain *
    /// estimate, floor)`, the estimate being the noise adaptation's pixel
    /// scale \[gain 1, floor 0.5\] ([`super::Window::covariance_pixel_scale`]).
    pub covariance_pixel_gain: f64,
    /// See `covariance_pixel_gain`.
    pub covariance_pixel_floor: f64,
    /// Inliers for [`super::Window::track_frame`] to call a pose good \[12\].
    pub min_track_inliers: usize,
    /// LM iterations of [`super::Window::track_frame`] \[8\].
    pub track_max_iterations: usize,
    /// The IMU's noise as the window weighs it: a scale on the declared
    /// densities, estimated online from the inertial residuals
    /// ([`super::noise_adaptation`]).
    pub noise_adaptation: NoiseAdaptationConfig,
    /// Camera 0's pose in the body and the frames' time offset, refined
    /// in the inertial solves from the calibration file ([`super::camera_imu`]).
    pub camera_imu: CameraImuRefinementConfig,
}

impl Default for WindowConfig {
    fn default() -> Self {
        Self {
            keyframes_kept: 10,
            keyframes_free: 7,
            pixel_sigma: 1.0,
            robust_kernel: RobustKernel::Huber,
            huber_px: 1.5,
            outlier_chi2: 5.991,
            landmark_test: Some(LandmarkTest::default()),
            max_iterations: 10,
            use_imu: false,
            min_parallax_deg: 1.0,
            stereo_min_parallax_deg: 0.25,
            min_depth_m: 0.05,
            max_depth_m: 200.0,
            init_max_error_px: 5.0,
            gravity_prior_sigma_rad: 0.02,
            velocity_prior_sigma_m_s: 0.5,
            gyro_bias_prior_sigma_rad_s: 0.01,
            accel_bias_prior_sigma_m_s2: 0.2,
            prior_weight: 0.5,
            marginalise_boundary: true,
            boundary_pose_covariance_scale: 4.0,
            boundary_prior_memory_s: 10.0,
            gravity_prior_weight: 0.5,
            covariance_shared_measurements: true,
            covariance_pixel_gain: 1.0,
            covariance_pixel_floor: 0.5,
            min_track_inliers: 12,
            track_max_iterations: 8,
            noise_adaptation: NoiseAdaptationConfig::default(),
            camera_imu: CameraImuRefinementConfig::default(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
/// Why the window could not be built or could not take an input.
pub enum WindowError {
    #[error("window config `{key}` = {value}: {allowed}")]
    /// A setting is out of range.
    InvalidConfig {
        /// The setting's key.
        key: &'static str,
        /// Its value, as written.
        value: String,
        /// The allowed range.
        allowed: &'static str,
    },
    #[error("IMU noise adaptation: {0}")]
    /// The IMU noise adaptation settings are invalid (the message says which).
    InvalidNoiseAdaptation(String),
    #[error("landmark test: {0}")]
    /// The landmark test's settings are invalid (the message says which).
    InvalidLandmarkTest(String),
    #[error("camera-IMU refinement: {0}")]
    /// The camera-IMU refinement settings are invalid (the message says which).
    InvalidCameraImu(String),
    #[error("the rig has no camera")]
    /// The rig has no camera.
    NoCamera,
    #[error("use_imu is set but the rig has no IMU")]
    /// `use_imu` is set but the rig has no IMU.
    NoImu,
    #[error("keyframe state at {t_ns} ns is not finite")]
    /// A keyframe's initial guess has a NaN or infinite value.
    NonFiniteState {
        /// The keyframe's stamp, ns.
        t_ns: i64,
    },
    #[error("keyframe at {t_ns} ns does not come after the latest one at {latest_ns} ns")]
    /// A keyframe is not after the latest one.
    NotIncreasing {
        /// The new keyframe's stamp, ns.
        t_ns: i64,
        /// The latest keyframe's stamp, ns.
        latest_ns: i64,
    },
    #[error(
        "preintegrated IMU spans {start_ns}..{end_ns} ns, expected {expected_start_ns}..{expected_end_ns} ns"
    )]
    /// A keyframe's preintegrated IMU interval does not run from the latest keyframe to it (or has
    /// no positive length).
    ImuIntervalMismatch {
        /// Start of the preintegrated interval, ns.
        start_ns: i64,
        /// End of the preintegrated interval, ns.
        end_ns: i64,
        /// The latest keyframe's stamp, ns.
        expected_start_ns: i64,
        /// The new keyframe's stamp, ns.
        expected_end_ns: i64,
    },
    #[error("{what}: got {got} values for {expected} keyframes")]
    /// A list given for the keyframes has the wrong length.
    LengthMismatch {
        /// What the list is (e.g. `states`).
        what: &'static str,
        /// Values given.
        got: usize,
        /// Keyframes in the window.
        expected: usize,
    },
    #[error("{what} is not finite or out of range")]
    /// A value given is not finite or out of range.
    InvalidValue {
        /// Which value.
        what: &'static str,
    },
}

impl WindowConfig {
    pub(super) fn validate(&self) -> Result<(), WindowError> {
        let bad = |key: &'static str, value: String, allowed: &'static str| {
            Err(WindowError::InvalidConfig {
                key,
                value,
                allowed,
            })
        };
        if self.keyframes_kept < 2 {
            return bad(
                "keyframes_kept",
                self.keyframes_kept.to_string(),
                "at least 2",
            );
        }
        if self.keyframes_free == 0 || self.keyframes_free >= self.keyframes_kept {
            return bad(
                "keyframes_free",
                self.keyframes_free.to_string(),
                "between 1 and keyframes_kept - 1",
            );
        }
        let positive = [
            ("pixel_sigma", self.pixel_sigma),
            ("huber_px", self.huber_px),
            ("min_parallax_deg", self.min_parallax_deg),
            ("stereo_min_parallax_deg", self.stereo_min_parallax_deg),
            ("min_depth_m", self.min_depth_m),
            ("max_depth_m", self.max_depth_m),
            ("init_max_error_px", self.init_max_error_px),
            ("gravity_prior_sigma_rad", self.gravity_prior_sigma_rad),
            ("velocity_prior_sigma_m_s", self.velocity_prior_sigma_m_s),
            (
                "gyro_bias_prior_sigma_rad_s",
                self.gyro_bias_prior_sigma_rad_s,
            ),
            (
                "accel_bias_prior_sigma_m_s2",
                self.accel_bias_prior_sigma_m_s2,
            ),
            ("prior_weight", self.prior_weight),
            ("gravity_prior_weight", self.gravity_prior_weight),
            (
                "boundary_pose_covariance_scale",
                self.boundary_pose_covariance_scale,
            ),
            ("covariance_pixel_gain", self.covariance_pixel_gain),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return bad(key, v.to_string(), "a finite number > 0");
            }
        }
        if !(self.covariance_pixel_floor.is_finite() && self.covariance_pixel_floor >= 0.0) {
            return bad(
                "covariance_pixel_floor",
                self.covariance_pixel_floor.to_string(),
                "a finite number >= 0",
            );
        }
        if self.boundary_prior_memory_s.is_nan() || self.boundary_prior_memory_s <= 0.0 {
            return bad(
                "boundary_prior_memory_s",
                self.boundary_prior_memory_s.to_string(),
                "a number > 0 (inf: no forgetting)",
            );
        }
        // Infinity switches the outlier flagging off.
        if self.outlier_chi2.is_nan() || self.outlier_chi2 <= 0.0 {
            return bad(
                "outlier_chi2",
                self.outlier_chi2.to_string(),
                "a number > 0 (inf: no flagging)",
            );
        }
        if let Some(Err(message)) = self.landmark_test.map(|t| t.validate()) {
            return Err(WindowError::InvalidLandmarkTest(message));
        }
        if let Err(message) = self.noise_adaptation.validate() {
            return Err(WindowError::InvalidNoiseAdaptation(message));
        }
        if let Err(message) = self.camera_imu.validate() {
            return Err(WindowError::InvalidCameraImu(message));
        }
        if self.max_depth_m <= self.min_depth_m {
            return bad(
                "max_depth_m",
                self.max_depth_m.to_string(),
                "above min_depth_m",
            );
        }
        Ok(())
    }
}
