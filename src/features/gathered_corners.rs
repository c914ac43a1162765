//! The four grey levels around eight scattered pixels at once (AVX2
//! gathers), for the bilinear samples of a warped window: an affine warp
//! puts every sample of a row at its own fraction, so the samples cannot
//! share one set of weights and are read one by one otherwise.
//!
//! Each lane's 32-bit gather at byte offset `o` reads `data[o..o + 4]`:
//! its low two bytes are the pixel and its right neighbour. A second
//! gather one row down gives the lower pair.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// `(top-left, top-right, bottom-left, bottom-right)` grey levels of the
/// eight pixels at byte `offsets` of a row-major image with `stride`
/// bytes a row, as f32 lanes; `None` when a lane's four-byte reads would
/// pass the end of `data` or start before it (the caller samples those
/// one by one).
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub unsafe fn gathered_corners(
    data: &[u8],
    stride: usize,
    offsets: __m256i,
) -> Option<[__m256; 4]> {
    let mut lanes = [0i32; 8];
    _mm256_storeu_si256(lanes.as_mut_ptr().cast(), offsets);
    let first = lanes.iter().copied().min().unwrap_or(0);
    let last = lanes.iter().copied().max().unwrap_or(0);
    // The lower read starts `stride` further on and takes four bytes.
    if first < 0 || last as usize + stride + 4 > data.len() {
        return None;
    }
    let base = data.as_ptr().cast::<i32>();
    let below = _mm256_add_epi32(offsets, _mm256_set1_epi32(stride as i32));
    // SAFETY: every read lies in `data` (checked above); gathers need no
    // alignment.
    let upper = unsafe { _mm256_i32gather_epi32::<1>(base, offsets) };
    let lower = unsafe { _mm256_i32gather_epi32::<1>(base, below) };
    let byte = _mm256_set1_epi32(0xff);
    let first = |v: __m256i| _mm256_cvtepi32_ps(_mm256_and_si256(v, byte));
    let second = |v: __m256i| _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32::<8>(v), byte));
    Some([first(upper), second(upper), first(lower), second(lower)])
}

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;

    #[test]
    fn the_gathered_corners_are_the_pixels_and_their_neighbours_and_the_end_is_refused() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let (width, height) = (13usize, 7usize);
        let data: Vec<u8> = (0..width * height)
            .map(|k| ((k * 37 + 11) % 251) as u8)
            .collect();
        let pixels = [0usize, 5, 12, 14, 30, 44, 60, 71];
        let offsets: Vec<i32> = pixels.iter().map(|&k| k as i32).collect();
        // SAFETY: AVX2 checked above.
        let corners = unsafe {
            let v = _mm256_loadu_si256(offsets.as_ptr().cast());
            gathered_corners(&data, width, v).expect("inside")
        };
        let mut got = [[0f32; 8]; 4];
        for (c, lane) in corners.iter().zip(got.iter_mut()) {
            // SAFETY: AVX2 checked above.
            unsafe { _mm256_storeu_ps(lane.as_mut_ptr(), *c) };
        }
        for (l, &k) in pixels.iter().enumerate() {
            assert_eq!(got[0][l], f32::from(data[k]), "top-left of lane {l}");
            assert_eq!(got[1][l], f32::from(data[k + 1]), "top-right of lane {l}");
            assert_eq!(
                got[2][l],
                f32::from(data[k + width]),
                "bottom-left of lane {l}"
            );
            assert_eq!(
                got[3][l],
                f32::from(data[k + width + 1]),
                "bottom-right of lane {l}"
            );
        }
        // The last pixel whose right and lower neighbours exist reads two
        // bytes past the end with a four-byte gather, and a negative offset
        // before the start: both refused.
        let last = (height - 2) * width + width - 2;
        for offsets in [[last as i32; 8], [0, 1, 2, -1, 4, 5, 6, 7]] {
            // SAFETY: AVX2 checked above.
            let refused = unsafe {
                let v = _mm256_loadu_si256(offsets.as_ptr().cast());
                gathered_corners(&data, width, v)
            };
            assert!(refused.is_none(), "{offsets:?}");
        }
    }
}
