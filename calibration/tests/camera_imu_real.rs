//! Camera-IMU calibration on the real EuRoC calibration recording
//! (../shared/data/calib/euroc_imu_april), against the published EuRoC
//! extrinsics (`T_BS` of cam0 and cam1 in ../shared/data/euroc/V1_01_micro;
//! `T_cam_imu` is its inverse). The sensors are hardware-synchronised, so
//! the true time offset is zero.

use nalgebra::{Matrix3, Matrix4, Vector3};
use rigslam::dataset::read_euroc_imu_csv;
use rigslam::imu::so3;
use rigslam::shared_data::shared_data_dir;
use rigslam_calibration::aprilgrid_detections::{read_detection_dir, target_poses};
use rigslam_calibration::camchain_yaml::read_intrinsics;
use rigslam_calibration::camera_imu_batch::{refine_camera_imu, BatchInput, BatchResult};
use rigslam_calibration::time_offset::{
    camera_rates, estimate_time_offset, GyroSeries, TimeOffsetEstimate,
};

#[rustfmt::skip]
const EUROC_T_BS: [(&str, [f64; 16]); 2] = [
    ("cam0", [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,
              0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,
              -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,
              0.0, 0.0, 0.0, 1.0]),
    ("cam1", [0.0125552670891, -0.999755099723, 0.0182237714554, -0.0198435579556,
              0.999598781151, 0.0130119051815, 0.0251588363115, 0.0453689425024,
              -0.0253898008918, 0.0179005838253, 0.999517347078, 0.00786212447038,
              0.0, 0.0, 0.0, 1.0]),
];

/// sequence.yaml: local gravity and the ADIS16448's accelerometer random walk.
const LOCAL_GRAVITY_M_S2: f64 = 9.81007;
const ACCEL_RANDOM_WALK: f64 = 3e-3;

/// Runs both stages for one camera; `scale` multiplies the target points
/// (1.0 = the true target; otherwise a wrong tag size).
fn calibrate(cam: &str, scale: f64) -> Option<(TimeOffsetEstimate, BatchResult)> {
    let dir = shared_data_dir()?.join("calib/euroc_imu_april/imu_april");
    let camera = read_intrinsics(&dir.join("sequence.yaml"), cam).expect("intrinsics");
    let mut detections = read_detection_dir(&dir.join(cam)).expect("detections");
    for d in &mut detections {
        for p in &mut d.target_points_m {
            *p *= scale;
        }
    }
    let poses = target_poses(&camera, &detections);
    let imu = read_euroc_imu_csv(&dir.join("imu0.csv")).expect("imu");
    let t0 = imu.samples[0].t_ns;
    let gyro = GyroSeries {
        t_s: imu
            .samples
            .iter()
            .map(|s| (s.t_ns - t0) as f64 * 1e-9)
            .collect(),
        w_rad_s: imu.samples.iter().map(|s| s.gyro_rad_s.into()).collect(),
    };
    let offset =
        estimate_time_offset(&camera_rates(&poses, t0, 0.075), &gyro, 0.2).expect("offset");
    let batch = refine_camera_imu(&BatchInput {
        poses: &poses,
        imu: &imu.samples,
        t_origin_ns: t0,
        R_imu_cam: offset.hand_eye.R_imu_cam,
        gyro_bias_rad_s: offset.hand_eye.gyro_bias_rad_s,
        timeshift_cam_imu_s: offset.timeshift_cam_imu_s,
        gravity_m_s2: Some(LOCAL_GRAVITY_M_S2),
        accel_random_walk: ACCEL_RANDOM_WALK,
    })
    .expect("batch");
    Some((offset, batch))
}

fn reference_t_cam_imu(cam: &str) -> Matrix4<f64> {
    let (_, data) = EUROC_T_BS
        .iter()
        .find(|(n, _)| *n == cam)
        .expect("known camera");
    Matrix4::from_row_slice(data)
        .try_inverse()
        .expect("rigid transform")
}

fn rotation_error_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    so3::log(&(a.transpose() * b)).norm().to_degrees()
}

#[test]
fn offsets_translation_and_scale_agree_with_euroc() {
    for cam in ["cam0", "cam1"] {
        let Some((offset, batch)) = calibrate(cam, 1.0) else {
            return;
        };
        assert!(
            offset.timeshift_cam_imu_s.abs() < 1e-3,
            "{cam}: gyro offset {}",
            offset.timeshift_cam_imu_s
        );
        assert!(
            offset.peak_correlation > 0.99,
            "{cam}: correlation {}",
            offset.peak_correlation
        );
        let reference = reference_t_cam_imu(cam);
        let r_ref = reference.fixed_view::<3, 3>(0, 0).into_owned();
        let t = batch.T_cam_imu();
        // The batch improves the gyro-only rotation (0.28 / 0.34 deg); the
        // 0.2 deg bar is checked by the test below.
        let gyro_err = rotation_error_deg(&offset.hand_eye.R_imu_cam.transpose(), &r_ref);
        let batch_err = rotation_error_deg(&t.fixed_view::<3, 3>(0, 0).into_owned(), &r_ref);
        assert!(
            batch_err < gyro_err,
            "{cam}: batch {batch_err} vs gyro {gyro_err} deg"
        );
        let t_err: Vector3<f64> = t.fixed_view::<3, 1>(0, 3) - reference.fixed_view::<3, 1>(0, 3);
        assert!(
            t_err.norm() <= 0.005,
            "{cam}: translation error {} m",
            t_err.norm()
        );
        // Held at sequence.yaml's local gravity.
        let g = batch.gravity_m_s2.norm();
        assert!((g - LOCAL_GRAVITY_M_S2).abs() < 1e-3, "{cam}: gravity {g}");
        // The batch's own offset, also within the 1 ms bar.
        let shift = batch.timeshift_cam_imu_s;
        assert!(shift.abs() <= 1e-3, "{cam}: batch offset {shift}");
        // The verdict's tolerance on the target scale.
        assert!(
            (batch.target_scale - 1.0).abs() < 0.03,
            "{cam}: scale {}",
            batch.target_scale
        );
    }
}

#[test]
fn batch_rotation_within_0_2_deg_of_euroc() {
    for cam in ["cam0", "cam1"] {
        let Some((_, batch)) = calibrate(cam, 1.0) else {
            return;
        };
        let reference = reference_t_cam_imu(cam);
        let t = batch.T_cam_imu();
        let r_err = rotation_error_deg(
            &t.fixed_view::<3, 3>(0, 0).into_owned(),
            &reference.fixed_view::<3, 3>(0, 0).into_owned(),
        );
        assert!(r_err <= 0.2, "{cam}: rotation {r_err} deg");
    }
}

#[test]
fn a_wrong_tag_size_shows_in_the_target_scale() {
    // Target points 10% too large: the IMU sees the target 1/1.1 as large.
    let Some((_, truth)) = calibrate("cam0", 1.0) else {
        return;
    };
    let Some((_, wrong)) = calibrate("cam0", 1.1) else {
        return;
    };
    let ratio = wrong.target_scale * 1.1 / truth.target_scale;
    assert!(
        (ratio - 1.0).abs() < 0.005,
        "scale {} vs {}",
        wrong.target_scale,
        truth.target_scale
    );
    assert!(
        (wrong.target_scale - 1.0).abs() > 0.03,
        "the verdict would not flag it"
    );
}
