"""allantools peer for `rigslam-calibrate noise`: overlapping Allan
deviation of the real 2.78 h ADIS16405 static log, per axis, in SI units
(gyro rad/s, accel m/s^2), at the cluster sizes rigslam uses
(m_k = floor(10^(k/10) + 0.5), k = 0, 1, ..., while m <= N/4, deduplicated).

Usage: allan_adis16405.py LOG.csv.gz OUT.json
"""
import json
import math
import sys
import time

import allantools
import numpy as np
import pandas as pd

RATE_HZ = 100.0
DEG = math.pi / 180.0
G_M_S2 = 9.80665
POINTS_PER_DECADE = 10


def cluster_sizes(n):
    out = []
    k = 0
    while True:
        m = math.floor(10 ** (k / POINTS_PER_DECADE) + 0.5)
        if m > n // 4:
            return out
        if not out or out[-1] != m:
            out.append(m)
        k += 1


def main(log, out):
    data = pd.read_csv(log).to_numpy(dtype=np.float64)
    n = data.shape[0]
    si = data * np.array([DEG, DEG, DEG, G_M_S2, G_M_S2, G_M_S2])
    m = np.array(cluster_sizes(n))
    taus = m / RATE_HZ
    result = {"allantools_version": allantools.__version__, "rate_hz": RATE_HZ,
              "samples": int(n), "axes": ["gx", "gy", "gz", "ax", "ay", "az"],
              "units": "gyro rad/s, accel m/s^2 (deg/s * pi/180, g * 9.80665)"}
    adevs = []
    t0 = time.perf_counter()
    for axis in range(6):
        t_used, adev, _, _ = allantools.oadev(si[:, axis], rate=RATE_HZ, data_type="freq", taus=taus)
        adevs.append(adev.tolist())
    result["allantools_wall_s"] = time.perf_counter() - t0
    result["tau_s"] = t_used.tolist()
    result["adev"] = adevs
    with open(out, "w") as f:
        json.dump(result, f)
        f.write("\n")
    print(f"{len(t_used)} taus, {n} samples, allantools {result['allantools_wall_s']:.2f} s")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
