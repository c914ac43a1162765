//! CDR as ROS 2 puts it on the wire and in bags (XCDR1, "plain CDR"):
//! a 4-byte encapsulation header, `00 01 00 00` for little-endian, then
//! the fields in declaration order, each primitive aligned to its own
//! size counted from the end of the header (so a `float64` after a
//! string may follow up to 7 bytes of zero padding). Strings are a
//! `uint32` length that counts the terminating NUL, the bytes, the NUL;
//! unbounded sequences (`T[]`) are a `uint32` element count then the
//! elements; fixed arrays (`T[N]`) are the elements alone; a nested
//! message is its fields, with no alignment of its own.
//!
//! [`CdrWriter`] writes little-endian; [`CdrReader`] reads either byte
//! order, refusing other encapsulations (XCDR2, parameter lists) and any
//! length that runs past the data.

use thiserror::Error;

/// The encapsulation header of little-endian plain CDR.
pub const LITTLE_ENDIAN_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Bytes of the encapsulation header; alignment counts from its end.
const HEADER_LEN: usize = 4;

/// Why a value cannot be written as CDR.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CdrError {
    /// A string or sequence longer than CDR's `uint32` length can say.
    #[error("{what} has {len} elements: CDR lengths stop at 2^32 - 1")]
    TooLong {
        /// What was being written.
        what: &'static str,
        /// Its length.
        len: usize,
    },
    /// A string with a NUL inside: CDR strings end at their first NUL.
    #[error("the string {0:?} holds a NUL byte, which would end it early")]
    Nul(String),
}

/// Writes one message as little-endian CDR, header first.
#[derive(Debug, Clone)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    /// A message holding only the encapsulation header.
    pub fn new() -> Self {
        Self::with_capacity(0)
    }

    /// [`Self::new`] with room for `bytes` more bytes.
    pub fn with_capacity(bytes: usize) -> Self {
        let mut buf = Vec::with_capacity(HEADER_LEN + bytes);
        buf.extend_from_slice(&LITTLE_ENDIAN_HEADER);
        Self { buf }
    }

    /// Zero bytes up to the next multiple of `size` after the header.
    fn align(&mut self, size: usize) {
        let pad = (size - (self.buf.len() - HEADER_LEN) % size) % size;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    /// A `uint8` (or `byte`, `char`).
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// A `bool`: one byte, 0 or 1.
    pub fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }

    /// A `uint32`.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// An `int32`.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// A `float64`.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// The `uint32` length of a sequence of `len` elements (the elements
    /// follow, written by the caller).
    pub fn sequence_len(&mut self, what: &'static str, len: usize) -> Result<(), CdrError> {
        let n = u32::try_from(len).map_err(|_| CdrError::TooLong { what, len })?;
        self.u32(n);
        Ok(())
    }

    /// A `string`: length with the NUL, the bytes, the NUL.
    pub fn string(&mut self, s: &str) -> Result<(), CdrError> {
        if s.as_bytes().contains(&0) {
            return Err(CdrError::Nul(s.to_owned()));
        }
        self.sequence_len("a string", s.len() + 1)?;
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
        Ok(())
    }

    /// A fixed array `float64[N]`: the elements alone.
    pub fn f64_array(&mut self, v: &[f64]) {
        for &x in v {
            self.f64(x);
        }
    }

    /// A sequence `float64[]`: the count, then the elements.
    pub fn f64_sequence(&mut self, v: &[f64]) -> Result<(), CdrError> {
        self.sequence_len("a float64 sequence", v.len())?;
        self.f64_array(v);
        Ok(())
    }

    /// A sequence `uint8[]`: the count, then the bytes.
    pub fn u8_sequence(&mut self, v: &[u8]) -> Result<(), CdrError> {
        self.sequence_len("a uint8 sequence", v.len())?;
        self.buf.extend_from_slice(v);
        Ok(())
    }

    /// The message so far, header included.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf
    }

    /// The message, header included.
    pub fn into_bytes(self) -> Vec<u8> {
        self.buf
    }
}

/// Reads one CDR message field by field; every error says what was being
/// read and at which byte.
#[derive(Debug, Clone)]
pub struct CdrReader<'a> {
    data: &'a [u8],
    pos: usize,
    little_endian: bool,
}

impl<'a> CdrReader<'a> {
    /// A reader after the encapsulation header, which must be plain CDR
    /// (`00 00` big-endian or `00 01` little-endian; the two option bytes
    /// after it are not looked at).
    pub fn new(data: &'a [u8]) -> Result<Self, String> {
        let little_endian = match data {
            [0x00, 0x00, _, _, ..] => false,
            [0x00, 0x01, _, _, ..] => true,
            [a, b, _, _, ..] => {
                return Err(format!(
                    "CDR encapsulation {a:#04x} {b:#04x}: only plain CDR \
                     (0x00 0x00 or 0x00 0x01) is read"
                ))
            }
            _ => {
                return Err(format!(
                    "{} bytes: shorter than the CDR encapsulation header",
                    data.len()
                ))
            }
        };
        Ok(Self {
            data,
            pos: HEADER_LEN,
            little_endian,
        })
    }

    /// The next `N` bytes, after the padding that aligns them to `N`, in
    /// little-endian order.
    fn take<const N: usize>(&mut self, what: &str) -> Result<[u8; N], String> {
        self.pos += (N - (self.pos - HEADER_LEN) % N) % N;
        let bytes = self.bytes(N, what)?;
        let mut out = [0; N];
        out.copy_from_slice(bytes);
        if self.little_endian {
            Ok(out)
        } else {
            out.reverse();
            Ok(out)
        }
    }

    /// The next `n` bytes as they are.
    fn bytes(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len());
        let Some(end) = end else {
            return Err(format!(
                "{what}: {n} bytes at byte {} run past the {}-byte message",
                self.pos,
                self.data.len()
            ));
        };
        let out = &self.data[self.pos..end];
        self.pos = end;
        Ok(out)
    }

    /// A `uint8`.
    pub fn u8(&mut self, what: &str) -> Result<u8, String> {
        Ok(self.bytes(1, what)?[0])
    }

    /// A `uint32`.
    pub fn u32(&mut self, what: &str) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(what)?))
    }

    /// An `int32`.
    pub fn i32(&mut self, what: &str) -> Result<i32, String> {
        Ok(i32::from_le_bytes(self.take(what)?))
    }

    /// A `float64`.
    pub fn f64(&mut self, what: &str) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.take(what)?))
    }

    /// A `string` (UTF-8, ending in its NUL).
    pub fn string(&mut self, what: &str) -> Result<String, String> {
        let len = self.u32(what)? as usize;
        let bytes = self.bytes(len, what)?;
        match bytes.split_last() {
            Some((0, text)) => std::str::from_utf8(text)
                .map(str::to_owned)
                .map_err(|e| format!("{what}: {e}")),
            _ => Err(format!("{what}: a string of {len} bytes without its NUL")),
        }
    }

    /// A fixed array `float64[N]`.
    pub fn f64_array<const N: usize>(&mut self, what: &str) -> Result<[f64; N], String> {
        let mut out = [0.0; N];
        for x in &mut out {
            *x = self.f64(what)?;
        }
        Ok(out)
    }

    /// A sequence `uint8[]`, borrowed from the message.
    pub fn u8_sequence(&mut self, what: &str) -> Result<&'a [u8], String> {
        let len = self.u32(what)? as usize;
        self.bytes(len, what)
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_message_starts_with_the_little_endian_header() {
        assert_eq!(CdrWriter::new().into_bytes(), vec![0x00, 0x01, 0x00, 0x00]);
        let mut w = CdrWriter::new();
        w.u8(7);
        assert_eq!(w.as_bytes(), &[0, 1, 0, 0, 7]);
    }

    /// A float64 after a string is aligned to 8 counting from the end of
    /// the header: "ab" takes 4 + 3 bytes, so one byte of padding.
    #[test]
    fn a_float64_after_a_string_is_aligned_after_the_header() {
        let mut w = CdrWriter::new();
        w.string("ab").expect("string");
        w.f64(1.5);
        #[rustfmt::skip]
        let expected = [
            0x00, 0x01, 0x00, 0x00, // header
            0x03, 0x00, 0x00, 0x00, // length, with the NUL
            b'a', b'b', 0x00,       // the bytes, the NUL
            0x00,                   // padding to 8 after the header
            0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0xf8, 0x3f, // 1.5
        ];
        assert_eq!(w.as_bytes(), &expected);
        // A string of 3 ends at 8 after the header: no padding.
        let mut w = CdrWriter::new();
        w.string("abc").expect("string");
        w.f64(-2.0);
        assert_eq!(w.as_bytes().len(), 4 + 4 + 4 + 8);
        assert_eq!(&w.as_bytes()[12..], &(-2.0f64).to_le_bytes());
    }

    #[test]
    fn the_empty_string_is_its_nul() {
        let mut w = CdrWriter::new();
        w.string("").expect("string");
        assert_eq!(w.as_bytes(), &[0, 1, 0, 0, 1, 0, 0, 0, 0]);
    }

    /// Sequences carry their element count; fixed arrays do not; a
    /// uint32 after a lone byte is aligned to 4.
    #[test]
    fn sequences_have_a_count_and_arrays_do_not() {
        let mut w = CdrWriter::new();
        w.u8(9);
        w.u8_sequence(&[1, 2, 3]).expect("bytes");
        w.f64_sequence(&[0.5, 0.25]).expect("doubles");
        w.f64_array(&[3.0]);
        w.bool(true);
        w.i32(-2);
        #[rustfmt::skip]
        let expected: Vec<u8> = [
            &[0x00, 0x01, 0x00, 0x00][..],
            &[9, 0, 0, 0],            // the byte, padding to 4
            &[3, 0, 0, 0], &[1, 2, 3], // count, bytes
            &[0],                      // padding to 4 (offset 11 -> 12)
            &[2, 0, 0, 0],             // count at 12..16
            &0.5f64.to_le_bytes(),     // at 16: already aligned
            &0.25f64.to_le_bytes(),
            &3.0f64.to_le_bytes(),     // fixed array: no count
            &[1],                      // bool
            &[0, 0, 0],                // padding to 4
            &(-2i32).to_le_bytes(),
        ]
        .concat();
        assert_eq!(w.as_bytes(), &expected[..]);
    }

    #[test]
    fn a_string_with_a_nul_is_refused() {
        let mut w = CdrWriter::new();
        assert_eq!(w.string("a\0b"), Err(CdrError::Nul("a\0b".to_owned())));
    }

    #[test]
    fn the_reader_reads_what_the_writer_wrote() {
        let mut w = CdrWriter::new();
        w.u8(200);
        w.string("frame").expect("string");
        w.f64(f64::MIN_POSITIVE);
        w.u32(u32::MAX);
        w.i32(i32::MIN);
        w.u8_sequence(b"pixels").expect("bytes");
        w.f64_array(&[1.0, -0.0, 1e300]);
        let bytes = w.into_bytes();
        let mut r = CdrReader::new(&bytes).expect("header");
        assert_eq!(r.u8("u8"), Ok(200));
        assert_eq!(r.string("s").as_deref(), Ok("frame"));
        assert_eq!(
            r.f64("f").map(f64::to_bits),
            Ok(f64::MIN_POSITIVE.to_bits())
        );
        assert_eq!(r.u32("u"), Ok(u32::MAX));
        assert_eq!(r.i32("i"), Ok(i32::MIN));
        assert_eq!(r.u8_sequence("b"), Ok(&b"pixels"[..]));
        let a: [f64; 3] = r.f64_array("a").expect("array");
        assert_eq!(a.map(f64::to_bits), [1.0, -0.0, 1e300].map(f64::to_bits));
        assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn the_reader_reads_big_endian_too() {
        // Header 00 00: big-endian; a uint32 then a float64 at 8.
        let mut bytes = vec![0, 0, 0, 0];
        bytes.extend_from_slice(&7u32.to_be_bytes());
        bytes.extend_from_slice(&[0; 4]);
        bytes.extend_from_slice(&2.5f64.to_be_bytes());
        let mut r = CdrReader::new(&bytes).expect("header");
        assert_eq!(r.u32("u"), Ok(7));
        assert_eq!(r.f64("f"), Ok(2.5));
    }

    #[test]
    fn the_reader_refuses_what_does_not_fit() {
        assert!(CdrReader::new(&[0, 1]).unwrap_err().contains("shorter"));
        let e = CdrReader::new(&[0, 7, 0, 0]).unwrap_err();
        assert!(e.contains("0x07"), "{e}");
        // A sequence claiming more bytes than the message has.
        let mut w = CdrWriter::new();
        w.u32(1000);
        w.u8(1);
        let bytes = w.into_bytes();
        let e = CdrReader::new(&bytes)
            .expect("header")
            .u8_sequence("data")
            .unwrap_err();
        assert!(e.contains("data") && e.contains("1000 bytes"), "{e}");
        // A string whose last byte is not its NUL.
        let bytes = [0, 1, 0, 0, 2, 0, 0, 0, b'a', b'b'];
        let e = CdrReader::new(&bytes)
            .expect("header")
            .string("frame_id")
            .unwrap_err();
        assert!(e.contains("NUL"), "{e}");
        // A float64 cut short.
        let bytes = [0, 1, 0, 0, 1, 2, 3];
        assert!(CdrReader::new(&bytes).expect("header").f64("x").is_err());
    }
}
