//! Fuzzes the YEI 3-Space codec: the stream decoder (in input-chosen
//! chunkings), the response finder and the device-side command parser must
//! never panic, and the decoder must account for every byte.
#![no_main]

use libfuzzer_sys::fuzz_target;
use rigslam_drivers::yei::commands::CommandParser;
use rigslam_drivers::yei::protocol::{
    find_response, HeaderConfig, ResponseScan, StreamDecoder, StreamLayout,
};

fuzz_target!(|data: &[u8]| {
    let Some((&chunk_seed, bytes)) = data.split_first() else {
        return;
    };
    let chunk = 1 + chunk_seed as usize;
    let mut decoder = StreamDecoder::new(HeaderConfig::STREAMING, StreamLayout::gyro_accel())
        .expect("streaming header is valid");
    let mut packets = 0u64;
    for c in bytes.chunks(chunk) {
        decoder.push(c);
        while decoder.next_packet().is_some() {
            packets += 1;
        }
    }
    let counts = decoder.counts();
    assert_eq!(counts.packets, packets);
    assert_eq!(
        counts.skipped_bytes + packets * decoder.frame_len() as u64 + decoder.buffered() as u64,
        bytes.len() as u64
    );
    assert!(counts.resyncs <= packets);

    if let ResponseScan::Found { payload_start, .. } =
        find_response(HeaderConfig::STREAMING, 0xED, 4, bytes)
    {
        assert!(payload_start + 4 <= bytes.len());
    }

    let mut parser = CommandParser::default();
    parser.push(bytes);
    let mut n = 0;
    while parser.next_received().is_some() {
        n += 1;
        assert!(n <= bytes.len());
    }
});
