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
//! of the positions fall under the chi-square bound of 3 dof (7.81).
//!
//! The fitted alignment takes up more than noise: every error the whole
//! run shares (where the map's origin and heading were put) is gone from
//! `e`, while the published covariance keeps the part of it it knows of
//! (a map anchored late carries the relative stage's uncertainty at the
//! anchor, see [`crate::absolute::AbsoluteStage`]). So the score is also
//! taken in the covariance's own frame of reference, as the relative
//! stage's NEES is ([`super::consistency`]): the map frame is the relative
//! stage's world frame at the anchor, and that frame is pinned by the
//! relative stage's origin (the keyframe that fixed its window, exact by
//! definition). The truth is carried from the origin's instant to the
//! position's and put on the estimated origin:
//!
//! ```text
//! p_true' = T_world_origin_est (T_world_origin_gt^-1 p_gt)      e = p_true' - p_map
//! ```

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use serde::Serialize;

use super::align::Sim3;
use super::consistency::{interpolate, marginal_per_dof, median};
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
    /// Each axis of the map frame alone, its error against its own
    /// variance (`e_i^2 / C_ii`, the mean over axes and positions): 1 when
    /// the published sigmas of x, y and z are right whatever their
    /// correlations (see [`super::consistency`]).
    pub marginal_per_dof: f64,
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
    summarise(positions.iter().filter_map(|p| {
        let truth = interpolate(ground_truth, p.t_ns)?.translation.vector;
        let e = truth - alignment.transform_point(&p.position_m);
        per_dof(&e, &(s2 * (r * p.covariance_m2 * r.transpose())))
    }))
}

/// The origin a map frame is pinned by: the relative stage's origin when
/// the map was anchored (its stamp and estimated pose, exact by
/// definition).
#[allow(non_snake_case)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapOrigin {
    /// Stamp of the origin, ns.
    pub t_ns: i64,
    /// Its estimated body pose in the map frame.
    pub T_map_origin: Isometry3<f64>,
}

/// NEES of every position the ground truth covers, with the error taken
/// from `origin` (module docs); None when none is, or when the truth does
/// not cover the origin.
pub fn map_position_nees_from_origin(
    positions: &[MapPosition],
    origin: &MapOrigin,
    ground_truth: &Trajectory,
) -> Option<PositionNeesReport> {
    let truth_origin = interpolate(ground_truth, origin.t_ns)?;
    let truth_to_map = origin.T_map_origin * truth_origin.inverse();
    summarise(positions.iter().filter_map(|p| {
        let truth = interpolate(ground_truth, p.t_ns)?.translation.vector;
        let e = (truth_to_map * Point3::from(truth)).coords - p.position_m;
        per_dof(&e, &p.covariance_m2)
    }))
}

/// `e^T C^-1 e / 3` and the axes alone (`marginal_per_dof`), when `C` is
/// positive definite and the result finite.
fn per_dof(e: &Vector3<f64>, c: &Matrix3<f64>) -> Option<(f64, f64)> {
    let c = 0.5 * (c + c.transpose());
    let nees = c.cholesky()?.solve(e).dot(e);
    let marginal = marginal_per_dof(e, &c);
    (nees.is_finite() && marginal.is_finite()).then_some((nees / 3.0, marginal))
}

fn summarise(scores: impl Iterator<Item = (f64, f64)>) -> Option<PositionNeesReport> {
    let (mut per_dof, marginal): (Vec<f64>, Vec<f64>) = scores.unzip();
    if per_dof.is_empty() {
        return None;
    }
    let n = per_dof.len();
    let mean_per_dof = per_dof.iter().sum::<f64>() / n as f64;
    let within_95 = per_dof.iter().filter(|v| **v * 3.0 <= CHI2_3DOF_95).count() as f64 / n as f64;
    let median_per_dof = median(&mut per_dof);
    let marginal_per_dof = marginal.iter().sum::<f64>() / n as f64;
    Some(PositionNeesReport {
        positions: n,
        mean_per_dof,
        median_per_dof,
        within_95,
        marginal_per_dof,
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
        assert!((r.marginal_per_dof - 1.0).abs() < 0.12, "{r:?}");

        for p in positions.iter_mut() {
            p.covariance_m2 /= 4.0;
        }
        let over = map_position_nees(&positions, &alignment, &gt).unwrap();
        assert!((over.mean_per_dof / r.mean_per_dof - 4.0).abs() < 1e-9);
        assert!((over.marginal_per_dof / r.marginal_per_dof - 4.0).abs() < 1e-9);
        assert!(over.within_95 < 0.6, "{over:?}");

        // Without the alignment the same positions are far off.
        let unaligned = map_position_nees(&positions, &Sim3::identity(), &gt).unwrap();
        assert!(unaligned.mean_per_dof > 100.0, "{unaligned:?}");
    }

    /// A map pinned by an origin: every run's positions share a shift
    /// (where its anchor was put, 4 cm) on top of their own noise (1 cm),
    /// and publish both in their covariance. Scored from the origin the
    /// runs average 1 per dof; after the fitted alignment, which takes the
    /// shift away, far below; with the shift left out of the covariance,
    /// the origin's score is far above.
    #[test]
    fn positions_scored_from_the_origin_keep_the_shift_the_run_shares() {
        use nalgebra::Translation3;

        use crate::eval::align::umeyama;
        let gt = truth();
        let origin_at = 100;
        let origin = MapOrigin {
            t_ns: gt.poses[origin_at].t_ns,
            T_map_origin: Isometry3::from_parts(
                Translation3::new(0.3, -1.0, 0.2),
                UnitQuaternion::from_euler_angles(0.01, -0.02, 0.8),
            ),
        };
        let truth_to_map = origin.T_map_origin * gt.poses[origin_at].T_world_body.inverse();
        let (shared, own) = (0.04_f64, 0.01_f64);
        let covariance_m2 = Matrix3::identity() * (shared * shared + own * own);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut normal = || Vector3::from_fn(|_, _| StandardNormal.sample(&mut rng));
        let (mut from_origin, mut aligned, mut without_shift) = (0.0, 0.0, 0.0);
        let runs = 200;
        for _ in 0..runs {
            let shift = shared * normal();
            let positions: Vec<MapPosition> = gt
                .poses
                .iter()
                .step_by(20)
                .map(|pose| MapPosition {
                    t_ns: pose.t_ns,
                    position_m: (truth_to_map * Point3::from(pose.position())).coords
                        + shift
                        + own * normal(),
                    covariance_m2,
                })
                .collect();
            from_origin += map_position_nees_from_origin(&positions, &origin, &gt)
                .unwrap()
                .mean_per_dof;
            let est: Vec<_> = positions.iter().map(|p| p.position_m).collect();
            let truth: Vec<_> = gt.poses.iter().step_by(20).map(|p| p.position()).collect();
            let alignment = umeyama(&est, &truth, false).unwrap();
            aligned += map_position_nees(&positions, &alignment, &gt)
                .unwrap()
                .mean_per_dof;
            let own_only: Vec<_> = positions
                .iter()
                .map(|p| MapPosition {
                    covariance_m2: Matrix3::identity() * own * own,
                    ..*p
                })
                .collect();
            without_shift += map_position_nees_from_origin(&own_only, &origin, &gt)
                .unwrap()
                .mean_per_dof;
        }
        let runs = runs as f64;
        let (from_origin, aligned, without_shift) =
            (from_origin / runs, aligned / runs, without_shift / runs);
        assert!((from_origin - 1.0).abs() < 0.15, "{from_origin}");
        assert!(aligned < 0.1, "{aligned}");
        assert!(without_shift > 10.0, "{without_shift}");
    }

    /// Without the truth at the origin's instant there is no score.
    #[test]
    fn an_origin_outside_the_truth_is_not_scored() {
        let gt = truth();
        let origin = MapOrigin {
            t_ns: -1_000_000_000,
            T_map_origin: Isometry3::identity(),
        };
        let at = MapPosition {
            t_ns: 0,
            position_m: Vector3::zeros(),
            covariance_m2: Matrix3::identity(),
        };
        assert_eq!(map_position_nees_from_origin(&[at], &origin, &gt), None);
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
