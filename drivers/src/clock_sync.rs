//! Sensor clock -> host clock alignment.
//!
//! A sensor stamps its samples with its own clock (the YEI's microsecond
//! counter, a camera's tick counter); the host stamps the moment the bytes
//! arrive. Receipt time is the sensor time mapped to the host clock plus a
//! transport delay that is never negative:
//!
//! `t_receipt = offset + (1 + drift) t_sensor + delay`, `delay >= 0`.
//!
//! So `y = t_receipt - t_sensor` lies on or above the line
//! `offset + drift * t_sensor`, and the best line is the lower envelope of
//! the points, not a least-squares fit (which would absorb the mean delay).
//! Following Moon, Skelly and Towsley, "Estimation and removal of clock skew
//! from network delay measurements" (INFOCOM 1999), the estimate is the line
//! below every point that minimises the summed vertical distance to them,
//! which is the edge of the lower convex hull spanning the points' mean
//! `t_sensor`. It runs over a sliding window so that drift may wander, on
//! one minimum-delay point per bucket so that updates stay cheap at kHz
//! rates.

use std::collections::VecDeque;

/// Tuning of [`ClockSync`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockSyncConfig {
    /// Span of sensor time the fit looks back over.
    pub window_ns: i64,
    /// Width of the buckets that keep one minimum-delay point each.
    pub bucket_ns: i64,
    /// Known fixed part of the transport delay (e.g. a packet's time on the
    /// wire), subtracted from every receipt time; the envelope cannot see it.
    pub min_latency_ns: i64,
    /// Largest rate difference a real oscillator shows (quartz: tens of
    /// ppm); a fit over a short noisy stretch that says more is clamped to
    /// it, the line kept under every point.
    pub max_drift_ppm: f64,
}

impl Default for ClockSyncConfig {
    fn default() -> Self {
        ClockSyncConfig {
            window_ns: 30_000_000_000,
            bucket_ns: 10_000_000,
            min_latency_ns: 0,
            max_drift_ppm: 500.0,
        }
    }
}

/// The current line `t_host = t_sensor + offset_ns + drift * (t_sensor - ref)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockEstimate {
    /// Sensor time the offset refers to, ns.
    pub reference_sensor_ns: i64,
    /// Host minus sensor time at the reference, ns.
    pub offset_ns: f64,
    /// Host clock rate relative to the sensor's, minus one (1e-6 = 1 ppm).
    pub drift: f64,
}

impl ClockEstimate {
    /// `drift` in parts per million.
    pub fn drift_ppm(&self) -> f64 {
        self.drift * 1e6
    }

    /// Maps a sensor time onto the host clock. Rounded down: the line is a
    /// lower envelope of the receipts, so a mapped stamp must not land
    /// after the receipt it was fitted under by a rounding nanosecond.
    pub fn to_host_ns(&self, sensor_ns: i64) -> i64 {
        let dx = (sensor_ns - self.reference_sensor_ns) as f64;
        sensor_ns + (self.offset_ns + self.drift * dx).floor() as i64
    }
}

#[derive(Debug, Clone, Copy)]
struct Point {
    /// Sensor time relative to the first observation, ns.
    x: f64,
    /// Receipt minus sensor time minus `min_latency_ns`, relative to the
    /// first observation's, ns.
    y: f64,
}

/// Online offset-and-drift estimator, robust to one-sided delay.
#[derive(Debug, Clone)]
pub struct ClockSync {
    config: ClockSyncConfig,
    origin: Option<(i64, i64)>,
    /// Completed buckets' minimum points, oldest first.
    points: VecDeque<Point>,
    /// Bucket index and minimum point of the bucket being filled.
    current: Option<(i64, Point)>,
    hull: Vec<Point>,
    line: Option<(f64, f64)>,
    observations: u64,
}

impl ClockSync {
    /// An estimator with no observations yet.
    pub fn new(config: ClockSyncConfig) -> ClockSync {
        ClockSync {
            config,
            origin: None,
            points: VecDeque::new(),
            current: None,
            hull: Vec::new(),
            line: None,
            observations: 0,
        }
    }

    /// Forgets everything (after a reconnect the sensor clock may restart).
    pub fn reset(&mut self) {
        *self = ClockSync::new(self.config);
    }

    /// Pairs passed to [`observe`](Self::observe) since creation or the
    /// last [`reset`](Self::reset).
    pub fn observations(&self) -> u64 {
        self.observations
    }

    /// Adds one (sensor stamp, host receipt) pair. Sensor stamps must not
    /// go backwards (unwrap a wrapping counter first).
    pub fn observe(&mut self, sensor_ns: i64, receipt_ns: i64) {
        self.observations += 1;
        let (x0, y0) = *self.origin.get_or_insert((
            sensor_ns,
            receipt_ns - sensor_ns - self.config.min_latency_ns,
        ));
        let p = Point {
            x: (sensor_ns - x0) as f64,
            y: (receipt_ns - sensor_ns - self.config.min_latency_ns - y0) as f64,
        };
        let bucket = (sensor_ns - x0).div_euclid(self.config.bucket_ns.max(1));
        match &mut self.current {
            Some((b, min)) if *b == bucket => {
                if p.y < min.y {
                    *min = p;
                    // The line must stay below every point: refit when the
                    // new minimum lies under it (cheap check otherwise).
                    let below = self.line.map_or(true, |(a, b)| p.y < a + b * p.x);
                    if below || self.points.len() < 2 {
                        self.refit();
                    }
                }
            }
            _ => {
                if let Some((_, done)) = self.current.take() {
                    self.points.push_back(done);
                }
                self.current = Some((bucket, p));
                let oldest_x = p.x - self.config.window_ns as f64;
                while self.points.front().is_some_and(|q| q.x < oldest_x) {
                    self.points.pop_front();
                }
                self.refit();
            }
        }
    }

    /// Lower hull of the window's points (monotone chain; x is increasing),
    /// then the hull edge spanning the mean x.
    fn refit(&mut self) {
        self.hull.clear();
        let current = self.current.map(|(_, p)| p);
        let n = self.points.len() + current.is_some() as usize;
        let mut sum_x = 0.0;
        for p in self.points.iter().copied().chain(current) {
            sum_x += p.x;
            while self.hull.len() >= 2 {
                let a = self.hull[self.hull.len() - 2];
                let b = self.hull[self.hull.len() - 1];
                // Drop b when it is not strictly below the segment a-p.
                let cross = (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x);
                if cross <= 0.0 {
                    self.hull.pop();
                } else {
                    break;
                }
            }
            self.hull.push(p);
        }
        if n == 0 {
            self.line = None;
            return;
        }
        let mean_x = sum_x / n as f64;
        if self.hull.len() == 1 {
            self.line = Some((self.hull[0].y, 0.0));
            return;
        }
        let edge = self
            .hull
            .windows(2)
            .find(|w| w[1].x >= mean_x)
            .unwrap_or(&self.hull[self.hull.len() - 2..]);
        let (a, b) = (edge[0], edge[1]);
        let max_slope = self.config.max_drift_ppm * 1e-6;
        let slope = (b.y - a.y) / (b.x - a.x);
        if slope.abs() <= max_slope {
            self.line = Some((a.y - slope * a.x, slope));
        } else {
            // The steepest plausible line that still lies under the hull.
            let slope = slope.clamp(-max_slope, max_slope);
            let intercept = self
                .hull
                .iter()
                .map(|p| p.y - slope * p.x)
                .fold(f64::INFINITY, f64::min);
            self.line = Some((intercept, slope));
        }
    }

    /// The current estimate, once at least one observation is in.
    pub fn estimate(&self) -> Option<ClockEstimate> {
        let (x0, y0) = self.origin?;
        let (intercept, slope) = self.line?;
        Some(ClockEstimate {
            reference_sensor_ns: x0,
            offset_ns: y0 as f64 + intercept,
            drift: slope,
        })
    }

    /// Maps a sensor time onto the host clock, if anything was observed.
    pub fn to_host_ns(&self, sensor_ns: i64) -> Option<i64> {
        self.estimate().map(|e| e.to_host_ns(sensor_ns))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A sensor clock running `drift` fast or slow against the host, seen
    /// through a delay drawn by `delay_ns`.
    fn run(
        drift: f64,
        rate_hz: f64,
        seconds: f64,
        seed: u64,
        mut delay_ns: impl FnMut(&mut ChaCha8Rng) -> f64,
    ) -> (ClockSync, impl Fn(i64) -> f64, i64, f64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let offset_ns = 123_456_789_012.0;
        let host_of = move |sensor_ns: i64| offset_ns + (1.0 + drift) * sensor_ns as f64;
        let mut sync = ClockSync::new(ClockSyncConfig::default());
        let n = (rate_hz * seconds) as i64;
        let dt_ns = (1e9 / rate_hz) as i64;
        let start_ns = 4_000_000_000_000; // a sensor clock that has run for a while
        let mut naive_sum = 0.0;
        for k in 0..n {
            let sensor_ns = start_ns + k * dt_ns;
            let receipt = host_of(sensor_ns) + delay_ns(&mut rng);
            naive_sum += receipt - sensor_ns as f64;
            sync.observe(sensor_ns, receipt.round() as i64);
        }
        let last = start_ns + (n - 1) * dt_ns;
        (sync, host_of, last, naive_sum / n as f64)
    }

    fn worst_error_ns(sync: &ClockSync, host_of: &impl Fn(i64) -> f64, last: i64) -> f64 {
        // Error over the last second of samples, where the live driver uses it.
        (0..200)
            .map(|k| last - k * 5_000_000)
            .map(|s| (sync.to_host_ns(s).expect("observed") as f64 - host_of(s)).abs())
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_short_noisy_start_never_claims_an_implausible_drift() {
        // 0.4 s at 50 Hz with 2 ms of one-sided jitter: the raw hull edge
        // can tilt by thousands of ppm; the estimate stays within the bound
        // and under every observation.
        for seed in 0..20 {
            let (sync, _, _, _) = run(20e-6, 50.0, 0.4, seed, |r| r.gen_range(0.0..2e6));
            let e = sync.estimate().expect("observed");
            assert!(e.drift_ppm().abs() <= 500.0 + 1e-9, "seed {seed}: {e:?}");
        }
        let mut sync = ClockSync::new(ClockSyncConfig::default());
        let points = [
            (0i64, 1_000_000i64),
            (10_000_000, 11_100_000),
            (20_000_000, 21_200_000),
        ];
        for (x, y) in points {
            sync.observe(x, y);
        }
        // An exact 1 % skew is far beyond quartz: clamped, and no mapped
        // point lies after its receipt.
        let e = sync.estimate().expect("observed");
        assert!((e.drift_ppm() - 500.0).abs() < 1e-6, "{e:?}");
        for (x, y) in points {
            assert!(e.to_host_ns(x) <= y);
        }
    }

    #[test]
    fn uniform_jitter_100ppm_both_ways_under_0_2_ms_after_10_s() {
        for (drift, seed) in [(100e-6, 1), (-100e-6, 2), (0.0, 3), (37e-6, 4)] {
            let (sync, host_of, last, naive_offset) =
                run(drift, 200.0, 10.0, seed, |r| r.gen_range(0.0..2e6));
            let err = worst_error_ns(&sync, &host_of, last);
            eprintln!("drift {drift:e}: worst offset error over the last second {err:.0} ns");
            assert!(err < 0.2e6, "drift {drift}: error {err} ns");
            let est = sync.estimate().expect("observed");
            assert!(
                (est.drift - drift).abs() < 20e-6,
                "drift {} vs {drift}",
                est.drift
            );
            // Receipt time alone is off by the mean delay (1 ms): the test
            // would catch an estimator that averaged.
            let naive_err =
                (naive_offset + drift * last as f64 - (host_of(last) - last as f64)).abs();
            assert!(naive_err > 0.5e6, "naive {naive_err}");
        }
    }

    #[test]
    fn exponential_delay_with_rare_fast_packets() {
        // Mostly slow transport (mean 1.5 ms, capped at 2 ms jitter) above a
        // known 0.3 ms floor the config subtracts.
        let floor_ns = 300_000.0;
        let (mut sync, host_of, last, _) = run(-100e-6, 100.0, 10.0, 7, |r| {
            let u: f64 = r.gen_range(1e-9..1.0);
            floor_ns + (-1.5e6 * u.ln()).min(2e6)
        });
        let err_without_floor = worst_error_ns(&sync, &host_of, last);
        assert!(err_without_floor > floor_ns * 0.8, "the floor must show");
        // Same data with the floor known.
        sync = ClockSync::new(ClockSyncConfig {
            min_latency_ns: floor_ns as i64,
            ..Default::default()
        });
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let start_ns = 4_000_000_000_000;
        for k in 0..1000 {
            let s = start_ns + k * 10_000_000;
            let u: f64 = rng.gen_range(1e-9..1.0);
            let d = floor_ns + (-1.5e6 * u.ln()).min(2e6);
            sync.observe(s, (host_of(s) + d).round() as i64);
        }
        let err = worst_error_ns(&sync, &host_of, last);
        eprintln!("exponential delay: worst offset error {err:.0} ns");
        assert!(err < 0.2e6, "error {err} ns");
    }

    #[test]
    fn exact_line_without_delay() {
        let mut sync = ClockSync::new(ClockSyncConfig::default());
        for k in 0..100i64 {
            let s = k * 10_000_000;
            sync.observe(s, 5_000 + s + s / 10_000); // +100 ppm, offset 5 us
        }
        let est = sync.estimate().expect("observed");
        assert!((est.drift - 1e-4).abs() < 1e-9, "{est:?}");
        assert_eq!(
            sync.to_host_ns(2_000_000_000),
            Some(5_000 + 2_000_000_000 + 200_000)
        );
    }

    #[test]
    fn window_forgets_an_old_clock_rate() {
        let mut sync = ClockSync::new(ClockSyncConfig {
            window_ns: 5_000_000_000,
            ..Default::default()
        });
        // 20 s at +100 ppm, then 20 s at -50 ppm (e.g. temperature).
        let mut host = 0.0f64;
        let mut s = 0i64;
        for k in 0..8000 {
            let drift = if k < 4000 { 100e-6 } else { -50e-6 };
            s += 5_000_000;
            host += 5e6 * (1.0 + drift);
            sync.observe(s, host.round() as i64);
        }
        let est = sync.estimate().expect("observed");
        assert!((est.drift + 50e-6).abs() < 1e-6, "{}", est.drift_ppm());
    }
}
