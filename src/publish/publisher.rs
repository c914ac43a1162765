//! The daemon's side: one publisher per stream, each followed by a
//! notification on the paired event service so that subscribers blocked
//! on it wake at once.

use crate::sensors::yei::device::host_monotonic_ns;

use super::message::{PoseMessage, StatusMessage};
use super::service::{create_node, IpcConfig, IpcError, Message, Services, Stream};
use iceoryx2::node::Node;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;

use super::service::Ipc;

/// Sends one stream's samples and wakes its subscribers.
pub struct StreamPublisher<T: Message> {
    service: String,
    publisher: Publisher<Ipc, T, ()>,
    notifier: Notifier<Ipc>,
    next_sequence: u64,
    // Keeps the service's static config alive as long as the ports.
    _services: Services<T>,
}

impl<T: Message> StreamPublisher<T> {
    fn open(node: &Node<Ipc>, name: String) -> Result<Self, IpcError> {
        let services = Services::<T>::open(node, &name)?;
        let (publisher, notifier) = services.publisher()?;
        Ok(Self {
            service: name,
            publisher,
            notifier,
            next_sequence: 0,
            _services: services,
        })
    }

    /// Copies `message` into shared memory with the next sequence number
    /// and the send time (host `CLOCK_MONOTONIC`) set, then notifies the
    /// event service. Returns the sequence number given. Never blocks: a
    /// subscriber that lags loses its oldest samples.
    pub fn publish(&mut self, message: &T) -> Result<u64, IpcError> {
        let sequence = self.next_sequence;
        let mut stamped = *message;
        stamped.stamp(sequence, host_monotonic_ns());
        self.publisher
            .send_copy(stamped)
            .map_err(|e| IpcError::service(&self.service, "send sample", e))?;
        self.next_sequence += 1;
        self.notifier
            .notify()
            .map_err(|e| IpcError::service(&self.service, "notify listeners", e))?;
        Ok(sequence)
    }

    /// The full service name, e.g. `rigslam/pose`.
    pub fn service_name(&self) -> &str {
        &self.service
    }

    /// Samples sent so far.
    pub fn sent(&self) -> u64 {
        self.next_sequence
    }
}

/// The daemon's publishing end: `<prefix>/pose`, `<prefix>/pose_fast` and
/// `<prefix>/status`, each paired with an event service of the same name.
///
/// `Send`, so it can move to the thread that produces poses.
pub struct PosePublisher {
    pose: StreamPublisher<PoseMessage>,
    pose_fast: StreamPublisher<PoseMessage>,
    status: StreamPublisher<StatusMessage>,
    // Dropped last: the ports above belong to it.
    _node: Node<Ipc>,
}

impl PosePublisher {
    /// Opens (or creates) the three services and their ports.
    pub fn open(config: &IpcConfig) -> Result<Self, IpcError> {
        let node = create_node(config)?;
        let prefix = &config.service_prefix;
        Ok(Self {
            pose: StreamPublisher::open(&node, Stream::Pose.service_name(prefix))?,
            pose_fast: StreamPublisher::open(&node, Stream::PoseFast.service_name(prefix))?,
            status: StreamPublisher::open(&node, Stream::Status.service_name(prefix))?,
            _node: node,
        })
    }

    /// Publishes a frame-rate pose on `<prefix>/pose`; returns its sequence number.
    pub fn publish(&mut self, message: &PoseMessage) -> Result<u64, IpcError> {
        self.pose.publish(message)
    }

    /// Publishes an IMU-rate pose on `<prefix>/pose_fast`.
    pub fn publish_fast(&mut self, message: &PoseMessage) -> Result<u64, IpcError> {
        self.pose_fast.publish(message)
    }

    /// Publishes the daemon's status on `<prefix>/status`.
    pub fn publish_status(&mut self, message: &StatusMessage) -> Result<u64, IpcError> {
        self.status.publish(message)
    }

    /// The three stream publishers apart, for a caller that feeds
    /// `pose_fast` from the IMU thread and `pose` from the frame thread.
    /// Returns (pose, pose_fast, status, node).
    pub fn split(
        self,
    ) -> (
        StreamPublisher<PoseMessage>,
        StreamPublisher<PoseMessage>,
        StreamPublisher<StatusMessage>,
        PublisherNode,
    ) {
        (
            self.pose,
            self.pose_fast,
            self.status,
            PublisherNode { _node: self._node },
        )
    }
}

/// The iceoryx2 node behind split publishers; keep it alive as long as
/// they are used.
pub struct PublisherNode {
    _node: Node<Ipc>,
}
