//! Basalt: `calibration.json` as its cereal loader reads it (one `value0`
//! object): per camera `T_imu_cam` as position + quaternion, intrinsics as
//! `pinhole-radtan8` (our k1, k2, p1, p2; its rational terms k3..k6 zero)
//! or `kb4` for equidistant, resolutions, the IMU's static calibration and
//! its noise as continuous-time densities (Basalt multiplies by
//! `sqrt(imu_update_rate)` itself).
//!
//! Basalt calibrates a raw sample as `(I + M) x_r - b`: for the gyroscope
//! M is a full 3x3 (12 parameters, column-major after the bias), for the
//! accelerometer a lower triangle (9 parameters). Ours is `S x_r + b`, so
//! `M = S - I` and Basalt's `b` is minus ours; the accelerometer's upper
//! triangle, which Basalt's model has no place for, is reported in the
//! notes when it is not zero.

use serde::Serialize;

use super::{radtan4, Export, ExportError, ExportFile};
use rigslam::camera::CameraModel;
use rigslam::rig::{CameraCalibration, ImuCalibration};

#[derive(Serialize)]
struct Pose {
    px: f64,
    py: f64,
    pz: f64,
    qx: f64,
    qy: f64,
    qz: f64,
    qw: f64,
}

#[derive(Serialize)]
#[serde(tag = "camera_type", content = "intrinsics")]
enum Intrinsics {
    #[serde(rename = "pinhole-radtan8")]
    Radtan8 {
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        k1: f64,
        k2: f64,
        p1: f64,
        p2: f64,
        k3: f64,
        k4: f64,
        k5: f64,
        k6: f64,
        rpmax: f64,
    },
    #[serde(rename = "kb4")]
    Kb4 {
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        k1: f64,
        k2: f64,
        k3: f64,
        k4: f64,
    },
}

#[allow(non_snake_case)]
#[derive(Serialize)]
struct Calibration {
    T_imu_cam: Vec<Pose>,
    intrinsics: Vec<Intrinsics>,
    resolution: Vec<[u32; 2]>,
    calib_accel_bias: [f64; 9],
    calib_gyro_bias: [f64; 12],
    imu_update_rate: f64,
    accel_noise_std: [f64; 3],
    gyro_noise_std: [f64; 3],
    accel_bias_std: [f64; 3],
    gyro_bias_std: [f64; 3],
    cam_time_offset_ns: i64,
}

#[derive(Serialize)]
struct File {
    value0: Calibration,
}

/// The largest normalised radius at which radial distortion
/// `r (1 + k1 r^2 + k2 r^4)` still grows (Basalt's `rpmax`: beyond it the
/// model folds back), capped at 10 (no turn in the image).
pub fn radtan_rpmax(k1: f64, k2: f64) -> f64 {
    // d/dr = 1 + 3 k1 u + 5 k2 u^2 with u = r^2.
    let (a, b, c) = (5.0 * k2, 3.0 * k1, 1.0);
    let roots: Vec<f64> = if a.abs() < 1e-15 {
        if b < 0.0 {
            vec![-c / b]
        } else {
            vec![]
        }
    } else {
        let disc = b * b - 4.0 * a * c;
        if disc < 0.0 {
            vec![]
        } else {
            let s = disc.sqrt();
            vec![(-b - s) / (2.0 * a), (-b + s) / (2.0 * a)]
        }
    };
    roots
        .into_iter()
        .filter(|u| *u > 0.0)
        .map(f64::sqrt)
        .fold(10.0, f64::min)
}

fn pose(t: &nalgebra::Isometry3<f64>) -> Pose {
    let p = t.translation.vector;
    let q = t.rotation;
    Pose {
        px: p.x,
        py: p.y,
        pz: p.z,
        qx: q.i,
        qy: q.j,
        qz: q.k,
        qw: q.w,
    }
}

pub fn export(cameras: &[CameraCalibration], imu: &ImuCalibration) -> Result<Export, ExportError> {
    let mut intrinsics = Vec::new();
    for (i, c) in cameras.iter().enumerate() {
        let [fx, fy, cx, cy] = c.model.pinhole();
        intrinsics.push(match c.model {
            CameraModel::PinholeEquidistant(_) => {
                let k = c.model.distortion_coefficients();
                Intrinsics::Kb4 {
                    fx,
                    fy,
                    cx,
                    cy,
                    k1: k[0],
                    k2: k[1],
                    k3: k[2],
                    k4: k[3],
                }
            }
            _ => {
                let [k1, k2, p1, p2] = radtan4(c, i)?;
                Intrinsics::Radtan8 {
                    fx,
                    fy,
                    cx,
                    cy,
                    k1,
                    k2,
                    p1,
                    p2,
                    k3: 0.0,
                    k4: 0.0,
                    k5: 0.0,
                    k6: 0.0,
                    rpmax: radtan_rpmax(k1, k2),
                }
            }
        });
    }
    let mut notes = Vec::new();
    let shifts: Vec<f64> = cameras.iter().map(|c| c.time_shift_cam_imu_s).collect();
    if shifts.iter().any(|s| (s - shifts[0]).abs() > 1e-9) {
        notes.push(format!(
            "Basalt has one camera time offset; cam0's is written (the cameras' shifts are {shifts:?} s)"
        ));
    }
    let i = &imu.intrinsics;
    let sa = i.accel_scale - nalgebra::Matrix3::identity();
    let upper = [sa[(0, 1)], sa[(0, 2)], sa[(1, 2)]];
    if upper.iter().any(|v| *v != 0.0) {
        notes.push(format!(
            "Basalt's accelerometer model is lower-triangular: the upper entries {upper:?} of S - I are left out"
        ));
    }
    let ba = -i.accel_offset_m_s2;
    let bg = -i.gyro_offset_rad_s;
    let sg = i.gyro_scale - nalgebra::Matrix3::identity();
    let mut calib_gyro_bias = [0.0; 12];
    calib_gyro_bias[..3].copy_from_slice(bg.as_slice());
    // nalgebra stores column-major, as Basalt's parameter vector is.
    calib_gyro_bias[3..].copy_from_slice(sg.as_slice());
    let n = &imu.noise;
    let file = File {
        value0: Calibration {
            T_imu_cam: cameras.iter().map(|c| pose(&c.T_body_cam)).collect(),
            intrinsics,
            resolution: cameras
                .iter()
                .map(|c| [c.model.width(), c.model.height()])
                .collect(),
            calib_accel_bias: [
                ba.x,
                ba.y,
                ba.z,
                sa[(0, 0)],
                sa[(1, 0)],
                sa[(2, 0)],
                sa[(1, 1)],
                sa[(2, 1)],
                sa[(2, 2)],
            ],
            calib_gyro_bias,
            imu_update_rate: imu.rate_hz,
            accel_noise_std: [n.accelerometer_noise_density; 3],
            gyro_noise_std: [n.gyroscope_noise_density; 3],
            accel_bias_std: [n.accelerometer_random_walk; 3],
            gyro_bias_std: [n.gyroscope_random_walk; 3],
            cam_time_offset_ns: (shifts.first().copied().unwrap_or(0.0) * 1e9).round() as i64,
        },
    };
    Ok(Export {
        files: vec![ExportFile {
            name: "calibration.json".into(),
            text: serde_json::to_string_pretty(&file).expect("numbers and strings serialise"),
        }],
        notes,
    })
}
