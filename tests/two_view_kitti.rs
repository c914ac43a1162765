//! Five-point MSAC relative pose on real KITTI correspondences against the
//! true relative rotations (`../shared/data/kitti/seq_a_matches.txt`, KLT
//! tracks made by OpenCV between consecutive seq_a frames, and
//! `seq_a_gt_rel.txt` from the sequence's poses).

use std::path::PathBuf;

use rigslam::dataset::matches_file::{
    normalise, read_matches, read_relative_motions, rotation_error_deg,
};
use rigslam::two_view::{estimate_relative_pose, RelativePoseConfig};

/// `../shared/data/kitti` (or under `$RIGSLAM_SHARED_DATA`), or `None`
/// (skip) when it is missing, unless `CI` is set, where missing data is a
/// failure.
fn kitti_dir() -> Option<PathBuf> {
    let data = std::env::var_os("RIGSLAM_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data")));
    let dir = data.join("kitti");
    if dir.join("seq_a_matches.txt").is_file() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI is set but {} is missing",
        dir.display()
    );
    eprintln!("skipping: {} is missing", dir.display());
    None
}

#[test]
fn consecutive_frame_rotation_error_median_below_a_tenth_of_a_degree() {
    let Some(dir) = kitti_dir() else { return };
    let matches_path = dir.join("seq_a_matches.txt");
    let file = read_matches(&matches_path).unwrap();
    let camera = file.camera(&matches_path).unwrap();
    let truth = read_relative_motions(&dir.join("seq_a_gt_rel.txt")).unwrap();
    let config = RelativePoseConfig::for_pixels(1.0, file.pinhole[0]);
    let mut errors_deg = Vec::new();
    for pair in &file.pairs {
        let gt = truth
            .iter()
            .find(|m| m.k == pair.k)
            .expect("ground truth for every pair");
        let (x1, x2) = normalise(&camera, pair);
        let pose = estimate_relative_pose(&x1, &x2, &config).unwrap();
        assert!(
            pose.translation_dir_c2_c1.is_some(),
            "pair {}: the car moves",
            pair.k
        );
        // Forward motion: the translation direction is near the true one.
        let t_err_deg = pose
            .translation_dir_c2_c1
            .unwrap()
            .angle(&gt.t_c2_c1)
            .to_degrees();
        assert!(
            t_err_deg < 10.0,
            "pair {}: translation direction off by {t_err_deg} deg",
            pair.k
        );
        errors_deg.push(rotation_error_deg(
            &gt.rotation_c2_c1,
            pose.rotation_c2_c1.matrix(),
        ));
    }
    assert_eq!(errors_deg.len(), 50);
    errors_deg.sort_by(f64::total_cmp);
    let median = errors_deg[errors_deg.len() / 2];
    let p90 = errors_deg[(0.9 * (errors_deg.len() - 1) as f64).round() as usize];
    eprintln!("KITTI seq_a rotation error: median {median:.4} deg, p90 {p90:.4} deg");
    assert!(median < 0.1, "median rotation error {median} deg");
    assert!(p90 < 0.5, "90th percentile rotation error {p90} deg");
}

#[test]
fn too_few_correspondences_from_a_real_pair_is_an_error() {
    let Some(dir) = kitti_dir() else { return };
    let matches_path = dir.join("seq_a_matches.txt");
    let file = read_matches(&matches_path).unwrap();
    let camera = file.camera(&matches_path).unwrap();
    let (x1, x2) = normalise(&camera, &file.pairs[0]);
    let config = RelativePoseConfig::for_pixels(1.0, file.pinhole[0]);
    assert!(estimate_relative_pose(&x1[..4], &x2[..4], &config).is_err());
}
