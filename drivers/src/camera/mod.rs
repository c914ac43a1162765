//! Cameras: the [`FrameSource`] trait and its drivers (V4L2, Aravis behind
//! the `aravis` feature, a fake), and the Bumblebee stereo splitter with its
//! demosaicing.

#[cfg(feature = "aravis")]
pub mod aravis;
pub mod buffer_pool;
pub mod bumblebee;
pub mod demosaic;
pub mod fake;
pub mod genicam;
pub mod source;
pub mod v4l2;
pub mod v4l2_format;

pub use source::{CameraError, CameraInfo, CaptureStats, FrameSource, TimestampSource};
