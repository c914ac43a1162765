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

/// Per frame of `dataset` (stereo-inertial) through `p`: the
/// published relative and corrected poses as bits; `finish` says whether
/// the caller calls `finish_frame` after each frame (else `push_frame`
/// does the work first). With `finish`, checks each keyframe on the way:
/// its pose went out before the window was optimised, and the second
/// stage took the optimised frame afterwards, not the published one.
fn published_bits(
    p: &mut SlamPipeline,
    dataset: &crate::dataset::Dataset,
    finish: bool,
) -> (Vec<Vec<u64>>, usize) {
    use crate::dataset::{SensorEvent, SensorStream, StreamOptions};
    let stream = SensorStream::new(
        dataset,
        StreamOptions {
            stereo: true,
            imu: true,
            start_ns: None,
            max_frames: None,
            imu_lead_ns: 0,
        },
    )
    .expect("stream");
    let bits = |t: &nalgebra::Isometry3<f64>| -> Vec<u64> {
        t.translation
            .vector
            .iter()
            .chain(t.rotation.coords.iter())
            .map(|v| v.to_bits())
            .collect()
    };
    let (mut published, mut moved) = (Vec::new(), 0);
    for event in stream {
        match event.expect("event") {
            SensorEvent::Imu(s) => p.push_imu(&s),
            SensorEvent::Frame { t_ns, left, right } => {
                let input = FrameInput {
                    t_ns,
                    left: &left.image,
                    right: right.as_ref().map(|r| &r.image),
                };
                let frames_before = p.absolute().map(|s| s.stats().frames);
                let frame = p.push_frame(&input);
                let mut row = bits(&frame.relative.T_world_body);
                if let Some(c) = &frame.corrected {
                    row.extend(bits(&c.T_world_body));
                }
                published.push(row);
                if !finish {
                    continue;
                }
                let pending = p.relative().work_pending();
                let optimised_before = p
                    .relative()
                    .last_timings()
                    .stages_ms
                    .iter()
                    .any(|(name, _)| *name == "window");
                let taken = p.absolute().map(|s| s.stats().frames);
                let refined = p.finish_frame();
                assert_eq!(pending, refined.is_some(), "frame {t_ns}");
                let Some(refined) = refined else {
                    continue;
                };
                assert!(
                    !optimised_before,
                    "keyframe {t_ns}: window optimised before its pose"
                );
                assert!(
                    p.relative()
                        .last_timings()
                        .stages_ms
                        .iter()
                        .any(|(name, _)| *name == "window"),
                    "keyframe {t_ns}: no window optimisation after its pose"
                );
                assert!(!p.relative().work_pending());
                assert_eq!(refined.relative.t_ns, t_ns);
                // The second stage took this frame only now, optimised.
                assert_eq!(taken, frames_before, "keyframe {t_ns}");
                assert_eq!(
                    p.absolute().map(|s| s.stats().frames),
                    frames_before.map(|n| n + 1)
                );
                if refined.relative.T_world_body != frame.relative.T_world_body {
                    moved += 1;
                }
            }
        }
    }
    (published, moved)
}

#[test]
fn a_keyframe_pose_goes_out_before_the_window_optimisation_whoever_calls_it() {
    // 6 s of the simulator's built-in motion, stereo with its IMU.
    let dir = tempfile::tempdir().expect("temp dir");
    let config = crate::simulate::SimConfig {
        duration_s: Some(6.0),
        stereo: true,
        show_progress: false,
        ..crate::simulate::SimConfig::default()
    };
    crate::simulate::simulate(&config, dir.path()).expect("render");
    let dataset = crate::dataset::open_dataset(dir.path()).expect("dataset");
    let rig = crate::run::dataset_run::rig_of(&dataset);
    let mut settings = SlamSettings::default();
    settings.absolute.enabled = true;
    let build = || {
        SlamPipeline::new(
            EstimatorKind::Window,
            SensorMode::StereoInertial,
            &rig,
            &settings,
            SecondStage::BuildMap,
        )
        .expect("a pipeline")
    };
    let (mut a, mut b) = (build(), build());
    let (finished, moved) = published_bits(&mut a, &dataset, true);
    let (unfinished, _) = published_bits(&mut b, &dataset, false);
    a.finish();
    b.finish();
    let keyframes = a
        .relative()
        .counters()
        .into_iter()
        .find(|(name, _)| *name == "keyframes")
        .map_or(0, |(_, n)| n);
    assert!(keyframes >= 10, "{keyframes} keyframes");
    // The optimisation moved the keyframes it was given (the published
    // pose is the tracked one, not the optimised one).
    assert!(
        moved as u64 >= keyframes / 2,
        "{moved} of {keyframes} moved"
    );
    assert_eq!(finished.len(), unfinished.len());
    for (i, (x, y)) in finished.iter().zip(&unfinished).enumerate() {
        assert_eq!(
            x, y,
            "frame {i}: the poses depend on who finishes the frame"
        );
    }
    let (sa, sb) = (
        a.absolute().expect("runs").stats(),
        b.absolute().expect("runs").stats(),
    );
    assert_eq!((sa.frames, sa.solves), (sb.frames, sb.solves));
    assert_eq!(sa.frames, finished.len());
}

#[test]
fn the_second_stage_takes_frames_in_time_order_and_measures_motion_from_the_last_it_took() {
    let run = drifting_laps(1.0, None);
    let mut settings = SlamSettings::default();
    settings.absolute.enabled = true;
    let mut p = pipeline(&settings, SecondStage::BuildMap);
    let outputs: Vec<_> = run
        .outputs
        .iter()
        .filter(|o| o.state == TrackingState::Tracking)
        .take(40)
        .cloned()
        .collect();
    assert_eq!(outputs.len(), 40);
    for o in &outputs[..20] {
        p.second_stage(o.clone());
    }
    let taken = |p: &SlamPipeline| p.absolute().expect("runs").stats().frames;
    assert_eq!(taken(&p), 20);
    // An answer again (a frame out of order): carried, not taken.
    let again = p.second_stage(outputs[19].clone());
    assert_eq!(taken(&p), 20);
    assert_eq!(again.relative, outputs[19], "the answer passes unchanged");
    // Five frames the second stage did not take, and an answer whose
    // motion the relative stage measured from something else: the next
    // one taken moves the filter by the whole way since the last one
    // taken.
    let mut skipping = outputs[25].clone();
    skipping.delta_translation_world_m = Vector3::new(100.0, 0.0, 0.0);
    let expected = p.absolute().expect("runs").carry(&RelativeOutput {
        delta_translation_world_m: outputs[25].T_world_body.translation.vector
            - outputs[19].T_world_body.translation.vector,
        ..outputs[25].clone()
    });
    let carried = p.carried(skipping.clone());
    assert_eq!(
        carried.corrected.expect("corrected").T_world_body,
        expected.T_world_body
    );
    assert_eq!(carried.relative, skipping, "the answer passes unchanged");
    let taken_frame = p.second_stage(skipping);
    assert_eq!(taken(&p), 21);
    let moved = taken_frame
        .corrected
        .expect("corrected")
        .T_world_body
        .translation
        .vector
        - again
            .corrected
            .expect("corrected")
            .T_world_body
            .translation
            .vector;
    let way =
        outputs[25].T_world_body.translation.vector - outputs[19].T_world_body.translation.vector;
    assert!(way.norm() > 0.5, "way {way:?}");
    assert!(
        (moved - way).norm() < 0.2 * way.norm(),
        "moved {moved:?}, way {way:?}"
    );
}

/// The relative stage's level turns by about a degree as its gravity
/// estimate settles (a start in flight), about the current position as
/// [`crate::relative::level`] turns it. The map is built in the relative
/// stage's own world, which does not turn: the map-frame poses are those
/// of the same run without the turn, turned with it. A map built from the
/// levelled poses as they come keeps the first seconds' tilt and is
/// centimetres worse against the truth.
#[test]
fn a_level_that_turns_as_gravity_settles_does_not_bend_the_map() {
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    let run = simulate_room_run(&RoomRunOptions {
        laps: 2.0,
        fresh_track_ids: true,
        descriptor_bit_flips: Some(20),
        sigma_translation_per_sqrt_m: 0.002,
        seed: 3,
        ..RoomRunOptions::default()
    });
    let n = run.outputs.len() as f64;
    let settled = UnitQuaternion::from_scaled_axis(Vector3::new(0.015, -0.01, 0.0));
    let mut settings = SlamSettings::default();
    settings.absolute.enabled = true;
    let mut unturned = pipeline(&settings, SecondStage::BuildMap);
    let mut own_world = pipeline(&settings, SecondStage::BuildMap);
    let mut as_they_come = pipeline(&settings, SecondStage::BuildMap);
    let mut level = Isometry3::<f64>::identity();
    let (mut same_m, mut own_m, mut bent_m) = (Vec::new(), Vec::new(), Vec::new());
    for (k, output) in run.outputs.iter().enumerate() {
        // The level follows the settled one, turned about where the body is.
        let p = output.T_world_body.translation.vector;
        let turn =
            UnitQuaternion::identity().slerp(&settled, 1.0 - (-(k as f64) / (0.2 * n)).exp());
        let p_level = level.transform_point(&p.into()).coords;
        level = Isometry3::from_parts(Translation3::from(p_level - turn * p), turn);
        let mut levelled = output.clone();
        levelled.T_world_body = level * output.T_world_body;
        levelled.velocity_world_m_s = level.rotation * output.velocity_world_m_s;
        levelled.delta_translation_world_m = level.rotation * output.delta_translation_world_m;
        let reference = unturned.second_stage(output.clone());
        own_world.levelling = level;
        let a = own_world.second_stage(levelled.clone());
        let b = as_they_come.second_stage(levelled.clone());
        assert_eq!(a.relative, levelled, "the odometry goes out as it came");
        if k as f64 >= 0.5 * n && output.state == TrackingState::Tracking {
            let position = |pose: Option<CorrectedPose>| {
                pose.expect("answers").T_world_body.translation.vector
            };
            let truth = level
                .transform_point(&run.truth_position_m[k].into())
                .coords;
            let unturned_m = level
                .transform_point(&position(reference.corrected).into())
                .coords;
            let a = position(a.corrected);
            same_m.push((a - unturned_m).norm());
            own_m.push((a - truth).norm());
            bent_m.push((position(b.corrected) - truth).norm());
        }
    }
    let (same, own, bent) = (rms(&same_m), rms(&own_m), rms(&bent_m));
    let stats = own_world.absolute().expect("runs").stats();
    assert!(stats.solves > 10 && stats.corrections > 40, "{stats:?}");
    assert!(
        same < 1e-4,
        "the map-frame poses are {same:.2e} m rms from the same run's without the turn"
    );
    assert!(
        bent > 2.0 * own,
        "the levelled poses as they come bend the map: {bent:.4} m from the truth, {own:.4} m in the own world"
    );
    // The map saved goes out in the world the poses are published in:
    // where the same run's without the turn puts its landmarks, levelled.
    own_world.finish();
    unturned.finish();
    let map = own_world.finish_map().expect("a map");
    let reference = unturned.finish_map().expect("a map");
    assert_eq!(map.landmarks.len(), reference.landmarks.len());
    let worst = map
        .landmarks
        .iter()
        .zip(&reference.landmarks)
        .map(|(l, r)| {
            assert_eq!(l.id, r.id);
            (l.position_m - level.transform_point(&r.position_m.into()).coords).norm()
        })
        .fold(0.0, f64::max);
    assert!(map.landmarks.len() > 50 && worst < 1e-4, "{worst:.2e} m");
}

/// A relative stage whose gravity estimate, in its own world, is tilted
/// by about a degree from its first guess (the own world's -z), moving
/// along x at 1 m/s with a frame every 50 ms.
struct TiltedGravity {
    frames: i64,
    timings: crate::relative::FrameTimings,
}

impl RelativeEstimator for TiltedGravity {
    fn push_imu(&mut self, _: &ImuSample) {}

    fn push_frame(&mut self, frame: &FrameInput<'_>) -> RelativeOutput {
        self.frames += 1;
        let mut out = RelativeOutput::tracking_at_origin(frame.t_ns, Vec::new());
        out.T_world_body.translation.vector = Vector3::new(0.05 * self.frames as f64, 0.0, 0.0);
        out
    }

    fn last_timings(&self) -> &crate::relative::FrameTimings {
        &self.timings
    }

    fn counters(&self) -> Vec<(&'static str, u64)> {
        Vec::new()
    }

    fn gravity_world_m_s2(&self) -> Option<Vector3<f64>> {
        Some(tilted_gravity())
    }
}

fn tilted_gravity() -> Vector3<f64> {
    nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(0.015, -0.01, 0.0))
        * Vector3::new(0.0, 0.0, -9.81)
}

/// The map's world follows the relative stage's gravity estimate, taken
/// back into the estimator's own world, with `[absolute]
/// level_time_constant_s`: with the relative stage's own 20 s it turns
/// exactly as the published poses do (the stage is then given them as
/// they are), with `inf` never, with 60 s a third as fast as 20 s early on.
#[test]
fn the_maps_world_follows_gravity_with_its_own_time_constant() {
    use crate::relative::level::levelled;
    use std::sync::Arc;
    let image = crate::sensors::Image::new(
        2,
        2,
        2,
        crate::sensors::PixelFormat::Mono8,
        Arc::from(vec![0u8; 4]),
    )
    .expect("image");
    let tilt = UnitQuaternion::rotation_between(&tilted_gravity(), &-Vector3::z())
        .expect("a turn")
        .angle();
    let run = |map_tau_s: f64| {
        let mut settings = SlamSettings::default();
        settings.absolute.enabled = true;
        settings.absolute.level_time_constant_s = map_tau_s;
        let mut p = pipeline(&settings, SecondStage::BuildMap);
        p.relative = levelled(
            Box::new(TiltedGravity {
                frames: 0,
                timings: Default::default(),
            }),
            20.0,
        );
        for k in 1..=100 {
            let frame = p.push_frame(&FrameInput {
                t_ns: k * 50_000_000,
                left: &image,
                right: None,
            });
            // The published pose is the relative stage's, whatever the map's
            // world.
            let own = nalgebra::Isometry3::translation(0.05 * k as f64, 0.0, 0.0);
            let expected = p.levelling * own;
            assert!(
                (frame.relative.T_world_body.translation.vector - expected.translation.vector)
                    .norm()
                    < 1e-12
            );
        }
        (p.levelling, p.map_level.level(), p.map_to_published())
    };
    use nalgebra::UnitQuaternion;
    let (published, map, between) = run(20.0);
    assert!(published.rotation.angle() > 0.2 * tilt, "the level turns");
    assert!(map.rotation.angle_to(&published.rotation) < 1e-12);
    assert!(between.rotation.angle() < 1e-12 && between.translation.vector.norm() < 1e-12);
    let (published, map, between) = run(f64::INFINITY);
    assert_eq!(map, nalgebra::Isometry3::identity());
    assert_eq!(between, published);
    let (published, map, _) = run(60.0);
    let ratio = map.rotation.angle() / published.rotation.angle();
    // 5 s in: (1 - exp(-5/60)) / (1 - exp(-5/20)) = 0.361.
    assert!((ratio - 0.361).abs() < 0.01, "{ratio}");
}
