//! The AprilGrid detector and target file on input that holds no grid or
//! is wrong: no tags and no panic, or an error naming the file.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rigslam::shared_data::shared_data_dir;
use rigslam_calibration::aprilgrid::{detect_aprilgrid, AprilGridTarget};

fn target() -> AprilGridTarget {
    AprilGridTarget {
        tag_rows: 6,
        tag_cols: 6,
        tag_size_m: 0.088,
        tag_spacing_ratio: 0.3,
    }
}

#[test]
fn a_chessboard_noise_and_flat_images_give_no_tags() {
    if let Some(data) = shared_data_dir() {
        let board = image::open(data.join("calib/chessboard_9x6_25mm/left01.jpg"))
            .expect("chessboard image")
            .to_luma8();
        assert!(detect_aprilgrid(&board, &target()).tags.is_empty());
    }
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let noise = image::GrayImage::from_fn(752, 480, |_, _| image::Luma([rng.gen::<u8>()]));
    assert!(detect_aprilgrid(&noise, &target()).tags.is_empty());
    // Blocky noise: dark squares of tag size, but no codes.
    let blocks: Vec<u8> = (0..(752 / 8) * (480 / 8))
        .map(|_| if rng.gen_bool(0.5) { 20 } else { 220 })
        .collect();
    let blocky = image::GrayImage::from_fn(752, 480, |x, y| {
        image::Luma([blocks[(y as usize / 8) * (752 / 8) + x as usize / 8]])
    });
    assert!(detect_aprilgrid(&blocky, &target()).tags.is_empty());
    for shade in [0u8, 128, 255] {
        let flat = image::GrayImage::from_pixel(640, 480, image::Luma([shade]));
        assert!(detect_aprilgrid(&flat, &target()).tags.is_empty());
    }
}

#[test]
fn tiny_empty_and_cut_images_do_not_panic() {
    for (w, h) in [
        (0, 0),
        (1, 1),
        (0, 480),
        (752, 0),
        (5, 5),
        (19, 300),
        (40, 40),
    ] {
        let img = image::GrayImage::from_pixel(w, h, image::Luma([90]));
        assert!(detect_aprilgrid(&img, &target()).tags.is_empty(), "{w}x{h}");
    }
    // The real image cut through the grid: some tags, none at the cut.
    let Some(data) = shared_data_dir() else {
        return;
    };
    let full = image::open(data.join("calib/euroc_imu_april/cam0_1403709395937837056.png"))
        .expect("image")
        .to_luma8();
    for (x, y, w, h) in [(0, 0, 330, 480), (300, 150, 452, 120), (350, 60, 9, 9)] {
        let cut = image::imageops::crop_imm(&full, x, y, w, h).to_image();
        let found = detect_aprilgrid(&cut, &target());
        for tag in &found.tags {
            for c in &tag.corners_px {
                assert!(c.x >= 0.0 && c.y >= 0.0 && c.x < w as f64 && c.y < h as f64);
            }
        }
        println!("crop {w}x{h} at ({x}, {y}): {} tags", found.tags.len());
    }
    // A grid of another size: only ids that exist on it.
    let small = AprilGridTarget {
        tag_rows: 2,
        tag_cols: 3,
        ..target()
    };
    assert!(detect_aprilgrid(&full, &small)
        .tags
        .iter()
        .all(|t| t.id < 6));
    // A nonsensical target gives nothing rather than a panic.
    let broken = AprilGridTarget {
        tag_cols: 0,
        ..target()
    };
    assert!(detect_aprilgrid(&full, &broken).tags.is_empty());
}

#[test]
fn target_files_that_are_wrong_say_which_file_and_what() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cases = [
        ("checkerboard.yaml", "target_type: 'checkerboard'\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: 0.06\ncolSpacingMeters: 0.06\n", "checkerboard"),
        ("no_size.yaml", "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSpacing: 0.3\n", "tag_size"),
        ("empty.yaml", "", "target file"),
    ];
    for (name, text, expected) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, text).expect("write");
        let message = AprilGridTarget::from_yaml_file(&path)
            .expect_err(name)
            .to_string();
        println!("{name}: {message}");
        assert!(
            message.contains(name) && message.contains(expected),
            "{message}"
        );
    }
    let message = AprilGridTarget::from_yaml_file(&dir.path().join("missing.yaml"))
        .expect_err("no file")
        .to_string();
    assert!(message.contains("missing.yaml"), "{message}");
}
