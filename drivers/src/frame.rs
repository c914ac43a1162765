//! Image frames: pixel formats, a shared buffer, mono and stereo frames.
//!
//! Pixel data sits in an `Arc<[u8]>`: cloning an [`Image`] or a [`Frame`]
//! shares the buffer, never copies it, so one frame can go to the tracker,
//! the recorder and the publisher at once.

use std::sync::Arc;

/// Colour filter layout of a raw Bayer sensor, named by its top-left 2x2 block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BayerPattern {
    /// Row 0: R G, row 1: G B.
    Rggb,
    /// Row 0: B G, row 1: G R.
    Bggr,
    /// Row 0: G R, row 1: B G.
    Grbg,
    /// Row 0: G B, row 1: R G.
    Gbrg,
}

/// How pixel bytes are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    /// 8-bit grey.
    Mono8,
    /// 16-bit grey, little endian; `significant_bits` of each word carry data
    /// (12 for many machine-vision sensors), left in the low bits.
    Mono16 {
        /// Bits of each word that carry data, 1..=16.
        significant_bits: u8,
    },
    /// 8-bit raw Bayer.
    Bayer8(BayerPattern),
    /// 16-bit raw Bayer, little endian.
    Bayer16(BayerPattern),
}

impl PixelFormat {
    /// Bytes one pixel occupies.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Mono8 | PixelFormat::Bayer8(_) => 1,
            PixelFormat::Mono16 { .. } | PixelFormat::Bayer16(_) => 2,
        }
    }
}

/// Why an image could not be built from a buffer.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum FrameError {
    /// Width or height is zero.
    #[error("image {width}x{height} has a zero dimension")]
    Empty {
        /// Requested width, pixels.
        width: u32,
        /// Requested height, pixels.
        height: u32,
    },
    #[error(
        "row stride {stride_bytes} B is shorter than a row of {width} px x {bytes_per_pixel} B"
    )]
    /// The row stride is shorter than one row of pixels.
    StrideTooShort {
        /// Given row stride, bytes.
        stride_bytes: usize,
        /// Image width, pixels.
        width: u32,
        /// Bytes per pixel of the format.
        bytes_per_pixel: usize,
    },
    /// The buffer ends before the last row does.
    #[error("buffer holds {got} B, a {width}x{height} image with stride {stride_bytes} B needs {needed} B")]
    BufferTooShort {
        /// Buffer length, bytes.
        got: usize,
        /// Bytes the image needs: `stride_bytes * (height - 1)` plus one
        /// row of pixels (the last row needs no padding).
        needed: usize,
        /// Image width, pixels.
        width: u32,
        /// Image height, pixels.
        height: u32,
        /// Row stride, bytes.
        stride_bytes: usize,
    },
    /// A `Mono16` format whose `significant_bits` (the value carried) is
    /// outside 1..=16.
    #[error("Mono16 with {0} significant bits: must be 1..=16")]
    BadBitDepth(u8),
}

/// One image: dimensions, format and a shared, immutable pixel buffer.
#[derive(Debug, Clone)]
pub struct Image {
    width: u32,
    height: u32,
    stride_bytes: usize,
    format: PixelFormat,
    data: Arc<[u8]>,
}

impl Image {
    /// Wraps a buffer after checking that it holds the whole image.
    pub fn new(
        width: u32,
        height: u32,
        stride_bytes: usize,
        format: PixelFormat,
        data: Arc<[u8]>,
    ) -> Result<Self, FrameError> {
        if width == 0 || height == 0 {
            return Err(FrameError::Empty { width, height });
        }
        if let PixelFormat::Mono16 { significant_bits } = format {
            if significant_bits == 0 || significant_bits > 16 {
                return Err(FrameError::BadBitDepth(significant_bits));
            }
        }
        let bpp = format.bytes_per_pixel();
        let row = width as usize * bpp;
        if stride_bytes < row {
            return Err(FrameError::StrideTooShort {
                stride_bytes,
                width,
                bytes_per_pixel: bpp,
            });
        }
        let needed = stride_bytes * (height as usize - 1) + row;
        if data.len() < needed {
            return Err(FrameError::BufferTooShort {
                got: data.len(),
                needed,
                width,
                height,
                stride_bytes,
            });
        }
        Ok(Self {
            width,
            height,
            stride_bytes,
            format,
            data,
        })
    }

    /// A tightly packed 8-bit grey image.
    pub fn mono8(width: u32, height: u32, pixels: Vec<u8>) -> Result<Self, FrameError> {
        Self::new(
            width,
            height,
            width as usize,
            PixelFormat::Mono8,
            pixels.into(),
        )
    }

    /// A tightly packed 16-bit grey image (little-endian words).
    pub fn mono16(
        width: u32,
        height: u32,
        significant_bits: u8,
        pixels: &[u16],
    ) -> Result<Self, FrameError> {
        let bytes: Vec<u8> = pixels.iter().flat_map(|p| p.to_le_bytes()).collect();
        Self::new(
            width,
            height,
            width as usize * 2,
            PixelFormat::Mono16 { significant_bits },
            bytes.into(),
        )
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }
    /// Height in pixels (number of rows).
    pub fn height(&self) -> u32 {
        self.height
    }
    /// Bytes from the start of one row to the start of the next; at least
    /// `width * bytes_per_pixel`, more when rows are padded.
    pub fn stride_bytes(&self) -> usize {
        self.stride_bytes
    }
    /// How the pixel bytes are laid out.
    pub fn format(&self) -> PixelFormat {
        self.format
    }
    /// The whole buffer, rows `stride_bytes` apart.
    pub fn data(&self) -> &[u8] {
        &self.data
    }
    /// The shared buffer itself, for handing on without a copy.
    pub fn shared_data(&self) -> &Arc<[u8]> {
        &self.data
    }

    /// Bytes of row `y` (exactly `width * bytes_per_pixel`), or `None` past the end.
    pub fn row(&self, y: u32) -> Option<&[u8]> {
        if y >= self.height {
            return None;
        }
        let start = y as usize * self.stride_bytes;
        Some(&self.data[start..start + self.width as usize * self.format.bytes_per_pixel()])
    }

    /// Grey value at (x, y) scaled to 0..=255 whatever the bit depth; for
    /// Bayer formats the raw value of that photosite. `None` outside.
    pub fn grey8_at(&self, x: u32, y: u32) -> Option<u8> {
        if x >= self.width {
            return None;
        }
        let row = self.row(y)?;
        Some(match self.format {
            PixelFormat::Mono8 | PixelFormat::Bayer8(_) => row[x as usize],
            PixelFormat::Mono16 { significant_bits } => {
                let i = x as usize * 2;
                let v = u16::from_le_bytes([row[i], row[i + 1]]);
                (u32::from(v) >> significant_bits.saturating_sub(8)).min(255) as u8
            }
            PixelFormat::Bayer16(_) => {
                let i = x as usize * 2;
                (u16::from_le_bytes([row[i], row[i + 1]]) >> 8) as u8
            }
        })
    }
}

/// An image with its timestamp and where it came from.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Exposure time stamp (middle of exposure where the driver knows it), ns.
    pub t_ns: i64,
    /// Per-camera frame number. The V4L2 source takes the driver's counter,
    /// so a gap there means dropped frames; the Aravis and pattern sources
    /// number the frames they hand out and count drops only in
    /// [`CaptureStats`](crate::camera::CaptureStats).
    pub seq: u64,
    /// Which camera of the rig (0 = left/cam0).
    pub camera_index: u8,
    /// The pixels; cloning the frame shares them.
    pub image: Image,
}

/// Left and right frames exposed together.
#[derive(Debug, Clone)]
pub struct StereoFrame {
    /// Stamp of the pair, ns, on the same clock as the frames' own `t_ns`
    /// (the Bumblebee splitter gives both eyes the captured frame's stamp).
    pub t_ns: i64,
    /// Left camera (`camera_index` 0).
    pub left: Frame,
    /// Right camera (`camera_index` 1).
    pub right: Frame,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cloning_shares_the_buffer() {
        let img = Image::mono8(4, 2, vec![7; 8]).expect("valid image");
        let frame = Frame {
            t_ns: 10,
            seq: 0,
            camera_index: 0,
            image: img,
        };
        let copy = frame.clone();
        assert!(Arc::ptr_eq(
            frame.image.shared_data(),
            copy.image.shared_data()
        ));
        assert_eq!(Arc::strong_count(frame.image.shared_data()), 2);
    }

    #[test]
    fn short_buffer_and_stride_are_rejected() {
        let short = Image::new(4, 2, 4, PixelFormat::Mono8, vec![0u8; 7].into());
        assert!(matches!(
            short,
            Err(FrameError::BufferTooShort {
                got: 7,
                needed: 8,
                ..
            })
        ));
        let stride = Image::new(4, 2, 3, PixelFormat::Mono8, vec![0u8; 8].into());
        assert!(matches!(stride, Err(FrameError::StrideTooShort { .. })));
        assert!(matches!(
            Image::mono8(0, 2, vec![]),
            Err(FrameError::Empty { .. })
        ));
        assert!(matches!(
            Image::mono16(1, 1, 17, &[0]),
            Err(FrameError::BadBitDepth(17))
        ));
    }

    #[test]
    fn padded_rows_and_16_bit_grey() {
        // 2x2 image with 1 byte of row padding.
        let img =
            Image::new(2, 2, 3, PixelFormat::Mono8, vec![1, 2, 99, 3, 4].into()).expect("valid");
        assert_eq!(img.row(1), Some(&[3u8, 4][..]));
        assert_eq!(img.grey8_at(1, 1), Some(4));
        assert_eq!(img.grey8_at(2, 0), None);
        let img16 = Image::mono16(2, 1, 12, &[4095, 16]).expect("valid");
        assert_eq!(img16.grey8_at(0, 0), Some(255));
        assert_eq!(img16.grey8_at(1, 0), Some(1));
        assert_eq!(img16.format().bytes_per_pixel(), 2);
    }
}
