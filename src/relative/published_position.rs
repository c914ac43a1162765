//! Where the relative stage says the body is: its estimate, except that a
//! keyframe solve's correction of the position reaches the published pose
//! at a bounded speed instead of in one step.
//!
//! A keyframe's pose goes out as tracked; the window's solve that follows
//! may move it (in a monocular window whose scale is still settling, by
//! centimetres), and the next frame, tracked against the corrected window,
//! would carry the whole correction as one step. A controller reads such a
//! step as motion. Here the published position of the solved keyframe is
//! kept where it was sent, the difference is held as an offset on the
//! estimate, and the offset shrinks by at most `speed_m_s` per second of
//! frame time. A correction smaller than one frame's allowance is gone by
//! the next frame, so in steady tracking the published pose is the
//! estimate.

use nalgebra::Vector3;

/// The offset between the published and the estimated position.
#[derive(Debug, Clone)]
pub(crate) struct PublishedPosition {
    /// Largest speed at which a correction reaches the published pose,
    /// m/s; 0: at once.
    speed_m_s: f64,
    /// Published minus estimated position, world frame, m.
    offset_m: Vector3<f64>,
    /// Stamp up to which the offset has been shrunk.
    t_ns: Option<i64>,
}

impl PublishedPosition {
    pub(crate) fn new(speed_m_s: f64) -> Self {
        Self {
            speed_m_s,
            offset_m: Vector3::zeros(),
            t_ns: None,
        }
    }

    /// The position to publish at `t_ns` for the estimate `estimate_m`:
    /// the offset first shrunk by the time since the last call (never
    /// grown by a stamp that goes back).
    pub(crate) fn at(&mut self, t_ns: i64, estimate_m: &Vector3<f64>) -> Vector3<f64> {
        let dt_s = self.t_ns.map_or(0.0, |t| (t_ns - t).max(0) as f64 * 1e-9);
        self.t_ns = Some(self.t_ns.map_or(t_ns, |t| t.max(t_ns)));
        let size = self.offset_m.norm();
        let allowance = self.speed_m_s * dt_s;
        self.offset_m = if size <= allowance {
            Vector3::zeros()
        } else {
            self.offset_m * ((size - allowance) / size)
        };
        estimate_m + self.offset_m
    }

    /// The estimate was corrected to `estimate_m` where `published_m` had
    /// already gone out for the same instant: go on from the published
    /// position (with a speed of 0, from the estimate).
    pub(crate) fn hold(&mut self, published_m: &Vector3<f64>, estimate_m: &Vector3<f64>) {
        if self.speed_m_s > 0.0 {
            self.offset_m = published_m - estimate_m;
        }
    }

    /// Forgets the offset (a new start).
    pub(crate) fn clear(&mut self) {
        self.offset_m = Vector3::zeros();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FRAME_NS: i64 = 50_000_000;

    #[test]
    fn a_correction_is_spread_over_frames_at_the_given_speed() {
        let mut published = PublishedPosition::new(0.2);
        let mut estimate = Vector3::new(1.0, 0.0, 0.0);
        let before = published.at(0, &estimate);
        assert_eq!(before, estimate);
        // The solve moves the estimate of the same instant by 5 cm.
        let corrected = estimate + Vector3::new(0.0, 0.05, 0.0);
        published.hold(&before, &corrected);
        assert_eq!(published.at(0, &corrected), before);
        estimate = corrected;
        let mut last = before;
        let mut frames = 0;
        for i in 1..20 {
            let p = published.at(i * FRAME_NS, &estimate);
            // 0.2 m/s at 20 Hz: 1 cm a frame, the rig standing still.
            assert!(
                (p - last).norm() <= 0.01 + 1e-12,
                "frame {i}: {}",
                (p - last).norm()
            );
            if p != estimate {
                frames = i;
            }
            last = p;
        }
        assert_eq!(last, estimate, "the correction reaches the published pose");
        assert_eq!(
            frames, 4,
            "5 cm at 1 cm a frame: the fifth frame is the estimate"
        );
    }

    #[test]
    fn a_correction_within_one_frame_allowance_is_gone_by_the_next_frame() {
        let mut published = PublishedPosition::new(0.2);
        let estimate = Vector3::new(0.0, 0.0, 1.0);
        let before = published.at(0, &estimate);
        let corrected = estimate + Vector3::new(0.004, 0.0, 0.0);
        published.hold(&before, &corrected);
        assert_eq!(published.at(FRAME_NS, &corrected), corrected);
    }

    #[test]
    fn at_speed_zero_the_estimate_goes_out_at_once() {
        let mut published = PublishedPosition::new(0.0);
        let estimate = Vector3::new(0.0, 0.0, 1.0);
        let before = published.at(0, &estimate);
        let corrected = estimate + Vector3::new(0.3, 0.0, 0.0);
        published.hold(&before, &corrected);
        assert_eq!(published.at(0, &corrected), corrected);
    }

    #[test]
    fn a_stamp_that_goes_back_does_not_grow_or_shrink_the_offset() {
        let mut published = PublishedPosition::new(0.2);
        let estimate = Vector3::zeros();
        published.at(10 * FRAME_NS, &estimate);
        published.hold(&Vector3::new(0.1, 0.0, 0.0), &estimate);
        let p = published.at(5 * FRAME_NS, &estimate);
        assert_eq!(p, Vector3::new(0.1, 0.0, 0.0));
        // Shrunk from the latest stamp seen, not from the one that went back.
        let p = published.at(11 * FRAME_NS, &estimate);
        assert!((p.x - 0.09).abs() < 1e-12, "{}", p.x);
        published.clear();
        assert_eq!(published.at(11 * FRAME_NS, &estimate), estimate);
    }
}
