//! A pose sink that keeps every pose and fast pose the daemon's SLAM
//! stage publishes, for tests that drive the pipeline in-process.

use std::sync::{Arc, Mutex};

use rigslam::daemon::PoseSink;
use rigslam::publish::PoseMessage;
use rigslam::relative::RelativeOutput;

#[derive(Clone, Default)]
pub struct Collect {
    pub poses: Arc<Mutex<Vec<PoseMessage>>>,
    pub fast: Arc<Mutex<Vec<PoseMessage>>>,
}

impl PoseSink for Collect {
    fn pose(&mut self, m: &PoseMessage, _: &RelativeOutput) -> bool {
        self.poses.lock().expect("lock").push(*m);
        true
    }
    fn pose_fast(&mut self, m: &PoseMessage) -> bool {
        self.fast.lock().expect("lock").push(*m);
        true
    }
}
