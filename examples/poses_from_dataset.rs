//! The relative stage on a recorded dataset folder (EuRoC, KITTI or TUM
//! layout), frame by frame; the tracked poses (body in the world frame) go
//! to a TUM file: `cargo run --release --example poses_from_dataset --
//! ../shared/data/euroc/V1_01_micro poses.tum`
use rigslam::dataset::trajectory_out::{write_trajectory, TrajectoryFormat};
use rigslam::dataset::{open_dataset, SensorEvent, SensorStream, StreamOptions};
use rigslam::relative::{
    build_estimator, EstimatorKind, FrameInput, RelativeConfig, TrackingState,
};
use rigslam::run::dataset_run::{default_mode, rig_of};
use rigslam::trajectory::{StampedPose, Trajectory};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [dir, out] = &args[..] else { anyhow::bail!("usage: poses_from_dataset DIR OUT.tum") };
    let dataset = open_dataset(dir.as_ref())?;
    let rig = rig_of(&dataset); // the calibration the dataset carries
    let mode = default_mode(&rig); // stereo-inertial with two cameras and an IMU
    let mut estimator =
        build_estimator(EstimatorKind::Window, mode, &rig, &RelativeConfig::default())?;
    let (stereo, imu) = (mode.uses_stereo(), mode.uses_imu());
    // A camera behind the IMU clock needs the IMU up to its instant on that clock.
    let imu_lead_ns = rig.frame_shift_ns();
    let options = StreamOptions { stereo, imu, start_ns: None, max_frames: None, imu_lead_ns };
    let mut poses = Vec::new();
    for event in SensorStream::new(&dataset, options)? {
        match event? {
            SensorEvent::Imu(sample) => estimator.push_imu(&sample),
            SensorEvent::Frame { t_ns, left, right } => {
                let right = right.as_ref().map(|r| &r.image);
                let pose = estimator.push_frame(&FrameInput { t_ns, left: &left.image, right });
                if pose.state == TrackingState::Tracking {
                    let (p, q) = (pose.T_world_body.translation.vector, pose.T_world_body.rotation);
                    poses.push(StampedPose::new(t_ns, p, q));
                }
            }
        }
    }
    write_trajectory(out.as_ref(), &Trajectory::new(poses), TrajectoryFormat::Tum)?;
    Ok(())
}
