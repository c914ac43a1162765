//! VINS-Fusion: `vins_config.yaml` (which cameras, `body_T_camN` as
//! OpenCV matrices, IMU noise, gravity, `td`) and one `camN.yaml` per
//! camera in camodocal's PINHOLE layout, all read through OpenCV's
//! `FileStorage`.
//!
//! VINS-Fusion takes the noise values as they are (Kalibr's continuous
//! densities are what its EuRoC example uses), `td` in its convention
//! "image clock + td = IMU clock", Kalibr's `timeshift_cam_imu`. It has no
//! IMU intrinsics: the notes say so when the rig has some.

use serde::Serialize;

use super::opencv_yaml::{self, Matrix};
use super::{radtan4, rows4, Export, ExportError, ExportFile};
use rigslam::rig::{CameraCalibration, ImuCalibration};

#[derive(Serialize)]
struct Distortion {
    k1: f64,
    k2: f64,
    p1: f64,
    p2: f64,
}

#[derive(Serialize)]
struct Projection {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
}

#[derive(Serialize)]
struct Camera {
    model_type: &'static str,
    camera_name: String,
    image_width: u32,
    image_height: u32,
    distortion_parameters: Distortion,
    projection_parameters: Projection,
}

/// The keys VINS-Fusion's estimator reads for the rig (tracker and solver
/// settings are left to its defaults file).
#[allow(non_snake_case)]
#[derive(Serialize)]
struct Config {
    imu: u32,
    num_of_cam: usize,
    imu_topic: &'static str,
    image0_topic: &'static str,
    image1_topic: &'static str,
    cam0_calib: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    cam1_calib: Option<&'static str>,
    image_width: u32,
    image_height: u32,
    estimate_extrinsic: u32,
    body_T_cam0: Matrix,
    #[serde(skip_serializing_if = "Option::is_none")]
    body_T_cam1: Option<Matrix>,
    acc_n: f64,
    gyr_n: f64,
    acc_w: f64,
    gyr_w: f64,
    g_norm: f64,
    estimate_td: u32,
    td: f64,
}

pub fn export(cameras: &[CameraCalibration], imu: &ImuCalibration) -> Result<Export, ExportError> {
    let Some(cam0) = cameras.first() else {
        return Err(ExportError::Camera("the rig has no camera".into()));
    };
    let stereo = cameras.len() > 1;
    let mut files = Vec::new();
    for (i, c) in cameras.iter().take(2).enumerate() {
        let [k1, k2, p1, p2] = radtan4(c, i)?;
        let [fx, fy, cx, cy] = c.model.pinhole();
        files.push(ExportFile {
            name: format!("cam{i}.yaml"),
            text: opencv_yaml::to_string(&Camera {
                model_type: "PINHOLE",
                camera_name: format!("cam{i}"),
                image_width: c.model.width(),
                image_height: c.model.height(),
                distortion_parameters: Distortion { k1, k2, p1, p2 },
                projection_parameters: Projection { fx, fy, cx, cy },
            }),
        });
    }
    let n = &imu.noise;
    let config = Config {
        imu: 1,
        num_of_cam: if stereo { 2 } else { 1 },
        imu_topic: "/imu0",
        image0_topic: "/cam0/image_raw",
        image1_topic: "/cam1/image_raw",
        cam0_calib: "cam0.yaml",
        cam1_calib: stereo.then_some("cam1.yaml"),
        image_width: cam0.model.width(),
        image_height: cam0.model.height(),
        estimate_extrinsic: 0,
        body_T_cam0: Matrix::from_rows(&rows4(&cam0.T_body_cam)),
        body_T_cam1: cameras
            .get(1)
            .filter(|_| stereo)
            .map(|c| Matrix::from_rows(&rows4(&c.T_body_cam))),
        acc_n: n.accelerometer_noise_density,
        gyr_n: n.gyroscope_noise_density,
        acc_w: n.accelerometer_random_walk,
        gyr_w: n.gyroscope_random_walk,
        g_norm: rigslam::imu::GRAVITY_M_S2,
        estimate_td: 0,
        td: cam0.time_shift_cam_imu_s,
    };
    files.insert(
        0,
        ExportFile {
            name: "vins_config.yaml".into(),
            text: opencv_yaml::to_string(&config),
        },
    );
    let mut notes = Vec::new();
    if !imu.intrinsics.is_identity() {
        notes.push(
            "VINS-Fusion has no IMU intrinsics: feed it samples already corrected by imu_intrinsics.yaml".into(),
        );
    }
    if cameras.len() > 2 {
        notes.push(format!(
            "VINS-Fusion takes two cameras: cam2..cam{} left out",
            cameras.len() - 1
        ));
    }
    notes.push("tracker and solver settings are not part of a calibration: merge these keys into a VINS-Fusion config".into());
    Ok(Export { files, notes })
}
