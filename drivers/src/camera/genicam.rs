//! GenICam/GigE Vision facts the Aravis driver needs, kept pure so CI tests
//! them without the `aravis` feature: pixel format names (GenICam SFNC /
//! PFNC) and frame (block) id gaps.

use crate::{BayerPattern, PixelFormat};

/// The frame format for a GenICam `PixelFormat` name, for the unpacked
/// formats we read (`Mono10`/`Mono12` sit in the low bits of 16-bit words).
pub fn pixel_format(name: &str) -> Option<PixelFormat> {
    let bayer = |p: &str| match p {
        "RG" => Some(BayerPattern::Rggb),
        "BG" => Some(BayerPattern::Bggr),
        "GR" => Some(BayerPattern::Grbg),
        "GB" => Some(BayerPattern::Gbrg),
        _ => None,
    };
    match name {
        "Mono8" => Some(PixelFormat::Mono8),
        "Mono10" => Some(PixelFormat::Mono16 {
            significant_bits: 10,
        }),
        "Mono12" => Some(PixelFormat::Mono16 {
            significant_bits: 12,
        }),
        "Mono16" => Some(PixelFormat::Mono16 {
            significant_bits: 16,
        }),
        _ => {
            let rest = name.strip_prefix("Bayer")?;
            let (pattern, bits) = rest.split_at_checked(2)?;
            let pattern = bayer(pattern)?;
            match bits {
                "8" => Some(PixelFormat::Bayer8(pattern)),
                "16" => Some(PixelFormat::Bayer16(pattern)),
                _ => None,
            }
        }
    }
}

/// Every GenICam name [`pixel_format`] reads, for error messages.
pub const SUPPORTED_NAMES: &[&str] = &[
    "Mono8",
    "Mono10",
    "Mono12",
    "Mono16",
    "BayerRG8",
    "BayerBG8",
    "BayerGR8",
    "BayerGB8",
    "BayerRG16",
    "BayerBG16",
    "BayerGR16",
    "BayerGB16",
];

/// Frames missing between two consecutive frame ids.
///
/// GigE Vision 1.x block ids are 16 bits and skip 0 (1, 2, ..., 65535, 1,
/// ...); GigE Vision 2 and USB3 Vision ids are 64 bits. A step back that is
/// not a 16-bit wrap is a restarted stream: no loss can be proven.
pub fn frame_id_gap(previous: u64, next: u64) -> u64 {
    const GEV1_LAST: u64 = 0xFFFF;
    if next > previous {
        next - previous - 1
    } else if previous <= GEV1_LAST && next >= 1 && previous > GEV1_LAST / 2 && next < GEV1_LAST / 2
    {
        (GEV1_LAST - previous) + (next - 1)
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_map_to_formats() {
        assert_eq!(pixel_format("Mono8"), Some(PixelFormat::Mono8));
        assert_eq!(
            pixel_format("Mono12"),
            Some(PixelFormat::Mono16 {
                significant_bits: 12
            })
        );
        assert_eq!(
            pixel_format("BayerGB8"),
            Some(PixelFormat::Bayer8(BayerPattern::Gbrg))
        );
        assert_eq!(
            pixel_format("BayerRG16"),
            Some(PixelFormat::Bayer16(BayerPattern::Rggb))
        );
        for bad in [
            "Mono12Packed",
            "BayerRG12p",
            "RGB8",
            "Bayer",
            "BayerXX8",
            "",
        ] {
            assert_eq!(pixel_format(bad), None, "{bad}");
        }
        for name in SUPPORTED_NAMES {
            assert!(pixel_format(name).is_some(), "{name}");
        }
    }

    #[test]
    fn frame_id_gaps_handle_the_16_bit_wrap() {
        assert_eq!(frame_id_gap(10, 11), 0);
        assert_eq!(frame_id_gap(10, 14), 3);
        // GigE Vision 1.x: 65535 is followed by 1.
        assert_eq!(frame_id_gap(65535, 1), 0);
        assert_eq!(frame_id_gap(65534, 2), 2);
        // 64-bit ids pass 65535 without wrapping.
        assert_eq!(frame_id_gap(65535, 65536), 0);
        // A restart is not a loss.
        assert_eq!(frame_id_gap(500, 1), 0);
        assert_eq!(frame_id_gap(7, 7), 0);
    }
}
