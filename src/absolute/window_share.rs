//! How much of a landmark's window estimate is new.
//!
//! The relative stage hands on, for every frame, its sliding window's
//! estimate of each landmark in view. Frames between two keyframes hand
//! on the same estimate, and consecutive keyframes' estimates share most
//! of their observations (see [`WindowSupport`]). Whoever uses such
//! estimates repeatedly (the map's frame nodes, the position filter's
//! published covariance) must count only the share each one adds: the
//! window keyframes new since the landmark's estimate was last used, out
//! of those the estimate rests on.

use crate::relative::types::WindowSupport;

/// Per map id, the newest window keyframe its estimate rested on when it
/// was last used.
#[derive(Clone, Debug, Default)]
pub(crate) struct WindowShares {
    used_up_to_keyframe: Vec<Option<u64>>,
}

impl WindowShares {
    /// The share of landmark `id`'s estimate (resting on `support`) that
    /// is new since its last use: 1 at its first use, or without a
    /// window; the new keyframes over the keyframes it rests on
    /// otherwise (0 for the same estimate again). A landmark is taken to be
    /// seen by every keyframe between the two uses' newest (a continuous
    /// track); where it was not, the share is over-estimated, as without
    /// this rule.
    pub(crate) fn share(&self, id: u32, support: Option<WindowSupport>) -> f64 {
        let Some(support) = support.filter(|s| s.keyframes > 0) else {
            return 1.0;
        };
        match self.used_up_to_keyframe.get(id as usize).copied().flatten() {
            None => 1.0,
            Some(last) => {
                let new = support
                    .newest_keyframe
                    .saturating_sub(last)
                    .min(u64::from(support.keyframes));
                new as f64 / f64::from(support.keyframes)
            }
        }
    }

    /// Notes that landmark `id`'s estimate resting on `support` was used.
    pub(crate) fn note_used(&mut self, id: u32, support: Option<WindowSupport>) {
        let Some(support) = support.filter(|s| s.keyframes > 0) else {
            return;
        };
        let k = id as usize;
        if self.used_up_to_keyframe.len() <= k {
            self.used_up_to_keyframe.resize(k + 1, None);
        }
        self.used_up_to_keyframe[k] = Some(support.newest_keyframe);
    }

    /// [`Self::share`], then [`Self::note_used`].
    pub(crate) fn use_estimate(&mut self, id: u32, support: Option<WindowSupport>) -> f64 {
        let share = self.share(id, support);
        self.note_used(id, support);
        share
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn support(keyframes: u16, newest_keyframe: u64) -> Option<WindowSupport> {
        Some(WindowSupport {
            keyframes,
            newest_keyframe,
        })
    }

    #[test]
    fn the_first_use_and_estimates_without_a_window_count_whole() {
        let mut shares = WindowShares::default();
        assert_eq!(shares.use_estimate(3, support(10, 7)), 1.0);
        assert_eq!(shares.use_estimate(4, None), 1.0);
        assert_eq!(shares.use_estimate(4, None), 1.0);
        // No keyframes: nothing to compare with.
        assert_eq!(shares.use_estimate(5, support(0, 7)), 1.0);
        assert_eq!(shares.use_estimate(5, support(0, 7)), 1.0);
    }

    #[test]
    fn a_later_use_counts_the_new_keyframes() {
        let mut shares = WindowShares::default();
        shares.use_estimate(2, support(10, 7));
        // The same estimate again: nothing new.
        assert_eq!(shares.share(2, support(10, 7)), 0.0);
        // Three new keyframes of ten.
        assert!((shares.share(2, support(10, 10)) - 0.3).abs() < 1e-15);
        // More new keyframes than it rests on: all of it.
        assert_eq!(shares.share(2, support(4, 20)), 1.0);
        // Looking does not note a use; using does.
        assert!((shares.use_estimate(2, support(10, 10)) - 0.3).abs() < 1e-15);
        assert_eq!(shares.share(2, support(10, 10)), 0.0);
        // A keyframe number going back (it never should) is no new one.
        assert_eq!(shares.share(2, support(10, 3)), 0.0);
    }
}
