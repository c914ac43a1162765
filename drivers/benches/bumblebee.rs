//! Per-frame cost of the Bumblebee stereo path at 1024x768 (target: under
//! 1 ms for split + demosaic). Input: a EuRoC V1_01 cam0/cam1 pair tiled
//! to 1024x768 and interleaved as the camera sends it (random bytes when
//! ../shared/data is missing).
//!
//! `cargo bench -p rigslam-drivers --bench bumblebee`

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use rigslam_drivers::camera::bumblebee::{
    interleave, BumblebeeSplitter, ByteOrder, Output, StereoLayout,
};
use rigslam_drivers::{BayerPattern, Frame, Image, PixelFormat};

const W: usize = 1024;
const H: usize = 768;

fn eye(path: PathBuf) -> Option<Vec<u8>> {
    let img = image::open(path).ok()?.into_luma8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    let raw = img.into_raw();
    Some(
        (0..W * H)
            .map(|i| raw[(i / W % h) * w + (i % W) % w])
            .collect(),
    )
}

fn stereo_input() -> (Vec<u8>, Vec<u8>) {
    let cam = |c: &str| {
        PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../shared/data/euroc/V1_01_micro/mav0"
        ))
        .join(c)
        .join("data/1403715273262142976.png")
    };
    match (eye(cam("cam0")), eye(cam("cam1"))) {
        (Some(l), Some(r)) => (l, r),
        _ => {
            eprintln!("EuRoC images missing: benchmarking random bytes");
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
            (
                (0..W * H).map(|_| rng.gen()).collect(),
                (0..W * H).map(|_| rng.gen()).collect(),
            )
        }
    }
}

fn bench(c: &mut Criterion) {
    let (left, right) = stereo_input();
    let bytes = interleave(&left, &right, ByteOrder::RightFirst);
    let mut group = c.benchmark_group("bumblebee_1024x768");
    group.throughput(Throughput::Bytes(bytes.len() as u64));
    let (mut l, mut r) = (vec![0u8; W * H], vec![0u8; W * H]);

    let mono = StereoLayout::packed(W, H, ByteOrder::RightFirst, None);
    let mut splitter = BumblebeeSplitter::new(mono, Output::Grey);
    group.bench_function("split_mono", |b| {
        b.iter(|| {
            splitter
                .split_buffers(black_box(&bytes), &mut l, &mut r)
                .expect("sizes match")
        })
    });

    let bayer = StereoLayout::packed(W, H, ByteOrder::RightFirst, Some(BayerPattern::Gbrg));
    let mut splitter = BumblebeeSplitter::new(bayer, Output::Grey);
    group.bench_function("split_demosaic_grey", |b| {
        b.iter(|| {
            splitter
                .split_buffers(black_box(&bytes), &mut l, &mut r)
                .expect("sizes match")
        })
    });

    // The whole frame path: 16-bit frame in, StereoFrame with fresh shared
    // buffers out.
    let frame = Frame {
        t_ns: 0,
        seq: 0,
        camera_index: 0,
        image: Image::new(
            W as u32,
            H as u32,
            2 * W,
            PixelFormat::Mono16 {
                significant_bits: 16,
            },
            bytes.clone().into(),
        )
        .expect("valid frame"),
    };
    group.bench_function("split_demosaic_grey_frame", |b| {
        b.iter(|| splitter.split_frame(black_box(&frame)).expect("splits"))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
