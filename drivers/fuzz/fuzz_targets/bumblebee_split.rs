//! Fuzzes the Bumblebee splitter and the grey demosaic: any shape, any
//! bytes. Nothing may panic; a split that succeeds must put byte
//! `y * stride + 2x + k` of the frame at pixel (x, y) of eye k; the fast
//! grey demosaic must equal luma of the reference RGB demosaic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use rigslam_drivers::camera::bumblebee::{
    split_into, BumblebeeSplitter, ByteOrder, Output, StereoLayout,
};
use rigslam_drivers::camera::demosaic::{bilinear_rgb, luma, GreyDemosaic};
use rigslam_drivers::{BayerPattern, Frame, Image, PixelFormat};

fuzz_target!(|data: &[u8]| {
    if data.len() < 4 {
        return;
    }
    // Header: width, height (small, so the fuzzer explores shapes), padding, flags.
    let width = usize::from(data[0] % 40);
    let height = usize::from(data[1] % 40);
    let padding = usize::from(data[2] % 5);
    let flags = data[3];
    let frame = &data[4..];
    let order = if flags & 1 == 0 {
        ByteOrder::LeftFirst
    } else {
        ByteOrder::RightFirst
    };
    let mosaic = match (flags >> 1) % 5 {
        0 => None,
        1 => Some(BayerPattern::Rggb),
        2 => Some(BayerPattern::Bggr),
        3 => Some(BayerPattern::Grbg),
        _ => Some(BayerPattern::Gbrg),
    };
    let layout = StereoLayout {
        width,
        height,
        // Sometimes a stride shorter than a row, which must be rejected.
        stride_bytes: (2 * width + padding).saturating_sub(usize::from(flags >> 7)),
        order,
        mosaic,
    };
    let n = width * height;
    let (mut left, mut right) = (vec![0u8; n], vec![0u8; n]);
    if split_into(frame, &layout, &mut left, &mut right).is_ok() {
        let (first, second) = match order {
            ByteOrder::LeftFirst => (&left, &right),
            ByteOrder::RightFirst => (&right, &left),
        };
        for y in 0..height {
            for x in 0..width {
                let at = y * layout.stride_bytes + 2 * x;
                assert_eq!(first[y * width + x], frame[at]);
                assert_eq!(second[y * width + x], frame[at + 1]);
            }
        }
        if let Some(pattern) = mosaic {
            let mut grey = vec![0u8; n];
            if GreyDemosaic::new()
                .run(&left, width, height, width, pattern, &mut grey)
                .is_ok()
            {
                let mut rgb = vec![0u8; 3 * n];
                bilinear_rgb(&left, width, height, width, pattern, &mut rgb)
                    .expect("the reference accepts what the fast path accepted");
                for (g, p) in grey.iter().zip(rgb.chunks_exact(3)) {
                    assert_eq!(*g, luma(p[0], p[1], p[2]));
                }
            }
        }
    }
    // The frame path: whatever the bytes, an error or a pair, never a panic.
    if let Ok(image) = Image::new(
        width as u32,
        height as u32,
        layout.stride_bytes,
        PixelFormat::Mono16 {
            significant_bits: 16,
        },
        frame.to_vec().into(),
    ) {
        let f = Frame {
            t_ns: 0,
            seq: 0,
            camera_index: 0,
            image,
        };
        for output in [Output::Raw, Output::Grey] {
            let _ = BumblebeeSplitter::new(layout, output).split_frame(&f);
        }
    }
});
