//! Length fields of an MCAP file checked against the bytes there are,
//! before the `mcap` crate reads them.
//!
//! The crate trusts some of them: a string's u32 length is reserved
//! in full before reading (`reserve_exact`, up to 4 GiB, an abort where
//! memory is short), a record inside a chunk longer than the rest of the
//! chunk underflows a counter (a panic with overflow checks, garbage
//! without), and an attachment record too short for its CRC panics on a
//! slice. Fuzzing found all three. [`check`] walks every record the crate
//! will parse, from the start, in chunks (also one cut off with the file)
//! and from the footer's summary start, and refuses a file whose lengths
//! do not fit, naming the byte where the field is. Whatever else is wrong (a bad magic,
//! a cut-off file, unknown channels) the crate still reports.

/// MCAP's magic, at both ends of the file.
pub(super) const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

const HEADER: u8 = 0x01;
const FOOTER: u8 = 0x02;
const SCHEMA: u8 = 0x03;
const CHANNEL: u8 = 0x04;
const CHUNK: u8 = 0x06;
const MESSAGE_INDEX: u8 = 0x07;
const CHUNK_INDEX: u8 = 0x08;
pub(super) const ATTACHMENT: u8 = 0x09;
const ATTACHMENT_INDEX: u8 = 0x0A;
const STATISTICS: u8 = 0x0B;
const METADATA: u8 = 0x0C;
const METADATA_INDEX: u8 = 0x0D;

/// Opcode and length before every record's body.
pub(super) const RECORD_HEADER: usize = 9;

/// Why a file is refused: the byte offset of the record (or field) and
/// what does not fit.
pub(super) type Refusal = (u64, String);

/// A record body being walked: `at` is the body's offset in the file,
/// `record_at` the record's.
struct Body<'a> {
    bytes: &'a [u8],
    pos: usize,
    at: usize,
    record_at: usize,
    opcode: u8,
}

/// `Ok(None)`: the body ended before the field, which the crate reports.
type Field<T> = Result<Option<T>, Refusal>;

impl<'a> Body<'a> {
    fn refuse(&self, what: &str, wanted: u64) -> Refusal {
        (
            (self.at + self.pos) as u64,
            format!(
                "record 0x{:02x} at byte {}: {what} of {wanted} bytes at byte {}, {} left in the record",
                self.opcode,
                self.record_at,
                self.at + self.pos,
                self.bytes.len() - self.pos
            ),
        )
    }

    fn fixed(&mut self, n: usize) -> Field<()> {
        Ok((self.bytes.len() - self.pos >= n).then(|| self.pos += n))
    }

    /// A u32- or u64-prefixed run of bytes (a string, a map, an array,
    /// data) that must lie inside the record.
    fn prefixed(&mut self, width: usize, what: &str) -> Field<&'a [u8]> {
        let bytes: &'a [u8] = self.bytes;
        let Some(raw) = self.bytes.get(self.pos..self.pos + width) else {
            return Ok(None);
        };
        let mut le = [0u8; 8];
        le[..width].copy_from_slice(raw);
        let n = u64::from_le_bytes(le);
        if n > (self.bytes.len() - self.pos - width) as u64 {
            return Err(self.refuse(what, n));
        }
        let start = self.pos + width;
        self.pos = start + n as usize;
        Ok(Some(&bytes[start..self.pos]))
    }

    /// The bytes a u64-prefixed run has before the body ends (a chunk
    /// cut off with its file), and whether that is all of them.
    fn prefixed_cut(&mut self) -> Field<(&'a [u8], bool)> {
        let bytes: &'a [u8] = self.bytes;
        let Some(raw) = bytes.get(self.pos..self.pos + 8) else {
            return Ok(None);
        };
        let n = u64::from_le_bytes(raw.try_into().expect("8 bytes"));
        let start = self.pos + 8;
        let whole = n <= (bytes.len() - start) as u64;
        self.pos = start + n.min((bytes.len() - start) as u64) as usize;
        Ok(Some((&bytes[start..self.pos], whole)))
    }

    fn string(&mut self, what: &str) -> Field<()> {
        Ok(self.prefixed(4, what)?.map(drop))
    }

    /// A map of strings to strings: its byte length, then key and value
    /// strings. The crate reads pairs while it has read fewer bytes than
    /// the map's length, the last pair past the map's end if need be: each
    /// string's length is checked against the record, as the crate reads.
    fn string_map(&mut self, what: &str) -> Field<()> {
        let Some(map) = self.prefixed(4, what)? else {
            return Ok(None);
        };
        let (start, len) = (self.pos - map.len(), map.len());
        self.pos = start;
        while self.pos - start < len {
            for _ in 0..2 {
                if self.string(what)?.is_none() {
                    return Ok(None);
                }
            }
        }
        Ok(Some(()))
    }
}

/// Checks the length fields of one record's body (`at`: its offset in
/// the file); `cut`: the file ends inside it.
fn check_record(opcode: u8, body: &[u8], at: usize, cut: bool) -> Result<(), Refusal> {
    let mut b = Body {
        bytes: body,
        pos: 0,
        at,
        record_at: at - RECORD_HEADER,
        opcode,
    };
    // A field the body ends before stops the check: the crate reports it.
    macro_rules! field {
        ($e:expr) => {
            match $e? {
                Some(v) => v,
                None => return Ok(()),
            }
        };
    }
    match opcode {
        HEADER => {
            field!(b.string("profile"));
            field!(b.string("library"));
        }
        SCHEMA => {
            field!(b.fixed(2));
            field!(b.string("name"));
            field!(b.string("encoding"));
            field!(b.prefixed(4, "schema data"));
        }
        CHANNEL => {
            field!(b.fixed(4));
            field!(b.string("topic"));
            field!(b.string("message encoding"));
            field!(b.string_map("metadata"));
        }
        CHUNK => {
            field!(b.fixed(28));
            let compression = field!(b.prefixed(4, "compression"));
            let (records, whole) = if cut {
                field!(b.prefixed_cut())
            } else {
                (field!(b.prefixed(8, "chunk records")), true)
            };
            // A compressed chunk's records are checked once decompressed
            // (`check_chunk_records`).
            if compression.is_empty() {
                // Records of a chunk cut off with its file are read too. A
                // record may only run past the chunk's end where the file
                // ends too.
                walk(records, at + b.pos - records.len(), whole, true)?;
            }
        }
        MESSAGE_INDEX => {
            field!(b.fixed(2));
            field!(b.prefixed(4, "message index entries"));
        }
        CHUNK_INDEX => {
            field!(b.fixed(32));
            field!(b.prefixed(4, "message index offsets"));
            field!(b.fixed(8));
            field!(b.string("compression"));
        }
        ATTACHMENT => {
            field!(b.fixed(16));
            field!(b.string("name"));
            field!(b.string("media type"));
            field!(b.prefixed(8, "attachment data"));
            if b.bytes.len() - b.pos < 4 {
                return Err(b.refuse("CRC", 4));
            }
        }
        ATTACHMENT_INDEX => {
            field!(b.fixed(40));
            field!(b.string("name"));
            field!(b.string("media type"));
        }
        STATISTICS => {
            field!(b.fixed(42));
            field!(b.prefixed(4, "channel message counts"));
        }
        METADATA => {
            field!(b.string("name"));
            field!(b.string_map("metadata"));
        }
        METADATA_INDEX => {
            field!(b.fixed(16));
            field!(b.string("name"));
        }
        // Footer, message, summary offset, data end: fixed fields and
        // trailing data; unknown opcodes are skipped by the crate.
        _ => {}
    }
    Ok(())
}

/// The crate reads a chunk's header (36 bytes and the compression
/// string) from the bytes after the record's length, whatever that length
/// says, and asks for all of it at once (the summary reader allocates
/// what it asks for): the header must fit in the record.
fn check_chunk_header(rest: &[u8], len: u64, record_at: usize) -> Result<(), Refusal> {
    let Some(raw) = rest.get(28..32) else {
        return Ok(());
    };
    let header = 36 + u64::from(u32::from_le_bytes(raw.try_into().expect("4 bytes")));
    if header > len {
        return Err((
            (record_at + RECORD_HEADER + 28) as u64,
            format!(
                "record 0x06 at byte {record_at}: a chunk header of {header} bytes in a record of {len}"
            ),
        ));
    }
    Ok(())
}

/// Walks the records of `bytes` (`at`: its offset in the file). Inside a
/// chunk (`complete`) every record must fit; otherwise a last record that
/// runs past the end is a cut-off file, the crate's to report (after the
/// records of a cut-off chunk, which it reads). Stops after the footer,
/// as the crate does, except `in_chunk`.
fn walk(bytes: &[u8], at: usize, complete: bool, in_chunk: bool) -> Result<(), Refusal> {
    let mut pos = 0;
    while bytes.len() - pos >= RECORD_HEADER {
        let opcode = bytes[pos];
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().expect("8 bytes"));
        let left = (bytes.len() - pos - RECORD_HEADER) as u64;
        if opcode == CHUNK {
            check_chunk_header(&bytes[pos + RECORD_HEADER..], len, at + pos)?;
        }
        if len > left {
            // The crate adds the header's 9 bytes to the length first: a
            // length that wraps makes it slice out of bounds.
            if len > (usize::MAX - RECORD_HEADER) as u64 {
                return Err((
                    (at + pos) as u64,
                    format!(
                        "record 0x{opcode:02x} at byte {} claims {len} bytes",
                        at + pos
                    ),
                ));
            }
            if !complete && opcode == CHUNK {
                check_record(
                    opcode,
                    &bytes[pos + RECORD_HEADER..],
                    at + pos + RECORD_HEADER,
                    true,
                )?;
            }
            if complete {
                return Err((
                    (at + pos) as u64,
                    format!(
                        "record 0x{opcode:02x} at byte {} claims {len} bytes, {left} are left",
                        at + pos
                    ),
                ));
            }
            return Ok(());
        }
        let body = &bytes[pos + RECORD_HEADER..pos + RECORD_HEADER + len as usize];
        check_record(opcode, body, at + pos + RECORD_HEADER, false)?;
        pos += RECORD_HEADER + len as usize;
        // The crate stops at a footer, but not inside a chunk.
        if opcode == FOOTER && !in_chunk {
            break;
        }
    }
    if complete && pos != bytes.len() {
        return Err((
            (at + pos) as u64,
            format!("{} stray bytes at byte {}", bytes.len() - pos, at + pos),
        ));
    }
    Ok(())
}

/// Checks the records of a decompressed chunk (which starts at byte
/// `at` of the file): each must fit the chunk whole.
pub(super) fn check_chunk_records(records: &[u8], at: usize) -> Result<(), Refusal> {
    walk(records, at, true, true)
}

/// Checks the length fields of one whole top-level record (its body, which
/// starts at byte `at` of the file), before the crate parses it.
pub(super) fn check_whole_record(opcode: u8, body: &[u8], at: usize) -> Result<(), Refusal> {
    check_record(opcode, body, at, false)
}

/// Checks every length field the crate will trust: in the records it
/// reads from the start, and in those its summary reader reads from
/// wherever the footer's summary start points to the end of the file.
pub(super) fn check(bytes: &[u8]) -> Result<(), Refusal> {
    // The message stream refuses a file without the opening magic; the
    // summary reader never looks at it.
    if bytes.starts_with(MAGIC) {
        walk(&bytes[MAGIC.len()..], MAGIC.len(), false, false)?;
    }
    // Footer: opcode, length 20, summary start, summary offset start, CRC;
    // then the closing magic.
    let footer = bytes.len().checked_sub(MAGIC.len() + RECORD_HEADER + 20);
    let Some(footer) = footer.filter(|&f| f >= MAGIC.len() && bytes[f] == FOOTER) else {
        return Ok(());
    };
    let at = footer + RECORD_HEADER;
    let start = u64::from_le_bytes(bytes[at..at + 8].try_into().expect("8 bytes"));
    if start != 0 && start < bytes.len() as u64 {
        walk(&bytes[start as usize..], start as usize, false, false)?;
    }
    Ok(())
}

/// Checks the record an attachment index points to (`offset`, `length`
/// from the summary) before the crate slices and parses it.
pub(super) fn check_attachment(bytes: &[u8], offset: u64, length: u64) -> Result<(), Refusal> {
    let end = offset
        .checked_add(length)
        .filter(|&e| e <= bytes.len() as u64);
    let (Some(end), true) = (end, length >= RECORD_HEADER as u64) else {
        return Err((
            offset,
            format!(
                "the summary puts an attachment at bytes {offset} + {length}, outside the {}-byte file",
                bytes.len()
            ),
        ));
    };
    let record = &bytes[offset as usize..end as usize];
    if record[0] != ATTACHMENT {
        return Err((offset, format!("no attachment record at byte {offset}")));
    }
    walk(record, offset as usize, true, false)
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;
    use std::path::Path;

    use super::super::{read_attachments_in, read_imu_channel_in, McapRecorder, RecordingError};
    use super::{MAGIC, RECORD_HEADER};
    use crate::sensors::ImuSample;

    /// A small closed recording: an IMU channel with three samples and an
    /// attachment.
    fn recording() -> Vec<u8> {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("r.mcap");
        let mut rec = McapRecorder::create(&path, super::super::Compression::None).expect("create");
        let imu = rec
            .add_imu_channel("/imu0", &BTreeMap::new())
            .expect("channel");
        for k in 0..3 {
            let s = ImuSample {
                t_ns: 1_000 + k,
                gyro_rad_s: [0.0; 3],
                accel_m_s2: [0.0, 0.0, 9.8],
            };
            rec.write_imu(imu, &s, 0).expect("write");
        }
        rec.attach(
            "calibration/imu0.yaml",
            "application/yaml",
            b"rate_hz: 200\n",
        )
        .expect("attach");
        rec.finish().expect("finish");
        std::fs::read(&path).expect("bytes")
    }

    fn find(bytes: &[u8], needle: &[u8]) -> usize {
        bytes
            .windows(needle.len())
            .position(|w| w == needle)
            .expect("present")
    }

    /// The first top-level record with `opcode`, by walking the records.
    fn first_record(bytes: &[u8], opcode: u8) -> usize {
        let mut pos = MAGIC.len();
        while bytes[pos] != opcode {
            let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().expect("8"));
            pos += RECORD_HEADER + len as usize;
        }
        pos
    }

    /// What `check` refuses; the reader walks the same bytes without a
    /// panic (it skips what it cannot read, or stops where the file ends).
    fn refused(bytes: &[u8]) -> (u64, String) {
        let _ = read_imu_channel_in(bytes, Path::new("r.mcap"), "/imu0");
        super::check(bytes).expect_err("refused")
    }

    fn malformed(e: RecordingError) -> (u64, String) {
        match e {
            RecordingError::Malformed { offset, reason, .. } => (offset, reason),
            other => panic!("expected a malformed-file error, got {other}"),
        }
    }

    #[test]
    fn the_recorder_writes_files_that_pass() {
        let bytes = recording();
        assert_eq!(super::check(&bytes), Ok(()));
        let path = Path::new("r.mcap");
        assert_eq!(
            read_imu_channel_in(&bytes, path, "/imu0")
                .expect("read")
                .len(),
            3
        );
        assert_eq!(read_attachments_in(&bytes, path).expect("read").len(), 1);
    }

    /// Found by fuzzing: a string's u32 length was reserved in full by the
    /// `mcap` crate (here 4 GiB) before it found the file too short.
    #[test]
    fn a_string_longer_than_its_record_is_refused_where_it_is() {
        let mut bytes = recording();
        // The topic of the channel record in the data section: u32 length 5.
        let at = find(&bytes, b"\x05\x00\x00\x00/imu0");
        bytes[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        let (offset, message) = refused(&bytes);
        assert_eq!(offset, at as u64);
        assert!(
            message.starts_with("record 0x04")
                && message.contains(&format!("topic of 4294967295 bytes at byte {at}")),
            "{message}"
        );
        // Reading the channel names the damaged chunk.
        let e = read_imu_channel_in(&bytes, Path::new("r.mcap"), "/imu0").unwrap_err();
        let message = e.to_string();
        assert!(
            message.starts_with("r.mcap: malformed MCAP: chunk at byte")
                && message.contains(&format!("topic of 4294967295 bytes at byte {at}")),
            "{message}"
        );
    }

    /// Found by fuzzing: the crate reads a chunk's records as they come,
    /// so those of a file cut off inside a chunk are parsed too.
    #[test]
    fn a_cut_off_chunk_is_checked_as_far_as_it_goes() {
        let mut bytes = recording();
        let at = find(&bytes, b"\x05\x00\x00\x00/imu0");
        bytes[at..at + 4].copy_from_slice(&u32::MAX.to_le_bytes());
        bytes.truncate(at + 100);
        let (offset, reason) = refused(&bytes);
        assert_eq!(offset, at as u64);
        assert!(reason.contains("topic"), "{reason}");
    }

    /// Found by fuzzing: in a file cut off after a chunk's records, the
    /// crate read a record longer than the chunk on past its end.
    #[test]
    fn a_cut_off_chunk_still_bounds_its_records() {
        let mut bytes = recording();
        // The chunk's records length (after the 28 fixed bytes and the
        // empty compression string) made 23, then the file cut off.
        let chunk = first_record(&bytes, 0x06);
        let at = chunk + 9 + 28 + 4;
        bytes[at..at + 8].copy_from_slice(&23u64.to_le_bytes());
        bytes.truncate(chunk + 9 + 28 + 4 + 8 + 23 + 14);
        let (offset, reason) = refused(&bytes);
        assert_eq!(offset, at as u64 + 8);
        assert!(
            reason.contains("claims") && reason.contains("14 are left"),
            "{reason}"
        );
    }

    /// Found by fuzzing: a record length near 2^64 wrapped when the crate
    /// added the record header's 9 bytes, and it sliced out of bounds.
    #[test]
    fn a_record_length_that_wraps_is_refused() {
        let mut bytes = recording();
        // The header record's length, right after the magic and opcode.
        bytes[9..17].copy_from_slice(&u64::MAX.to_le_bytes());
        let (offset, reason) = refused(&bytes);
        assert_eq!(offset, 8);
        assert!(
            reason.contains("claims 18446744073709551615 bytes"),
            "{reason}"
        );
    }

    /// Found by fuzzing: a chunk record too short for its header made the
    /// crate read the header from the bytes after it, and the summary
    /// reader allocate room for a compression string of 1.7 GB.
    #[test]
    fn a_chunk_header_longer_than_its_record_is_refused() {
        let mut bytes = recording();
        let chunk = first_record(&bytes, 0x06);
        bytes[chunk + 1..chunk + 9].copy_from_slice(&0u64.to_le_bytes());
        bytes[chunk + 9 + 28..chunk + 9 + 32].copy_from_slice(&0x6800_0000u32.to_le_bytes());
        let e = super::super::channel_counts_in(&bytes, Path::new("r.mcap")).unwrap_err();
        let (offset, reason) = malformed(e);
        assert_eq!(offset, (chunk + 9 + 28) as u64);
        assert!(
            reason.contains("chunk header of 1744830500 bytes in a record of 0"),
            "{reason}"
        );
    }

    /// Found by fuzzing: the crate reads a metadata map's last pair past
    /// the map's end (it reads while it has read less than the map's
    /// length), so a string length there was trusted too.
    #[test]
    fn a_map_entry_past_the_map_is_checked_against_the_record() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("m.mcap");
        let mut rec = McapRecorder::create(&path, super::super::Compression::None).expect("create");
        let meta = BTreeMap::from([
            ("a".to_string(), "b".to_string()),
            ("k".to_string(), "v".to_string()),
        ]);
        rec.add_imu_channel("/imu0", &meta).expect("channel");
        rec.finish().expect("finish");
        let mut bytes = std::fs::read(&path).expect("bytes");
        // A map of two pairs, 20 bytes, made 11: the crate reads the first
        // pair (10 bytes), then, being short of 11, the second key, which
        // now runs past the map's end; its length is made huge.
        let at = find(&bytes, b"\x14\x00\x00\x00\x01\x00\x00\x00a");
        bytes[at] = 11;
        let after = at + 4 + 10;
        bytes[after..after + 4].copy_from_slice(&0xf000_0000u32.to_le_bytes());
        let e = read_imu_channel_in(&bytes, Path::new("m.mcap"), "/imu0").unwrap_err();
        let (offset, reason) = malformed(e);
        assert_eq!(offset, after as u64);
        assert!(reason.contains("metadata of 4026531840 bytes"), "{reason}");
    }

    /// Found by fuzzing: the summary reader goes straight to the footer,
    /// so the summary's strings were trusted even in a file whose opening
    /// magic was wrong.
    #[test]
    fn the_summary_is_checked_whatever_the_start() {
        let mut bytes = recording();
        bytes[3] ^= 0x08;
        // The topic in the summary's channel record: the last one.
        let at = bytes
            .windows(9)
            .rposition(|w| w == b"\x05\x00\x00\x00/imu0")
            .expect("present");
        bytes[at..at + 4].copy_from_slice(&0x6e6f_736au32.to_le_bytes());
        let e = super::super::channel_counts_in(&bytes, Path::new("r.mcap")).unwrap_err();
        let (offset, reason) = malformed(e);
        assert_eq!(offset, at as u64);
        assert!(reason.contains("topic"), "{reason}");
    }

    /// Found by fuzzing: a record inside a chunk longer than the rest of
    /// the chunk underflowed the crate's count of what is left (a panic
    /// with overflow checks).
    #[test]
    fn a_record_running_past_its_chunk_is_refused() {
        let mut bytes = recording();
        // The first message record (opcode 5) inside the chunk (after its
        // 28 fixed bytes, the empty compression string and the records'
        // length): its length.
        let chunk = first_record(&bytes, 0x06);
        let mut pos = chunk + 9 + 28 + 4 + 8;
        while bytes[pos] != 0x05 {
            let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().expect("8"));
            pos += RECORD_HEADER + len as usize;
        }
        let at = pos + 1;
        bytes[at..at + 8].copy_from_slice(&(1u64 << 40).to_le_bytes());
        let (offset, reason) = refused(&bytes);
        assert_eq!(offset, at as u64 - 1);
        assert!(reason.contains("claims 1099511627776 bytes"), "{reason}");
    }

    /// Found by fuzzing: an attachment index pointing past the file (or
    /// at a record too short for its CRC) made the crate slice out of
    /// bounds.
    #[test]
    fn an_attachment_index_outside_the_file_is_refused() {
        let bytes = recording();
        for (offset, length) in [(u64::MAX, 2), (8, u64::MAX), (0, 4)] {
            let (at, reason) = super::check_attachment(&bytes, offset, length).unwrap_err();
            assert_eq!(at, offset);
            assert!(reason.contains("attachment"), "{reason}");
        }
        // The attachment record: opcode, length, two stamps, then its name.
        let record = (find(&bytes, b"calibration/imu0.yaml") - 4 - 16 - 9) as u64;
        assert_eq!(bytes[record as usize], super::ATTACHMENT);
        let (at, reason) = super::check_attachment(&bytes, record, 20).unwrap_err();
        assert_eq!(at, record);
        assert!(reason.contains("claims"), "{reason}");
    }
}
