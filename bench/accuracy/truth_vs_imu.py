#!/usr/bin/env python3
"""How far a sequence's ground truth and its IMU disagree, band by band.

A rendering made from a recorded ground truth and the real IMU of the same
flight (`rigslam simulate --imu real:...`) moves its cameras as the ground
truth says and its IMU as the IMU felt. Where the two disagree, the images
and the IMU disagree too: a camera on a soft mount, as far as the estimator
can tell. Vision alone follows the ground truth's motion (it is rendered
into the images and scored against the same poses); an IMU-aided estimate
cannot. This script measures that disagreement, so an accuracy table can
say what the rendering itself costs an inertial mode.

For each band (Fourier, on a common 200 Hz grid, the first and last second
left out):
- rotation: the truth's body rate (from consecutive orientations) against
  the gyroscope less the truth's gyroscope bias: the gain per axis
  (gyroscope / truth, least squares) and the angle the two disagree by
  (the rate difference integrated, rms, deg);
- translation: the truth's acceleration (its positions differentiated
  twice) against the accelerometer turned into the world less gravity and
  the truth's accelerometer bias: the displacement the two disagree by
  (the difference integrated twice, rms, mm; from 1 Hz up), and the
  accelerometer's gain on the truth's acceleration (least squares over
  the three axes; a scale error of the accelerometer, or of the truth's
  positions, shows here, and an estimate whose lengths come from the IMU,
  mono-inertial, takes it as its scale error). Noise in the truth's
  acceleration pulls the fit towards zero and noise in the
  accelerometer's pulls the reverse fit (its inverse) away from it: both
  are printed and the gain lies between them; where they differ by much
  (V1_01's truth above 0.3 Hz) the truth is too noisy in that band to say.
And the lag between the truth's rates and the gyroscope (cross-correlation,
ms; positive: the truth lags the IMU), and the angle between the truth's
body frame and the IMU's (the rotation that best takes one's rates onto
the other's).

usage: bench/accuracy/truth_vs_imu.py [SEQUENCE ...] [--truth CSV --imu CSV]

SEQUENCE is a EuRoC folder holding mav0/state_groundtruth_estimate0 and
mav0/imu0 (or mav0 itself); --truth and --imu give the two files instead.
Use it on a recorded sequence: a rendering's own ground-truth file is the
truth resampled at the IMU's stamps, whose kinks are accelerations nobody
flew.
"""
import argparse
import os

import numpy as np

BANDS = [(0.05, 0.3), (0.3, 1.0), (1.0, 3.0), (3.0, 10.0)]
DT = 0.005
GRAVITY = np.array([0.0, 0.0, 9.81])


def read_csv(path, columns, what):
    try:
        data = np.loadtxt(path, delimiter=",", comments="#", ndmin=2)
    except (OSError, ValueError) as e:
        raise SystemExit(f"{path}: cannot read the {what}: {e}")
    if data.shape[1] < columns or len(data) < 100:
        raise SystemExit(f"{path}: the {what} needs {columns} columns and 100 rows (EuRoC csv), "
                         f"has {data.shape[1]} and {len(data)}")
    return data


def sequence_files(folder):
    mav0 = folder if os.path.basename(os.path.normpath(folder)) == "mav0" else os.path.join(folder, "mav0")
    return (os.path.join(mav0, "state_groundtruth_estimate0", "data.csv"),
            os.path.join(mav0, "imu0", "data.csv"))


def quat_to_matrix(q):
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], 1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], 1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], 1),
    ], 1)


def resample(t, x, grid):
    return np.stack([np.interp(grid, t, x[:, i]) for i in range(x.shape[1])], 1)


def body_rates(t, q):
    """Body-frame angular rate between consecutive truth orientations, at the midpoints."""
    r = quat_to_matrix(q)
    rel = np.einsum("nji,njk->nik", r[:-1], r[1:])  # R_k^T R_k+1
    angle = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))
    axis = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], 1)
    scale = np.where(angle > 1e-12, angle / (2 * np.sin(np.maximum(angle, 1e-12))), 0.5)
    return (t[:-1] + t[1:]) / 2, axis * scale[:, None] / np.diff(t)[:, None]


def spectrum(x):
    return np.fft.rfft(x - x.mean(0), axis=0), np.fft.rfftfreq(len(x), DT)


def in_band(spec, f, lo, hi):
    s = spec.copy()
    s[(f < lo) | (f > hi)] = 0
    return s


def integrate(spec, f, times):
    """The spectrum integrated `times` times (zero below 1e-6 Hz)."""
    w = 2j * np.pi * f
    w[0] = 1.0
    out = spec / (w[:, None] ** times)
    out[0] = 0
    return out


def lag_ms(t, q, gyro_t, gyro, start, end):
    grid = np.arange(start, end, 0.001)
    tm, rates = body_rates(t, q)
    truth_rate = resample(tm, rates, grid)
    best = None
    for lag in np.arange(-0.02, 0.02001, 0.0002):
        g = resample(gyro_t + lag, gyro, grid)
        cost = np.sum(((g - g.mean(0)) - (truth_rate - truth_rate.mean(0))) ** 2)
        if best is None or cost < best[0]:
            best = (cost, lag)
    return 1e3 * best[1]


def analyse(name, truth_path, imu_path):
    truth = read_csv(truth_path, 8, "ground truth (t, p, q[, v, b_w, b_a])")
    imu = read_csv(imu_path, 7, "IMU log (t, w, a)")
    folder = name
    t = truth[:, 0] * 1e-9
    ti = imu[:, 0] * 1e-9
    start, end = max(t[0], ti[0]) + 1.0, min(t[-1], ti[-1]) - 1.0
    if end - start < 10:
        raise SystemExit(f"{folder}: ground truth and IMU overlap by {end - start:.1f} s, need 10")
    grid = np.arange(start, end, DT)
    q = truth[:, 4:8] / np.linalg.norm(truth[:, 4:8], axis=1)[:, None]
    # q and -q are one rotation, and recorded truths flip between them
    # (EuRoC keeps w >= 0); interpolating across a flip would pass near
    # zero, so make the sign continuous first.
    flips = np.cumsum(np.concatenate([[0], np.sum(q[1:] * q[:-1], 1) < 0])) % 2
    q = q * np.where(flips == 1, -1.0, 1.0)[:, None]
    tm, rates = body_rates(t, q)
    truth_rate = resample(tm, rates, grid)
    gyro_bias = resample(t, truth[:, 11:14], grid) if truth.shape[1] >= 17 else 0.0
    accel_bias = resample(t, truth[:, 14:17], grid) if truth.shape[1] >= 17 else 0.0
    gyro = resample(ti, imu[:, 1:4], grid) - gyro_bias
    accel = resample(ti, imu[:, 4:7], grid) - accel_bias
    qg = resample(t, q, grid)
    r = quat_to_matrix(qg / np.linalg.norm(qg, axis=1)[:, None])
    accel_world = np.einsum("nij,nj->ni", r, accel) - GRAVITY
    position = resample(t, truth[:, 1:4], grid)

    # The rotation that best takes the truth's rates onto the gyroscope's
    # (Kabsch): how far the truth's body frame is turned from the IMU's.
    h = (truth_rate - truth_rate.mean(0)).T @ (gyro - gyro.mean(0))
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    turned = np.degrees(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1, 1)))
    print(f"{folder}: {end - start:.0f} s; lag of the truth's rates behind the gyroscope "
          f"{lag_ms(t, q, ti, imu[:, 1:4], start, end):+.1f} ms; the IMU turned {turned:.3f} deg "
          "from the truth's body frame")
    print("| band Hz | gyroscope / truth rate, x y z | attitude apart, deg rms | truth acceleration, m/s^2 rms | accelerometer / truth acceleration, fit and reverse fit | position apart, mm rms |")
    print("|---|---|---|---|---|---|")
    s_wt, f = spectrum(truth_rate)
    s_wg, _ = spectrum(gyro)
    s_p, _ = spectrum(position)
    s_a, _ = spectrum(accel_world)
    n = len(grid)
    for lo, hi in BANDS:
        wt = np.fft.irfft(in_band(s_wt, f, lo, hi), n=n, axis=0)
        wg = np.fft.irfft(in_band(s_wg, f, lo, hi), n=n, axis=0)
        gain = np.sum(wt * wg, 0) / np.maximum(np.sum(wt * wt, 0), 1e-30)
        attitude = np.fft.irfft(integrate(in_band(s_wg - s_wt, f, lo, hi), f, 1), n=n, axis=0)
        truth_accel = np.fft.irfft(in_band(s_p * ((2j * np.pi * f) ** 2)[:, None], f, lo, hi), n=n, axis=0)
        felt = np.fft.irfft(in_band(s_a, f, lo, hi), n=n, axis=0)
        both = np.sum(truth_accel * felt)
        accel_gain = both / max(np.sum(truth_accel ** 2), 1e-30)
        accel_gain_reverse = np.sum(felt ** 2) / both if both > 0 else float("nan")
        apart = np.fft.irfft(in_band(s_p - integrate(s_a, f, 2), f, lo, hi), n=n, axis=0)
        # Below 1 Hz, twice integrating turns the accelerometer's bias and
        # scale errors into more than the motion: not shown.
        position = f"{1e3 * np.sqrt((apart ** 2).sum(1).mean()):.2f}" if lo >= 1.0 else "-"
        print(f"| {lo}-{hi} | {gain[0]:.3f} {gain[1]:.3f} {gain[2]:.3f} | "
              f"{np.degrees(np.sqrt((attitude ** 2).sum(1).mean())):.3f} | "
              f"{np.sqrt((truth_accel ** 2).sum(1).mean()):.3f} | "
              f"{accel_gain:.3f}, {accel_gain_reverse:.3f} | "
              f"{position} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=__doc__.split("\n\n", 1)[1])
    parser.add_argument("sequences", nargs="*", help="EuRoC folders (holding mav0/, or mav0 itself)")
    parser.add_argument("--truth", help="a ground-truth csv (EuRoC state_groundtruth_estimate0 columns)")
    parser.add_argument("--imu", help="the IMU csv recorded with --truth (EuRoC imu0 columns)")
    args = parser.parse_args()
    if bool(args.truth) != bool(args.imu):
        parser.error("--truth and --imu go together")
    jobs = [(folder, *sequence_files(folder)) for folder in args.sequences]
    if args.truth:
        jobs.append((args.truth, args.truth, args.imu))
    if not jobs:
        parser.error("give a sequence folder or --truth and --imu")
    for name, truth_path, imu_path in jobs:
        analyse(name, truth_path, imu_path)
        print()


if __name__ == "__main__":
    main()
