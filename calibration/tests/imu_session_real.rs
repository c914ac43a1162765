//! `rigslam-calibrate imu` on the real imucal Ferraris session
//! (../shared/data/imu/imucal_ferraris_session_102p4hz.csv, 102.4 Hz, gyro
//! deg/s, accel m/s^2) against imucal 2.6.0's own Ferraris calibration of
//! the same file with its section list (fixtures/imucal/ferraris_session.json,
//! made by bench/peers/imucal_ferraris.sh).

use std::path::PathBuf;

use nalgebra::{Matrix3, Vector3};
use rigslam_calibration::accel_calibration::AccelModel;
use rigslam_calibration::gyro_calibration::{read_section_list, rotations_from_sections};
use rigslam_calibration::imu_calibration::{
    calibrate_imu_session, ImuCalibrationOptions, ImuSessionCalibration,
};
use rigslam_calibration::imu_log::{read_imu_log, AccelUnit, GyroUnit, ImuLog, ImuLogLayout};

fn data(name: &str) -> Option<PathBuf> {
    Some(
        rigslam::shared_data::shared_data_dir()?
            .join("imu")
            .join(name),
    )
}

fn session() -> Option<(ImuLog, PathBuf)> {
    let csv = data("imucal_ferraris_session_102p4hz.csv")?;
    let layout = ImuLogLayout {
        columns: ImuLogLayout::parse_columns("skip,gx,gy,gz,ax,ay,az").expect("valid"),
        gyro_unit: GyroUnit::DegPerS,
        accel_unit: AccelUnit::MPerS2,
        rate_hz: Some(102.4),
        header: true,
    };
    let log = read_imu_log(&csv, &layout).expect("the real session reads");
    Some((log, data("imucal_ferraris_session_list.json")?))
}

struct Imucal {
    accel_scale: Matrix3<f64>,
    accel_bias: Vector3<f64>,
    accel_raw_offset: Vector3<f64>,
    gyro_scale: Matrix3<f64>,
    gyro_bias: Vector3<f64>,
}

fn imucal() -> Imucal {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../fixtures/imucal/ferraris_session.json"
    );
    let text = std::fs::read_to_string(path).expect("the imucal fixture is in the repository");
    let v: serde_json::Value = serde_json::from_str(&text).expect("valid JSON");
    let m = |k: &str| Matrix3::from_fn(|i, j| v[k][i][j].as_f64().expect("number"));
    let x = |k: &str| Vector3::from_fn(|i, _| v[k][i].as_f64().expect("number"));
    Imucal {
        accel_scale: m("accel_scale_matrix"),
        accel_bias: x("accel_bias_m_s2"),
        accel_raw_offset: x("accel_raw_offset_m_s2"),
        gyro_scale: m("gyro_scale_matrix"),
        gyro_bias: x("gyro_bias_rad_s"),
    }
}

fn rms_after(cal: &ImuSessionCalibration, s: &Matrix3<f64>, b: &Vector3<f64>) -> f64 {
    let g = cal.accel.gravity_m_s2;
    let sum: f64 = cal
        .intervals
        .iter()
        .map(|i| ((s * i.accel_mean_m_s2 + b).norm() - g).powi(2))
        .sum();
    (sum / cal.intervals.len() as f64).sqrt()
}

#[test]
fn ferraris_session_agrees_with_imucal() {
    let Some((log, sections_path)) = session() else {
        eprintln!("skipped: ../shared/data missing");
        return;
    };
    let sections =
        read_section_list(&sections_path, log.samples.len()).expect("the section list reads");
    let rotations = rotations_from_sections(&sections);
    let cal = calibrate_imu_session(
        &log.samples,
        log.rate_hz,
        Some(rotations),
        &ImuCalibrationOptions::default(),
    )
    .expect("the real session calibrates");
    let peer = imucal();

    // Every face section of the list lies inside one detected still interval.
    for face in ["x_p", "x_a", "y_p", "y_a", "z_p", "z_a"] {
        let (start, end) = sections[face];
        assert!(
            cal.intervals
                .iter()
                .any(|i| i.start <= start && end <= i.end),
            "{face} {start}..{end} not inside a detected still interval"
        );
    }
    // Six faces: the diagonal model (misalignment needs tilted poses too).
    assert_eq!(cal.distinct_poses, 6);
    assert_eq!(cal.accel.model, AccelModel::Diagonal);

    // Gyroscope: same turns, same method; imucal also removes the
    // g-sensitivity K_ga (we do not) and takes the offset from the six
    // face sections only (we use every still interval): 3.9e-5 measured.
    let g = cal.gyro_scale.as_ref().expect("three turns in the list");
    assert!(
        (g.scale - peer.gyro_scale).amax() < 1e-4,
        "{}",
        g.scale - peer.gyro_scale
    );
    assert!((cal.intrinsics.gyro_offset_rad_s - peer.gyro_bias).amax() < 1e-4);

    // Accelerometer: the raw offset o = -S^-1 b and the per-axis scale
    // (imucal's column norms of S, which include its misalignment) agree
    // to 2.3e-3 m/s^2 and 2.1e-4.
    let s = cal.intrinsics.accel_scale;
    let offset = -(s.try_inverse().expect("S invertible") * cal.intrinsics.accel_offset_m_s2);
    assert!(
        (offset - peer.accel_raw_offset).amax() < 5e-3,
        "{}",
        offset - peer.accel_raw_offset
    );
    for k in 0..3 {
        let peer_scale = peer.accel_scale.column(k).norm();
        assert!(
            (s[(k, k)] - peer_scale).abs() < 5e-4,
            "axis {k}: {} vs {peer_scale}",
            s[(k, k)]
        );
    }
    // Gravity magnitude: 0.564 m/s^2 RMS raw; ours fits it (2.6e-3), and
    // imucal's own calibration applied to the same still means is no better.
    assert!(cal.accel.rms_before_m_s2 > 0.5);
    let ours = cal.accel.levenberg_marquardt.rms_m_s2;
    let theirs = rms_after(&cal, &peer.accel_scale, &peer.accel_bias);
    eprintln!(
        "gravity-magnitude RMS: raw {:.4}, rigslam {ours:.4}, imucal {theirs:.4} m/s^2",
        cal.accel.rms_before_m_s2
    );
    assert!(
        ours < 0.005 && ours <= theirs,
        "ours {ours}, imucal {theirs}"
    );
    // The simplex and LM land on the same minimum.
    assert!(cal.accel.scale_agreement < 1e-7 && cal.accel.bias_agreement_m_s2 < 1e-6);
}

#[test]
fn the_turns_are_found_without_the_section_list() {
    let Some((log, sections_path)) = session() else {
        eprintln!("skipped: ../shared/data missing");
        return;
    };
    let sections =
        read_section_list(&sections_path, log.samples.len()).expect("the section list reads");
    let cal = calibrate_imu_session(
        &log.samples,
        log.rate_hz,
        None,
        &ImuCalibrationOptions::default(),
    )
    .expect("the real session calibrates");
    assert_eq!(cal.rotations.len(), 3);
    for r in &cal.rotations {
        let (start, end) = sections[["x_rot", "y_rot", "z_rot"][r.axis]];
        // The found turn runs from still to still: it covers the hand-picked
        // section but for a few samples the list counts into the still.
        let overlap = r.end.min(end).saturating_sub(r.start.max(start));
        assert!(
            overlap as f64 >= 0.98 * (end - start) as f64,
            "axis {}: {}..{} vs {start}..{end}",
            r.axis,
            r.start,
            r.end
        );
    }
    let peer = imucal();
    let g = cal.gyro_scale.as_ref().expect("three turns found");
    assert!(
        (g.scale - peer.gyro_scale).amax() < 5e-4,
        "{}",
        g.scale - peer.gyro_scale
    );
}
