//! A real V4L2 camera. Everything above the ioctl layer is tested with a
//! scripted fake in `camera::v4l2`; this checks the ioctl layer itself on a
//! machine with a camera:
//! `RIGSLAM_V4L2_DEVICE=/dev/video0 cargo test --release -p rigslam-drivers --test v4l2_device -- --ignored`

use std::time::Duration;

use rigslam_drivers::camera::v4l2::{open_v4l2, V4l2Config};
use rigslam_drivers::camera::FrameSource;

#[test]
#[ignore = "needs a V4L2 camera at /dev/video0 (or RIGSLAM_V4L2_DEVICE)"]
fn streams_from_a_real_camera() {
    let device = std::env::var("RIGSLAM_V4L2_DEVICE").unwrap_or_else(|_| "/dev/video0".into());
    let mut source = open_v4l2(&V4l2Config::new(&device)).expect("open the camera");
    let (width, height) = (source.info().width, source.info().height);
    let mut last_t_ns = i64::MIN;
    for _ in 0..60 {
        let frame = source
            .next_frame(Duration::from_secs(2))
            .expect("a frame within 2 s");
        assert_eq!((frame.image.width(), frame.image.height()), (width, height));
        assert!(frame.t_ns > last_t_ns, "stamps increase");
        last_t_ns = frame.t_ns;
    }
    let stats = source.stats();
    assert!(stats.frames >= 60, "{stats:?}");
}
