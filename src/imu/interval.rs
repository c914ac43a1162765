//! From a raw IMU stream to the samples of one frame interval.
//!
//! [`ImuStream`] takes samples as they arrive, applies the intrinsic
//! correction (eq. 14-16), and drops what cannot be integrated: non-finite
//! readings and stamps that repeat or go backwards. Every dropped sample is
//! remembered with where in the stream it arrived, so that
//! [`ImuStream::interval`] can report the damage inside each frame interval.
//! Uneven spacing and dropped samples need no repair: the integration rules
//! use the actual stamps. A gap longer than the configured limit, or any
//! dropped sample inside the interval, marks the interval unreliable.

use crate::rig::ImuIntrinsics;
use crate::sensors::ImuSample;

/// Limits an interval's samples must respect to be called reliable.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntervalConfig {
    /// Longest acceptable time between consecutive samples.
    pub max_gap_ns: i64,
}

impl Default for IntervalConfig {
    /// 25 ms: four missing samples at 200 Hz.
    fn default() -> Self {
        Self {
            max_gap_ns: 25_000_000,
        }
    }
}

/// Why a sample was not used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RejectReason {
    /// A NaN or infinite value.
    NotFinite,
    /// Same stamp as the previous accepted sample.
    RepeatedStamp,
    /// Stamp before the previous accepted sample.
    Backwards,
}

/// A sample that was dropped, and the stamp of the last accepted sample
/// before it arrived (`i64::MIN` if none), which places it in the stream.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RejectedSample {
    /// Stamp of the last accepted sample when this one arrived, ns (`i64::MIN` if none).
    pub arrived_after_ns: i64,
    /// The rejected sample's own stamp, ns.
    pub t_ns: i64,
    /// Why it was rejected.
    pub reason: RejectReason,
}

/// What went wrong inside one interval.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct IntervalReport {
    /// Rejected samples with NaN or infinite values.
    pub not_finite: usize,
    /// Rejected samples with the same stamp as the previous accepted one.
    pub repeated_stamps: usize,
    /// Rejected samples stamped before the previous accepted one.
    pub backwards_stamps: usize,
    /// Gaps between consecutive accepted samples longer than the limit.
    pub long_gaps: usize,
    /// Longest gap between consecutive accepted samples in the interval, ns.
    pub longest_gap_ns: i64,
    /// False when anything above is non-zero.
    pub reliable: bool,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
/// Why the samples of an interval could not be gathered.
pub enum IntervalError {
    #[error("interval ends at {t_end_ns} ns, not after its start {t_start_ns} ns")]
    /// The interval's end is not after its start.
    Empty {
        /// Interval start, ns.
        t_start_ns: i64,
        /// Interval end, ns.
        t_end_ns: i64,
    },
    #[error("no IMU sample at or before the interval start {t_start_ns} ns")]
    /// No accepted sample at or before the start.
    StartNotCovered {
        /// Interval start, ns.
        t_start_ns: i64,
    },
    #[error("no IMU sample at or after the interval end {t_end_ns} ns (yet)")]
    /// No accepted sample at or after the end yet (wait for more samples).
    EndNotCovered {
        /// Interval end, ns.
        t_end_ns: i64,
    },
}

/// The samples of one interval, with one more on either side when the
/// stream has them (for the quadratic rule's centred triples).
#[derive(Debug, Clone, PartialEq)]
pub struct ImuInterval<'a> {
    /// Accepted samples from the last one at or before `t_start_ns` to the first one at or after
    /// `t_end_ns`, plus one more on either side when the stream has it.
    pub samples: &'a [ImuSample],
    /// Interval start, ns.
    pub t_start_ns: i64,
    /// Interval end, ns.
    pub t_end_ns: i64,
    /// Rejections and gaps inside the interval.
    pub report: IntervalReport,
}

/// The accepted, corrected samples of a stream, strictly increasing.
#[derive(Debug, Clone, Default)]
pub struct ImuStream {
    /// Correction applied to every accepted sample.
    pub intrinsics: ImuIntrinsics,
    samples: Vec<ImuSample>,
    rejected: Vec<RejectedSample>,
}

impl ImuStream {
    /// An empty stream that corrects samples with `intrinsics`.
    pub fn new(intrinsics: ImuIntrinsics) -> Self {
        Self {
            intrinsics,
            samples: Vec::new(),
            rejected: Vec::new(),
        }
    }

    /// A stream of all `raw` samples, in arrival order.
    pub fn from_samples(intrinsics: ImuIntrinsics, raw: &[ImuSample]) -> Self {
        let mut stream = Self::new(intrinsics);
        stream.samples.reserve(raw.len());
        for s in raw {
            stream.push(s);
        }
        stream
    }

    /// Accepts or rejects one raw sample; returns whether it was accepted.
    pub fn push(&mut self, raw: &ImuSample) -> bool {
        let last_ns = self.samples.last().map_or(i64::MIN, |s| s.t_ns);
        let reason = if !raw.is_finite() {
            Some(RejectReason::NotFinite)
        } else if raw.t_ns == last_ns {
            Some(RejectReason::RepeatedStamp)
        } else if raw.t_ns < last_ns {
            Some(RejectReason::Backwards)
        } else {
            None
        };
        match reason {
            Some(reason) => {
                self.rejected.push(RejectedSample {
                    arrived_after_ns: last_ns,
                    t_ns: raw.t_ns,
                    reason,
                });
                false
            }
            None => {
                let corrected = if self.intrinsics.is_identity() {
                    *raw
                } else {
                    self.intrinsics.correct(raw)
                };
                self.samples.push(corrected);
                true
            }
        }
    }

    /// The accepted, corrected samples, strictly increasing in time.
    pub fn samples(&self) -> &[ImuSample] {
        &self.samples
    }

    /// Every rejected sample, in arrival order.
    pub fn rejected(&self) -> &[RejectedSample] {
        &self.rejected
    }

    /// Forgets samples older than `t_ns` except the one at or before it.
    pub fn discard_before(&mut self, t_ns: i64) {
        let keep = self
            .samples
            .partition_point(|s| s.t_ns <= t_ns)
            .saturating_sub(2);
        self.samples.drain(..keep);
        let first_ns = self.samples.first().map_or(i64::MIN, |s| s.t_ns);
        self.rejected.retain(|r| r.arrived_after_ns >= first_ns);
    }

    /// The samples covering `[t_start_ns, t_end_ns]` and what went wrong in
    /// that stretch of the stream.
    pub fn interval(
        &self,
        t_start_ns: i64,
        t_end_ns: i64,
        config: &IntervalConfig,
    ) -> Result<ImuInterval<'_>, IntervalError> {
        if t_end_ns <= t_start_ns {
            return Err(IntervalError::Empty {
                t_start_ns,
                t_end_ns,
            });
        }
        let s = &self.samples;
        let after_start = s.partition_point(|x| x.t_ns <= t_start_ns);
        if after_start == 0 {
            return Err(IntervalError::StartNotCovered { t_start_ns });
        }
        let k0 = after_start - 1;
        let k1 = s.partition_point(|x| x.t_ns < t_end_ns);
        if k1 == s.len() {
            return Err(IntervalError::EndNotCovered { t_end_ns });
        }
        let mut report = IntervalReport::default();
        for pair in s[k0..=k1].windows(2) {
            let gap = pair[1].t_ns - pair[0].t_ns;
            report.longest_gap_ns = report.longest_gap_ns.max(gap);
            if gap > config.max_gap_ns {
                report.long_gaps += 1;
            }
        }
        // Rejected samples that arrived between the covering samples.
        let (from, to) = (s[k0].t_ns, s[k1].t_ns);
        let first = self.rejected.partition_point(|r| r.arrived_after_ns < from);
        for r in self.rejected[first..]
            .iter()
            .take_while(|r| r.arrived_after_ns < to)
        {
            match r.reason {
                RejectReason::NotFinite => report.not_finite += 1,
                RejectReason::RepeatedStamp => report.repeated_stamps += 1,
                RejectReason::Backwards => report.backwards_stamps += 1,
            }
        }
        report.reliable = report.long_gaps == 0
            && report.not_finite == 0
            && report.repeated_stamps == 0
            && report.backwards_stamps == 0;
        let lo = k0.saturating_sub(1);
        let hi = (k1 + 2).min(s.len());
        Ok(ImuInterval {
            samples: &s[lo..hi],
            t_start_ns,
            t_end_ns,
            report,
        })
    }
}

/// The sample at `t_ns` interpolated linearly between `s0` and `s1`
/// (`s0.t_ns < s1.t_ns`), e.g. at a frame's stamp between two samples.
pub fn interpolate_sample(s0: &ImuSample, s1: &ImuSample, t_ns: i64) -> ImuSample {
    let u = (t_ns - s0.t_ns) as f64 / (s1.t_ns - s0.t_ns) as f64;
    let mix = |a: [f64; 3], b: [f64; 3]| {
        [
            a[0] + (b[0] - a[0]) * u,
            a[1] + (b[1] - a[1]) * u,
            a[2] + (b[2] - a[2]) * u,
        ]
    };
    ImuSample {
        t_ns,
        gyro_rad_s: mix(s0.gyro_rad_s, s1.gyro_rad_s),
        accel_m_s2: mix(s0.accel_m_s2, s1.accel_m_s2),
    }
}

impl ImuInterval<'_> {
    /// The (linearly interpolated) sample at `t_ns` inside the samples' span.
    pub fn sample_at(&self, t_ns: i64) -> Option<ImuSample> {
        let s = self.samples;
        let k = s.partition_point(|x| x.t_ns <= t_ns);
        match k {
            0 => None,
            k if s[k - 1].t_ns == t_ns => Some(s[k - 1]),
            k if k == s.len() => None,
            k => Some(interpolate_sample(&s[k - 1], &s[k], t_ns)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, Vector3};

    fn s(t_ns: i64, x: f64) -> ImuSample {
        ImuSample {
            t_ns,
            gyro_rad_s: [x, 2.0 * x, -x],
            accel_m_s2: [0.0, x, 9.81],
        }
    }

    #[test]
    fn clean_stream_cuts_intervals_with_context() {
        let raw: Vec<_> = (0..20).map(|k| s(k * 5_000_000, k as f64)).collect();
        let stream = ImuStream::from_samples(ImuIntrinsics::IDENTITY, &raw);
        let iv = stream
            .interval(12_000_000, 50_000_000, &IntervalConfig::default())
            .expect("covered");
        // Covering samples 2 (10 ms) and 10 (50 ms), one more on each side.
        assert_eq!(iv.samples.first().map(|x| x.t_ns), Some(5_000_000));
        assert_eq!(iv.samples.last().map(|x| x.t_ns), Some(55_000_000));
        assert!(iv.report.reliable);
        assert_eq!(iv.report.longest_gap_ns, 5_000_000);
        // A stamp between samples is interpolated linearly.
        let mid = iv.sample_at(12_000_000).expect("inside");
        assert!((mid.gyro_rad_s[1] - 2.0 * 2.4).abs() < 1e-12);
        assert_eq!(iv.sample_at(15_000_000), Some(raw[3]));
        assert_eq!(iv.sample_at(0), None);
        assert!(matches!(
            stream.interval(50, 50, &IntervalConfig::default()),
            Err(IntervalError::Empty { .. })
        ));
        assert!(matches!(
            stream.interval(-1, 50, &IntervalConfig::default()),
            Err(IntervalError::StartNotCovered { .. })
        ));
        assert!(matches!(
            stream.interval(0, 95_000_001, &IntervalConfig::default()),
            Err(IntervalError::EndNotCovered { .. })
        ));
    }

    #[test]
    fn bad_samples_are_counted_in_their_interval_and_mark_it_unreliable() {
        let mut raw: Vec<_> = (0..40).map(|k| s(k * 5_000_000, k as f64)).collect();
        raw[5].accel_m_s2[0] = f64::NAN; // in [0, 50] ms
        raw[7].t_ns = raw[6].t_ns; // repeated, in [0, 50] ms
        raw[8].t_ns = 1_000_000; // backwards, in [0, 50] ms
        raw.drain(25..31); // a 35 ms gap between 120 and 155 ms
        let stream = ImuStream::from_samples(ImuIntrinsics::IDENTITY, &raw);
        assert_eq!(stream.rejected().len(), 3);
        assert_eq!(stream.samples().len(), raw.len() - 3);
        let config = IntervalConfig::default();
        let first = stream.interval(0, 50_000_000, &config).expect("covered");
        assert_eq!(
            (
                first.report.not_finite,
                first.report.repeated_stamps,
                first.report.backwards_stamps
            ),
            (1, 1, 1)
        );
        assert!(!first.report.reliable);
        assert_eq!(first.report.longest_gap_ns, 15_000_000); // 20 -> 35 ms, two missing
        let clean = stream
            .interval(50_000_000, 100_000_000, &config)
            .expect("covered");
        assert_eq!(
            clean.report,
            IntervalReport {
                longest_gap_ns: 5_000_000,
                reliable: true,
                ..Default::default()
            }
        );
        let gap = stream
            .interval(100_000_000, 170_000_000, &config)
            .expect("covered");
        assert_eq!(
            (gap.report.long_gaps, gap.report.longest_gap_ns),
            (1, 35_000_000)
        );
        assert!(!gap.report.reliable);
        // The preintegrated interval carries the flag.
        let pre = crate::imu::Preintegrator::new(
            crate::imu::IntegrationScheme::Quadratic,
            crate::rig::ImuNoise::EUROC_ADIS16448,
        )
        .integrate_interval(&gap, &Default::default())
        .expect("integrable");
        assert!(!pre.reliable && pre.delta_v_m_s.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn intrinsics_are_applied_on_push_and_old_samples_dropped() {
        let intrinsics = ImuIntrinsics {
            accel_scale: Matrix3::identity() * 2.0,
            gyro_offset_rad_s: Vector3::new(0.5, 0.0, 0.0),
            ..ImuIntrinsics::IDENTITY
        };
        let mut stream = ImuStream::new(intrinsics);
        for k in 0..10 {
            assert!(stream.push(&s(k * 5_000_000, 1.0)));
        }
        assert!(!stream.push(&s(0, 1.0)));
        assert_eq!(stream.samples()[0].accel_m_s2, [0.0, 2.0, 19.62]);
        assert_eq!(stream.samples()[0].gyro_rad_s, [1.5, 2.0, -1.0]);
        stream.discard_before(22_000_000);
        // Keeps 15 ms (one before the sample at or before 22 ms) onwards.
        assert_eq!(stream.samples()[0].t_ns, 15_000_000);
        // The rejected sample arrived after 45 ms, inside what is kept.
        assert_eq!(stream.rejected().len(), 1);
        stream.discard_before(60_000_000);
        assert_eq!(stream.rejected().len(), 1);
        assert!(stream
            .interval(40_000_000, 45_000_000, &IntervalConfig::default())
            .is_ok());
    }
}
