//! Bumblebee stereo frames: the camera sends both images in one frame of
//! 16-bit pixels, byte `2i` from one camera and byte `2i + 1` from the
//! other (Point Grey's "pixel interleaved" stereo mode), each image
//! optionally Bayer-mosaiced. [`split_into`] separates them,
//! [`BumblebeeSplitter`] turns a captured [`Frame`] into a [`StereoFrame`],
//! demosaicing to grey when the sensors are colour ([`super::demosaic`]).

use std::sync::Arc;

use super::buffer_pool::BufferPool;
use super::demosaic::{DemosaicError, GreyDemosaic};
use crate::{BayerPattern, Frame, FrameError, Image, PixelFormat, StereoFrame};

/// Which camera's byte comes first in each 16-bit pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ByteOrder {
    /// Byte 0 left, byte 1 right.
    LeftFirst,
    /// Byte 0 right, byte 1 left (Bumblebee2/XB3 over libdc1394 default).
    RightFirst,
}

/// What the splitter hands out per eye.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Output {
    /// The bytes as the sensor gave them: Mono8, or Bayer8 for colour sensors.
    Raw,
    /// Mono8; colour sensors are demosaiced (bilinear) and converted to luma.
    Grey,
}

/// Shape of an interleaved stereo frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StereoLayout {
    /// Pixels per row of each eye (= 16-bit pixels per row of the frame).
    pub width: usize,
    /// Rows of each eye (= rows of the frame).
    pub height: usize,
    /// Bytes from one row of the interleaved frame to the next (>= 2 * width).
    pub stride_bytes: usize,
    /// Which eye's byte comes first in each 16-bit pixel.
    pub order: ByteOrder,
    /// Colour filter of both sensors; `None` for monochrome.
    pub mosaic: Option<BayerPattern>,
}

impl StereoLayout {
    /// Tightly packed rows.
    pub fn packed(
        width: usize,
        height: usize,
        order: ByteOrder,
        mosaic: Option<BayerPattern>,
    ) -> Self {
        Self {
            width,
            height,
            stride_bytes: 2 * width,
            order,
            mosaic,
        }
    }

    /// Bytes the interleaved frame must hold.
    pub fn needed_bytes(&self) -> usize {
        if self.height == 0 {
            return 0;
        }
        self.stride_bytes * (self.height - 1) + 2 * self.width
    }
}

/// Why a frame could not be split.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum BumblebeeError {
    /// Width or height is zero.
    #[error("stereo frame {width}x{height} has a zero dimension")]
    Empty {
        /// Pixels per row of each eye.
        width: usize,
        /// Rows.
        height: usize,
    },
    /// The row stride is shorter than `2 * width` bytes.
    #[error("row stride {stride_bytes} B is shorter than {width} interleaved 16-bit pixels")]
    StrideTooShort {
        /// Given row stride, bytes.
        stride_bytes: usize,
        /// Pixels per row of each eye.
        width: usize,
    },
    /// The interleaved frame ends before its last row does.
    #[error("interleaved frame holds {got} B, {width}x{height} stereo needs {needed} B")]
    ShortInput {
        /// Bytes the input held.
        got: usize,
        /// Bytes the layout needs ([`StereoLayout::needed_bytes`]).
        needed: usize,
        /// Pixels per row of each eye.
        width: usize,
        /// Rows.
        height: usize,
    },
    /// A caller's output buffer is shorter than one eye.
    #[error("output buffers hold {left} B and {right} B, each eye needs {needed} B")]
    ShortOutput {
        /// Length of the left output, bytes.
        left: usize,
        /// Length of the right output, bytes.
        right: usize,
        /// Bytes one eye needs (`width * height`).
        needed: usize,
    },
    /// The captured frame is not 2 bytes per pixel (the format it has).
    #[error("a Bumblebee frame is 16 bits per pixel (Mono16), got {0:?}")]
    NotSixteenBit(PixelFormat),
    /// Demosaicing an eye failed.
    #[error(transparent)]
    Demosaic(#[from] DemosaicError),
    /// An eye did not make a valid [`Image`].
    #[error(transparent)]
    Frame(#[from] FrameError),
}

fn check(layout: &StereoLayout, input_len: usize) -> Result<(), BumblebeeError> {
    let StereoLayout {
        width,
        height,
        stride_bytes,
        ..
    } = *layout;
    if width == 0 || height == 0 {
        return Err(BumblebeeError::Empty { width, height });
    }
    if stride_bytes < 2 * width {
        return Err(BumblebeeError::StrideTooShort {
            stride_bytes,
            width,
        });
    }
    let needed = layout.needed_bytes();
    if input_len < needed {
        return Err(BumblebeeError::ShortInput {
            got: input_len,
            needed,
            width,
            height,
        });
    }
    Ok(())
}

/// Separates an interleaved frame into two tightly packed 8-bit images
/// (`width * height` bytes each): the raw sensor bytes, no demosaicing.
pub fn split_into(
    interleaved: &[u8],
    layout: &StereoLayout,
    left: &mut [u8],
    right: &mut [u8],
) -> Result<(), BumblebeeError> {
    check(layout, interleaved.len())?;
    let n = layout.width * layout.height;
    if left.len() < n || right.len() < n {
        return Err(BumblebeeError::ShortOutput {
            left: left.len(),
            right: right.len(),
            needed: n,
        });
    }
    let (first, second) = match layout.order {
        ByteOrder::LeftFirst => (left, right),
        ByteOrder::RightFirst => (right, left),
    };
    let w = layout.width;
    for y in 0..layout.height {
        let src = &interleaved[y * layout.stride_bytes..][..2 * w];
        let a = &mut first[y * w..(y + 1) * w];
        let b = &mut second[y * w..(y + 1) * w];
        deinterleave_row(src, a, b);
    }
    Ok(())
}

/// `a[i] = src[2i]`, `b[i] = src[2i + 1]`, as 16-bit words split into
/// their low and high bytes (a form the compiler vectorises).
fn deinterleave_row(src: &[u8], a: &mut [u8], b: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above); the function is
        // safe Rust compiled with AVX2 enabled.
        unsafe { deinterleave_row_avx2(src, a, b) };
        return;
    }
    deinterleave_row_portable(src, a, b);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn deinterleave_row_avx2(src: &[u8], a: &mut [u8], b: &mut [u8]) {
    deinterleave_row_portable(src, a, b)
}

#[inline(always)]
fn deinterleave_row_portable(src: &[u8], a: &mut [u8], b: &mut [u8]) {
    let n = a.len();
    let (src, b) = (&src[..2 * n], &mut b[..n]);
    for i in 0..n {
        let word = u16::from_le_bytes([src[2 * i], src[2 * i + 1]]);
        a[i] = word as u8;
        b[i] = (word >> 8) as u8;
    }
}

/// The inverse of [`split_into`]: builds a packed interleaved frame from two
/// images of `width * height` bytes. For tests, simulation and the bench.
pub fn interleave(left: &[u8], right: &[u8], order: ByteOrder) -> Vec<u8> {
    assert_eq!(left.len(), right.len(), "both eyes have one size");
    let (first, second) = match order {
        ByteOrder::LeftFirst => (left, right),
        ByteOrder::RightFirst => (right, left),
    };
    first
        .iter()
        .zip(second)
        .flat_map(|(&a, &b)| [a, b])
        .collect()
}

/// Stereo frames a consumer may hold before the splitter allocates new buffers.
const POOLED_FRAMES: usize = 8;

/// Splits captured Bumblebee frames into stereo frames, reusing its
/// scratch buffers between frames.
#[derive(Debug)]
pub struct BumblebeeSplitter {
    layout: StereoLayout,
    output: Output,
    raw_left: Vec<u8>,
    raw_right: Vec<u8>,
    demosaic: GreyDemosaic,
    left_pool: BufferPool,
    right_pool: BufferPool,
}

impl BumblebeeSplitter {
    /// A splitter for frames of `layout`, handing out `output`.
    /// [`split_buffers`](Self::split_buffers) uses the whole layout;
    /// [`split_frame`](Self::split_frame) replaces its size and stride with
    /// each frame's.
    pub fn new(layout: StereoLayout, output: Output) -> Self {
        Self {
            layout,
            output,
            raw_left: Vec::new(),
            raw_right: Vec::new(),
            demosaic: GreyDemosaic::new(),
            left_pool: BufferPool::new(POOLED_FRAMES),
            right_pool: BufferPool::new(POOLED_FRAMES),
        }
    }

    /// The layout in use: as given to [`new`](Self::new), with the size and
    /// stride of the last frame passed to [`split_frame`](Self::split_frame).
    pub fn layout(&self) -> &StereoLayout {
        &self.layout
    }

    /// Splits (and for [`Output::Grey`] with a mosaic, demosaics) one
    /// interleaved buffer into caller-owned eyes of `width * height` bytes.
    /// Allocates nothing after the first call.
    pub fn split_buffers(
        &mut self,
        interleaved: &[u8],
        left: &mut [u8],
        right: &mut [u8],
    ) -> Result<(), BumblebeeError> {
        let l = &self.layout;
        match (self.output, l.mosaic) {
            (Output::Grey, Some(pattern)) => {
                let n = l.width * l.height;
                self.raw_left.resize(n, 0);
                self.raw_right.resize(n, 0);
                split_into(interleaved, l, &mut self.raw_left, &mut self.raw_right)?;
                let d = &mut self.demosaic;
                d.run(&self.raw_left, l.width, l.height, l.width, pattern, left)?;
                d.run(&self.raw_right, l.width, l.height, l.width, pattern, right)?;
                Ok(())
            }
            _ => split_into(interleaved, l, left, right),
        }
    }

    /// A captured 16-bit frame (as V4L2 `Y16` or GenICam `Mono16` delivers
    /// it) as a stereo pair with the frame's stamp and sequence; left is
    /// camera 0, right camera 1.
    pub fn split_frame(&mut self, frame: &Frame) -> Result<StereoFrame, BumblebeeError> {
        let image = &frame.image;
        if image.format().bytes_per_pixel() != 2 {
            return Err(BumblebeeError::NotSixteenBit(image.format()));
        }
        let layout = StereoLayout {
            width: image.width() as usize,
            height: image.height() as usize,
            stride_bytes: image.stride_bytes(),
            ..self.layout
        };
        self.layout = layout;
        let n = layout.width * layout.height;
        let mut left_px = self.left_pool.checkout(n);
        let mut right_px = self.right_pool.checkout(n);
        self.split_buffers(
            image.data(),
            Arc::get_mut(&mut left_px).expect("checkout hands out unique buffers"),
            Arc::get_mut(&mut right_px).expect("checkout hands out unique buffers"),
        )?;
        self.left_pool.track(&left_px);
        self.right_pool.track(&right_px);
        let format = match (self.output, layout.mosaic) {
            (Output::Raw, Some(p)) => PixelFormat::Bayer8(p),
            _ => PixelFormat::Mono8,
        };
        let eye = |pixels: Arc<[u8]>, camera_index: u8| -> Result<Frame, BumblebeeError> {
            Ok(Frame {
                t_ns: frame.t_ns,
                seq: frame.seq,
                camera_index,
                image: Image::new(
                    layout.width as u32,
                    layout.height as u32,
                    layout.width,
                    format,
                    pixels,
                )?,
            })
        };
        Ok(StereoFrame {
            t_ns: frame.t_ns,
            left: eye(left_px, 0)?,
            right: eye(right_px, 1)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_inverts_interleave_in_both_orders() {
        let left: Vec<u8> = (0..12).collect();
        let right: Vec<u8> = (100..112).collect();
        for order in [ByteOrder::LeftFirst, ByteOrder::RightFirst] {
            let frame = interleave(&left, &right, order);
            let layout = StereoLayout::packed(4, 3, order, None);
            let (mut l, mut r) = (vec![0; 12], vec![0; 12]);
            split_into(&frame, &layout, &mut l, &mut r).expect("sizes match");
            assert_eq!((l.as_slice(), r.as_slice()), (&left[..], &right[..]));
        }
        // Byte 0 is the left eye's first pixel when left comes first.
        assert_eq!(interleave(&[1], &[2], ByteOrder::LeftFirst), [1, 2]);
        assert_eq!(interleave(&[1], &[2], ByteOrder::RightFirst), [2, 1]);
    }

    #[test]
    fn row_padding_is_skipped() {
        // 2x2 per eye, stride 6 (2 bytes of padding per row).
        let frame = [1, 5, 2, 6, 99, 99, 3, 7, 4, 8];
        let layout = StereoLayout {
            stride_bytes: 6,
            ..StereoLayout::packed(2, 2, ByteOrder::LeftFirst, None)
        };
        let (mut l, mut r) = ([0; 4], [0; 4]);
        split_into(&frame, &layout, &mut l, &mut r).expect("sizes match");
        assert_eq!((l, r), ([1, 2, 3, 4], [5, 6, 7, 8]));
    }

    #[test]
    fn bad_shapes_are_errors_not_panics() {
        let layout = StereoLayout::packed(4, 3, ByteOrder::LeftFirst, None);
        let (mut l, mut r) = (vec![0; 12], vec![0; 12]);
        assert_eq!(
            split_into(&[0; 23], &layout, &mut l, &mut r),
            Err(BumblebeeError::ShortInput {
                got: 23,
                needed: 24,
                width: 4,
                height: 3
            })
        );
        assert!(matches!(
            split_into(&[0; 24], &layout, &mut l[..11], &mut r),
            Err(BumblebeeError::ShortOutput { needed: 12, .. })
        ));
        let narrow = StereoLayout {
            stride_bytes: 7,
            ..layout
        };
        assert!(matches!(
            split_into(&[0; 64], &narrow, &mut l, &mut r),
            Err(BumblebeeError::StrideTooShort { .. })
        ));
        let empty = StereoLayout::packed(0, 3, ByteOrder::LeftFirst, None);
        assert!(matches!(
            split_into(&[], &empty, &mut l, &mut r),
            Err(BumblebeeError::Empty { .. })
        ));
        // A Bayer layout too small to demosaic.
        let tiny = StereoLayout::packed(1, 1, ByteOrder::LeftFirst, Some(BayerPattern::Rggb));
        let mut s = BumblebeeSplitter::new(tiny, Output::Grey);
        assert!(matches!(
            s.split_buffers(&[0, 0], &mut l, &mut r),
            Err(BumblebeeError::Demosaic(DemosaicError::TooSmall { .. }))
        ));
    }

    #[test]
    fn a_captured_frame_becomes_a_stereo_pair() {
        let (left, right) = (vec![10u8; 6], vec![20u8; 6]);
        let bytes = interleave(&left, &right, ByteOrder::RightFirst);
        let frame = Frame {
            t_ns: 42,
            seq: 7,
            camera_index: 0,
            image: Image::new(
                3,
                2,
                6,
                PixelFormat::Mono16 {
                    significant_bits: 16,
                },
                bytes.into(),
            )
            .expect("valid"),
        };
        let layout = StereoLayout::packed(0, 0, ByteOrder::RightFirst, None);
        let mut splitter = BumblebeeSplitter::new(layout, Output::Grey);
        let pair = splitter.split_frame(&frame).expect("16-bit frame");
        assert_eq!(
            (pair.t_ns, pair.left.seq, pair.right.camera_index),
            (42, 7, 1)
        );
        assert_eq!(pair.left.image.data(), &left[..]);
        assert_eq!(pair.right.image.data(), &right[..]);
        assert_eq!(pair.left.image.format(), PixelFormat::Mono8);

        let mono8 = Frame {
            image: Image::mono8(2, 1, vec![0, 0]).expect("valid"),
            ..frame
        };
        assert!(matches!(
            splitter.split_frame(&mono8),
            Err(BumblebeeError::NotSixteenBit(PixelFormat::Mono8))
        ));
    }
}
