//! `rigslam-calibrate camera`: intrinsics (pinhole + radtan) from chessboard
//! images; writes the camera's entry of `camchain.yaml` (Kalibr's camera
//! chain, intrinsics only; the other cameras' entries are kept) in the
//! calibration folder, and a report beside it.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use nalgebra::Vector3;
use rigslam_calibration::camera_report::{coverage_fraction, verdict, write_camera_report};
use rigslam_calibration::chessboard::{detect_chessboard, ChessboardConfig, GreyImage};
use rigslam_calibration::intrinsics_lm::{calibrate_intrinsics_with, IntrinsicsOptions, MIN_VIEWS};

#[derive(clap::Args)]
pub struct CameraArgs {
    /// Folder of chessboard images (PNG or JPEG), all from one camera.
    #[arg(long)]
    images: PathBuf,
    /// Inner corners of the board, COLSxROWS (e.g. 9x6).
    #[arg(long)]
    board: String,
    /// Square edge length, m.
    #[arg(long)]
    square: f64,
    /// The rig's calibration folder (created if need be): this camera's
    /// entry goes into camchain.yaml there, with `<camera>_report.md` and the
    /// plots beside it.
    #[arg(long, value_name = "DIR", default_value = "calibration")]
    out: PathBuf,
    /// Which camera of the rig the images are from: cam0 (left) or cam1
    /// (right).
    #[arg(long, default_value = "cam0")]
    camera: String,
    /// Hold fx / fy at this ratio (1 when given without a value): OpenCV's
    /// CALIB_FIX_ASPECT_RATIO, for square pixels or to compare with a
    /// calibration made that way.
    #[arg(long, value_name = "FX_OVER_FY", num_args = 0..=1, default_missing_value = "1")]
    fix_aspect_ratio: Option<f64>,
    /// Estimate k3 too (OpenCV's five-coefficient radtan). By default k3
    /// is held at zero: Kalibr's radtan has four coefficients, and Kalibr,
    /// OpenVINS and Basalt refuse or drop a fifth, so a k3 that is not
    /// zero is reported but not written to camchain.yaml.
    #[arg(long)]
    free_k3: bool,
    /// Print one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

/// Puts `camera` into the chain at `path` under `name`, keeping the other
/// cameras' entries; atomically. `Err(why)` (not an error of the command)
/// when the model has no Kalibr form (a k3 that is not zero).
fn write_chain_entry(
    path: &Path,
    name: &str,
    camera: &rigslam::camera::PinholeRadtan,
) -> anyhow::Result<Result<(), String>> {
    use rigslam::rig::kalibr;
    if !(name.starts_with("cam") && name[3..].parse::<u32>().is_ok()) {
        bail!("--camera {name:?}: name it cam0 (left), cam1 (right), ...");
    }
    let mut chain = match std::fs::read_to_string(path) {
        Ok(text) => kalibr::parse_camchain(&text, path)?,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Default::default(),
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
    };
    let calibration = rigslam::rig::CameraCalibration {
        model: camera.clone().into(),
        T_body_cam: nalgebra::Isometry3::identity(),
        rate_hz: 0.0,
        time_shift_cam_imu_s: 0.0,
    };
    let entry = match kalibr::kalibr_camera(
        &calibration,
        None,
        &format!("/{name}/image_raw"),
        Vec::new(),
        false,
    ) {
        Ok(e) => e,
        Err(why) => return Ok(Err(why)),
    };
    chain.insert(name.to_owned(), entry);
    let text = serde_yaml::to_string(&chain)?;
    rigslam::rig::folder::write_atomically(path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(Ok(()))
}

fn parse_board(text: &str) -> anyhow::Result<(usize, usize)> {
    let parse = || -> Option<(usize, usize)> {
        let (c, r) = text
            .to_ascii_lowercase()
            .split_once('x')
            .map(|(a, b)| (a.to_string(), b.to_string()))?;
        Some((c.trim().parse().ok()?, r.trim().parse().ok()?))
    };
    match parse() {
        Some((c, r)) if c >= 3 && r >= 3 => Ok((c, r)),
        _ => bail!(
            "--board {text:?}: expected inner corners as COLSxROWS with both at least 3, e.g. 9x6"
        ),
    }
}

fn image_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading the image folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg"))
        })
        .collect();
    files.sort();
    Ok(files)
}

pub fn run(args: CameraArgs) -> anyhow::Result<()> {
    let (cols, rows) = parse_board(&args.board)?;
    if !(args.square > 0.0 && args.square.is_finite()) {
        bail!(
            "--square {}: the square edge must be a positive length in metres (e.g. 0.025)",
            args.square
        );
    }
    let files = image_files(&args.images)?;
    if files.is_empty() {
        bail!("no PNG or JPEG images in {}", args.images.display());
    }
    let config = ChessboardConfig::default();
    let mut names = Vec::new();
    let mut views = Vec::new();
    let mut missing = Vec::new();
    let mut size: Option<(u32, u32)> = None;
    for file in &files {
        let name = file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let img = image::open(file)
            .with_context(|| format!("reading image {}", file.display()))?
            .to_luma8();
        let dims = img.dimensions();
        if let Some(first) = size {
            if first != dims {
                bail!("{} is {}x{} but the first image is {}x{}: use images from one camera at one resolution", file.display(), dims.0, dims.1, first.0, first.1);
            }
        }
        size = Some(dims);
        let grey = GreyImage::from_luma8(dims.0 as usize, dims.1 as usize, img.as_raw());
        match detect_chessboard(&grey, cols, rows, &config) {
            Some(found) => {
                names.push(name);
                views.push(found.corners_px);
            }
            None => {
                eprintln!("board not found in {name}");
                missing.push(name);
            }
        }
    }
    if views.len() < MIN_VIEWS {
        bail!(
            "the {cols}x{rows} board was found in only {} of {} images (need {MIN_VIEWS}): check --board counts inner corners, and recollect with the whole board in view, sharp and evenly lit",
            views.len(),
            files.len()
        );
    }
    let (width, height) = size.expect("at least one image was read");
    let board: Vec<Vector3<f64>> = (0..rows)
        .flat_map(|r| {
            (0..cols)
                .map(move |c| Vector3::new(c as f64 * args.square, r as f64 * args.square, 0.0))
        })
        .collect();
    let options = IntrinsicsOptions {
        fix_aspect_ratio: args.fix_aspect_ratio,
        fix_k3: !args.free_k3,
        ..IntrinsicsOptions::default()
    };
    let cal = calibrate_intrinsics_with(width, height, &board, &views, &options)?;
    let coverage = coverage_fraction(&cal, &views);
    let mut text = verdict(&cal, coverage);
    // The square size only scales the board distances; flag implausible ones.
    let mut distances: Vec<f64> = cal.views.iter().map(|v| v.t_cam_board.norm()).collect();
    distances.sort_by(f64::total_cmp);
    let median_distance_m = distances[distances.len() / 2];
    if !(0.05..=10.0).contains(&median_distance_m) {
        text = format!(
            "CHECK --square: the board would be {median_distance_m:.2} m away, so the square edge is probably not in metres (e.g. 0.025 for 25 mm); the intrinsics do not depend on it ({text})"
        );
    }
    let chain_path = crate::output_file(&args.out, rigslam::rig::folder::CAMCHAIN_INTRINSICS)?;
    let c = &cal.camera;
    let written = write_chain_entry(&chain_path, &args.camera, c)?;
    write_camera_report(
        &args.out,
        &cal,
        &names,
        &views,
        &missing,
        &text,
        &format!("{}_camera", args.camera),
    )?;
    if args.json {
        let per_view: Vec<_> = cal
            .views
            .iter()
            .zip(&names)
            .map(|(v, n)| serde_json::json!({"image": n, "rms_px": v.rms_px, "outlier": v.outlier}))
            .collect();
        let json = serde_json::json!({
            "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
            "distortion": c.distortion,
            "rms_px": cal.rms_px,
            "views_used": cal.views_used,
            "views_found": views.len(),
            "images": files.len(),
            "per_view": per_view,
            "boards_not_found": missing,
            "fix_aspect_ratio": args.fix_aspect_ratio,
            "free_k3": args.free_k3,
            "verdict": text,
        });
        println!("{json}");
    } else {
        println!(
            "fx {:.3} fy {:.3} cx {:.3} cy {:.3}",
            c.fx, c.fy, c.cx, c.cy
        );
        println!("distortion k1 k2 p1 p2 k3 {:?}", c.distortion);
        for (v, n) in cal.views.iter().zip(&names) {
            println!(
                "  {n}: {:.3} px{}",
                v.rms_px,
                if v.outlier {
                    " (outlier, left out)"
                } else {
                    ""
                }
            );
        }
        println!("{text}");
        match &written {
            Ok(()) => println!(
                "wrote {}'s entry of {} and {}_camera_report.md",
                args.camera,
                chain_path.display(),
                args.camera
            ),
            Err(why) => println!("{} not written: {why}", chain_path.display()),
        }
    }
    Ok(())
}
