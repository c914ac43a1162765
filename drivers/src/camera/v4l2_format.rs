//! V4L2 pixel formats rigslam reads, and copying a driver buffer out into an
//! owned [`Image`] (pure: no device, no ioctl).
//!
//! Format codes are the kernel's FourCCs (`include/uapi/linux/videodev2.h`):
//! GREY, Y10, Y12, Y16 (grey in little-endian 16-bit words, data in the low
//! bits), YUYV (4:2:2, of which we keep the luma) and the 8- and 16-bit
//! Bayer layouts.

use super::buffer_pool::BufferPool;
use crate::{BayerPattern, FrameError, Image, PixelFormat};

/// A V4L2 capture format rigslam can turn into an [`Image`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireFormat {
    /// `GREY`: 8-bit grey.
    Grey,
    /// `Y10 `, `Y12 `, `Y16 `: grey in 16-bit little-endian words with this
    /// many significant (low) bits.
    Grey16 {
        /// Data bits per word: 10 (`Y10 `), 12 (`Y12 `) or 16 (`Y16 `; any
        /// other value also maps to `Y16 `).
        significant_bits: u8,
    },
    /// `YUYV`: packed 4:2:2 Y0 U Y1 V; frames carry the luma only.
    Yuyv,
    /// `BA81`/`GBRG`/`GRBG`/`RGGB`: 8-bit raw Bayer.
    Bayer8(BayerPattern),
    /// `BYR2`/`GB16`/`GR16`/`RG16`: 16-bit little-endian raw Bayer.
    Bayer16(BayerPattern),
}

/// Every format we read, in the order we prefer them when the user asks for none.
pub const SUPPORTED: &[WireFormat] = &[
    WireFormat::Grey,
    WireFormat::Grey16 {
        significant_bits: 16,
    },
    WireFormat::Grey16 {
        significant_bits: 12,
    },
    WireFormat::Grey16 {
        significant_bits: 10,
    },
    WireFormat::Bayer8(BayerPattern::Bggr),
    WireFormat::Bayer8(BayerPattern::Gbrg),
    WireFormat::Bayer8(BayerPattern::Grbg),
    WireFormat::Bayer8(BayerPattern::Rggb),
    WireFormat::Bayer16(BayerPattern::Bggr),
    WireFormat::Bayer16(BayerPattern::Gbrg),
    WireFormat::Bayer16(BayerPattern::Grbg),
    WireFormat::Bayer16(BayerPattern::Rggb),
    WireFormat::Yuyv,
];

impl WireFormat {
    /// The format a FourCC names, if we read it.
    pub fn from_fourcc(code: [u8; 4]) -> Option<Self> {
        SUPPORTED.iter().copied().find(|f| f.fourcc() == code)
    }

    /// The format a name given on the command line names: a FourCC
    /// ("GREY", "Y16", "BA81", trailing spaces optional) or "mono8"/"mono16".
    pub fn parse(name: &str) -> Option<Self> {
        match name.to_ascii_lowercase().as_str() {
            "mono8" => return Some(WireFormat::Grey),
            "mono16" => {
                return Some(WireFormat::Grey16 {
                    significant_bits: 16,
                })
            }
            _ => {}
        }
        let bytes = name.as_bytes();
        if bytes.is_empty() || bytes.len() > 4 {
            return None;
        }
        let mut code = [b' '; 4];
        code[..bytes.len()].copy_from_slice(bytes);
        Self::from_fourcc(code)
    }

    /// The kernel's FourCC for this format.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            WireFormat::Grey => *b"GREY",
            WireFormat::Grey16 { significant_bits } => match significant_bits {
                10 => *b"Y10 ",
                12 => *b"Y12 ",
                _ => *b"Y16 ",
            },
            WireFormat::Yuyv => *b"YUYV",
            WireFormat::Bayer8(p) => match p {
                BayerPattern::Bggr => *b"BA81",
                BayerPattern::Gbrg => *b"GBRG",
                BayerPattern::Grbg => *b"GRBG",
                BayerPattern::Rggb => *b"RGGB",
            },
            WireFormat::Bayer16(p) => match p {
                BayerPattern::Bggr => *b"BYR2",
                BayerPattern::Gbrg => *b"GB16",
                BayerPattern::Grbg => *b"GR16",
                BayerPattern::Rggb => *b"RG16",
            },
        }
    }

    /// Bytes per pixel on the wire.
    pub fn wire_bytes_per_pixel(self) -> usize {
        match self {
            WireFormat::Grey | WireFormat::Bayer8(_) => 1,
            WireFormat::Grey16 { .. } | WireFormat::Yuyv | WireFormat::Bayer16(_) => 2,
        }
    }

    /// Format of the frames we hand out.
    pub fn output_format(self) -> PixelFormat {
        match self {
            WireFormat::Grey | WireFormat::Yuyv => PixelFormat::Mono8,
            WireFormat::Grey16 { significant_bits } => PixelFormat::Mono16 { significant_bits },
            WireFormat::Bayer8(p) => PixelFormat::Bayer8(p),
            WireFormat::Bayer16(p) => PixelFormat::Bayer16(p),
        }
    }
}

/// A FourCC as text ("YUYV", "Y16"), unprintable bytes as '?'.
pub fn fourcc_name(code: [u8; 4]) -> String {
    code.iter()
        .map(|&b| if b.is_ascii_graphic() { b as char } else { '?' })
        .collect::<String>()
        .trim_end_matches('?')
        .to_string()
}

/// How a negotiated format lays a frame out in a driver buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameLayout {
    /// Pixel format in the buffer.
    pub format: WireFormat,
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Bytes from one row to the next in the buffer (V4L2 `bytesperline`).
    pub bytes_per_line: usize,
}

impl FrameLayout {
    /// A layout; a `bytes_per_line` of 0 (drivers may leave it unset) or
    /// shorter than a row means tightly packed rows.
    pub fn new(format: WireFormat, width: u32, height: u32, bytes_per_line: u32) -> Self {
        let row = width as usize * format.wire_bytes_per_pixel();
        Self {
            format,
            width,
            height,
            bytes_per_line: (bytes_per_line as usize).max(row),
        }
    }

    /// Bytes a buffer must hold for one frame.
    pub fn needed_bytes(&self) -> usize {
        if self.height == 0 {
            return 0;
        }
        self.bytes_per_line * (self.height as usize - 1)
            + self.width as usize * self.format.wire_bytes_per_pixel()
    }

    /// Copies a frame out of `wire` (a driver buffer, at least
    /// [`needed_bytes`](Self::needed_bytes) long) into a tightly packed,
    /// owned image. Copying is what lets the driver re-queue its buffer.
    pub fn to_image(&self, wire: &[u8]) -> Result<Image, LayoutError> {
        self.to_image_in(wire, &mut BufferPool::new(1))
    }

    /// [`to_image`](Self::to_image) into a buffer from `pool`, so steady
    /// capture allocates nothing.
    pub fn to_image_in(&self, wire: &[u8], pool: &mut BufferPool) -> Result<Image, LayoutError> {
        let needed = self.needed_bytes();
        if wire.len() < needed {
            return Err(LayoutError::Short {
                got: wire.len(),
                needed,
            });
        }
        let out_format = self.format.output_format();
        let out_row = self.width as usize * out_format.bytes_per_pixel();
        let wire_row = self.width as usize * self.format.wire_bytes_per_pixel();
        let pixels = pool.take(out_row * self.height as usize, |out| {
            for (y, dst) in out.chunks_exact_mut(out_row).enumerate() {
                let start = y * self.bytes_per_line;
                let src = &wire[start..start + wire_row];
                match self.format {
                    WireFormat::Yuyv => {
                        for (d, pair) in dst.iter_mut().zip(src.chunks_exact(2)) {
                            *d = pair[0];
                        }
                    }
                    _ => dst.copy_from_slice(src),
                }
            }
        });
        Image::new(self.width, self.height, out_row, out_format, pixels).map_err(LayoutError::Frame)
    }
}

/// Why a buffer could not be turned into an image.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum LayoutError {
    /// The buffer is shorter than one frame.
    #[error("buffer holds {got} B, the frame needs {needed} B")]
    Short {
        /// Bytes the buffer held.
        got: usize,
        /// Bytes one frame needs ([`FrameLayout::needed_bytes`]).
        needed: usize,
    },
    /// The copied pixels did not make a valid [`Image`] (a zero dimension,
    /// for instance).
    #[error(transparent)]
    Frame(FrameError),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fourccs_round_trip_and_parse() {
        for &f in SUPPORTED {
            assert_eq!(WireFormat::from_fourcc(f.fourcc()), Some(f));
            assert_eq!(WireFormat::parse(&fourcc_name(f.fourcc())), Some(f));
        }
        assert_eq!(
            WireFormat::parse("Y16"),
            Some(WireFormat::Grey16 {
                significant_bits: 16
            })
        );
        assert_eq!(WireFormat::parse("MJPG"), None);
        assert_eq!(WireFormat::from_fourcc(*b"MJPG"), None);
        assert_eq!(fourcc_name(*b"Y12 "), "Y12");
    }

    #[test]
    fn yuyv_keeps_the_luma_and_drops_row_padding() {
        // 4x2 YUYV with 4 bytes of padding per row: Y values 10.., chroma 200.
        let w = 4;
        let stride = w * 2 + 4;
        let mut wire = vec![255u8; stride * 2];
        for y in 0..2 {
            for x in 0..w {
                wire[y * stride + 2 * x] = (10 + y * w + x) as u8;
                wire[y * stride + 2 * x + 1] = 200;
            }
        }
        let layout = FrameLayout::new(WireFormat::Yuyv, 4, 2, stride as u32);
        let img = layout.to_image(&wire).expect("buffer is long enough");
        assert_eq!(img.format(), PixelFormat::Mono8);
        assert_eq!(img.data(), &[10, 11, 12, 13, 14, 15, 16, 17]);
    }

    #[test]
    fn grey16_and_bayer_are_copied_as_is() {
        let words: Vec<u8> = [1000u16, 4095, 7, 0]
            .iter()
            .flat_map(|w| w.to_le_bytes())
            .collect();
        let layout = FrameLayout::new(
            WireFormat::Grey16 {
                significant_bits: 12,
            },
            2,
            2,
            0,
        );
        let img = layout.to_image(&words).expect("exact size");
        assert_eq!(img.data(), &words[..]);
        assert_eq!(img.grey8_at(1, 0), Some(255));
        let bayer = FrameLayout::new(WireFormat::Bayer8(BayerPattern::Rggb), 2, 1, 0);
        let img = bayer.to_image(&[9, 8, 7]).expect("longer is fine");
        assert_eq!(img.format(), PixelFormat::Bayer8(BayerPattern::Rggb));
        assert_eq!(img.data(), &[9, 8]);
    }

    #[test]
    fn short_buffer_is_an_error() {
        let layout = FrameLayout::new(WireFormat::Grey, 4, 4, 8);
        assert_eq!(layout.needed_bytes(), 8 * 3 + 4);
        assert_eq!(
            layout.to_image(&[0; 27]).err(),
            Some(LayoutError::Short {
                got: 27,
                needed: 28
            })
        );
    }
}
