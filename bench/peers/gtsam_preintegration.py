"""GTSAM peer for rigslam's IMU preintegration.

Preintegrates the real EuRoC V1_01 IMU between consecutive 20 Hz ground-truth
stamps with GTSAM's PreintegratedImuMeasurements, holding each sample constant
until the next one (GTSAM's scheme), with the ground-truth biases at the start
of each interval. Writes GTSAM's own preintegrated vector and covariance as a
text fixture, then times the same integration per sample.

Usage (from the repository root, via bench/peers/gtsam_preintegration.sh):
  .venv/bin/python bench/peers/gtsam_preintegration.py IMU_CSV GT_CSV OUT INTERVALS
  .venv/bin/python bench/peers/gtsam_preintegration.py --time-only IMU_CSV GT_CSV INTERVALS
"""
import sys
import time
import importlib.metadata

import numpy as np
import gtsam

# Kalibr continuous-time densities of the EuRoC ADIS16448 (imu0/sensor.yaml).
GYRO_NOISE_DENSITY = 1.6968e-04  # rad/s/sqrt(Hz)
ACCEL_NOISE_DENSITY = 2.0e-3  # m/s^2/sqrt(Hz)
GRAVITY_M_S2 = 9.81


def load(imu_csv, gt_csv):
    imu_t = np.loadtxt(imu_csv, delimiter=",", comments="#", usecols=0, dtype=np.int64)
    imu = np.loadtxt(imu_csv, delimiter=",", comments="#")[:, 1:]
    gt_t = np.loadtxt(gt_csv, delimiter=",", comments="#", usecols=0, dtype=np.int64)
    gt = np.loadtxt(gt_csv, delimiter=",", comments="#")[:, 1:]
    return imu_t, imu, gt_t, gt


def stride_of(gt_t, count):
    return max(1, (len(gt_t) - 1) // count)


def params():
    p = gtsam.PreintegrationParams.MakeSharedU(GRAVITY_M_S2)
    p.setGyroscopeCovariance(GYRO_NOISE_DENSITY**2 * np.eye(3))
    p.setAccelerometerCovariance(ACCEL_NOISE_DENSITY**2 * np.eye(3))
    p.setIntegrationCovariance(np.zeros((3, 3)))
    return p


def steps(imu_t, t_i, t_j):
    """(sample index, dt_s) pairs covering [t_i, t_j]: sample k is held over
    [max(t_k, t_i), min(t_k+1, t_j)]."""
    k = int(np.searchsorted(imu_t, t_i, side="right")) - 1
    out = []
    while k + 1 < len(imu_t) and imu_t[k] < t_j:
        lo = max(imu_t[k], t_i)
        hi = min(imu_t[k + 1], t_j)
        if hi > lo:
            out.append((k, (hi - lo) * 1e-9))
        k += 1
    return out


def intervals(imu_t, imu, gt_t, gt, count):
    """Per interval: (t_i, t_j, bias, [(gyro, accel, dt)])."""
    # Spread over the whole flight (the first seconds are on the ground).
    stride = stride_of(gt_t, count)
    out = []
    for n in range(0, stride * count, stride):
        t_i, t_j = int(gt_t[n]), int(gt_t[n + 1])
        # GT columns: p(3) q wxyz(4) v(3) gyro bias(3) accel bias(3)
        bias = gtsam.imuBias.ConstantBias(gt[n, 13:16], gt[n, 10:13])
        meas = [(imu[k, 0:3].copy(), imu[k, 3:6].copy(), dt) for k, dt in steps(imu_t, t_i, t_j)]
        out.append((t_i, t_j, bias, meas))
    return out


def main():
    args = sys.argv[1:]
    time_only = args[0] == "--time-only"
    if time_only:
        imu_csv, gt_csv, count = args[1], args[2], int(args[3])
    else:
        imu_csv, gt_csv, out_path, count = args[0], args[1], args[2], int(args[3])
    imu_t, imu, gt_t, gt = load(imu_csv, gt_csv)
    work = intervals(imu_t, imu, gt_t, gt, count)
    p = params()
    samples = sum(len(m) for *_, m in work)

    if not time_only:
        with open(out_path, "w") as f:
            f.write(f"# GTSAM {importlib.metadata.version('gtsam')} PreintegratedImuMeasurements "
                    f"(tangent preintegration), EuRoC V1_01, {count} intervals between "
                    f"consecutive ground-truth stamps (every {stride_of(gt_t, count)}th), GT biases; gyro/accel covariance {GYRO_NOISE_DENSITY}^2, "
                    f"{ACCEL_NOISE_DENSITY}^2 (continuous), integration covariance 0\n")
            f.write("# t_i_ns t_j_ns steps theta_x theta_y theta_z dp_x dp_y dp_z dv_x dv_y dv_z "
                    "cov_upper_rowmajor[45] (9x9 over theta, dp, dv)\n")
            for t_i, t_j, bias, meas in work:
                pim = gtsam.PreintegratedImuMeasurements(p, bias)
                for w, a, dt in meas:
                    pim.integrateMeasurement(a, w, dt)
                x = pim.preintegrated()
                cov = pim.preintMeasCov()
                upper = [cov[r, c] for r in range(9) for c in range(r, 9)]
                f.write(f"{t_i} {t_j} {len(meas)} " + " ".join(repr(float(v)) for v in x) + " "
                        + " ".join(f"{v:.12e}" for v in upper) + "\n")
        print(f"wrote {out_path}: {count} intervals, {samples} steps")

    # Timing: the same steps, preintegration only (inputs prepared in advance).
    repeats = 20
    runs = []
    for _ in range(repeats):
        start = time.perf_counter_ns()
        for _, _, bias, meas in work:
            pim = gtsam.PreintegratedImuMeasurements(p, bias)
            for w, a, dt in meas:
                pim.integrateMeasurement(a, w, dt)
        runs.append(time.perf_counter_ns() - start)
    best = min(runs)
    median = sorted(runs)[repeats // 2]
    # The Python loop and call overhead alone, for reference.
    base = float("inf")
    for _ in range(repeats):
        start = time.perf_counter_ns()
        for _, _, bias, meas in work:
            for w, a, dt in meas:
                (lambda a, w, dt: None)(a, w, dt)
        base = min(base, time.perf_counter_ns() - start)
    print(f"gtsam {importlib.metadata.version('gtsam')}: {samples} samples in {count} intervals, "
          f"median of {repeats} runs {median / samples:.1f} ns/sample, best {best / samples:.1f} ns/sample "
          f"(python loop+call overhead alone {base / samples:.1f} ns/sample)")


if __name__ == "__main__":
    main()
