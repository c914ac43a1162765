//! Static start: is the rig at rest, and if so, where is "up" and what is
//! the gyroscope bias.
//!
//! At rest the gyroscope reads its bias and the accelerometer reads the
//! reaction to gravity, `R_world_body^T (0, 0, g)`, plus the accelerometer
//! bias. So over a window at rest the mean gyro is the bias, the mean
//! accelerometer points "up" in the body frame, and the velocity is zero.
//!
//! Telling rest from motion. A real rig at rest is rarely quiet: on EuRoC
//! the MAV sits on the ground with its rotors running, and the samples
//! jitter by 0.01-0.08 rad/s and 0.2-1 m/s^2, as much as in flight. That
//! vibration is fast, motion is slow. The window is therefore cut into
//! short blocks (0.1 s), each block averaged, and the spread of the block
//! means about the window mean is tested, for both sensors:
//!
//! - threshold = max(`white_noise_sigmas` x the spread that the sensor's
//!   white noise alone gives a block mean, `sigma_c sqrt(3 / block_s)`
//!   for the norm over three axes, the `vibration` allowance).
//!   For the ADIS16448 the white-noise term is 2.7e-3 rad/s and
//!   0.032 m/s^2 (5 sigma), so on EuRoC the allowances decide: 0.02 rad/s
//!   (EuRoC at rest: 0.004-0.008; every 1 s window of V1_02's flight:
//!   at least 0.08) and 0.2 m/s^2 (rest: 0.03-0.11). The price: a sway of
//!   1 cm at 1 Hz (0.4 m/s^2 peak, 6 cm/s) passes for rest.
//! - the mean gyro must be a plausible bias (`max_gyro_bias_rad_s`): a
//!   steady turn about the vertical leaves both spreads small and only
//!   shows in the mean;
//! - the mean accelerometer norm must be within `max_gravity_error_m_s2`
//!   of g.
//!
//! What the IMU cannot tell: a rig gliding at constant velocity without
//! rotating or vibrating reads exactly as at rest. That is why every
//! threshold errs on the side of refusing, and why a caller that can
//! should also require still images (no feature flow) before trusting
//! the zero velocity. A wrongly accepted rest would be worse than a late
//! start: the velocity prior of zero would be wrong by the flight speed.

use nalgebra::{UnitQuaternion, Vector3};

use super::level_rotation;
use crate::imu::GRAVITY_M_S2;
use crate::rig::ImuNoise;
use crate::sensors::ImuSample;

/// Settings of [`detect_static_start`].
#[derive(Debug, Clone, PartialEq)]
pub struct StaticStartConfig {
    /// Length of the window that must be at rest, ending at `t_end_ns`.
    pub window_s: f64,
    /// Length of the blocks whose means are compared.
    pub block_s: f64,
    /// How many standard deviations of white noise a block mean may wander.
    pub white_noise_sigmas: f64,
    /// Spread of the gyro block means allowed for vibration at rest
    /// (norm over the three axes).
    pub gyro_vibration_rad_s: f64,
    /// Spread of the accelerometer block means allowed for vibration.
    pub accel_vibration_m_s2: f64,
    /// Largest plausible gyroscope bias (norm of the mean rate).
    pub max_gyro_bias_rad_s: f64,
    /// Largest allowed difference between |mean accel| and g.
    pub max_gravity_error_m_s2: f64,
    /// Largest gap between samples (and between the window's ends and the
    /// nearest sample).
    pub max_gap_s: f64,
}

impl Default for StaticStartConfig {
    fn default() -> Self {
        Self {
            window_s: 1.0,
            block_s: 0.1,
            white_noise_sigmas: 5.0,
            gyro_vibration_rad_s: 0.02,
            accel_vibration_m_s2: 0.2,
            max_gyro_bias_rad_s: 0.2,
            max_gravity_error_m_s2: 0.5,
            max_gap_s: 0.05,
        }
    }
}

/// Why a window is not taken as a static start.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StaticRefusal {
    #[error("setting `{key}` = {value} is outside the allowed range {allowed}")]
    /// A setting is out of range.
    InvalidConfig {
        /// The setting's key.
        key: &'static str,
        /// Its value.
        value: f64,
        /// The allowed range.
        allowed: &'static str,
    },
    #[error("IMU sample {index} at {t_ns} ns is not finite")]
    /// A sample has a NaN or infinite value.
    NotFinite {
        /// Its index in the samples given.
        index: usize,
        /// Its stamp, ns.
        t_ns: i64,
    },
    #[error("IMU sample {index} at {t_ns} ns does not come after the previous one")]
    /// A sample's stamp is not after the previous sample's.
    NotIncreasing {
        /// Its index in the samples given.
        index: usize,
        /// Its stamp, ns.
        t_ns: i64,
    },
    #[error("the window {t_start_ns}..{t_end_ns} ns is not covered: a gap of {gap_s} s")]
    /// The samples leave a gap in the window (or do not reach its start).
    Gap {
        /// Window start, ns.
        t_start_ns: i64,
        /// Window end, ns.
        t_end_ns: i64,
        /// Length of the gap, s.
        gap_s: f64,
    },
    #[error("only {blocks} blocks with samples in the window, need 4")]
    /// Fewer than 4 blocks of the window hold samples.
    TooFewBlocks {
        /// Blocks with samples.
        blocks: usize,
    },
    #[error("rotating: gyro block means spread {spread_rad_s} rad/s, threshold {threshold_rad_s}")]
    /// The gyro block means spread more than the threshold: the rig rotates.
    Rotating {
        /// Spread of the gyro block means (norm over the axes), rad/s.
        spread_rad_s: f64,
        /// The threshold, rad/s.
        threshold_rad_s: f64,
    },
    #[error(
        "accelerating: accelerometer block means spread {spread_m_s2} m/s^2, \
         threshold {threshold_m_s2}"
    )]
    /// The accelerometer block means spread more than the threshold: the rig accelerates.
    Accelerating {
        /// Spread of the accelerometer block means (norm over the axes), m/s^2.
        spread_m_s2: f64,
        /// The threshold, m/s^2.
        threshold_m_s2: f64,
    },
    #[error("mean rate {rate_rad_s} rad/s is more than a gyro bias can be ({max_rad_s})")]
    /// The mean rate is larger than a gyro bias can be: the rig turns steadily.
    Turning {
        /// Norm of the mean rate, rad/s.
        rate_rad_s: f64,
        /// Largest plausible gyro bias, rad/s.
        max_rad_s: f64,
    },
    #[error("mean specific force {norm_m_s2} m/s^2 is not gravity")]
    /// The mean specific force is too far from 9.81 m/s^2.
    NotGravity {
        /// Its norm, m/s^2.
        norm_m_s2: f64,
    },
}

/// The state at the end of a window at rest.
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticStart {
    /// Window start, ns.
    pub t_start_ns: i64,
    /// Window end, ns: the instant the state is for.
    pub t_end_ns: i64,
    /// Levels the body: maps the mean specific force onto world +z; yaw 0.
    pub R_world_body: UnitQuaternion<f64>,
    /// Unit vector opposite to gravity, in the body frame.
    pub up_body: Vector3<f64>,
    /// Mean gyro over the window.
    pub gyro_bias_rad_s: Vector3<f64>,
    /// Standard deviation of that mean per axis, from the block means.
    pub gyro_bias_sigma_rad_s: Vector3<f64>,
    /// Zero by assumption.
    pub velocity_world_m_s: Vector3<f64>,
    /// Mean specific force over the window, body frame, m/s^2.
    pub accel_mean_m_s2: Vector3<f64>,
    /// Standard deviation of the tilt from the spread of the accelerometer
    /// block means (the accelerometer bias, not observable at rest, adds
    /// up to |b_a| / g more).
    pub tilt_sigma_rad: f64,
    /// Spread of the gyro block means (norm over the axes), rad/s.
    pub gyro_spread_rad_s: f64,
    /// Spread of the accelerometer block means (norm over the axes), m/s^2.
    pub accel_spread_m_s2: f64,
    /// 1 minus the largest ratio of a test statistic to its threshold
    /// (gyro spread, accelerometer spread, gravity error): 1 for a perfectly
    /// quiet window, near 0 at the edge of refusal.
    pub confidence: f64,
}

/// Tests whether the rig was at rest over the `config.window_s` seconds
/// ending at `t_end_ns` (samples after it are ignored), and if so returns
/// the static start. `samples` must be time-ordered; only those in the
/// window are examined. `noise` gives the white-noise part of the
/// thresholds (see the module documentation for how).
pub fn detect_static_start(
    samples: &[ImuSample],
    t_end_ns: i64,
    noise: &ImuNoise,
    config: &StaticStartConfig,
) -> Result<StaticStart, StaticRefusal> {
    validate(config)?;
    let window_ns = (config.window_s * 1e9).round() as i64;
    let block_ns = ((config.block_s * 1e9).round() as i64).max(1);
    let max_gap_ns = (config.max_gap_s * 1e9).round() as i64;
    let t_start_ns = t_end_ns - window_ns;
    let lo = samples.partition_point(|s| s.t_ns < t_start_ns);
    let hi = samples.partition_point(|s| s.t_ns <= t_end_ns);
    let window = &samples[lo..hi.max(lo)];

    // Coverage and sanity of the window's samples.
    let mut previous = t_start_ns;
    for (k, s) in window.iter().enumerate() {
        if !s.is_finite() {
            return Err(StaticRefusal::NotFinite {
                index: lo + k,
                t_ns: s.t_ns,
            });
        }
        if k > 0 && s.t_ns <= window[k - 1].t_ns {
            return Err(StaticRefusal::NotIncreasing {
                index: lo + k,
                t_ns: s.t_ns,
            });
        }
        if s.t_ns - previous > max_gap_ns {
            return Err(gap(t_start_ns, t_end_ns, s.t_ns - previous));
        }
        previous = s.t_ns;
    }
    if t_end_ns - previous > max_gap_ns {
        return Err(gap(t_start_ns, t_end_ns, t_end_ns - previous));
    }

    // Block means.
    let block_count = (window_ns / block_ns).max(1) as usize;
    let mut means: Vec<(Vector3<f64>, Vector3<f64>)> = Vec::with_capacity(block_count);
    let mut k = 0;
    for b in 0..block_count {
        let end_ns = if b + 1 == block_count {
            t_end_ns + 1
        } else {
            t_start_ns + (b as i64 + 1) * block_ns
        };
        let (mut g, mut a, mut n) = (Vector3::zeros(), Vector3::zeros(), 0usize);
        while k < window.len() && window[k].t_ns < end_ns {
            g += Vector3::from(window[k].gyro_rad_s);
            a += Vector3::from(window[k].accel_m_s2);
            n += 1;
            k += 1;
        }
        if n > 0 {
            means.push((g / n as f64, a / n as f64));
        }
    }
    if means.len() < 4 {
        return Err(StaticRefusal::TooFewBlocks {
            blocks: means.len(),
        });
    }
    let nb = means.len() as f64;
    let gyro_mean = means.iter().map(|m| m.0).sum::<Vector3<f64>>() / nb;
    let accel_mean = means.iter().map(|m| m.1).sum::<Vector3<f64>>() / nb;
    let gyro_var = means
        .iter()
        .map(|m| (m.0 - gyro_mean).component_mul(&(m.0 - gyro_mean)))
        .sum::<Vector3<f64>>()
        / (nb - 1.0);
    let accel_var = means
        .iter()
        .map(|m| (m.1 - accel_mean).component_mul(&(m.1 - accel_mean)))
        .sum::<Vector3<f64>>()
        / (nb - 1.0);
    let gyro_spread = gyro_var.sum().sqrt();
    let accel_spread = accel_var.sum().sqrt();

    // Thresholds: white noise of a block mean, or the vibration allowance.
    let white = config.white_noise_sigmas * (3.0 / config.block_s).sqrt();
    let gyro_threshold = (white * noise.gyroscope_noise_density).max(config.gyro_vibration_rad_s);
    let accel_threshold =
        (white * noise.accelerometer_noise_density).max(config.accel_vibration_m_s2);
    if gyro_spread > gyro_threshold {
        return Err(StaticRefusal::Rotating {
            spread_rad_s: gyro_spread,
            threshold_rad_s: gyro_threshold,
        });
    }
    if accel_spread > accel_threshold {
        return Err(StaticRefusal::Accelerating {
            spread_m_s2: accel_spread,
            threshold_m_s2: accel_threshold,
        });
    }
    if gyro_mean.norm() > config.max_gyro_bias_rad_s {
        return Err(StaticRefusal::Turning {
            rate_rad_s: gyro_mean.norm(),
            max_rad_s: config.max_gyro_bias_rad_s,
        });
    }
    let gravity_error = (accel_mean.norm() - GRAVITY_M_S2).abs();
    if gravity_error > config.max_gravity_error_m_s2 {
        return Err(StaticRefusal::NotGravity {
            norm_m_s2: accel_mean.norm(),
        });
    }
    let r_world_body = level_rotation(&accel_mean).ok_or(StaticRefusal::NotGravity {
        norm_m_s2: accel_mean.norm(),
    })?;
    let worst = (gyro_spread / gyro_threshold)
        .max(accel_spread / accel_threshold)
        .max(gravity_error / config.max_gravity_error_m_s2);
    // Horizontal spread of the block means over g: the tilt noise of one
    // block, divided by sqrt(blocks) for the mean.
    let up_body = accel_mean / accel_mean.norm();
    let horizontal_var = accel_var.sum() - up_body.dot(&accel_var.component_mul(&up_body));
    Ok(StaticStart {
        t_start_ns,
        t_end_ns,
        R_world_body: r_world_body,
        up_body,
        gyro_bias_rad_s: gyro_mean,
        gyro_bias_sigma_rad_s: gyro_var.map(|v| (v / nb).sqrt()),
        velocity_world_m_s: Vector3::zeros(),
        accel_mean_m_s2: accel_mean,
        tilt_sigma_rad: (horizontal_var.max(0.0) / nb).sqrt() / accel_mean.norm(),
        gyro_spread_rad_s: gyro_spread,
        accel_spread_m_s2: accel_spread,
        confidence: (1.0 - worst).clamp(0.0, 1.0),
    })
}

fn gap(t_start_ns: i64, t_end_ns: i64, gap_ns: i64) -> StaticRefusal {
    StaticRefusal::Gap {
        t_start_ns,
        t_end_ns,
        gap_s: gap_ns as f64 * 1e-9,
    }
}

fn validate(config: &StaticStartConfig) -> Result<(), StaticRefusal> {
    let checks: [(&'static str, f64, &'static str); 8] = [
        ("window_s", config.window_s, "> 0"),
        ("block_s", config.block_s, "> 0 and <= window_s / 4"),
        ("white_noise_sigmas", config.white_noise_sigmas, "> 0"),
        ("gyro_vibration_rad_s", config.gyro_vibration_rad_s, "> 0"),
        ("accel_vibration_m_s2", config.accel_vibration_m_s2, "> 0"),
        ("max_gyro_bias_rad_s", config.max_gyro_bias_rad_s, "> 0"),
        (
            "max_gravity_error_m_s2",
            config.max_gravity_error_m_s2,
            "> 0",
        ),
        ("max_gap_s", config.max_gap_s, "> 0"),
    ];
    for (key, value, allowed) in checks {
        let ok = value.is_finite()
            && value > 0.0
            && (key != "block_s" || value * 4.0 <= config.window_s);
        if !ok {
            return Err(StaticRefusal::InvalidConfig {
                key,
                value,
                allowed,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::{read_euroc_groundtruth, read_euroc_imu_csv};
    use crate::imu::ImuBiases;
    use crate::shared_data::shared_data_dir;
    use crate::simulate::imu_synth::{synthesize, ImuSynthConfig};
    use crate::simulate::motion::{BuiltinMotion, Motion, Sinusoid};

    const NOISE: ImuNoise = ImuNoise::EUROC_ADIS16448;

    fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
        a.angle(b).to_degrees()
    }

    /// A body that does not move, tilted, with the given biases.
    fn still_motion(position: [Vec<Sinusoid>; 3], angles: [Vec<Sinusoid>; 3]) -> Motion {
        Motion::Builtin(BuiltinMotion {
            start_ns: 0,
            duration_s: 10.0,
            centre_m: Vector3::new(1.0, 2.0, 1.0),
            position,
            angles,
        })
    }

    fn constant(value: f64) -> Vec<Sinusoid> {
        // sin(pi/2) at t = 0 with a negligible frequency: a constant.
        vec![Sinusoid {
            amplitude: value,
            omega_rad_s: 0.0,
            phase_rad: std::f64::consts::FRAC_PI_2,
        }]
    }

    #[test]
    fn synthetic_rest_gives_gravity_and_bias() {
        let motion = still_motion(
            [vec![], vec![], vec![]],
            [constant(0.7), constant(0.2), constant(-0.3)],
        );
        let biases = ImuBiases {
            gyro_rad_s: Vector3::new(0.01, -0.02, 0.03),
            accel_m_s2: Vector3::zeros(),
        };
        let config = ImuSynthConfig {
            initial_biases: biases,
            seed: 3,
            ..ImuSynthConfig::default()
        };
        let imu = synthesize(&motion, 0, 3_000_000_000, &config);
        let start = detect_static_start(
            &imu.samples,
            2_000_000_000,
            &NOISE,
            &StaticStartConfig::default(),
        )
        .expect("at rest");
        let truth = motion.state(2_000_000_000).T_world_body.rotation;
        let up_true = truth.inverse() * Vector3::z();
        let err_deg = angle_deg(&(start.R_world_body.inverse() * Vector3::z()), &up_true);
        // White noise only: 0.028 m/s^2 per sample, 200 samples: ~1e-4 rad.
        assert!(err_deg < 0.05, "gravity off by {err_deg} deg");
        for axis in 0..3 {
            let err = (start.gyro_bias_rad_s[axis] - imu.biases[300].gyro_rad_s[axis]).abs();
            // 2.4e-3 rad/s per sample over 200 samples: 1.7e-4 rad/s.
            assert!(err < 8e-4, "axis {axis}: bias off by {err}");
            assert!(err < 5.0 * start.gyro_bias_sigma_rad_s[axis] + 1e-5);
        }
        assert_eq!(start.velocity_world_m_s, Vector3::zeros());
        assert!(start.confidence > 0.8, "{}", start.confidence);
        assert!(start.tilt_sigma_rad < 1e-3);
    }

    #[test]
    fn synthetic_motion_is_refused() {
        let motion = Motion::Builtin(BuiltinMotion::standard(0, 20.0));
        let imu = synthesize(&motion, 0, 20_000_000_000, &ImuSynthConfig::default());
        let config = StaticStartConfig::default();
        for t_s in 1..20 {
            let result = detect_static_start(&imu.samples, t_s * 1_000_000_000, &NOISE, &config);
            assert!(
                result.is_err(),
                "accepted a window ending at {t_s} s in motion"
            );
        }
    }

    #[test]
    fn gentle_sway_and_steady_turn_are_refused() {
        // 2 cm sway at 1 Hz: 0.8 m/s^2 peak, nothing on the gyro. (A 1 cm
        // sway, 0.4 m/s^2 peak, would pass: the allowance for vibration.)
        let sway = still_motion(
            [
                vec![Sinusoid {
                    amplitude: 0.02,
                    omega_rad_s: 2.0 * std::f64::consts::PI,
                    phase_rad: 0.0,
                }],
                vec![],
                vec![],
            ],
            [vec![], vec![], vec![]],
        );
        let config = StaticStartConfig::default();
        let synth = ImuSynthConfig::default();
        let imu = synthesize(&sway, 0, 3_000_000_000, &synth);
        let refusal = detect_static_start(&imu.samples, 2_000_000_000, &NOISE, &config);
        assert!(
            matches!(refusal, Err(StaticRefusal::Accelerating { .. })),
            "{refusal:?}"
        );
        // A steady turn about the vertical at 0.3 rad/s: only the mean shows it.
        let turn = still_motion(
            [vec![], vec![], vec![]],
            [
                vec![Sinusoid {
                    amplitude: 3000.0,
                    omega_rad_s: 1e-4,
                    phase_rad: 0.0,
                }],
                vec![],
                vec![],
            ],
        );
        let imu = synthesize(&turn, 0, 3_000_000_000, &synth);
        let refusal = detect_static_start(&imu.samples, 2_000_000_000, &NOISE, &config);
        assert!(
            matches!(refusal, Err(StaticRefusal::Turning { .. })),
            "{refusal:?}"
        );
    }

    #[test]
    fn damaged_windows_are_refused() {
        let motion = still_motion([vec![], vec![], vec![]], [vec![], vec![], vec![]]);
        let imu = synthesize(&motion, 0, 3_000_000_000, &ImuSynthConfig::default());
        let config = StaticStartConfig::default();
        let t_end = 2_000_000_000;
        assert!(detect_static_start(&imu.samples, t_end, &NOISE, &config).is_ok());
        let mut nan = imu.samples.clone();
        nan[300].accel_m_s2[1] = f64::NAN;
        assert!(matches!(
            detect_static_start(&nan, t_end, &NOISE, &config),
            Err(StaticRefusal::NotFinite { index: 300, .. })
        ));
        let mut gappy = imu.samples.clone();
        gappy.drain(250..280);
        assert!(matches!(
            detect_static_start(&gappy, t_end, &NOISE, &config),
            Err(StaticRefusal::Gap { .. })
        ));
        // Before the first sample there is nothing.
        assert!(detect_static_start(&imu.samples, 500_000_000, &NOISE, &config).is_err());
        assert!(detect_static_start(&[], t_end, &NOISE, &config).is_err());
        let bad = StaticStartConfig {
            block_s: f64::NAN,
            ..config
        };
        assert!(matches!(
            detect_static_start(&imu.samples, t_end, &NOISE, &bad),
            Err(StaticRefusal::InvalidConfig { key: "block_s", .. })
        ));
    }

    /// EuRoC V1_01: the MAV stands on the ground for the first 4.7 s with
    /// its rotors running.
    #[test]
    fn euroc_v1_01_rest_matches_ground_truth() {
        let Some(data) = shared_data_dir() else {
            return;
        };
        let dir = data.join("euroc/V1_01_micro/mav0");
        let imu = read_euroc_imu_csv(&dir.join("imu0/data.csv"))
            .expect("V1_01 IMU")
            .samples;
        let truth = read_euroc_groundtruth(&dir.join("state_groundtruth_estimate0/data.csv"))
            .expect("V1_01 ground truth");
        let t0 = imu[0].t_ns;
        let config = StaticStartConfig::default();
        let mut accepted = 0;
        // Every 1 s window ending between 1.0 and 4.7 s.
        for k in 0..=15 {
            let t_end = t0 + 1_000_000_000 + k * 245_000_000;
            let start = detect_static_start(&imu, t_end, &NOISE, &config).unwrap_or_else(|e| {
                panic!(
                    "window ending {} s refused: {e}",
                    (t_end - t0) as f64 * 1e-9
                )
            });
            accepted += 1;
            let gt = &truth[truth.partition_point(|s| s.t_ns <= t_end) - 1];
            let up_true = gt.T_world_body.rotation.inverse() * Vector3::z();
            let up_est = start.R_world_body.inverse() * Vector3::z();
            let err_deg = angle_deg(&up_est, &up_true);
            assert!(err_deg < 1.0, "gravity off by {err_deg} deg");
            for axis in 0..3 {
                let err = (start.gyro_bias_rad_s[axis] - gt.gyro_bias_rad_s[axis]).abs();
                let sigma = start.gyro_bias_sigma_rad_s[axis];
                // The rotors' vibration dominates sigma (up to 4e-3 rad/s
                // while they spin up); 1e-3 rad/s allows for the error of
                // EuRoC's own bias estimate.
                assert!(sigma < 5e-3, "axis {axis}: sigma {sigma}");
                assert!(
                    err < 3.0 * sigma + 1e-3,
                    "axis {axis}: bias off by {err}, sigma {sigma}"
                );
            }
        }
        assert_eq!(accepted, 16);
    }

    /// EuRoC V1_02 in flight: no 1 s window where the ground truth moves
    /// is taken for rest; the windows on the ground before take-off are.
    #[test]
    fn euroc_v1_02_flight_is_never_rest() {
        let Some((imu, truth)) = super::super::v1_02_imu_and_truth() else {
            return;
        };
        let config = StaticStartConfig::default();
        let (mut flight_windows, mut ground_windows, mut ground_accepted) = (0, 0, 0);
        let last = imu.last().expect("samples").t_ns;
        let mut t_end = truth[0].t_ns + 1_000_000_000;
        while t_end < last.min(truth.last().expect("states").t_ns) {
            // Fastest ground-truth speed inside the window and, to keep
            // the take-off's first twitches out of "ground", 0.5 s after.
            let lo = truth.partition_point(|s| s.t_ns < t_end - 1_000_000_000);
            let hi = truth.partition_point(|s| s.t_ns <= t_end);
            let after = truth.partition_point(|s| s.t_ns <= t_end + 500_000_000);
            let fastest = |states: &[crate::dataset::GroundTruthState]| {
                states
                    .iter()
                    .map(|s| s.velocity_m_s.norm())
                    .fold(0.0, f64::max)
            };
            let speed = fastest(&truth[lo..hi]);
            let speed_around = fastest(&truth[lo..after]);
            let result = detect_static_start(&imu, t_end, &NOISE, &config);
            if speed > 0.1 {
                flight_windows += 1;
                assert!(
                    result.is_err(),
                    "window ending {} ns (speed {speed} m/s) taken for rest",
                    t_end
                );
            } else if speed_around < 0.02 {
                ground_windows += 1;
                if let Ok(start) = result {
                    ground_accepted += 1;
                    let gt = &truth[hi - 1];
                    let up_true = gt.T_world_body.rotation.inverse() * Vector3::z();
                    let err = angle_deg(&(start.R_world_body.inverse() * Vector3::z()), &up_true);
                    assert!(err < 1.0, "gravity off by {err} deg");
                }
            }
            t_end += 250_000_000;
        }
        assert!(flight_windows > 300, "{flight_windows}");
        assert!(ground_windows >= 6, "{ground_windows}");
        assert_eq!(ground_accepted, ground_windows);
    }
}
