//! `rigslam-calibrate noise` on the real 2.78 h ADIS16405 still log
//! (../shared/data/imu/adis16405_static_100hz_2p78h.csv.gz; gyro deg/s,
//! accel g) against allantools 2024.6's overlapping Allan deviation of the
//! same data at the same cluster sizes (fixtures/allan/adis16405_oadev.json,
//! made by bench/peers/allan_adis16405.sh).

use rigslam_calibration::allan::{cluster_sizes, AllanCurve};
use rigslam_calibration::imu_log::{read_imu_log, AccelUnit, GyroUnit, ImuLogLayout};
use rigslam_calibration::noise_calibration::{calibrate_noise, StillnessLimits};
use rigslam_calibration::noise_fit::fit_axis;

#[test]
fn allan_deviation_matches_allantools_on_the_real_log() {
    let Some(dir) = rigslam::shared_data::shared_data_dir() else {
        eprintln!("skipped: ../shared/data missing");
        return;
    };
    let layout = ImuLogLayout {
        columns: ImuLogLayout::parse_columns("gx,gy,gz,ax,ay,az").expect("valid"),
        gyro_unit: GyroUnit::DegPerS,
        accel_unit: AccelUnit::G,
        rate_hz: Some(100.0),
        header: true,
    };
    let log = read_imu_log(
        &dir.join("imu/adis16405_static_100hz_2p78h.csv.gz"),
        &layout,
    )
    .expect("the real log reads");
    assert_eq!(log.samples.len(), 1_000_000);
    let cal = calibrate_noise(&log.samples, log.rate_hz, 10, &StillnessLimits::default())
        .expect("a still log");

    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../fixtures/allan/adis16405_oadev.json"
    );
    let peer: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(path).expect("the allantools fixture is in the repository"),
    )
    .expect("valid JSON");
    let peer_tau: Vec<f64> = peer["tau_s"]
        .as_array()
        .expect("taus")
        .iter()
        .map(|v| v.as_f64().expect("number"))
        .collect();
    // Same cluster sizes by construction (the peer script uses our rule).
    let ours_m = cluster_sizes(log.samples.len(), 10);
    assert_eq!(peer_tau.len(), ours_m.len());
    let mut worst: f64 = 0.0;
    for axis in 0..6 {
        let peer_adev: Vec<f64> = peer["adev"][axis]
            .as_array()
            .expect("adev")
            .iter()
            .map(|v| v.as_f64().expect("number"))
            .collect();
        let ours = &cal.curves[axis];
        for i in 0..peer_tau.len() {
            assert!((ours.tau_s[i] - peer_tau[i]).abs() < 1e-12);
            worst = worst.max((ours.adev[i] / peer_adev[i] - 1.0).abs());
        }
        // The same fit on allantools' curve gives the same numbers.
        let on_peer = fit_axis(&AllanCurve {
            tau_s: peer_tau.clone(),
            adev: peer_adev,
        });
        let a = &cal.axes[axis];
        assert!((on_peer.white_noise_density / a.white_noise_density - 1.0).abs() < 1e-6);
        assert!((on_peer.random_walk / a.random_walk - 1.0).abs() < 1e-6);
    }
    eprintln!("largest relative difference from allantools: {worst:.2e}");
    assert!(worst < 1e-9, "{worst}");
    // The gyro white noise of all three axes lies on a clean -1/2 line.
    for a in &cal.axes[..3] {
        assert!(a.white_points >= 10, "{a:?}");
    }
}
