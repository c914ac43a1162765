//! The relative stage on sequences rendered from the real V1_02 flight
//! (its Vicon trajectory, its real ADIS16448 IMU): a start at rest and a
//! start in full flight must both initialise, and damaged input (black
//! and frozen frames, IMU gaps, repeated and reordered stamps, a camera
//! that starts before the IMU) must never give NaN or an unannounced jump.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use rigslam::dataset::{
    open_dataset, read_euroc_groundtruth, write_euroc_groundtruth, Dataset, SensorEvent,
    SensorStream, StreamOptions,
};
use rigslam::relative::{
    build_estimator, EstimatorKind, FrameInput, FullWindowAlignment, RelativeConfig, SensorMode,
    TrackingState,
};
use rigslam::run::dataset_run::{rig_of, run_dataset, DatasetRun};
use rigslam::sensors::Image;
use rigslam::simulate::{simulate, ImuSource, SimConfig};

fn v1_02() -> Option<(PathBuf, PathBuf)> {
    let dir = rigslam::shared_data::path_or_skip("euroc/ground_truth")?;
    Some((
        dir.join("V1_02_groundtruth.csv"),
        dir.join("V1_02_imu0.csv"),
    ))
}

/// Renders `seconds` of V1_02 starting `skip_s` into the flight.
fn render(out: &Path, skip_s: f64, seconds: f64) -> Option<()> {
    let (gt, imu) = v1_02()?;
    let trajectory = if skip_s > 0.0 {
        let states = read_euroc_groundtruth(&gt).expect("ground truth");
        let t0 = states[0].t_ns + (skip_s * 1e9) as i64;
        let cut: Vec<_> = states.into_iter().filter(|s| s.t_ns >= t0).collect();
        let path = out.with_extension("gt.csv");
        write_euroc_groundtruth(&path, &cut).expect("write");
        path
    } else {
        gt
    };
    let config = SimConfig {
        trajectory: Some(trajectory),
        duration_s: Some(seconds),
        imu: ImuSource::Real(imu),
        stereo: true,
        seed: 7,
        show_progress: false,
        ..SimConfig::default()
    };
    simulate(&config, out).expect("render");
    Some(())
}

/// Both images and the IMU of the whole of `dataset`, in time order.
fn stereo_imu_stream(dataset: &Dataset) -> SensorStream<'_> {
    SensorStream::new(
        dataset,
        StreamOptions {
            stereo: true,
            imu: true,
            start_ns: None,
            max_frames: None,
            imu_lead_ns: 0,
        },
    )
    .expect("stream")
}

fn ate_and_init(dir: &Path, mode: SensorMode) -> (f64, f64, u64, serde_json::Value) {
    let run = DatasetRun {
        mode: Some(mode),
        ..DatasetRun::default()
    };
    let result = run_dataset(dir, &run, |_, _| {}).expect("run");
    let report = serde_json::to_value(&result.report).expect("json");
    let eval = result.report.eval.as_ref().expect("ground truth");
    let init = result.report.initialized_at_s.expect("initialised");
    eprintln!(
        "{mode}: ATE {:.3} m, initialised at {init:.2} s",
        eval.ate_rmse_m
    );
    (eval.ate_rmse_m, init, result.report.lost_count, report)
}

#[test]
fn a_start_at_rest_uses_the_static_start() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("rest");
    if render(&dir, 0.0, 12.0).is_none() {
        return;
    }
    for (mode, bar_m) in [
        // Measured 0.008 m and 0.056 m (2026-11-23); bars about twice that.
        // Along the spline through the ground truth: 0.009 m and 0.038 m;
        // with the IMU noise measured against it: 0.007 m and 0.031 m.
        (SensorMode::StereoInertial, 0.02),
        (SensorMode::MonoInertial, 0.10),
    ] {
        let (ate, init, lost, report) = ate_and_init(&dir, mode);
        assert!(init < 0.6, "{mode}: initialised at {init} s");
        assert!(
            report["counters"]["static_frames"].as_u64().unwrap_or(0) > 10,
            "{mode}: {report}"
        );
        assert_eq!(lost, 0, "{mode}");
        assert!(ate < bar_m, "{mode}: ATE {ate} m over 12 s (bar {bar_m})");
    }
}

#[test]
fn a_start_in_full_flight_is_not_taken_for_rest() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("flight");
    // 25 s into V1_02 the MAV flies at 0.85 m/s.
    if render(&dir, 25.0, 12.0).is_none() {
        return;
    }
    for (mode, init_bar_s, ate_bar_m) in [
        // Measured: 1.55 s / 0.017 m and 1.60 s / 0.025 m (2026-11-23);
        // along the spline through the ground truth 1.60 s / 0.012 m and
        // 1.60 s / 0.018 m; with the IMU noise measured against it
        // 1.60 s / 0.006 m and 1.60 s / 0.008 m.
        (SensorMode::StereoInertial, 3.0, 0.04),
        (SensorMode::MonoInertial, 3.0, 0.06),
    ] {
        let (ate, init, lost, report) = ate_and_init(&dir, mode);
        assert_eq!(
            report["counters"]["static_frames"].as_u64(),
            Some(0),
            "{mode}: a flight taken for rest"
        );
        assert!(init <= init_bar_s, "{mode}: initialised at {init} s");
        assert_eq!(lost, 0, "{mode}");
        assert!(ate < ate_bar_m, "{mode}: ATE {ate} m (bar {ate_bar_m})");
    }
}

#[test]
fn a_start_in_flight_aligns_on_a_full_window_whatever_it_spans() {
    // By default stereo-inertial waits for a full window before the
    // alignment; switched off, it tries as soon as `init_keyframes` span
    // `init_min_span_s` (0 here, so that the span does not decide). Then a
    // span the window can never reach (10 keyframes in fast flight span
    // 1-2 s), with every mode waiting for the full window: the stage used
    // to wait for the span forever, tracking by vision alone and
    // publishing nothing.
    // Measured with the full window taken: 1.5 s stereo-inertial, 4.7 s
    // mono-inertial (whose scale must also be certain).
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("flight");
    if render(&dir, 25.0, 8.0).is_none() {
        return;
    }
    let window = RelativeConfig::default().window_keyframes as u64;
    let run_with = |mode: SensorMode, full: FullWindowAlignment, span_s: Option<f64>| {
        let mut run = DatasetRun {
            mode: Some(mode),
            ..DatasetRun::default()
        };
        run.settings.relative.init_full_window = full;
        if let Some(span_s) = span_s {
            run.settings.relative.init_min_span_s = span_s;
        }
        let result = run_dataset(&dir, &run, |_, _| {}).expect("run");
        let report = serde_json::to_value(&result.report).expect("json");
        let keyframes = report["counters"]["alignment_keyframes"].as_u64();
        let links = report["counters"]["alignment_links"].as_u64();
        let tried = report["counters"]["alignments_tried"].as_u64();
        let init = result.report.initialized_at_s;
        let ate = result.report.eval.as_ref().map(|e| e.ate_rmse_m);
        eprintln!(
            "{mode} {full:?} span {span_s:?}: initialised at {init:?} s on {keyframes:?} \
             keyframes ({links:?} inertial links) after {tried:?} tries, ATE {ate:?} m"
        );
        // With one camera the keyframes gathered by vision alone are
        // linked by the IMU as soon as the alignment switches the inertial
        // terms on; a stereo window links them as it replaces them.
        let expected = match mode {
            SensorMode::MonoInertial => keyframes.map(|k| k - 1),
            _ => keyframes.map(|_| 0),
        };
        assert_eq!(links, expected, "{mode}: intervals linked at the alignment");
        (init, keyframes, ate, tried)
    };
    let stereo = SensorMode::StereoInertial;
    let (_, keyframes, _, tried_full) = run_with(stereo, FullWindowAlignment::Auto, Some(0.0));
    assert_eq!(keyframes, Some(window), "by default stereo-inertial waits");
    // Switched off it tries from `init_keyframes` on (here those tries
    // fail until the window is full, and the same alignment follows).
    let (_, _, _, tried_early) = run_with(stereo, FullWindowAlignment::Off, Some(0.0));
    let early = RelativeConfig::default().init_keyframes as u64;
    assert!(
        tried_early.unwrap_or(0) >= tried_full.unwrap_or(u64::MAX) + (window - early),
        "switched off it tries before the window is full: {tried_early:?} against {tried_full:?}"
    );
    for mode in [SensorMode::StereoInertial, SensorMode::MonoInertial] {
        let (init, keyframes, ate, _) = run_with(mode, FullWindowAlignment::On, Some(60.0));
        assert!(
            init.is_some_and(|s| s < 6.0),
            "{mode}: initialised at {init:?} s"
        );
        assert_eq!(keyframes, Some(window), "{mode}");
        assert!(ate.is_some_and(|a| a < 0.1), "{mode}: ATE {ate:?} m");
    }
}

/// Feeds a rendered flight with damage and checks every answer.
#[test]
fn damaged_input_never_gives_nan_or_an_unannounced_jump() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("damage");
    if render(&dir, 25.0, 8.0).is_none() {
        return;
    }
    let dataset = open_dataset(&dir).expect("open");
    let rig = rig_of(&dataset);
    for mode in [SensorMode::StereoInertial, SensorMode::MonoInertial] {
        // Black frames lose every track: stereo re-triangulates at once,
        // mono-inertial rebuilds its map from IMU-carried keyframes.
        let black_frames = 60..65;
        let mut estimator = build_estimator(
            EstimatorKind::Window,
            mode,
            &rig,
            &RelativeConfig::default(),
        )
        .expect("estimator");
        let stream = stereo_imu_stream(&dataset);
        let events: Vec<SensorEvent> = stream.map(|e| e.expect("event")).collect();
        let first_frame_ns = events
            .iter()
            .find_map(|e| match e {
                SensorEvent::Frame { t_ns, .. } => Some(*t_ns),
                _ => None,
            })
            .expect("frames");
        let (w, h) = (rig.cameras[0].model.width(), rig.cameras[0].model.height());
        let black = Image::mono8(w, h, vec![0; (w * h) as usize]).expect("image");
        let mut frame_index = 0usize;
        let mut last_frame: Option<Image> = None;
        let mut previous: Option<(i64, nalgebra::Vector3<f64>, TrackingState)> = None;
        let mut previous_tracked: Option<(i64, nalgebra::UnitQuaternion<f64>)> = None;
        let mut outputs = 0;
        for event in &events {
            match event {
                SensorEvent::Imu(s) => {
                    let t = s.t_ns - first_frame_ns;
                    // The camera starts 0.3 s before the IMU; a 0.2 s IMU
                    // gap at 4 s; a NaN sample; a repeated sample.
                    if t < 300_000_000 || (4_000_000_000..4_200_000_000).contains(&t) {
                        continue;
                    }
                    let mut s = *s;
                    if (5_000_000_000..5_005_000_000).contains(&t) {
                        s.gyro_rad_s[0] = f64::NAN;
                    }
                    estimator.push_imu(&s);
                    if (5_500_000_000..5_505_000_000).contains(&t) {
                        estimator.push_imu(&s);
                    }
                }
                SensorEvent::Frame { t_ns, left, right } => {
                    frame_index += 1;
                    // Frames 60-64 black, 90-93 frozen (the previous image again).
                    let image = if black_frames.contains(&frame_index) {
                        black.clone()
                    } else if (90..94).contains(&frame_index) {
                        last_frame.clone().expect("a frame before")
                    } else {
                        left.image.clone()
                    };
                    let right_image = if mode == SensorMode::StereoInertial {
                        Some(if black_frames.contains(&frame_index) {
                            &black
                        } else {
                            &right.as_ref().expect("stereo").image
                        })
                    } else {
                        None
                    };
                    let input = FrameInput {
                        t_ns: *t_ns,
                        left: &image,
                        right: right_image,
                    };
                    let out = estimator.push_frame(&input);
                    // A repeated stamp right after: answered, not used.
                    if frame_index == 120 {
                        let again = estimator.push_frame(&input);
                        assert_eq!(again.t_ns, out.t_ns);
                    }
                    outputs += 1;
                    let p = out.T_world_body.translation.vector;
                    if std::env::var_os("RIGSLAM_TEST_TRACE").is_some() {
                        eprintln!(
                            "{mode} {frame_index} {:?} {:.3} {:.3} {:.3} {:?}",
                            out.state,
                            p.x,
                            p.y,
                            p.z,
                            estimator.counters()
                        );
                    }
                    assert!(
                        p.iter().all(|v| v.is_finite())
                            && out
                                .T_world_body
                                .rotation
                                .coords
                                .iter()
                                .all(|v| v.is_finite())
                            && out.velocity_world_m_s.iter().all(|v| v.is_finite()),
                        "{mode}: non-finite output at frame {frame_index}"
                    );
                    for l in &out.landmarks {
                        assert!(l.position_body_m.iter().all(|v| v.is_finite()));
                        assert!(l.covariance_body_m2.iter().all(|v| v.is_finite()));
                    }
                    if let Some((t_prev, p_prev, s_prev)) = previous {
                        if s_prev == TrackingState::Tracking && out.state == TrackingState::Tracking
                        {
                            let dt = (*t_ns - t_prev) as f64 * 1e-9;
                            let speed = (p - p_prev).norm() / dt;
                            // V1_02 flies at most about 1.5 m/s.
                            assert!(
                                speed < 4.0,
                                "{mode}: jumped {:.3} m in {dt:.3} s at frame {frame_index} without saying so",
                                (p - p_prev).norm()
                            );
                        }
                    }
                    if out.state == TrackingState::Tracking {
                        // Nor a turn: across a loss too (a rest found
                        // after it keeps the heading), V1_02 turns at
                        // most about 100 deg/s.
                        if let Some((t_prev, q_prev)) = previous_tracked {
                            let dt = (*t_ns - t_prev) as f64 * 1e-9;
                            let rate =
                                q_prev.angle_to(&out.T_world_body.rotation).to_degrees() / dt;
                            assert!(
                                rate < 400.0,
                                "{mode}: turned at {rate:.0} deg/s at frame {frame_index}"
                            );
                        }
                        previous_tracked = Some((*t_ns, out.T_world_body.rotation));
                    }
                    previous = Some((*t_ns, p, out.state));
                    last_frame = Some(image);
                }
            }
        }
        assert!(outputs > 150);
        // A frame stamped before the last one: the last answer again.
        let stale = estimator.push_frame(&FrameInput {
            t_ns: first_frame_ns,
            left: &black,
            right: None,
        });
        assert!(stale.t_ns > first_frame_ns);
        let counters: std::collections::HashMap<_, _> = estimator.counters().into_iter().collect();
        assert!(counters["frames_out_of_order"] >= 2, "{counters:?}");
        assert!(counters["imu_samples_dropped"] >= 2, "{counters:?}");
        // Tracking at the end despite everything.
        assert_eq!(
            previous.expect("frames").2,
            TrackingState::Tracking,
            "{mode}"
        );
    }
}

/// The EKF baseline flying on the IMU alone (every frame black from 7 s
/// on, in motion) must say it is lost within `imu_only_max_s`, not keep
/// reporting a drifting pose as tracked (it once output 260 m that way).
/// Frames missing for 2.5 s in flight (longer than the IMU may carry the
/// state): the stage loses track, restarts from vision and aligns again.
/// The new start is placed where the IMU carries the last trusted state,
/// so the trajectory goes on instead of jumping back to the origin.
/// Measured 2026-11-26: moved 1.71 / 1.75 m across the loss where the
/// truth moved 1.59 / 1.75 m (stereo- / mono-inertial; the spans differ).
/// Without the placement the restart began at the origin and the check
/// fails; on the development rendering with the same loss at 30 s, ATE
/// 2.51 -> 0.44 m and 1.78 -> 0.37 m (bench/accuracy/README.md).
#[test]
fn a_loss_in_flight_continues_the_trajectory() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("loss");
    if render(&dir, 25.0, 14.0).is_none() {
        return;
    }
    let truth = rigslam::dataset::read_euroc_trajectory(
        &dir.join("mav0/state_groundtruth_estimate0/data.csv"),
    )
    .expect("ground truth");
    let dataset = open_dataset(&dir).expect("open");
    let rig = rig_of(&dataset);
    let events: Vec<SensorEvent> = stereo_imu_stream(&dataset)
        .map(|e| e.expect("event"))
        .collect();
    let first_frame_ns = events
        .iter()
        .find_map(|e| match e {
            SensorEvent::Frame { t_ns, .. } => Some(*t_ns),
            _ => None,
        })
        .expect("frames");
    let gap = (
        first_frame_ns + 5_000_000_000,
        first_frame_ns + 7_500_000_000,
    );
    for mode in [SensorMode::StereoInertial, SensorMode::MonoInertial] {
        let mut estimator = build_estimator(
            EstimatorKind::Window,
            mode,
            &rig,
            &RelativeConfig::default(),
        )
        .expect("estimator");
        let mut tracked: Vec<(i64, nalgebra::Isometry3<f64>)> = Vec::new();
        for event in &events {
            match event {
                SensorEvent::Imu(s) => estimator.push_imu(s),
                SensorEvent::Frame { t_ns, left, right } => {
                    if (gap.0..gap.1).contains(t_ns) {
                        continue;
                    }
                    let out = estimator.push_frame(&FrameInput {
                        t_ns: *t_ns,
                        left: &left.image,
                        right: (mode == SensorMode::StereoInertial)
                            .then(|| &right.as_ref().expect("stereo").image),
                    });
                    if out.state == TrackingState::Tracking {
                        tracked.push((out.t_ns, out.T_world_body));
                    }
                }
            }
        }
        let counters: std::collections::HashMap<_, _> = estimator.counters().into_iter().collect();
        assert!(counters["resets"] >= 1, "{mode}: {counters:?}");
        assert!(counters["resumed"] >= 1, "{mode}: {counters:?}");
        let before = *tracked.iter().rfind(|p| p.0 < gap.0).expect("before");
        let after = *tracked.iter().find(|p| p.0 >= gap.1).expect("after");
        let at =
            |t: i64| rigslam::eval::consistency::interpolate(&truth, t).expect("inside the truth");
        let moved = (after.1.translation.vector - before.1.translation.vector).norm();
        let truly = (at(after.0).translation.vector - at(before.0).translation.vector).norm();
        // The turn across the loss, in the body frame before it (the same
        // in any world): the estimate's against the truth's.
        let turned = before.1.rotation.inverse() * after.1.rotation;
        let truly_turned = at(before.0).rotation.inverse() * at(after.0).rotation;
        let turn_error_deg = turned.angle_to(&truly_turned).to_degrees();
        eprintln!(
            "{mode}: moved {moved:.3} m across the loss ({:.2} s), the truth {truly:.3} m; turned {:.1} deg, {turn_error_deg:.2} deg off the truth",
            (after.0 - before.0) as f64 * 1e-9,
            truly_turned.angle().to_degrees()
        );
        assert!(
            (moved - truly).abs() < 0.5,
            "{mode}: moved {moved} m, the truth {truly} m"
        );
        // Measured 1.3 / 1.1 deg (stereo-inertial / mono-inertial); with
        // the heading read from where the body's x axis points (near
        // vertical on EuRoC's IMU) 3.4 / 3.1 deg.
        assert!(
            turn_error_deg < 2.5,
            "{mode}: turned {turn_error_deg} deg off the truth across the loss"
        );
    }
}

#[test]
fn the_ekf_on_the_imu_alone_in_motion_reports_lost() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("ekf_blind");
    if render(&dir, 0.0, 12.0).is_none() {
        return;
    }
    let dataset = open_dataset(&dir).expect("open");
    let rig = rig_of(&dataset);
    let config = RelativeConfig::default();
    let mut estimator = build_estimator(
        EstimatorKind::Ekf,
        SensorMode::StereoInertial,
        &rig,
        &config,
    )
    .expect("estimator");
    let stream = stereo_imu_stream(&dataset);
    let (w, h) = (rig.cameras[0].model.width(), rig.cameras[0].model.height());
    let black = Image::mono8(w, h, vec![0; (w * h) as usize]).expect("image");
    let blind_from = 140;
    let mut states = Vec::new();
    for event in stream {
        match event.expect("event") {
            SensorEvent::Imu(s) => estimator.push_imu(&s),
            SensorEvent::Frame { t_ns, left, right } => {
                let blind = states.len() >= blind_from;
                let right = right.expect("stereo");
                let out = estimator.push_frame(&FrameInput {
                    t_ns,
                    left: if blind { &black } else { &left.image },
                    right: Some(if blind { &black } else { &right.image }),
                });
                states.push(out.state);
            }
        }
    }
    assert_eq!(states[blind_from - 1], TrackingState::Tracking);
    let frames_allowed = (config.imu_only_max_s * 20.0).ceil() as usize + 2;
    let lost_at = states[blind_from..]
        .iter()
        .position(|s| *s == TrackingState::Lost)
        .expect("never said it was lost");
    assert!(
        lost_at <= frames_allowed,
        "lost only {lost_at} frames later"
    );
    // In flight there is no rest to restart from: never tracking again.
    assert!(
        states[blind_from + lost_at..]
            .iter()
            .all(|s| *s != TrackingState::Tracking),
        "{:?}",
        &states[blind_from..]
    );
}

/// A user's calibration: V1_02's real IMU declared with its datasheet
/// noise (ten times too quiet for its accelerometer against the motion,
/// four times for its gyroscope). Rendered with the poses interpolated
/// from the ground truth (no spline), 30 s from rest. Weighed as
/// declared, the IMU pulls stereo-inertial off; with the online noise
/// estimate the scales land near what the ground truth reveals (the
/// agreement measured against it: accelerometer 9.5x, gyroscope 4.5x)
/// and the error drops. Measured 2026-11-26: 0.0244 m as declared,
/// 0.0199 m adapted (gyro 6.2x, accel 6.5x, pixel 0.23x); on this short
/// sequence the gain is smaller than on the 83 s renderings
/// (bench/accuracy/README.md: 0.057 -> 0.019 m).
#[test]
fn datasheet_noise_is_corrected_online() {
    let Some((gt, imu)) = v1_02() else {
        return;
    };
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("datasheet");
    let config = SimConfig {
        trajectory: Some(gt),
        duration_s: Some(30.0),
        imu: ImuSource::Real(imu),
        stereo: true,
        seed: 11,
        interpolate_poses: true,
        declare_measured_noise: false,
        show_progress: false,
        ..SimConfig::default()
    };
    simulate(&config, &dir).expect("render");
    let run = |adapt: bool| {
        let run = DatasetRun {
            mode: Some(SensorMode::StereoInertial),
            // The noise adaptation alone: the camera-IMU refinement
            // (on by default in stereo-inertial) changes what the
            // inertial residuals show. With it on, this sequence gave
            // ATE 0.0164 m but NEES 5.1 per dof (bench/README.md).
            settings: rigslam::slam_config::SlamSettings {
                relative: RelativeConfig {
                    imu_noise_adaptation: adapt,
                    camera_imu_refinement: rigslam::relative::CameraImuRefinement::Off,
                    ..RelativeConfig::default()
                },
                ..Default::default()
            },
            ..DatasetRun::default()
        };
        let result = run_dataset(&dir, &run, |_, _| {}).expect("run");
        let ate = result
            .report
            .eval
            .as_ref()
            .expect("ground truth")
            .ate_rmse_m;
        let scale = result.report.imu_noise_scale.expect("an IMU");
        let nees = result.report.nees.clone();
        eprintln!("adaptation {adapt}: ATE {ate:.4} m, scale {scale:?}, NEES {nees:?}");
        (ate, scale, nees)
    };
    let (ate_declared, declared, nees_declared) = run(false);
    let (ate_adapted, adapted, nees) = run(true);
    assert_eq!(declared.accel, 1.0);
    assert!(
        (2.0..30.0).contains(&adapted.accel) && (1.5..15.0).contains(&adapted.gyro),
        "{adapted:?}"
    );
    assert!(adapted.pixel < 0.6, "{adapted:?}");
    assert!(
        ate_adapted < 0.9 * ate_declared,
        "adapted {ate_adapted} m vs declared {ate_declared} m"
    );
    // The published covariance against the truth: a consistent one scores
    // 1 per degree of freedom. Measured 2026-11-26: 9.5 with the declared
    // noise, 3.1 with the estimated one; 2026-12-02, with the propagated
    // covariance and its pixel sigma floored at the declared one
    // (docs/results/pose-covariance-2026-12-02.md): 10.0 and 1.24, inside
    // the target of 0.5-2; 2026-12-07, the floor at half the declared
    // sigma (docs/results/covariance-pixel-floor-2026-12-07.md): 2.51 and
    // 0.77.
    let nees = nees.expect("a covariance on the tracked frames");
    let nees_declared = nees_declared.expect("a covariance on the tracked frames");
    assert!(nees.poses > 500 && nees.origins == 1, "{nees:?}");
    assert!((0.5..2.0).contains(&nees.mean_per_dof), "{nees:?}");
    assert!(
        nees.mean_per_dof < 0.5 * nees_declared.mean_per_dof,
        "{nees:?} vs declared {nees_declared:?}"
    );
}

/// Both stages in stereo-inertial on `rig` with `settings`.
fn two_stages(
    rig: &rigslam::rig::RigModel,
    settings: &rigslam::slam_config::SlamSettings,
) -> rigslam::slam_pipeline::SlamPipeline {
    rigslam::slam_pipeline::SlamPipeline::new(
        EstimatorKind::Window,
        SensorMode::StereoInertial,
        rig,
        settings,
        rigslam::slam_pipeline::SecondStage::BuildMap,
    )
    .expect("pipeline")
}

/// Whether the map-frame pose of `answer` is the relative pose (the
/// second stage has not corrected it).
fn passes_through(answer: &rigslam::slam_pipeline::PipelineFrame) -> bool {
    let corrected = answer.corrected.as_ref().expect("the absolute stage runs");
    (corrected.T_world_body.translation.vector - answer.relative.T_world_body.translation.vector)
        .norm()
        < 1e-12
}

/// After a start in flight the relative stage says it is settling until
/// every keyframe the alignment placed has left its window, and the
/// pipeline's absolute stage starts its map only then: until that frame
/// the map-frame pose is the relative pose, with no filter covariance.
#[test]
fn the_map_waits_for_a_start_in_flight_to_settle() {
    use rigslam::slam_config::SlamSettings;
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("flight");
    if render(&dir, 25.0, 8.0).is_none() {
        return;
    }
    let dataset = open_dataset(&dir).expect("open");
    let rig = rig_of(&dataset);
    let mut settings = SlamSettings::default();
    settings.absolute.enabled = true;
    let mut pipeline = two_stages(&rig, &settings);
    // (stamp, tracking, settling, map-frame pose == relative pose, filter
    // covariance, accelerometer bias sigma)
    let mut frames: Vec<(i64, bool, bool, bool, bool, f64)> = Vec::new();
    for event in stereo_imu_stream(&dataset) {
        match event.expect("event") {
            SensorEvent::Imu(s) => pipeline.push_imu(&s),
            SensorEvent::Frame { t_ns, left, right } => {
                let input = FrameInput {
                    t_ns,
                    left: &left.image,
                    right: right.as_ref().map(|r| &r.image),
                };
                let answer = pipeline.push_frame(&input);
                let settling = pipeline.relative().settling();
                let same = passes_through(&answer);
                let corrected = answer.corrected.expect("the absolute stage runs");
                frames.push((
                    t_ns,
                    answer.relative.state == TrackingState::Tracking,
                    settling,
                    same,
                    corrected.position_covariance_m2.is_some(),
                    pipeline
                        .relative()
                        .accel_bias_sigma_m_s2()
                        .unwrap_or(f64::INFINITY),
                ));
            }
        }
    }
    let first_tracking = frames
        .iter()
        .position(|f| f.1)
        .expect("the flight start initialises");
    assert!(
        frames[first_tracking].2,
        "settling on the first tracking frame"
    );
    let settled = first_tracking
        + frames[first_tracking..]
            .iter()
            .position(|f| !f.2)
            .expect("the start settles within the 8 s");
    let settle_s = (frames[settled].0 - frames[first_tracking].0) as f64 * 1e-9;
    eprintln!("settled {settle_s:.2} s after the first tracking frame");
    // Ten keyframes: between a second and a few at this speed.
    assert!(
        (0.5..5.0).contains(&settle_s),
        "settled {settle_s} s after tracking began"
    );
    assert!(
        frames[settled..].iter().all(|f| !f.2),
        "settling again after it settled"
    );
    for f in &frames[..settled] {
        assert!(f.3 && !f.4, "the map started while settling: {f:?}");
    }
    // The map also waits for the accelerometer bias to be known (see the
    // start from rest below): it starts promptly once both hold.
    let wait = settings.absolute.wait_accel_bias_sigma_m_s2;
    let ready = settled
        + frames[settled..]
            .iter()
            .position(|f| f.5 <= wait)
            .expect("the bias becomes known");
    eprintln!(
        "bias known to {wait} m/s^2 {:.2} s after settling",
        (frames[ready].0 - frames[settled].0) as f64 * 1e-9
    );
    let anchored = frames[ready..]
        .iter()
        .position(|f| f.4)
        .expect("the map starts once settled");
    assert!(
        anchored < 20,
        "the map started {anchored} frames after settling with the bias known"
    );
}

/// After a start from rest the accelerometer bias is not told from tilt
/// until the rig turns: the relative stage reports its bias sigma, and the
/// pipeline's absolute stage takes no landmarks while it is above
/// `wait_accel_bias_sigma_m_s2` (the map-frame pose is the relative pose,
/// with no filter covariance), then starts its map. Without the wait the
/// map starts earlier, on the first frames of the motion.
#[test]
fn the_map_waits_for_the_accelerometer_bias_after_a_start_from_rest() {
    use rigslam::slam_config::SlamSettings;
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("rest");
    if render(&dir, 0.0, 12.0).is_none() {
        return;
    }
    let dataset = open_dataset(&dir).expect("open");
    let rig = rig_of(&dataset);
    let mut settings = SlamSettings::default();
    settings.absolute.enabled = true;
    let wait = settings.absolute.wait_accel_bias_sigma_m_s2;
    assert!(wait > 0.0, "the wait is on by default");
    let mut no_wait = settings.clone();
    no_wait.absolute.wait_accel_bias_sigma_m_s2 = 0.0;
    let build = |settings: &SlamSettings| two_stages(&rig, settings);
    // A wait limited to half a second (10 frames) ends before the bias
    // is known.
    let mut capped_settings = settings.clone();
    capped_settings.absolute.wait_accel_bias_max_s = 0.5;
    let (mut waiting, mut eager) = (build(&settings), build(&no_wait));
    let mut capped = build(&capped_settings);
    // (waiting, map started) per frame of the capped pipeline.
    let mut capped_frames: Vec<(bool, bool)> = Vec::new();
    // (tracking, bias sigma, waiting, map-frame pose == relative pose,
    // filter covariance, traces of the relative and map-frame position
    // covariances)
    let mut frames: Vec<(bool, f64, bool, bool, bool, f64, f64)> = Vec::new();
    let mut eager_anchored = None;
    for event in stereo_imu_stream(&dataset) {
        match event.expect("event") {
            SensorEvent::Imu(s) => {
                waiting.push_imu(&s);
                eager.push_imu(&s);
                capped.push_imu(&s);
            }
            SensorEvent::Frame { t_ns, left, right } => {
                let input = FrameInput {
                    t_ns,
                    left: &left.image,
                    right: right.as_ref().map(|r| &r.image),
                };
                let answer = waiting.push_frame(&input);
                waiting.finish_frame();
                let same = passes_through(&answer);
                let corrected = answer.corrected.expect("the absolute stage runs");
                frames.push((
                    answer.relative.state == TrackingState::Tracking,
                    // None only before the first frame is placed.
                    waiting
                        .relative()
                        .accel_bias_sigma_m_s2()
                        .unwrap_or(f64::NAN),
                    waiting.second_stage_waiting(),
                    same,
                    corrected.position_covariance_m2.is_some(),
                    answer
                        .relative
                        .pose_covariance
                        .map_or(0.0, |c| c.matrix.fixed_view::<3, 3>(0, 0).trace()),
                    corrected.position_covariance_m2.map_or(0.0, |c| c.trace()),
                ));
                let short = capped.push_frame(&input);
                capped.finish_frame();
                capped_frames.push((
                    capped.second_stage_waiting(),
                    short
                        .corrected
                        .is_some_and(|c| c.position_covariance_m2.is_some()),
                ));
                let other = eager.push_frame(&input);
                eager.finish_frame();
                if eager_anchored.is_none()
                    && other
                        .corrected
                        .is_some_and(|c| c.position_covariance_m2.is_some())
                {
                    eager_anchored = Some(frames.len() - 1);
                }
            }
        }
    }
    // At rest the pose is held and no sigma is reported; the first
    // frames of the motion do not know the bias yet, and the map waits.
    let moving = frames
        .iter()
        .position(|f| f.0 && !f.1.is_nan())
        .expect("the rig moves");
    assert!(
        frames[moving].1 > wait && frames[moving].2,
        "leaving rest the bias is not known and the map waits: {:?}",
        frames[moving]
    );
    let known = frames
        .iter()
        .position(|f| f.1 <= wait)
        .expect("the bias becomes known within the 12 s");
    eprintln!(
        "bias known to {wait} m/s^2 at frame {known} ({:.1} s); without the wait the map started at frame {eager_anchored:?}",
        known as f64 / 20.0
    );
    for f in frames.iter().filter(|f| !(f.1 <= wait)) {
        assert!(
            (f.2 || f.1.is_nan()) && f.3 && !f.4,
            "the map started before the bias was known: {f:?}"
        );
    }
    let anchored = frames[known..]
        .iter()
        .position(|f| f.4)
        .expect("the map starts once the bias is known")
        + known;
    assert!(
        anchored - known < 20,
        "the map started {} frames after the bias was known",
        anchored - known
    );
    // The map is anchored where the relative stage had drifted to by
    // then: the published map-frame covariance carries that uncertainty
    // (the relative stage's own) instead of starting from nothing.
    let (relative_trace, map_trace) = (frames[anchored].5, frames[anchored].6);
    eprintln!(
        "at the anchor: relative position variance {relative_trace:.2e} m^2, map-frame {map_trace:.2e} m^2"
    );
    assert!(
        relative_trace > 1e-7 && map_trace >= 0.5 * relative_trace,
        "anchored with {map_trace:.2e} m^2 where the relative stage had {relative_trace:.2e}"
    );
    let eager_anchored = eager_anchored.expect("the map starts without the wait");
    assert!(
        eager_anchored < known,
        "without the wait the map starts at frame {eager_anchored}, before the bias is known at {known}"
    );
    assert_eq!(
        waiting.bias_waits_given_up(),
        0,
        "the default wait ended by itself"
    );
    // The limited wait gives up after its 0.5 s (10 frames at 20 Hz), says
    // so, and the map starts then, before the bias is known.
    let capped_wait = capped_frames
        .iter()
        .position(|f| f.0)
        .expect("the capped pipeline waits too");
    let capped_anchored = capped_frames
        .iter()
        .position(|f| f.1)
        .expect("the capped map starts");
    eprintln!("limited to 0.5 s: waited from frame {capped_wait}, mapped from {capped_anchored}");
    assert_eq!(capped.bias_waits_given_up(), 1);
    assert!(
        (10..=13).contains(&(capped_anchored - capped_wait)) && capped_anchored < known,
        "the limited wait started at frame {capped_wait} and the map at {capped_anchored} (bias known at {known})"
    );
    assert!(
        capped_frames[capped_anchored..].iter().all(|f| !f.0),
        "once given up, the wait does not come back while the bias is still unknown"
    );
}

/// A pose of the lap `bench/soak/lap_trajectory.py` drives (its defaults)
/// at lap fraction `u`: body position and orientation in the world, z up,
/// the cameras (body z) looking along the direction of travel's side.
fn lap_pose(u: f64) -> Isometry3<f64> {
    let a = 2.0 * std::f64::consts::PI * u;
    let position = Vector3::new(-1.2 * a.cos(), a.sin(), 1.3 + 0.15 * (2.0 * a).sin());
    let (yaw, pitch, roll) = (
        0.9 * a.sin(),
        0.12 * (2.0 * a).sin(),
        0.06 * (3.0 * a).sin(),
    );
    // Body axes in the forward frame (x forward, z up): body z forward,
    // body x up, body y to the right.
    let forward_from_body = Rotation3::from_matrix_unchecked(Matrix3::new(
        0.0, 0.0, 1.0, 0.0, -1.0, 0.0, 1.0, 0.0, 0.0,
    ));
    let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), -pitch)
        * Rotation3::from_axis_angle(&Vector3::x_axis(), roll)
        * forward_from_body;
    Isometry3::from_parts(
        Translation3::from(position),
        UnitQuaternion::from_rotation_matrix(&rotation),
    )
}

/// A robot leaving its dock: 1 s at rest, then a lap whose speed eases in
/// (smootherstep over 18 s: 4 mm in the first 0.7 s, 5 cm in 1.7 s). A
/// monocular window started at the rest has no landmarks until the motion
/// gives parallax; the IMU carries the rest's state until then. Measured
/// 2026-12-02 on two such laps: with the IMU allowed the 1 s it gets
/// after a loss in motion the stage reset at about 3 s and started again
/// with a 0.2 m jump, and its scale stayed 5-7 % off for the rest of the
/// run; carried for up to 3 s, no reset and the scale within 1 %.
/// Measured 2026-12-05 with the affine KLT warp: a keyframe solve 4 s
/// after the rest moved the pose already published by 3.5 cm (the
/// monocular scale settling), and the next frame stepped 5.3 cm; with the
/// correction published at up to 0.2 m/s (`published_correction_m_s`),
/// the largest step is 3.6 cm.
#[test]
fn a_gentle_start_from_rest_is_carried_until_the_images_have_parallax() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let trajectory = tmp.path().join("dock.tum");
    let mut text = String::from("# timestamp tx ty tz qx qy qz qw\n");
    for i in 0..=(9 * 200) {
        let t = i as f64 / 200.0;
        let x = ((t - 1.0) / 18.0).clamp(0.0, 1.0);
        let u = x * x * x * (x * (6.0 * x - 15.0) + 10.0);
        let p = lap_pose(u);
        let (v, q) = (p.translation.vector, p.rotation.coords);
        text += &format!(
            "{t:.6} {:.9} {:.9} {:.9} {:.12} {:.12} {:.12} {:.12}\n",
            v.x, v.y, v.z, q.x, q.y, q.z, q.w
        );
    }
    std::fs::write(&trajectory, text).expect("write trajectory");
    let dir = tmp.path().join("dock");
    simulate(
        &SimConfig {
            trajectory: Some(trajectory),
            duration_s: Some(8.5),
            seed: 7,
            show_progress: false,
            ..SimConfig::default()
        },
        &dir,
    )
    .expect("render");
    let run = |after_rest_s: f64| {
        let mut run = DatasetRun {
            mode: Some(SensorMode::MonoInertial),
            ..DatasetRun::default()
        };
        run.settings.relative.imu_only_after_rest_max_s = after_rest_s;
        let result = run_dataset(&dir, &run, |_, _| {}).expect("run");
        let poses = &result.outcome.trajectory.poses;
        let step = poses
            .windows(2)
            .map(|w| {
                (w[1].T_world_body.translation.vector - w[0].T_world_body.translation.vector).norm()
            })
            .fold(0.0, f64::max);
        let report = serde_json::to_value(&result.report).expect("json");
        (
            report["counters"]["resets"].as_u64().expect("resets"),
            step,
            report,
        )
    };
    let (resets, step, report) = run(RelativeConfig::default().imu_only_after_rest_max_s);
    eprintln!("carried: {resets} resets, largest step {step:.3} m");
    assert_eq!(resets, 0, "{report}");
    assert_eq!(report["lost_count"].as_u64(), Some(0), "{report}");
    assert!(
        report["counters"]["static_frames"].as_u64().unwrap_or(0) > 10,
        "a static start: {report}"
    );
    // 20 Hz and at most 0.5 m/s here: a step over 5 cm is a jump.
    assert!(step < 0.05, "largest step {step:.3} m");
    // As after a loss in motion, the start loses track and starts again.
    let (resets, _, _) = run(RelativeConfig::default().imu_only_max_s);
    assert!(resets >= 1, "the 1 s after a loss would have reset");
}
