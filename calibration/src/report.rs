//! The Markdown reports written beside the YAML: what was measured, the
//! pictures, and the verdict in words a technician acts on.

use std::fmt::Write;

use nalgebra::{Matrix3, Vector3};

use crate::imu_calibration::ImuSessionCalibration;
use crate::noise_calibration::{NoiseCalibration, AXIS_NAMES};

fn matrix_rows(m: &Matrix3<f64>) -> String {
    (0..3)
        .map(|r| format!("[{:+.6}, {:+.6}, {:+.6}]", m[(r, 0)], m[(r, 1)], m[(r, 2)]))
        .collect::<Vec<_>>()
        .join("<br>")
}

fn vector(v: &Vector3<f64>) -> String {
    format!("[{:+.6}, {:+.6}, {:+.6}]", v.x, v.y, v.z)
}

/// `rigslam-calibrate imu`'s report.
pub fn imu_report(
    cal: &ImuSessionCalibration,
    input: &str,
    yaml: &str,
    residual_png: &str,
    verdict: &[String],
) -> String {
    let a = &cal.accel;
    let mut md = String::new();
    let _ = writeln!(md, "# IMU intrinsics calibration\n");
    let _ = writeln!(md, "Input: `{input}`. Output: `{yaml}` (`x_c = S x_r + b`, accelerometer m/s^2, gyroscope rad/s).\n");
    let _ = writeln!(md, "## Verdict\n");
    for line in verdict {
        let _ = writeln!(md, "- {line}");
    }
    let _ = writeln!(md, "\n## Still poses\n");
    let _ = writeln!(
        md,
        "{} still intervals, {} distinct orientations; model: {}; local gravity {:.5} m/s^2.\n",
        cal.intervals.len(),
        cal.distinct_poses,
        a.model.name(),
        a.gravity_m_s2
    );
    let _ = writeln!(md, "![gravity-magnitude error per pose]({residual_png})\n");
    let _ = writeln!(md, "| pose | samples | raw mean accel [m/s^2] | raw \\|a\\| - g | calibrated \\|a\\| - g | raw mean gyro [deg/s] |");
    let _ = writeln!(md, "|---|---|---|---|---|---|");
    for (i, interval) in cal.intervals.iter().enumerate() {
        let g = interval.gyro_mean_rad_s.map(f64::to_degrees);
        let _ = writeln!(
            md,
            "| {i} | {}..{} | {} | {:+.4} | {:+.4} | [{:+.3}, {:+.3}, {:+.3}] |",
            interval.start,
            interval.end,
            vector(&interval.accel_mean_m_s2),
            a.residuals_before_m_s2[i],
            a.levenberg_marquardt.residuals_m_s2[i],
            g.x,
            g.y,
            g.z
        );
    }
    let _ = writeln!(
        md,
        "\n## Accelerometer: simplex (paper) and Levenberg-Marquardt\n"
    );
    let _ = writeln!(md, "| | S | b [m/s^2] | RMS \\|a\\| - g [m/s^2] | work |");
    let _ = writeln!(md, "|---|---|---|---|---|");
    let _ = writeln!(md, "| raw | identity | 0 | {:.5} | |", a.rms_before_m_s2);
    for (name, fit, unit) in [
        ("Nelder-Mead", &a.nelder_mead, "evaluations"),
        ("Levenberg-Marquardt", &a.levenberg_marquardt, "iterations"),
    ] {
        let _ = writeln!(
            md,
            "| {name} | {} | {} | {:.5} | {} {unit} |",
            matrix_rows(&fit.scale),
            vector(&fit.bias_m_s2),
            fit.rms_m_s2,
            fit.work
        );
    }
    let _ = writeln!(
        md,
        "\nAgreement: largest difference {:.2e} in S, {:.2e} m/s^2 in b.\n",
        a.scale_agreement, a.bias_agreement_m_s2
    );
    let _ = writeln!(md, "## Gyroscope\n");
    let _ = writeln!(
        md,
        "Raw offset at rest: {} rad/s; spread between poses {} rad/s.\n",
        vector(&cal.gyro_offset_raw_rad_s),
        vector(&cal.gyro_offset_spread_rad_s)
    );
    match &cal.gyro_scale {
        Ok(g) => {
            let _ = writeln!(
                md,
                "Turns (samples): {}.\n",
                cal.rotations
                    .iter()
                    .map(|r| format!("{} {}..{}", ["x", "y", "z"][r.axis], r.start, r.end))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
            let _ = writeln!(md, "| | value |\n|---|---|");
            let _ = writeln!(
                md,
                "| integrated turns [deg] (columns) | {} |",
                matrix_rows(&g.integrated_rad.map(f64::to_degrees))
            );
            let _ = writeln!(
                md,
                "| expected [deg] | {} |",
                vector(&g.expected_rad.map(f64::to_degrees))
            );
            let _ = writeln!(md, "| S_g | {} |", matrix_rows(&g.scale));
        }
        Err(why) => {
            let _ = writeln!(md, "Scale not estimated: {why}");
        }
    }
    let _ = writeln!(
        md,
        "| b_g [rad/s] | {} |",
        vector(&cal.intrinsics.gyro_offset_rad_s)
    );
    md
}

/// `rigslam-calibrate noise`'s report.
pub fn noise_report(
    cal: &NoiseCalibration,
    input: &str,
    yaml: &str,
    allan_png: &str,
    warnings: &[String],
) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# IMU noise (Allan deviation)\n");
    let _ = writeln!(
        md,
        "Input: `{input}`: {} samples at {:.1} Hz ({:.2} h). Output: `{yaml}` (Kalibr, continuous time, SI; the largest axis of each sensor).\n",
        cal.samples,
        cal.rate_hz,
        cal.duration_s / 3600.0
    );
    let _ = writeln!(md, "## Verdict\n");
    if warnings.is_empty() {
        let _ = writeln!(md, "- all six axes show a clean white-noise slope and a random-walk slope: the values are measured, not bounded");
    }
    for line in warnings {
        let _ = writeln!(md, "- {line}");
    }
    let _ = writeln!(md, "\n![Allan deviation]({allan_png})\n");
    let _ = writeln!(md, "Dashed: the fitted lines, slope -1/2 (white noise N, read at tau = 1 s) and +1/2 (random walk K, read at tau = 3 s). B = floor / 0.664.\n");
    let _ = writeln!(md, "| axis | N (per sqrt Hz) | K (per s per sqrt Hz) | B (bias instability) | floor at tau [s] | points on -1/2 / +1/2 |");
    let _ = writeln!(md, "|---|---|---|---|---|---|");
    for (name, a) in AXIS_NAMES.iter().zip(&cal.axes) {
        let _ = writeln!(
            md,
            "| {name} | {:.4e} | {:.4e} | {:.4e} | {:.1} | {} / {} |",
            a.white_noise_density,
            a.random_walk,
            a.bias_instability,
            a.tau_floor_s,
            a.white_points,
            a.walk_points
        );
    }
    let _ = writeln!(
        md,
        "\nUnits: gyro rad/s, accel m/s^2. Allan curves of six axes in {:.0} ms.",
        cal.allan_ms
    );
    md
}
