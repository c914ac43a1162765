"""imucal peer for `rigslam-calibrate imu`: runs imucal's Ferraris
calibration on the real session with its section list and writes the
matrices, in imucal's own convention and in ours (x_c = S x_r + b, SI), as
JSON.

imucal: acc_c = inv(R_a) inv(K_a) (acc_r - b_a)
        gyr_c = inv(R_g) inv(K_g) (gyr_r - K_ga acc_c - b_g)   (deg/s)
ours:   S_a = inv(K_a R_a), b_a_ours = -S_a b_a  (m/s^2)
        S_g = inv(K_g R_g), b_g_ours = -S_g b_g  (rad/s; K_ga has no counterpart)

Usage: imucal_ferraris.py SESSION.csv SECTIONS.json OUT.json
"""
import json
import math
import sys

import imucal
import numpy as np
import pandas as pd
from imucal import FerrarisCalibration, ferraris_regions_from_section_list

RATE_HZ = 102.4
GRAV = 9.81


def main(session, sections, out):
    data = pd.read_csv(session)
    data = data[["acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"]]
    with open(sections) as f:
        section_list = pd.DataFrame(json.load(f)).T
    regions = ferraris_regions_from_section_list(data, section_list)
    cal = FerrarisCalibration(grav=GRAV, expected_angle=-360).compute(
        regions, RATE_HZ, from_acc_unit="m/s^2", from_gyr_unit="deg/s"
    )
    s_a = np.linalg.inv(cal.K_a @ cal.R_a)
    s_g = np.linalg.inv(cal.K_g @ cal.R_g)
    deg = math.pi / 180.0
    result = {
        "imucal_version": imucal.__version__ if hasattr(imucal, "__version__") else "2.6.0",
        "grav_m_s2": GRAV,
        "expected_angle_deg": -360,
        "rate_hz": RATE_HZ,
        "K_a": cal.K_a.tolist(),
        "R_a": cal.R_a.tolist(),
        "b_a_m_s2": cal.b_a.tolist(),
        "K_g": cal.K_g.tolist(),
        "R_g": cal.R_g.tolist(),
        "b_g_deg_s": cal.b_g.tolist(),
        "K_ga": cal.K_ga.tolist(),
        "accel_scale_matrix": s_a.tolist(),
        "accel_bias_m_s2": (-(s_a @ cal.b_a)).tolist(),
        "accel_raw_offset_m_s2": cal.b_a.tolist(),
        "gyro_scale_matrix": s_g.tolist(),
        "gyro_bias_rad_s": (-(s_g @ cal.b_g) * deg).tolist(),
        "gyro_raw_offset_rad_s": (cal.b_g * deg).tolist(),
    }
    with open(out, "w") as f:
        json.dump(result, f, indent=1)
        f.write("\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main(*sys.argv[1:4])
