//! YEI 3-Space stream decoding throughput (target >= 1,000,000
//! packets/s on one core). Input: 10,000 gyro+accel packets with the
//! streaming header (32 bytes each), fed in 4 KiB reads as from a port.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rigslam_drivers::yei::protocol::{
    encode_stream_packet, HeaderConfig, StreamDecoder, StreamLayout, StreamPacket,
};
use rigslam_drivers::yei::simulated::generated_values;

fn stream(n: u32) -> Vec<u8> {
    let layout = StreamLayout::gyro_accel();
    let mut bytes = Vec::new();
    for k in 0..n {
        let packet = StreamPacket {
            timestamp_us: k.wrapping_mul(500),
            values: generated_values(k as f64 * 5e-4),
        };
        encode_stream_packet(HeaderConfig::STREAMING, &layout, &packet, &mut bytes);
    }
    bytes
}

fn decode(c: &mut Criterion) {
    let n = 10_000u32;
    let clean = stream(n);
    // One corrupt byte every 100 packets: the resync path.
    let mut noisy = clean.clone();
    for at in (0..noisy.len()).step_by(3200) {
        noisy[at + 17] ^= 0xA5;
    }
    let mut group = c.benchmark_group("yei_decode");
    group.throughput(Throughput::Elements(n as u64));
    for (name, bytes) in [("clean", &clean), ("1pct_corrupt", &noisy)] {
        group.bench_function(name, |b| {
            let mut decoder =
                StreamDecoder::new(HeaderConfig::STREAMING, StreamLayout::gyro_accel())
                    .expect("streaming header");
            b.iter(|| {
                let mut got = 0u32;
                let mut gyro_sum = 0.0f32;
                for chunk in bytes.chunks(4096) {
                    decoder.push(chunk);
                    while let Some(p) = decoder.next_packet() {
                        got += 1;
                        gyro_sum += p.values.gyro_rad_s.map_or(0.0, |g| g[0]);
                    }
                }
                criterion::black_box((got, gyro_sum))
            });
        });
    }
    group.finish();
}

criterion_group!(benches, decode);
criterion_main!(benches);
