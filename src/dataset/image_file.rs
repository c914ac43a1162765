//! PNG files to and from sensor [`Image`]s: 8-bit grey, 16-bit grey, and
//! colour converted to 8-bit grey on reading.

use std::io::BufWriter;
use std::path::Path;

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{DynamicImage, ExtendedColorType, ImageEncoder, ImageFormat};

use crate::dataset::error::DatasetError;
use crate::sensors::{Image, PixelFormat};

/// Decodes a PNG file. 8-bit grey stays Mono8, 16-bit grey becomes Mono16
/// with 16 significant bits (PNG does not say how many carry data), and
/// anything else (RGB, palette, grey+alpha) is converted to 8-bit grey
/// with the `image` crate's Rec. 709 luma weights.
pub fn read_png(path: &Path) -> Result<Image, DatasetError> {
    let bytes = std::fs::read(path).map_err(|e| DatasetError::io(path, e))?;
    let image_error = |message: String| DatasetError::Image {
        path: path.to_path_buf(),
        message,
    };
    let decoded = image::load_from_memory_with_format(&bytes, ImageFormat::Png)
        .map_err(|e| image_error(e.to_string()))?;
    let (width, height) = (decoded.width(), decoded.height());
    let image = match decoded {
        DynamicImage::ImageLuma16(buffer) => Image::mono16(width, height, 16, buffer.as_raw()),
        DynamicImage::ImageLuma8(buffer) => Image::mono8(width, height, buffer.into_raw()),
        other => Image::mono8(width, height, other.to_luma8().into_raw()),
    };
    image.map_err(|e| image_error(e.to_string()))
}

/// Reads only a PNG's header: (width, height).
pub fn png_dimensions(path: &Path) -> Result<(u32, u32), DatasetError> {
    image::ImageReader::open(path)
        .map_err(|e| DatasetError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| DatasetError::io(path, e))?
        .into_dimensions()
        .map_err(|e| DatasetError::Image {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
}

/// Encodes an image as PNG: Mono8 as 8-bit grey, Mono16 as 16-bit grey
/// (pixel values unchanged). Bayer images are refused: the file would not
/// say they are mosaiced.
pub fn write_png(path: &Path, image: &Image) -> Result<(), DatasetError> {
    let image_error = |message: String| DatasetError::Image {
        path: path.to_path_buf(),
        message,
    };
    let (width, height) = (image.width(), image.height());
    let rows = (0..height).map(|y| image.row(y).expect("y < height"));
    let (pixels, colour): (Vec<u8>, _) = match image.format() {
        PixelFormat::Mono8 => (rows.flatten().copied().collect(), ExtendedColorType::L8),
        PixelFormat::Mono16 { .. } => (
            // The encoder takes 16-bit samples in native byte order.
            rows.flat_map(|r| r.chunks_exact(2))
                .flat_map(|b| u16::from_le_bytes([b[0], b[1]]).to_ne_bytes())
                .collect(),
            ExtendedColorType::L16,
        ),
        other => {
            return Err(image_error(format!(
                "{other:?} images are not written as PNG; demosaic them first"
            )))
        }
    };
    let file = std::fs::File::create(path).map_err(|e| DatasetError::io(path, e))?;
    let mut out = BufWriter::new(file);
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
        .write_image(&pixels, width, height, colour)
        .map_err(|e| image_error(e.to_string()))?;
    std::io::Write::flush(&mut out).map_err(|e| DatasetError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sensors::BayerPattern;

    fn pattern8(width: u32, height: u32) -> Vec<u8> {
        (0..width * height).map(|i| (i * 37 % 251) as u8).collect()
    }

    #[test]
    fn mono8_and_mono16_round_trip_bit_exact() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("a.png");
        let img = Image::mono8(13, 7, pattern8(13, 7)).expect("image");
        write_png(&path, &img).expect("write");
        let back = read_png(&path).expect("read");
        assert_eq!(back.format(), PixelFormat::Mono8);
        assert_eq!((back.width(), back.height()), (13, 7));
        assert_eq!(back.data(), img.data());
        assert_eq!(png_dimensions(&path).expect("header"), (13, 7));

        let words: Vec<u16> = (0..13 * 7).map(|i| (i * 4099 % 65536) as u16).collect();
        let img = Image::mono16(13, 7, 12, &words).expect("image");
        write_png(&path, &img).expect("write");
        let back = read_png(&path).expect("read");
        assert_eq!(
            back.format(),
            PixelFormat::Mono16 {
                significant_bits: 16
            }
        );
        assert_eq!(back.data(), img.data());
    }

    #[test]
    fn padded_rows_are_written_without_padding() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("s.png");
        let mut buf = vec![0u8; 8 * 3];
        for y in 0..3 {
            for x in 0..5 {
                buf[y * 8 + x] = (10 * y + x) as u8;
            }
        }
        let img = Image::new(5, 3, 8, PixelFormat::Mono8, buf.into()).expect("image");
        write_png(&path, &img).expect("write");
        let back = read_png(&path).expect("read");
        for y in 0..3 {
            assert_eq!(back.row(y), img.row(y));
        }
    }

    #[test]
    fn rgb_is_converted_to_grey() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("rgb.png");
        let rgb = image::RgbImage::from_fn(4, 2, |x, _| {
            if x < 2 {
                image::Rgb([200, 200, 200])
            } else {
                image::Rgb([255, 0, 0])
            }
        });
        rgb.save(&path).expect("save rgb");
        let back = read_png(&path).expect("read");
        assert_eq!(back.format(), PixelFormat::Mono8);
        // A grey pixel keeps its value; pure red gets the red luma weight (0.2126).
        assert_eq!(back.grey8_at(0, 0), Some(200));
        assert_eq!(back.grey8_at(3, 1), Some(54));
    }

    #[test]
    fn truncated_and_garbage_pngs_are_image_errors() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("t.png");
        let img = Image::mono8(64, 48, pattern8(64, 48)).expect("image");
        write_png(&path, &img).expect("write");
        let good = std::fs::read(&path).expect("read bytes");
        for bad in [
            &good[..good.len() / 2],
            &good[..20],
            &good[..0],
            b"not a png at all".as_slice(),
        ] {
            std::fs::write(&path, bad).expect("write");
            let err = read_png(&path).expect_err("corrupt");
            assert!(matches!(err, DatasetError::Image { .. }), "{err}");
            assert!(err.to_string().contains("t.png"));
        }
        // Flipped bytes inside the compressed data: the CRC or zlib check fails.
        let mut flipped = good.clone();
        let mid = flipped.len() / 2;
        flipped[mid] ^= 0xff;
        std::fs::write(&path, &flipped).expect("write");
        assert!(matches!(read_png(&path), Err(DatasetError::Image { .. })));
        assert!(matches!(
            read_png(&dir.path().join("absent.png")),
            Err(DatasetError::Io { .. })
        ));
    }

    #[test]
    fn bayer_is_refused() {
        let dir = tempfile::tempdir().expect("temp dir");
        let img = Image::new(
            2,
            2,
            2,
            PixelFormat::Bayer8(BayerPattern::Rggb),
            vec![1, 2, 3, 4].into(),
        )
        .expect("image");
        let err = write_png(&dir.path().join("b.png"), &img).expect_err("bayer");
        assert!(err.to_string().contains("demosaic"), "{err}");
    }
}
