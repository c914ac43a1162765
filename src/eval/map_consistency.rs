//! Is the published map-frame position covariance honest? The NEES of the
//! positions the second stage publishes (the position filter's, or the
//! localiser's in a saved map) against the ground truth.
//!
//! The map frame is only defined up to the transformation the accuracy
//! score fits (the map's origin and heading are the estimator's own), so
//! the error is taken after that same alignment, and the covariance is
//! turned (and scaled, for a similarity) with it:
//!
//! ```text
//! e = p_gt - (s R p_map + t)      Σ' = s² R Σ R^T      NEES = e^T Σ'^-1 e
//! ```
//!
//! A consistent covariance averages 3 (1 per degree of freedom), and 95 %
//! of the positions fall under the chi-square bound of 3 dof (7.81). The
//! fitted alignment takes up some of the error, so over a short run the
//! score is slightly optimistic; over the thousands of positions of a
//! run it is not measurably so.

use nalgebra::{Matrix3, Vector3};
use serde::Serialize;

use super::align::Sim3;
use super::consistency::interpolate;
use crate::trajectory::Trajectory;

/// The 95 % quantile of chi-square with 3 degrees of freedom.
pub const CHI2_3DOF_95: f64 = 7.815;

/// A published map-frame position with its covariance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPosition {
    /// Stamp, ns.
    pub t_ns: i64,
    /// Body position in the map frame, m.
    pub position_m: Vector3<f64>,
    /// Its published covariance, m².
    pub covariance_m2: Matrix3<f64>,
}

/// NEES of the map-frame positions over a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PositionNeesReport {
    /// Positions scored (covered by the ground truth, covariance positive
    /// definite).
    pub positions: usize,
    /// Mean of `NEES / 3`: 1 when consistent, above when too confident.
    pub mean_per_dof: f64,
    /// Median of `NEES / 3` (0.79 when consistent): the mean's tail apart.
    pub median_per_dof: f64,
    /// Share of positions under the 95 % bound of 3 dof (0.95 when
    /// consistent).
    pub within_95: f64,
}

/// NEES of every position the ground truth covers, after `alignment` (the
/// one that scored the trajectory); None when none is.
pub fn map_position_nees(
    positions: &[MapPosition],
    alignment: &Sim3,
    ground_truth: &Trajectory,
) -> Option<PositionNeesReport> {
    let r = alignment.rotation.matrix();
    let s2 = alignment.scale * alignment.scale;
    let mut per_dof: Vec<f64> = positions
        .iter()
        .filter_map(|p| {
            let truth = interpolate(ground_truth, p.t_ns)?.translation.vector;
            let e = truth - alignment.transform_point(&p.position_m);
            let c = s2 * (r * p.covariance_m2 * r.transpose());
            let c = 0.5 * (c + c.transpose());
            let nees = c.cholesky()?.solve(&e).dot(&e);
            nees.is_finite().then_some(nees / 3.0)
        })
        .collect();
    if per_dof.is_empty() {
        return None;
    }
    let n = per_dof.len();
    let mean_per_dof = per_dof.iter().sum::<f64>() / n as f64;
    let within_95 = per_dof.iter().filter(|v| **v * 3.0 <= CHI2_3DOF_95).count() as f64 / n as f64;
    per_dof.sort_by(f64::total_cmp);
    let median_per_dof = if n % 2 == 1 {
        per_dof[n / 2]
    } else {
        0.5 * (per_dof[n / 2 - 1] + per_dof[n / 2])
    };
    Some(PositionNeesReport {
        positions: n,
        mean_per_dof,
        median_per_dof,
        within_95,
    })
}

#[cfg(test)]
mod tests {
    use nalgebra::{Rotation3, UnitQuaternion};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    use super::*;
    use crate::trajectory::StampedPose;

    fn truth() -> Trajectory {
        Trajectory::new(
            (0..1000)
                .map(|k| {
                    let t = k as f64 * 0.01;
                    StampedPose::new(
                        k * 10_000_000,
                        Vector3::new(t.cos() * 3.0, t.sin() * 2.0, 0.1 * t),
                        UnitQuaternion::identity(),
                    )
                })
                .collect(),
        )
    }

    /// Positions drawn from their covariance around the truth, given in a
    /// map frame that is turned, shifted and scaled from the truth's,
    /// score near 1 per dof with 95 % under the bound; the same errors
    /// claimed 4x more precise score near 4.
    #[test]
    fn positions_drawn_from_their_covariance_score_one_per_dof() {
        let gt = truth();
        // Map -> truth: the alignment a scorer would have fitted.
        let alignment = Sim3 {
            rotation: Rotation3::from_euler_angles(0.1, -0.2, 1.1),
            translation: Vector3::new(4.0, -2.0, 0.5),
            scale: 1.3,
        };
        let inverse_rotation = alignment.rotation.inverse();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut positions = Vec::new();
        for (k, pose) in gt.poses.iter().enumerate().step_by(2) {
            // A covariance that changes along the run, in the map frame.
            let l = Matrix3::new(
                0.01 + 0.02 * (k as f64 * 0.01).sin().abs(),
                0.0,
                0.0,
                0.004,
                0.015,
                0.0,
                -0.003,
                0.002,
                0.03,
            );
            let covariance_m2 = l * l.transpose();
            let z = Vector3::from_fn(|_, _| StandardNormal.sample(&mut rng));
            let truth_in_map =
                inverse_rotation * (pose.position() - alignment.translation) / alignment.scale;
            positions.push(MapPosition {
                t_ns: pose.t_ns,
                position_m: truth_in_map + l * z,
                covariance_m2,
            });
        }
        let r = map_position_nees(&positions, &alignment, &gt).unwrap();
        assert_eq!(r.positions, positions.len());
        assert!((r.mean_per_dof - 1.0).abs() < 0.12, "{r:?}");
        assert!((r.median_per_dof - 0.79).abs() < 0.1, "{r:?}");
        assert!((r.within_95 - 0.95).abs() < 0.03, "{r:?}");

        for p in positions.iter_mut() {
            p.covariance_m2 /= 4.0;
        }
        let over = map_position_nees(&positions, &alignment, &gt).unwrap();
        assert!((over.mean_per_dof / r.mean_per_dof - 4.0).abs() < 1e-9);
        assert!(over.within_95 < 0.6, "{over:?}");

        // Without the alignment the same positions are far off.
        let unaligned = map_position_nees(&positions, &Sim3::identity(), &gt).unwrap();
        assert!(unaligned.mean_per_dof > 100.0, "{unaligned:?}");
    }

    #[test]
    fn positions_outside_the_truth_or_without_a_covariance_are_not_scored() {
        let gt = truth();
        let at = |t_ns, covariance_m2| MapPosition {
            t_ns,
            position_m: Vector3::new(3.0, 0.0, 0.0),
            covariance_m2,
        };
        let none = map_position_nees(
            &[
                at(-1_000_000_000, Matrix3::identity()),
                at(0, Matrix3::zeros()),
                at(0, Matrix3::from_element(f64::NAN)),
            ],
            &Sim3::identity(),
            &gt,
        );
        assert_eq!(none, None);
        let one = map_position_nees(&[at(0, Matrix3::identity() * 0.01)], &Sim3::identity(), &gt)
            .unwrap();
        assert_eq!(one.positions, 1);
        assert!(one.mean_per_dof.abs() < 1e-12, "{one:?}");
    }
}
