//! Every observation the front end makes on a dataset, for studying the
//! tracker offline (with `bench/accuracy/track_truth.py`, against the
//! scene of a rendering): the relative stage's tracker driven alone on the
//! stereo pair, with the stereo-inertial mode's default settings and no
//! rotation prediction, its keyframe suggestions taken as keyframes.
//!
//! `cargo bench -p rigslam --bench tracks -- DATASET OUT.csv [MAX_FRAMES]
//! [--first-patch | --no-first-patch]` (tracks moved at keyframes to their
//! first patch or not, `[relative] track_first_patch`; default: as the
//! stereo-inertial mode, on)
//!
//! CSV: `t_ns,id,camera,u,v,keyframe` (distorted pixels as measured;
//! camera 0 left, 1 right; keyframe 1 on the frames the tracker suggested
//! as keyframes). Not a criterion bench: it measures nothing itself.

use std::io::Write;

use anyhow::Context;
use rigslam::dataset::{open_dataset, SensorEvent, SensorStream, StreamOptions};
use rigslam::relative::tracker::{Tracker, TrackerConfig};
use rigslam::relative::{FrameInput, RelativeConfig};
use rigslam::run::dataset_run::rig_of;

fn main() -> anyhow::Result<()> {
    // `cargo bench` passes `--bench` to every bench target.
    let mut args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    let first_patch_flag = args.iter().any(|a| a == "--first-patch");
    let no_first_patch_flag = args.iter().any(|a| a == "--no-first-patch");
    args.retain(|a| a != "--first-patch" && a != "--no-first-patch");
    let (dataset_dir, out) = match &args[..] {
        [d, o] | [d, o, _] => (d, o),
        _ => anyhow::bail!(
            "usage: cargo bench -p rigslam --bench tracks -- DATASET OUT.csv [MAX_FRAMES] [--first-patch | --no-first-patch]"
        ),
    };
    let max_frames = match args.get(2) {
        Some(m) => Some(
            m.parse::<usize>()
                .with_context(|| format!("MAX_FRAMES: {m} is not a count"))?,
        ),
        None => None,
    };
    let dataset = open_dataset(dataset_dir.as_ref())
        .with_context(|| format!("opening the dataset {dataset_dir}"))?;
    let rig = rig_of(&dataset);
    anyhow::ensure!(
        rig.cameras.len() >= 2,
        "{dataset_dir}: needs a stereo pair (cam0 and cam1)"
    );
    let relative = RelativeConfig::default();
    let config = TrackerConfig {
        target_features: relative.features,
        klt_affine: relative.klt_affine,
        first_patch: (relative
            .track_first_patch
            .enabled_in(rigslam::relative::SensorMode::StereoInertial)
            || first_patch_flag)
            && !no_first_patch_flag,
        ..TrackerConfig::default()
    };
    let mut tracker = Tracker::new(config, &rig.cameras[..2], true)?;
    let options = StreamOptions {
        stereo: true,
        imu: false,
        start_ns: None,
        max_frames,
        imu_lead_ns: 0,
    };
    let file = std::fs::File::create(out).with_context(|| format!("creating {out}"))?;
    let mut csv = std::io::BufWriter::new(file);
    writeln!(csv, "t_ns,id,camera,u,v,keyframe")?;
    let mut frames = 0usize;
    for event in SensorStream::new(&dataset, options)? {
        let SensorEvent::Frame { t_ns, left, right } = event? else {
            continue;
        };
        let right = right.as_ref().map(|r| &r.image);
        let frame = tracker.track(
            &FrameInput {
                t_ns,
                left: &left.image,
                right,
            },
            None,
        )?;
        if frame.is_keyframe {
            tracker.mark_keyframe(t_ns);
        }
        for o in &frame.observations {
            writeln!(
                csv,
                "{},{},{},{},{},{}",
                t_ns, o.landmark, o.camera_index, o.pixel.x, o.pixel.y, frame.is_keyframe as u8
            )?;
        }
        frames += 1;
    }
    csv.flush().with_context(|| format!("writing {out}"))?;
    eprintln!("{frames} frames tracked; observations in {out}");
    Ok(())
}
