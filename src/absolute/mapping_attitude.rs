//! The map's error from its origin that the relative stage's attitude
//! puts in it.
//!
//! The map is solved from differences between landmarks seen in the same
//! frame, turned into the world frame with the relative stage's
//! orientation of that frame. Its translation drift cancels in those
//! differences; its attitude error does not, and the map's own
//! covariance (from the landmarks' measured noise) has none of it, so a
//! robot corrected against those landmarks is placed with that error
//! and a covariance that does not know it.
//!
//! The model: the relative stage's attitude error grows by independent
//! steps `w_j` (its rotation covariance `Σθ`, world axes, grows by
//! `Q_j`), and a step taken with the robot at `p_j` turns everything
//! mapped after it about `p_j`: a landmark mapped at `x` is off by
//! `Σ_j w_j × (x − p_j)` over the steps before its mapping. A robot at
//! `p` that sees it at `b = x − p` through the relative stage's attitude
//! of now (off by all the steps, `Σ_j w_j × b`) is placed off by the
//! difference: `Σ_j w_j × (p − p_j)` over the steps before the mapping
//! (covariance `Σ_j [p − p_j]× Q_j [p − p_j]×ᵀ`: the heading error turned
//! the map about where the robot was when it grew, and a robot far from
//! there is placed as far off), and `−Σ_j w_j × b` over the steps since
//! (`[b]× (Σ Q_now − Σ Q_mapped) [b]×ᵀ`). Three running sums give the
//! first for any `p` (`Σ Q_j`, `Σ [p_j]× Q_j`, `Σ [p_j]× Q_j [p_j]×ᵀ`),
//! kept as they were in each frame that mapped a landmark. The
//! orientation filter ([`super::orientation_filter`]) would take the
//! steps since out where it follows them; it lets its offset wander by a
//! fraction of what a relative stage's heading does (a simulated room
//! with a heading that walks 0.1 deg per sqrt(m) is consistent with the
//! second term and twice too sure without it), so they stay.
//!
//! Positions are from the map's anchor; the anchor's own attitude
//! covariance is the first step, taken there. `Q_j` is the part of the
//! published `Σθ` beyond what the sums hold already (its positive part:
//! roll and pitch, which gravity bounds, add nothing once their sigma
//! stops growing). A relative stage that starts over publishes its
//! covariance from a new origin, from zero again: the steps are then
//! counted from what the sums held when the origin moved.
//!
//! A position corrected against several landmarks carries the mean of
//! their covariances: their errors come from one drifting attitude, so
//! they are taken as fully correlated (a mean of covariances, not the
//! covariance of a mean). A landmark first mapped on a later pass,
//! placed by the map against landmarks mapped before, takes the larger
//! sums of then: that leans to the cautious side.

use nalgebra::{Matrix3, Matrix6, SymmetricEigen, Vector3};

/// The attitude steps up to a frame and where they were taken:
/// `Σ Q_j`, `Σ [p_j]× Q_j` and `Σ [p_j]× Q_j [p_j]×ᵀ`, positions `p_j` from
/// a point of the map (the anchor while mapping; a saved map keeps them
/// about each landmark's own position).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AttitudeMoments {
    /// `Σ Q_j`, rad².
    pub steps_rad2: Matrix3<f64>,
    /// `Σ [p_j]× Q_j`, m rad².
    pub first_m_rad2: Matrix3<f64>,
    /// `Σ [p_j]× Q_j [p_j]×ᵀ`, m² rad².
    pub second_m2_rad2: Matrix3<f64>,
}

impl AttitudeMoments {
    /// `Σ_j [p − p_j]× Q_j [p − p_j]×ᵀ`, m²: what the steps put in a robot
    /// at `p_m` (from the same point) placed against what was mapped
    /// after them, its attitude taken from the map.
    pub fn covariance_at(&self, p_m: &Vector3<f64>) -> Matrix3<f64> {
        let p = p_m.cross_matrix();
        let c = p * self.steps_rad2 * p.transpose()
            - p * self.first_m_rad2.transpose()
            - self.first_m_rad2 * p.transpose()
            + self.second_m2_rad2;
        (c + c.transpose()) * 0.5
    }

    /// The same steps with positions from `x_m` instead (`p_j − x`).
    pub fn about(&self, x_m: &Vector3<f64>) -> Self {
        let x = x_m.cross_matrix();
        let second = self.second_m2_rad2
            - x * self.first_m_rad2.transpose()
            - self.first_m_rad2 * x.transpose()
            + x * self.steps_rad2 * x.transpose();
        Self {
            steps_rad2: self.steps_rad2,
            first_m_rad2: self.first_m_rad2 - x * self.steps_rad2,
            second_m2_rad2: (second + second.transpose()) * 0.5,
        }
    }

    /// The same steps in a frame turned by `r` (new = `r` old).
    pub fn rotated(&self, r: &Matrix3<f64>) -> Self {
        Self {
            steps_rad2: r * self.steps_rad2 * r.transpose(),
            first_m_rad2: r * self.first_m_rad2 * r.transpose(),
            second_m2_rad2: r * self.second_m2_rad2 * r.transpose(),
        }
    }

    /// Whether the sums can be steps at all (what a file may hold): every
    /// entry finite, and `Σ [I; [p_j]×] Q_j [I; [p_j]×]ᵀ`, the 6x6 matrix
    /// `[[ΣQ, (Σ[p]×Q)ᵀ], [Σ[p]×Q, Σ[p]×Q[p]×ᵀ]]` they make, symmetric and
    /// positive semi-definite: then the covariance they give at any
    /// position is one too.
    pub fn is_usable(&self) -> bool {
        if ![self.steps_rad2, self.first_m_rad2, self.second_m2_rad2]
            .iter()
            .all(|m| m.iter().all(|v| v.is_finite()))
        {
            return false;
        }
        let mut joint = Matrix6::zeros();
        joint
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&self.steps_rad2);
        joint
            .fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&self.first_m_rad2.transpose());
        joint
            .fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&self.first_m_rad2);
        joint
            .fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&self.second_m2_rad2);
        let size = joint.amax().max(1e-300);
        if (joint - joint.transpose()).amax() > 1e-9 * size {
            return false;
        }
        let joint = (joint + joint.transpose()) * 0.5;
        SymmetricEigen::new(joint).eigenvalues.min() >= -1e-9 * size
    }
}

/// The running sums, and per map landmark the sums of its first
/// mapping frame.
#[derive(Clone, Debug, Default)]
pub(crate) struct MappingAttitude {
    now: AttitudeMoments,
    /// The sums of frames that mapped a landmark first, in order.
    snapshots: Vec<AttitudeMoments>,
    /// Whether the last snapshot is `now`.
    snapshot_current: bool,
    /// Per map id: 1 + its mapping frame's index in `snapshots`, 0 when
    /// not mapped yet.
    by_id: Vec<u32>,
    /// The stamp of the origin the relative stage's covariance is taken
    /// from, and the steps held when it moved there: a relative stage
    /// that starts over (after a loss) publishes its covariance from a
    /// new origin, growing from zero again, and only what it adds beyond
    /// that origin is a step.
    origin: Option<(i64, Matrix3<f64>)>,
}

impl MappingAttitude {
    /// Takes the relative stage's rotation covariance of a frame (rad²,
    /// world axes), from the origin stamped `origin_t_ns`, with the robot
    /// at `position_m` from the map's anchor: its growth beyond what the
    /// sums hold since that origin is a step taken there. A covariance or
    /// position that is not finite, or a covariance that is not
    /// symmetric, is ignored.
    pub(crate) fn advance(
        &mut self,
        rotation_covariance: &Matrix3<f64>,
        origin_t_ns: i64,
        position_m: &Vector3<f64>,
    ) {
        let usable = rotation_covariance.iter().all(|v| v.is_finite())
            && position_m.iter().all(|v| v.is_finite())
            && (rotation_covariance - rotation_covariance.transpose()).amax()
                <= 1e-9 * rotation_covariance.amax().max(1e-300);
        if !usable {
            return;
        }
        let held_at_origin = match self.origin {
            Some((stamp, held)) if stamp == origin_t_ns => held,
            _ => {
                // The first origin is the anchor's world: nothing held.
                let held = if self.origin.is_some() {
                    self.now.steps_rad2
                } else {
                    Matrix3::zeros()
                };
                self.origin = Some((origin_t_ns, held));
                held
            }
        };
        let growth =
            SymmetricEigen::new(rotation_covariance - (self.now.steps_rad2 - held_at_origin));
        if growth.eigenvalues.iter().all(|&v| v <= 0.0) {
            return;
        }
        let step = growth.eigenvectors
            * Matrix3::from_diagonal(&growth.eigenvalues.map(|v| v.max(0.0)))
            * growth.eigenvectors.transpose();
        let step = (step + step.transpose()) * 0.5;
        let lever = position_m.cross_matrix();
        self.now.steps_rad2 += step;
        self.now.first_m_rad2 += lever * step;
        self.now.second_m2_rad2 += lever * step * lever.transpose();
        self.snapshot_current = false;
    }

    /// Notes map landmark `id` as mapped now, unless it was before (its
    /// first mapping frame keeps it).
    pub(crate) fn note_mapped(&mut self, id: u32) {
        let k = id as usize;
        if self.by_id.len() <= k {
            self.by_id.resize(k + 1, 0);
        }
        if self.by_id[k] != 0 {
            return;
        }
        if !self.snapshot_current || self.snapshots.is_empty() {
            self.snapshots.push(self.now);
            self.snapshot_current = true;
        }
        self.by_id[k] = self.snapshots.len() as u32;
    }

    /// The sums as they were when map landmark `id` was mapped
    /// (positions from the map's anchor), if it was noted.
    pub(crate) fn mapped_moments(&self, id: u32) -> Option<&AttitudeMoments> {
        let slot = *self.by_id.get(id as usize)?;
        self.snapshots.get((slot as usize).checked_sub(1)?)
    }

    /// The covariance (m²) the relative stage's attitude errors put in a
    /// robot at `robot_m` from the map's anchor corrected against
    /// `landmarks`, each with its offset from the robot (world axes): the
    /// mean over those noted. Zero when none is.
    pub(crate) fn position_covariance_m2(
        &self,
        landmarks: impl IntoIterator<Item = (u32, Vector3<f64>)>,
        robot_m: &Vector3<f64>,
    ) -> Matrix3<f64> {
        let mut sum = Matrix3::zeros();
        let mut count = 0usize;
        for (id, offset) in landmarks {
            let Some(sums) = self.mapped_moments(id) else {
                continue;
            };
            let b = offset.cross_matrix();
            sum += sums.covariance_at(robot_m)
                + b * (self.now.steps_rad2 - sums.steps_rad2) * b.transpose();
            count += 1;
        }
        if count == 0 {
            return Matrix3::zeros();
        }
        let mean = sum / count as f64;
        (mean + mean.transpose()) * 0.5
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::UnitQuaternion;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    use super::*;

    fn heading(variance: f64) -> Matrix3<f64> {
        Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, variance))
    }

    #[test]
    fn a_heading_step_turns_the_map_about_where_it_was_taken() {
        // A heading step of variance s² at the anchor, a landmark mapped
        // then: a robot 5 m along x is placed 5 s off along y, whatever
        // the landmark's offset from it (it saw it with the same
        // heading error the map was built with).
        let s2 = 1e-4;
        let mut attitude = MappingAttitude::default();
        attitude.advance(&heading(s2), 0, &Vector3::zeros());
        attitude.note_mapped(4);
        let robot = Vector3::new(5.0, 0.0, 0.0);
        let c = attitude.position_covariance_m2([(4, Vector3::new(0.0, 2.0, 1.0))], &robot);
        let expected = Matrix3::from_diagonal(&Vector3::new(0.0, 25.0 * s2, 0.0));
        assert!((c - expected).amax() < 1e-15, "{c}");
        // A second step, taken at the robot after the mapping: it turns
        // the robot's view of the landmark (3 m along y: off along x),
        // not the map about the robot.
        attitude.advance(&heading(3.0 * s2), 0, &robot);
        let b = Vector3::new(0.0, 3.0, 0.0);
        let c = attitude.position_covariance_m2([(4, b)], &robot);
        let expected = Matrix3::from_diagonal(&Vector3::new(9.0 * 2.0 * s2, 25.0 * s2, 0.0));
        assert!((c - expected).amax() < 1e-15, "{c}");
        // A landmark mapped after both steps, seen from the anchor: only
        // the second step, taken 5 m away, places the robot off.
        attitude.note_mapped(5);
        let c = attitude.position_covariance_m2([(5, b)], &Vector3::zeros());
        let expected = Matrix3::from_diagonal(&Vector3::new(0.0, 25.0 * 2.0 * s2, 0.0));
        assert!((c - expected).amax() < 1e-15, "{c}");
    }

    #[test]
    fn the_model_matches_a_drifting_dead_reckoning_drawn_many_times() {
        // Independent reference: a relative stage whose attitude error
        // walks by full 3-D steps integrates its path and places a
        // landmark through rotations, and the robot, later, through the
        // rotation of then; the error of the robot's position over many
        // draws against the model's covariance.
        let path: Vec<Vector3<f64>> = (0..30)
            .map(|k| {
                let t = k as f64 * 0.2;
                Vector3::new(4.0 * t.sin(), 3.0 * (1.0 - t.cos()), 0.1 * t)
            })
            .collect();
        let landmark = Vector3::new(6.0, 4.0, 1.5);
        let (mapped_at, robot_at) = (10, 24);
        let q = Matrix3::new(2.0, 0.3, 0.1, 0.3, 1.0, -0.2, 0.1, -0.2, 5.0) * 1e-6;
        let l = q.cholesky().expect("positive definite").l();
        let mut attitude = MappingAttitude::default();
        for (k, p) in path.iter().enumerate().take(robot_at + 1) {
            attitude.advance(&(q * (k + 1) as f64), 0, &(p - path[0]));
            if k == mapped_at {
                attitude.note_mapped(0);
            }
        }
        let robot = path[robot_at] - path[0];
        let model = attitude.position_covariance_m2([(0, landmark - path[robot_at])], &robot);
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let draws = 40_000;
        let mut drawn = Matrix3::zeros();
        for _ in 0..draws {
            let mut error = Vector3::zeros();
            let mut estimate = path[0];
            let mut seen = Vector3::zeros();
            let mut robot_estimate = Vector3::zeros();
            for k in 0..=robot_at {
                let w = l * Vector3::from_fn(|_, _| StandardNormal.sample(&mut rng));
                error += w;
                let turn = UnitQuaternion::from_scaled_axis(error);
                if k == mapped_at {
                    seen = estimate + turn * (landmark - path[k]);
                }
                if k == robot_at {
                    robot_estimate = seen - turn * (landmark - path[k]);
                }
                if k + 1 < path.len() {
                    estimate += turn * (path[k + 1] - path[k]);
                }
            }
            let e = robot_estimate - path[robot_at];
            drawn += e * e.transpose();
        }
        drawn /= draws as f64;
        assert!(
            (drawn - model).amax() < 0.03 * model.amax(),
            "drawn {drawn} model {model}"
        );
    }

    #[test]
    fn moments_moved_to_another_point_give_the_same_covariance() {
        // Steps at three places; the sums about a landmark (as a saved
        // map keeps them) must give every robot position's covariance
        // as the sums about the anchor do.
        let mut attitude = MappingAttitude::default();
        let q = Matrix3::new(2.0, 0.3, 0.1, 0.3, 1.0, -0.2, 0.1, -0.2, 5.0) * 1e-6;
        for (k, p) in [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(3.0, -1.0, 0.2),
            Vector3::new(6.0, 2.0, 0.5),
        ]
        .iter()
        .enumerate()
        {
            attitude.advance(&(q * (k + 1) as f64), 0, p);
        }
        let at_anchor = attitude.now;
        let landmark = Vector3::new(4.0, 5.0, 1.5);
        let about = at_anchor.about(&landmark);
        for robot in [
            Vector3::new(1.0, 2.0, 0.0),
            Vector3::new(-3.0, 0.5, 1.0),
            landmark,
        ] {
            let direct = at_anchor.covariance_at(&robot);
            let moved = about.covariance_at(&(robot - landmark));
            assert!(
                (direct - moved).amax() < 1e-12 * direct.amax(),
                "{direct} {moved}"
            );
        }
        assert!(about.is_usable() && at_anchor.is_usable());
        // Sums no steps can make: each block fine alone, the first moment
        // too large for the other two (a covariance that would go
        // negative at some position).
        let impossible = AttitudeMoments {
            first_m_rad2: at_anchor.first_m_rad2 * 1e3,
            ..at_anchor
        };
        assert!(!impossible.is_usable());
        let robot = Vector3::new(50.0, -20.0, 3.0);
        assert!(
            SymmetricEigen::new(impossible.covariance_at(&robot))
                .eigenvalues
                .min()
                < 0.0
                || SymmetricEigen::new(impossible.covariance_at(&-robot))
                    .eigenvalues
                    .min()
                    < 0.0
        );
    }

    #[test]
    fn a_bounded_tilt_adds_no_step_once_it_stops_growing() {
        // Roll and pitch: gravity holds them, their variance rises then
        // falls; only the rise is a step. The heading keeps growing.
        let mut attitude = MappingAttitude::default();
        let p = Vector3::new(1.0, 0.0, 0.0);
        attitude.advance(
            &Matrix3::from_diagonal(&Vector3::new(4e-6, 4e-6, 1e-6)),
            0,
            &p,
        );
        attitude.advance(
            &Matrix3::from_diagonal(&Vector3::new(1e-6, 1e-6, 2e-6)),
            0,
            &p,
        );
        let expected = Matrix3::from_diagonal(&Vector3::new(4e-6, 4e-6, 2e-6));
        assert!(
            (attitude.now.steps_rad2 - expected).amax() < 1e-18,
            "{}",
            attitude.now.steps_rad2
        );
        // A covariance that shrinks everywhere adds nothing at all.
        let before = attitude.now;
        attitude.advance(&(Matrix3::identity() * 1e-7), 0, &p);
        assert_eq!(attitude.now, before);
    }

    #[test]
    fn a_relative_stage_that_starts_over_adds_steps_from_its_new_origin() {
        // The heading variance grows to 4e-6, the relative stage starts
        // over (a new origin) and publishes from zero again: 1e-6 there is
        // a step of 1e-6, not nothing (below the 4e-6 held), and the
        // attitude error held before stays.
        let mut attitude = MappingAttitude::default();
        let p = Vector3::zeros();
        attitude.advance(&heading(4e-6), 0, &p);
        attitude.advance(&heading(1e-6), 5, &p);
        assert!((attitude.now.steps_rad2[(2, 2)] - 5e-6).abs() < 1e-18);
        attitude.advance(&heading(3e-6), 5, &p);
        assert!((attitude.now.steps_rad2[(2, 2)] - 7e-6).abs() < 1e-18);
        // The same origin again: nothing new below what it published.
        attitude.advance(&heading(2e-6), 5, &p);
        assert!((attitude.now.steps_rad2[(2, 2)] - 7e-6).abs() < 1e-18);
    }

    #[test]
    fn unusable_inputs_leave_the_sums_alone() {
        let mut attitude = MappingAttitude::default();
        attitude.advance(&heading(1e-6), 0, &Vector3::zeros());
        let before = attitude.now;
        let mut nan = heading(2e-6);
        nan[(0, 1)] = f64::NAN;
        attitude.advance(&nan, 0, &Vector3::zeros());
        let mut skew = heading(2e-6);
        skew[(0, 1)] = 1e-7;
        attitude.advance(&skew, 0, &Vector3::zeros());
        attitude.advance(&heading(2e-6), 0, &Vector3::new(f64::INFINITY, 0.0, 0.0));
        assert_eq!(attitude.now, before);
    }

    #[test]
    fn a_landmark_keeps_its_first_mapping_and_the_correction_averages() {
        let mut attitude = MappingAttitude::default();
        attitude.advance(&heading(1e-6), 0, &Vector3::zeros());
        attitude.note_mapped(1);
        attitude.advance(&heading(9e-6), 0, &Vector3::zeros());
        attitude.note_mapped(1);
        attitude.note_mapped(2);
        // Two landmarks mapped in one frame share its sums.
        attitude.note_mapped(3);
        assert_eq!(attitude.snapshots.len(), 2);
        let robot = Vector3::new(1.0, 0.0, 0.0);
        let at = |ids: &[u32]| {
            let landmarks = ids.iter().map(|&id| (id, Vector3::zeros()));
            attitude.position_covariance_m2(landmarks, &robot)[(1, 1)]
        };
        assert!((at(&[1]) - 1e-6).abs() < 1e-18);
        assert!((at(&[2]) - 9e-6).abs() < 1e-18);
        assert!((at(&[1, 2]) - 5e-6).abs() < 1e-18);
        // Landmarks never noted are left out, not counted as zero.
        assert!((at(&[1, 7]) - 1e-6).abs() < 1e-18);
        assert_eq!(at(&[7]), 0.0);
        assert_eq!(at(&[]), 0.0);
    }
}
