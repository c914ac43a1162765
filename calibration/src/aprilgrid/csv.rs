//! The detection file `camera-imu` reads (`aprilgrid_detections`): one row
//! per corner,
//! `ts,tag_rows,tag_cols,tag_size,tag_spacing,kp_x,kp_y,p_x,p_y,p_z,tag_id,corner_idx`,
//! written to a temporary file beside the target and renamed over it, so a
//! reader never sees half a file.

use std::io::Write;
use std::path::Path;

use rigslam::dataset::DatasetError;

use super::target::AprilGridTarget;
use crate::aprilgrid_detections::TargetDetection;

/// Writes `detection` to `path`; `corner_ids[i]` is `(tag_id, corner_idx)`
/// of keypoint `i` (see `GridDetection::corner_ids`).
pub fn write_detection_csv(
    path: &Path,
    detection: &TargetDetection,
    target: &AprilGridTarget,
    corner_ids: &[(usize, usize)],
) -> Result<(), DatasetError> {
    let n = detection.keypoints_px.len();
    if detection.target_points_m.len() != n || corner_ids.len() != n {
        return Err(DatasetError::Layout {
            path: path.to_path_buf(),
            message: format!(
                "{n} keypoints, {} target points and {} corner ids: they must match one to one",
                detection.target_points_m.len(),
                corner_ids.len()
            ),
        });
    }
    let mut text = String::from(
        "#ts,tag_rows,tag_cols,tag_size,tag_spacing,kp_x,kp_y,p_x,p_y,p_z,tag_id,corner_idx\n",
    );
    for ((kp, p), (tag_id, corner_idx)) in detection
        .keypoints_px
        .iter()
        .zip(&detection.target_points_m)
        .zip(corner_ids)
    {
        text.push_str(&format!(
            "{},{},{},{:.6},{:.6},{:.10},{:.10},{:.6},{:.6},{:.6},{},{}\n",
            detection.t_ns,
            target.tag_rows,
            target.tag_cols,
            target.tag_size_m,
            target.tag_spacing_ratio,
            kp.x,
            kp.y,
            p.x,
            p.y,
            p.z,
            tag_id,
            corner_idx
        ));
    }
    let file_name =
        path.file_name()
            .and_then(|n| n.to_str())
            .ok_or_else(|| DatasetError::Layout {
                path: path.to_path_buf(),
                message: "not a file path".into(),
            })?;
    let temporary = path.with_file_name(format!(".{file_name}.{}.tmp", std::process::id()));
    let written = std::fs::File::create(&temporary).and_then(|mut f| {
        f.write_all(text.as_bytes())?;
        f.sync_all()
    });
    if let Err(e) = written.and_then(|()| std::fs::rename(&temporary, path)) {
        let _ = std::fs::remove_file(&temporary);
        return Err(DatasetError::io(path, e));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aprilgrid_detections::read_detection_file;
    use nalgebra::{Vector2, Vector3};

    #[test]
    fn written_file_reads_back_and_mismatched_ids_are_refused() {
        let target = AprilGridTarget {
            tag_rows: 6,
            tag_cols: 6,
            tag_size_m: 0.088,
            tag_spacing_ratio: 0.3,
        };
        let detection = TargetDetection {
            t_ns: 1_403_709_395_937_837_056,
            keypoints_px: vec![Vector2::new(10.25, 20.5), Vector2::new(30.125, 40.0)],
            target_points_m: vec![Vector3::zeros(), Vector3::new(0.088, 0.0, 0.0)],
            tag_size_m: 0.088,
        };
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("1403709395937837056.csv");
        write_detection_csv(&path, &detection, &target, &[(0, 0), (0, 1)]).expect("written");
        let back = read_detection_file(&path).expect("reads back");
        assert_eq!(back.t_ns, detection.t_ns);
        assert_eq!(back.keypoints_px, detection.keypoints_px);
        assert_eq!(back.target_points_m, detection.target_points_m);
        let text = std::fs::read_to_string(&path).expect("text");
        assert!(
            text.lines().nth(2).is_some_and(|l| l.ends_with(",0,1")),
            "{text}"
        );
        // Only the file itself is left in the folder.
        assert_eq!(std::fs::read_dir(dir.path()).expect("list").count(), 1);
        let message = write_detection_csv(&path, &detection, &target, &[(0, 0)])
            .expect_err("one id for two keypoints")
            .to_string();
        assert!(message.contains("corner ids"), "{message}");
    }
}
