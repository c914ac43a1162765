use nalgebra::Vector3;

use super::*;
use crate::absolute::simulate_relative::{simulate_room_run, RoomRun, RoomRunOptions};
use crate::relative::TrackingState;
use crate::rig::euroc::{euroc_cam0, euroc_cam1, euroc_imu0};

fn rig() -> RigModel {
    RigModel {
        cameras: vec![euroc_cam0(), euroc_cam1()],
        imu: Some(euroc_imu0()),
    }
}

fn pipeline(settings: &SlamSettings, second: SecondStage) -> SlamPipeline {
    SlamPipeline::new(
        EstimatorKind::Window,
        SensorMode::StereoInertial,
        &rig(),
        settings,
        second,
    )
    .expect("a pipeline")
}

/// Laps of a room on odometry that drifts 1 % of the way, with landmarks
/// re-identified under new track ids (what the relative stage gives).
fn drifting_laps(laps: f64, noise_seed: Option<u64>) -> RoomRun {
    simulate_room_run(&RoomRunOptions {
        laps,
        fresh_track_ids: true,
        descriptor_bit_flips: Some(20),
        drift_per_m: Vector3::new(0.008, -0.006, 0.0),
        noise_seed,
        seed: 3,
        ..RoomRunOptions::default()
    })
}

fn rms(errors: &[f64]) -> f64 {
    (errors.iter().map(|e| e * e).sum::<f64>() / errors.len().max(1) as f64).sqrt()
}

#[test]
fn the_settings_choose_the_second_stage() {
    let mut settings = SlamSettings::default();
    assert!(matches!(
        SecondStage::from_settings(&settings),
        SecondStage::None
    ));
    let p = pipeline(&settings, SecondStage::from_settings(&settings));
    assert!(p.absolute().is_none() && p.localiser().is_none());
    settings.absolute.enabled = true;
    assert!(matches!(
        SecondStage::from_settings(&settings),
        SecondStage::BuildMap
    ));
    let p = pipeline(&settings, SecondStage::from_settings(&settings));
    assert!(p.absolute().is_some() && p.localiser().is_none());
    assert_eq!(p.mode(), SensorMode::StereoInertial);
}

#[test]
fn a_bad_absolute_setting_is_refused_only_when_that_stage_runs() {
    let mut settings = SlamSettings::default();
    settings.absolute.policy = "knn:x".into();
    // Not run: not read.
    assert!(SlamPipeline::new(
        EstimatorKind::Window,
        SensorMode::StereoInertial,
        &rig(),
        &settings,
        SecondStage::None,
    )
    .is_ok());
    let e = SlamPipeline::new(
        EstimatorKind::Window,
        SensorMode::StereoInertial,
        &rig(),
        &settings,
        SecondStage::BuildMap,
    )
    .err()
    .expect("refused");
    assert!(e.to_string().contains("absolute.policy"), "{e}");
}

#[test]
fn the_absolute_stage_bounds_the_drift_of_the_relative_stage() {
    let run = drifting_laps(4.0, None);
    let mut settings = SlamSettings::default();
    settings.absolute.enabled = true;
    let mut p = pipeline(&settings, SecondStage::BuildMap);
    let mut plain = pipeline(&settings, SecondStage::None);
    let (mut relative_m, mut corrected_m) = (Vec::new(), Vec::new());
    let last_lap = run.outputs.len() * 3 / 4;
    for (k, output) in run.outputs.iter().enumerate() {
        let frame = p.second_stage(output.clone());
        assert_eq!(
            frame.relative, *output,
            "the relative answer passes unchanged"
        );
        let pose = frame
            .corrected
            .expect("the absolute stage answers every frame");
        assert!(frame.localised.is_none());
        assert!(plain.second_stage(output.clone()).corrected.is_none());
        if k >= last_lap && output.state == TrackingState::Tracking {
            let truth = run.truth_position_m[k];
            relative_m.push((output.T_world_body.translation.vector - truth).norm());
            corrected_m.push((pose.T_world_body.translation.vector - truth).norm());
        }
    }
    p.finish();
    let stats = p.absolute().expect("runs").stats();
    let (relative, corrected) = (rms(&relative_m), rms(&corrected_m));
    assert!(stats.solves > 10 && stats.recognised > 50, "{stats:?}");
    assert!(relative > 0.5, "the odometry drifts: {relative:.3} m");
    assert!(
        corrected < 0.25 * relative,
        "last lap: relative {relative:.3} m, corrected {corrected:.3} m"
    );
}

#[test]
fn a_map_built_in_one_drive_places_the_robot_in_another() {
    let mut settings = SlamSettings::default();
    settings.absolute.enabled = true;
    let mut builder = pipeline(&settings, SecondStage::BuildMap);
    for output in &drifting_laps(1.0, None).outputs {
        builder.second_stage(output.clone());
    }
    builder.finish();
    let map = builder
        .absolute_mut()
        .and_then(|stage| stage.finish_map())
        .expect("a map");
    assert!(
        map.landmarks.len() > 50,
        "{} landmarks",
        map.landmarks.len()
    );

    let second = drifting_laps(1.0, Some(77));
    let mut localiser = pipeline(&settings, SecondStage::Localise(Arc::new(map)));
    let mut placed = Vec::new();
    for (k, output) in second.outputs.iter().enumerate() {
        let frame = localiser.second_stage(output.clone());
        assert!(frame.corrected.is_none());
        if let Some(pose) = frame.localised {
            placed.push((pose.T_map_body.translation.vector - second.truth_position_m[k]).norm());
        }
    }
    let stats = localiser.localiser().expect("localising").stats();
    assert!(
        placed.len() > second.outputs.len() / 2,
        "localised in {} of {} frames: {stats:?}",
        placed.len(),
        second.outputs.len()
    );
    // Both drives start where the map's world starts, so the map frame is
    // the true one up to the map's own error.
    assert!(rms(&placed) < 0.15, "rms {:.3} m: {stats:?}", rms(&placed));
}
