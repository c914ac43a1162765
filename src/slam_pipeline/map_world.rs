//! The absolute stage's world. The relative stage publishes its poses
//! levelled by its gravity estimate ([`crate::relative::level`]), and that
//! level turns as the estimate settles (about a degree over the first
//! 15-20 s of a start in flight) and as the estimator's own roll and
//! pitch drift. A map built from the published poses holds each frame
//! node's landmark offsets turned by the level of its time: the first
//! seconds' tilt stayed in the map, and the map-frame pose was pulled
//! back to it (the published attitude kept half a degree of tilt after
//! the odometry had lost it). The stage is given the outputs in a world
//! of its own instead: the estimator's world, which its first keyframe
//! fixes, levelled more slowly (`[absolute] level_time_constant_s`). What
//! the stage answers (poses, covariances, maps to save) is turned into
//! the world the relative stage publishes in now.

use nalgebra::{Isometry3, Matrix3};

use crate::absolute::map_file::SavedMap;
use crate::absolute::CorrectedPose;
use crate::relative::RelativeOutput;

/// `output` (published) in the absolute stage's world, where
/// `map_to_published` takes that world into the published one. The
/// body-frame landmarks and the biases do not change.
pub(super) fn into_map_world(
    output: &RelativeOutput,
    map_to_published: &Isometry3<f64>,
) -> RelativeOutput {
    let mut in_map = output.clone();
    in_map.move_to_world(&map_to_published.inverse());
    in_map
}

/// The absolute stage's `pose` in the published world.
pub(super) fn into_published_world(
    mut pose: CorrectedPose,
    map_to_published: &Isometry3<f64>,
) -> CorrectedPose {
    let r = rotation(map_to_published);
    pose.T_world_body = map_to_published * pose.T_world_body;
    pose.position_covariance_m2 = pose.position_covariance_m2.map(|c| r * c * r.transpose());
    pose
}

/// A map the absolute stage built in the published world, as a localiser
/// in a later run, whose poses are levelled, reads it.
pub(super) fn map_into_published_world(
    mut map: SavedMap,
    map_to_published: &Isometry3<f64>,
) -> SavedMap {
    let r = rotation(map_to_published);
    for l in &mut map.landmarks {
        l.position_m = map_to_published
            .transform_point(&l.position_m.into())
            .coords;
        l.covariance_m2 = r * l.covariance_m2 * r.transpose();
        l.attitude = l.attitude.map(|a| a.rotated(&r));
    }
    map
}

fn rotation(isometry: &Isometry3<f64>) -> Matrix3<f64> {
    isometry.rotation.to_rotation_matrix().into_inner()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::absolute::map_file::MapLandmark;
    use crate::absolute::mapping_attitude::AttitudeMoments;
    use crate::relative::types::PoseCovariance;
    use nalgebra::{Matrix6, Translation3, UnitQuaternion, Vector3};

    /// A turn of about a degree, about a point away from the origin.
    fn levelling() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.03, -0.02, 0.01),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.012, -0.009, 0.0)),
        )
    }

    fn output() -> RelativeOutput {
        let mut o = RelativeOutput::tracking_at_origin(7, Vec::new());
        o.T_world_body = Isometry3::from_parts(
            Translation3::new(2.0, -1.0, 1.5),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.2, 0.1, 1.3)),
        );
        o.velocity_world_m_s = Vector3::new(0.5, 0.2, -0.1);
        o.delta_translation_world_m = Vector3::new(0.02, 0.01, -0.005);
        let a = Matrix6::from_fn(|r, c| ((r * 7 + c * 3) % 5) as f64 * 0.01);
        o.pose_covariance = Some(PoseCovariance {
            matrix: a * a.transpose() + Matrix6::identity() * 1e-4,
            origin_t_ns: 3,
            T_world_origin: Isometry3::translation(0.1, 0.2, 0.3),
        });
        o
    }

    #[test]
    fn an_output_taken_into_the_maps_world_and_back_is_unchanged() {
        let o = output();
        let l = levelling();
        let in_map = into_map_world(&o, &l);
        // The map-world pose is different (the test would pass vacuously
        // with an identity).
        assert!(
            (in_map.T_world_body.translation.vector - o.T_world_body.translation.vector).norm()
                > 1e-3
        );
        let pose = CorrectedPose {
            t_ns: in_map.t_ns,
            T_world_body: in_map.T_world_body,
            position_covariance_m2: in_map
                .pose_covariance
                .map(|c| c.matrix.fixed_view::<3, 3>(0, 0).into_owned()),
            landmarks_used: 0,
            map_version: 0,
            nis: 0.0,
        };
        let back = into_published_world(pose, &l);
        assert!(
            (back.T_world_body.translation.vector - o.T_world_body.translation.vector).norm()
                < 1e-12
        );
        assert!(
            back.T_world_body
                .rotation
                .angle_to(&o.T_world_body.rotation)
                < 1e-12
        );
        let c = o
            .pose_covariance
            .expect("set")
            .matrix
            .fixed_view::<3, 3>(0, 0)
            .into_owned();
        assert!((back.position_covariance_m2.expect("set") - c).norm() < 1e-15);
    }

    #[test]
    fn motion_and_covariance_turn_with_the_world() {
        let o = output();
        let l = levelling();
        let in_map = into_map_world(&o, &l);
        let r = rotation(&l);
        // What was moved in the map's world, turned, is what was published.
        assert!(
            (r * in_map.delta_translation_world_m - o.delta_translation_world_m).norm() < 1e-15
        );
        assert!((r * in_map.velocity_world_m_s - o.velocity_world_m_s).norm() < 1e-15);
        // A direction's variance is the same seen from either world.
        let u = Vector3::new(0.3, -0.5, 0.8).normalize();
        let level = o
            .pose_covariance
            .expect("set")
            .matrix
            .fixed_view::<3, 3>(0, 0)
            .into_owned();
        let in_map_c = in_map
            .pose_covariance
            .expect("set")
            .matrix
            .fixed_view::<3, 3>(0, 0)
            .into_owned();
        let v = r.transpose() * u;
        assert!((u.dot(&(level * u)) - v.dot(&(in_map_c * v))).abs() < 1e-15);
        // The origin of the covariance moves into the in_map world too.
        let origin = in_map.pose_covariance.expect("set").T_world_origin;
        assert!(
            (l * origin)
                .translation
                .vector
                .metric_distance(&Vector3::new(0.1, 0.2, 0.3))
                < 1e-12
        );
        assert_eq!(in_map.landmarks, o.landmarks);
    }

    #[test]
    fn a_saved_map_is_levelled_like_the_poses() {
        let l = levelling();
        let p = Vector3::new(3.0, 1.0, -0.5);
        let c = Matrix3::from_diagonal(&Vector3::new(1e-4, 4e-4, 9e-4));
        let attitude = AttitudeMoments {
            steps_rad2: Matrix3::from_diagonal(&Vector3::new(1e-7, 2e-7, 5e-6)),
            first_m_rad2: Matrix3::new(0.0, 1.0, 2.0, -1.0, 0.0, 3.0, 0.5, 0.0, 1.0) * 1e-6,
            second_m2_rad2: Matrix3::from_diagonal(&Vector3::new(2e-5, 3e-5, 1e-5)),
        };
        let map = SavedMap {
            landmarks: vec![MapLandmark {
                id: 4,
                position_m: p,
                covariance_m2: c,
                descriptor: None,
                attitude: Some(attitude),
            }],
        };
        let levelled = map_into_published_world(map, &l);
        let m = &levelled.landmarks[0];
        assert!((m.position_m - (l * nalgebra::Point3::from(p)).coords).norm() < 1e-12);
        let r = rotation(&l);
        assert!((m.covariance_m2 - r * c * r.transpose()).norm() < 1e-15);
        assert_eq!(m.id, 4);
        // What the attitude puts in a robot 2 m away turns with the map.
        let d = Vector3::new(2.0, -1.0, 0.5);
        let turned = m.attitude.expect("kept").covariance_at(&(r * d));
        let expected = r * attitude.covariance_at(&d) * r.transpose();
        assert!(
            (turned - expected).amax() < 1e-12 * expected.amax(),
            "{turned} {expected}"
        );
    }
}
