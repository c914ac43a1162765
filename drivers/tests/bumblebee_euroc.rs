//! Bumblebee splitting on real stereo pairs: interleave EuRoC V1_01 cam0/cam1
//! images the way the camera does, split them back, and get the originals
//! exactly (and, through a Bayer filter, the reference demosaic exactly).

use std::path::PathBuf;

use rigslam_drivers::camera::bumblebee::{
    interleave, split_into, BumblebeeSplitter, ByteOrder, Output, StereoLayout,
};
use rigslam_drivers::camera::demosaic::{bilinear_rgb, luma};
use rigslam_drivers::{BayerPattern, Frame, Image, PixelFormat};

/// `../shared/data` beside the repository (or `$RIGSLAM_SHARED_DATA`);
/// missing data fails under CI and skips otherwise.
fn shared_data() -> Option<PathBuf> {
    let dir = std::env::var_os("RIGSLAM_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data"))
        });
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "CI is set but the shared data folder {} is missing",
        dir.display()
    );
    eprintln!("skipping: {} is missing", dir.display());
    None
}

/// A stereo pair: width, height, left pixels, right pixels.
type Pair = (u32, u32, Vec<u8>, Vec<u8>);

/// Stereo pairs (same file name in cam0 and cam1).
fn euroc_pairs(limit: usize) -> Option<Vec<Pair>> {
    let mav0 = shared_data()?.join("euroc/V1_01_micro/mav0");
    let mut names: Vec<_> = std::fs::read_dir(mav0.join("cam0/data"))
        .expect("cam0/data is listable")
        .map(|e| e.expect("directory entry").file_name())
        .filter(|n| mav0.join("cam1/data").join(n).is_file())
        .collect();
    names.sort();
    let load = |p: PathBuf| {
        let img = image::open(&p)
            .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
            .into_luma8();
        (img.width(), img.height(), img.into_raw())
    };
    Some(
        names
            .iter()
            .take(limit)
            .map(|n| {
                let (w, h, l) = load(mav0.join("cam0/data").join(n));
                let (w1, h1, r) = load(mav0.join("cam1/data").join(n));
                assert_eq!((w, h), (w1, h1), "cam0 and cam1 differ in size");
                (w, h, l, r)
            })
            .collect(),
    )
}

#[test]
fn euroc_pairs_come_back_exactly() {
    let Some(pairs) = euroc_pairs(usize::MAX) else {
        return;
    };
    assert!(pairs.len() >= 90, "V1_01_micro has 95 stereo frames");
    for (i, (w, h, left, right)) in pairs.iter().enumerate() {
        assert_ne!(
            left, right,
            "pair {i}: the eyes must differ for the test to mean anything"
        );
        let order = if i % 2 == 0 {
            ByteOrder::LeftFirst
        } else {
            ByteOrder::RightFirst
        };
        let bytes = interleave(left, right, order);
        let layout = StereoLayout::packed(*w as usize, *h as usize, order, None);
        let (mut l, mut r) = (vec![0; left.len()], vec![0; right.len()]);
        split_into(&bytes, &layout, &mut l, &mut r).expect("sizes match");
        assert!(l == *left && r == *right, "pair {i} not recovered");

        // Through the frame path: a 16-bit frame as the driver hands it.
        let frame = Frame {
            t_ns: i as i64,
            seq: i as u64,
            camera_index: 0,
            image: Image::new(
                *w,
                *h,
                2 * *w as usize,
                PixelFormat::Mono16 {
                    significant_bits: 16,
                },
                bytes.into(),
            )
            .expect("valid frame"),
        };
        let mut splitter = BumblebeeSplitter::new(layout, Output::Grey);
        let pair = splitter.split_frame(&frame).expect("splits");
        assert!(pair.left.image.data() == left.as_slice());
        assert!(pair.right.image.data() == right.as_slice());
    }
}

#[test]
fn mosaiced_euroc_pairs_split_raw_and_demosaic_like_the_reference() {
    let Some(pairs) = euroc_pairs(3) else {
        return;
    };
    let pattern = BayerPattern::Gbrg;
    for (w, h, left, right) in &pairs {
        let (w, h) = (*w as usize, *h as usize);
        // The grey images stand in for raw Bayer photosite values.
        let bytes = interleave(left, right, ByteOrder::RightFirst);
        let layout = StereoLayout::packed(w, h, ByteOrder::RightFirst, Some(pattern));
        let (mut l, mut r) = (vec![0; w * h], vec![0; w * h]);
        BumblebeeSplitter::new(layout, Output::Raw)
            .split_buffers(&bytes, &mut l, &mut r)
            .expect("raw split");
        assert!(l == *left && r == *right);

        BumblebeeSplitter::new(layout, Output::Grey)
            .split_buffers(&bytes, &mut l, &mut r)
            .expect("demosaic split");
        for (raw, grey) in [(left, &l), (right, &r)] {
            let mut rgb = vec![0; 3 * w * h];
            bilinear_rgb(raw, w, h, w, pattern, &mut rgb).expect("reference demosaic");
            let reference: Vec<u8> = rgb
                .chunks_exact(3)
                .map(|p| luma(p[0], p[1], p[2]))
                .collect();
            assert!(
                *grey == reference,
                "fast grey path differs from the reference"
            );
        }
    }
}
