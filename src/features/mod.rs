//! Image front end: pyramids, corners, ORB descriptors, matching and KLT
//! tracking, from an 8-bit (or normalised 16-bit) grey [`Image`] to
//! keypoints, descriptors and tracks.
//!
//! A frame goes [`pyramid`] -> [`fast`] + [`score`] -> [`grid`] (spread,
//! mask of what is already tracked) -> [`klt`] (tracking) or [`orb`]
//! (descriptors, matched by [`matching`]). Every stage owns its buffers and
//! reuses them, so nothing is allocated per frame once sizes are stable.
//!
//! [`Image`]: crate::sensors::Image

pub mod brief_pattern;
pub mod corners;
pub mod fast;
pub mod gathered_corners;
pub mod grid;
pub mod klt;
pub mod matching;
pub mod orb;
pub mod pyramid;
pub mod score;

pub use corners::{CornerConfig, CornerDetector};
pub use fast::{detect_fast9, Corner};
pub use grid::{GridConfig, GridSelector};
pub use klt::{predict_from_rotation, KltConfig, KltTracker, TrackStatus};
pub use matching::{hamming, match_descriptors, Match, MatchConfig, Matcher, SearchWindow};
pub use orb::{Descriptor, Keypoint, OrbConfig, OrbExtractor};

pub use pyramid::{GreyImage, Pyramid, PyramidConfig};
pub use score::{harris_score, shi_tomasi_score};

/// Why an image cannot enter the front end.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FeatureError {
    #[error("image {width}x{height} is empty")]
    /// The image has no pixels.
    Empty {
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
    },
    #[error("buffer of {got} B is too short for a {width}x{height} grey image")]
    /// The pixel buffer holds fewer than `width * height` bytes.
    BufferTooShort {
        /// Buffer length, bytes.
        got: usize,
        /// Width, px.
        width: usize,
        /// Height, px.
        height: usize,
    },
    #[error("{format} images are not grey; demosaic them before the front end")]
    /// The image is not grey (8 or 16 bit), e.g. Bayer or colour.
    UnsupportedFormat {
        /// The image's pixel format.
        format: String,
    },
    #[error("bad configuration: {0}")]
    /// A detector, tracker or pyramid setting is out of range (the message names it).
    Config(String),
}
