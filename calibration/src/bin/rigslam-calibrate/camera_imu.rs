//! `rigslam-calibrate camera-imu`: camera-IMU rotation, translation and time
//! offset from per-frame target detections and the IMU log; writes
//! `camchain-imucam.yaml` (Kalibr's layout) into the calibration folder and
//! a report beside it. What earlier steps left in the folder is used: the
//! intrinsics from `camchain.yaml`, the IMU intrinsics from
//! `imu_intrinsics.yaml` (applied to the log) and the accelerometer random
//! walk from `imu.yaml`.

use std::path::PathBuf;

use anyhow::{bail, Context};
use nalgebra::Matrix4;
use rigslam::dataset::read_euroc_imu_csv;
use rigslam_calibration::aprilgrid::AprilGridTarget;
use rigslam_calibration::aprilgrid_detections::target_poses;

use crate::target_input;
use rigslam_calibration::camchain_yaml::{read_intrinsics, CamchainEntry};
use rigslam_calibration::camera_imu_batch::{refine_camera_imu, BatchInput};
use rigslam_calibration::camera_imu_report::{write_camera_imu_report, CameraImuResult};
use rigslam_calibration::stereo_extrinsic::{refine_stereo, stereo_extrinsic, StereoInstant};
use rigslam_calibration::time_offset::{camera_rates, estimate_time_offset, GyroSeries};

#[derive(clap::Args)]
pub struct CameraImuArgs {
    /// Folder with one sub-folder of detections per camera (cam0/<t_ns>.csv,
    /// cam1/...), as Kalibr-style tools export them.
    #[arg(long, conflicts_with_all = ["images", "recording"], required_unless_present_any = ["images", "recording"])]
    detections: Option<PathBuf>,
    /// Folder of images of the AprilGrid: camN/<t_ns>.png (or a EuRoC
    /// folder, mav0/camN/data/); needs --target.
    #[arg(long, conflicts_with = "recording", requires = "target")]
    images: Option<PathBuf>,
    /// A recording rigslamd made while the target was waved in front of the
    /// rig: its frames are searched for the target and its IMU is used
    /// (no --imu); needs --target.
    #[arg(long, requires = "target")]
    recording: Option<PathBuf>,
    /// The AprilGrid's description, Kalibr's target.yaml (aprilgrid,
    /// tagRows, tagCols, tagSize, tagSpacing).
    #[arg(long)]
    target: Option<PathBuf>,
    /// IMU log, EuRoC layout (t_ns, gyro xyz rad/s, accel xyz m/s^2);
    /// taken from the recording with --recording.
    #[arg(long, required_unless_present = "recording")]
    imu: Option<PathBuf>,
    /// Intrinsics file (default: camchain.yaml in the --out folder when
    /// `rigslam-calibrate camera` wrote one, else sequence.yaml in the
    /// detections folder).
    #[arg(long)]
    intrinsics: Option<PathBuf>,
    /// Largest time offset searched, s.
    #[arg(long, default_value_t = 0.2)]
    max_timeshift_s: f64,
    /// Local gravity magnitude, m/s^2, held fixed in the batch (Kalibr
    /// does the same); without it the batch estimates it.
    #[arg(long)]
    gravity: Option<f64>,
    /// Accelerometer bias random walk, m/s^3/sqrt(Hz) (default: imu.yaml's
    /// `accelerometer_random_walk` in the --out folder, else EuRoC's
    /// ADIS16448 value 3e-3).
    #[arg(long)]
    accel_random_walk: Option<f64>,
    /// The rig's calibration folder (created if need be):
    /// camchain-imucam.yaml goes there, with camera_imu_report.md and the
    /// plots beside it.
    #[arg(long, value_name = "DIR", default_value = "calibration")]
    out: PathBuf,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

pub fn run(args: CameraImuArgs) -> anyhow::Result<()> {
    use rigslam::rig::folder::{CAMCHAIN, CAMCHAIN_INTRINSICS, IMU_INTRINSICS, IMU_NOISE};
    let folder_chain = args.out.join(CAMCHAIN_INTRINSICS);
    let intrinsics_path = match (&args.intrinsics, &args.detections) {
        (Some(p), _) => p.clone(),
        (None, _) if folder_chain.exists() => folder_chain.clone(),
        (None, Some(d)) => d.join("sequence.yaml"),
        (None, None) => bail!(
            "no intrinsics: run `rigslam-calibrate camera --out {}` first, or give --intrinsics",
            args.out.display()
        ),
    };
    let accel_random_walk = match (args.accel_random_walk, args.out.join(IMU_NOISE)) {
        (Some(v), _) => v,
        (None, p) if p.exists() => {
            rigslam::rig::kalibr::imu_from_kalibr(&std::fs::read_to_string(&p)?, &p)?
                .noise
                .accelerometer_random_walk
        }
        (None, _) => 3e-3,
    };
    let imu_intrinsics = match args.out.join(IMU_INTRINSICS) {
        p if p.exists() => Some(rigslam::rig::imu_intrinsics_file::read_intrinsics_yaml(&p)?),
        _ => None,
    };
    if let Some(g) = args.gravity {
        if !(5.0..=15.0).contains(&g) {
            bail!("--gravity {g}: give the local gravity magnitude in m/s^2 (about 9.78-9.83 on Earth)");
        }
    }
    if !(accel_random_walk.is_finite() && accel_random_walk > 0.0) {
        bail!(
            "--accel-random-walk {accel_random_walk}: give the accelerometer bias random walk in m/s^3/sqrt(Hz), a positive number (imu.yaml accelerometer_random_walk)"
        );
    }
    let save = args.out.join("detections");
    let observations = match (&args.detections, &args.images, &args.recording) {
        (Some(d), _, _) => target_input::from_detections(d)?,
        (None, images, recording) => {
            let target_path = args
                .target
                .as_ref()
                .context("--target is needed with --images or --recording")?;
            let target = AprilGridTarget::from_yaml_file(target_path)?;
            match (images, recording) {
                (Some(i), _) => target_input::from_images(i, &target, &save)?,
                (None, Some(r)) => target_input::from_recording(r, &target, &save)?,
                (None, None) => bail!("give --detections, --images or --recording"),
            }
        }
    };
    let imu_source = args
        .imu
        .clone()
        .or_else(|| args.recording.clone())
        .unwrap_or_default();
    let mut imu = match (&args.imu, observations.imu.clone()) {
        (Some(path), _) => read_euroc_imu_csv(path)?,
        (None, Some(samples)) => rigslam::dataset::ImuCsv {
            samples,
            dropped_nonfinite: 0,
            first_nonfinite_line: None,
        },
        (None, None) => bail!("--imu is needed (the IMU log recorded with the target)"),
    };
    if let Some(i) = &imu_intrinsics {
        for s in imu.samples.iter_mut() {
            *s = i.correct(s);
        }
    }
    if imu.samples.len() < 100 {
        bail!(
            "{}: only {} IMU samples; record at least a minute of IMU with the target in view",
            imu_source.display(),
            imu.samples.len()
        );
    }
    let t_origin_ns = imu.samples[0].t_ns;
    let imu_end_ns = imu.samples.last().expect("non-empty").t_ns;
    let gyro = GyroSeries {
        t_s: imu
            .samples
            .iter()
            .map(|s| (s.t_ns - t_origin_ns) as f64 * 1e-9)
            .collect(),
        w_rad_s: imu.samples.iter().map(|s| s.gyro_rad_s.into()).collect(),
    };
    let yaml_path = crate::output_file(&args.out, CAMCHAIN)?;
    let mut entries = Vec::new();
    let mut results = Vec::new();
    let mut all_poses = Vec::new();
    let mut all_detections = Vec::new();
    for (cam, detections) in observations.cameras {
        let cam = &cam;
        let camera = read_intrinsics(&intrinsics_path, cam)?;
        let poses = target_poses(&camera, &detections);
        let (first, last) = match (poses.first(), poses.last()) {
            (Some(a), Some(b)) if poses.len() >= 50 => (a.t_ns, b.t_ns),
            _ => bail!(
                "{cam}: the target pose was found in only {} of {} frames (need 50): recollect with the whole target in view and sharp images",
                poses.len(),
                detections.len()
            ),
        };
        let overlap_s = (last.min(imu_end_ns) - first.max(t_origin_ns)) as f64 * 1e-9;
        if overlap_s < 0.5 * (last - first) as f64 * 1e-9 {
            bail!(
                "{cam}: the detections ({:.1}-{:.1} s) and the IMU log ({:.1}-{:.1} s, Unix time) overlap for only {:.1} s: record the IMU and the camera together, over the same time",
                first as f64 * 1e-9, last as f64 * 1e-9, t_origin_ns as f64 * 1e-9, imu_end_ns as f64 * 1e-9, overlap_s.max(0.0)
            );
        }
        let median_dt_s = {
            let mut dts: Vec<f64> = poses
                .windows(2)
                .map(|w| (w[1].t_ns - w[0].t_ns) as f64 * 1e-9)
                .collect();
            dts.sort_by(f64::total_cmp);
            dts[dts.len() / 2]
        };
        let rates = camera_rates(&poses, t_origin_ns, 1.5 * median_dt_s);
        let offset = estimate_time_offset(&rates, &gyro, args.max_timeshift_s).with_context(|| {
            format!("{cam}: the rotation could not be determined; recollect rotating the rig about all three axes in front of the target")
        })?;
        let batch = refine_camera_imu(&BatchInput {
            poses: &poses,
            imu: &imu.samples,
            t_origin_ns,
            R_imu_cam: offset.hand_eye.R_imu_cam,
            gyro_bias_rad_s: offset.hand_eye.gyro_bias_rad_s,
            timeshift_cam_imu_s: offset.timeshift_cam_imu_s,
            gravity_m_s2: args.gravity,
            accel_random_walk,
        })
        .with_context(|| format!("{cam}: batch refinement"))?;
        let t_cam_imu: Matrix4<f64> = batch.T_cam_imu();
        entries.push(CamchainEntry {
            name: cam.clone(),
            camera: camera.clone(),
            T_cam_imu: t_cam_imu,
            timeshift_cam_imu_s: batch.timeshift_cam_imu_s,
        });
        results.push(CameraImuResult {
            name: cam.clone(),
            frames: detections.len(),
            poses: poses.len(),
            offset,
            batch,
        });
        all_poses.push(poses);
        all_detections.push(detections);
    }
    // Cameras after the first: placed by the stereo extrinsic the target
    // measures directly, composed with cam0's camera-IMU result, on
    // cam0's clock (one exposure trigger).
    let mut stereo_notes = Vec::new();
    for k in 1..entries.len() {
        let Some(stereo) = stereo_extrinsic(&all_poses[0], &all_poses[k]) else {
            stereo_notes.push(format!(
                "{}: fewer than 10 instants with the target seen by both cameras; placed by its own camera-IMU estimate",
                entries[k].name
            ));
            continue;
        };
        // The target as declared: the IMU's view of its scale (the batch's
        // `target_scale`) is reported, not applied; on the EuRoC recording
        // it is 1.8 % small and would shrink the baseline by as much.
        let scale = 1.0;
        let instants: Vec<StereoInstant<'_>> = all_poses[0]
            .iter()
            .filter_map(|p0| {
                all_poses[k].iter().find(|p| p.t_ns == p0.t_ns)?;
                let cam0 = all_detections[0].iter().find(|d| d.t_ns == p0.t_ns)?;
                let cam1 = all_detections[k].iter().find(|d| d.t_ns == p0.t_ns)?;
                let t_target_cam0 = nalgebra::Isometry3::from_parts(
                    nalgebra::Translation3::from(p0.p_target_cam * scale),
                    nalgebra::UnitQuaternion::from_matrix(&p0.R_target_cam),
                );
                Some(StereoInstant {
                    cam0,
                    cam1,
                    T_cam0_target: t_target_cam0.inverse(),
                })
            })
            .collect();
        let mut initial = stereo.T_cam0_cam1;
        initial.translation.vector *= scale;
        let t_cam0_cam = match refine_stereo(
            &entries[0].camera,
            &entries[k].camera,
            &instants,
            &initial,
            scale,
        ) {
            Some(r) => {
                stereo_notes.push(format!(
                    "{}: stereo refined on {} instants to {:.3} px RMS",
                    entries[k].name, r.instants, r.rms_px
                ));
                r.T_cam0_cam1
            }
            None => initial,
        };
        let independent = entries[k].T_cam_imu;
        let composed = t_cam0_cam.inverse().to_homogeneous() * entries[0].T_cam_imu;
        let d = independent.try_inverse().unwrap_or_else(Matrix4::identity) * composed;
        let angle_deg = nalgebra::Rotation3::from_matrix(&d.fixed_view::<3, 3>(0, 0).into_owned())
            .angle()
            .to_degrees();
        stereo_notes.push(format!(
            "{}: stereo extrinsic from {} of {} common instants (spread {:.3} deg, {:.2} mm); its own camera-IMU estimate differs by {:.3} deg, {:.1} mm",
            entries[k].name,
            stereo.pairs_used,
            stereo.pairs,
            stereo.rotation_rms_deg,
            stereo.translation_rms_m * 1e3,
            angle_deg,
            d.fixed_view::<3, 1>(0, 3).norm() * 1e3
        ));
        entries[k].T_cam_imu = composed;
        entries[k].timeshift_cam_imu_s = entries[0].timeshift_cam_imu_s;
    }
    let rig_cameras: Vec<rigslam::rig::CameraCalibration> = entries
        .iter()
        .map(|e| {
            let t_cam_imu = nalgebra::Isometry3::from_parts(
                nalgebra::Translation3::from(e.T_cam_imu.fixed_view::<3, 1>(0, 3).into_owned()),
                nalgebra::UnitQuaternion::from_matrix(
                    &e.T_cam_imu.fixed_view::<3, 3>(0, 0).into_owned(),
                ),
            );
            rigslam::rig::CameraCalibration {
                model: e.camera.clone().into(),
                T_body_cam: t_cam_imu.inverse(),
                rate_hz: 0.0,
                time_shift_cam_imu_s: e.timeshift_cam_imu_s,
            }
        })
        .collect();
    let chain = rigslam::rig::kalibr::camchain_yaml(&rig_cameras, true)
        .map_err(|e| anyhow::anyhow!("{}: {e}", intrinsics_path.display()))?;
    rigslam::rig::folder::write_atomically(&yaml_path, chain.as_bytes())
        .with_context(|| format!("writing {}", yaml_path.display()))?;
    let verdict = write_camera_imu_report(&args.out, &results)?;
    if args.json {
        let first = &entries[0];
        let rows: Vec<Vec<f64>> = (0..4)
            .map(|r| (0..4).map(|c| first.T_cam_imu[(r, c)]).collect())
            .collect();
        let per_camera: Vec<_> = entries
            .iter()
            .zip(&results)
            .map(|(e, r)| {
                let rows: Vec<Vec<f64>> = (0..4).map(|i| (0..4).map(|j| e.T_cam_imu[(i, j)]).collect()).collect();
                serde_json::json!({
                    "camera": e.name,
                    "T_cam_imu": rows,
                    "timeshift_cam_imu_s": e.timeshift_cam_imu_s,
                    "timeshift_from_gyro_s": r.offset.timeshift_cam_imu_s,
                    "R_cam_imu_from_gyro": (0..3).map(|i| (0..3).map(|j| r.offset.hand_eye.R_imu_cam[(j, i)]).collect::<Vec<f64>>()).collect::<Vec<_>>(),
                    "gravity_norm_m_s2": r.batch.gravity_m_s2.norm(),
                    "target_scale": r.batch.target_scale,
                    "accel_rms_m_s2": r.batch.accel_rms_m_s2,
                    "position_rms_m": r.batch.position_rms_m,
                })
            })
            .collect();
        println!(
            "{}",
            serde_json::json!({
                "T_cam_imu": rows,
                "timeshift_cam_imu_s": first.timeshift_cam_imu_s,
                "cameras": per_camera,
                "stereo": stereo_notes,
                "verdict": verdict,
            })
        );
    } else {
        for (e, r) in entries.iter().zip(&results) {
            println!(
                "{}: {} of {} frames posed; time shift {:.3} ms (gyro correlation {:.3} ms)",
                e.name,
                r.poses,
                r.frames,
                e.timeshift_cam_imu_s * 1e3,
                r.offset.timeshift_cam_imu_s * 1e3
            );
            println!("T_cam_imu =\n{:.6}", e.T_cam_imu);
        }
        for note in &stereo_notes {
            println!("{note}");
        }
        println!("{verdict}");
        println!("wrote {} and camera_imu_report.md", yaml_path.display());
    }
    Ok(())
}
