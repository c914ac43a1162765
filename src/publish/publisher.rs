//! The daemon's side: one publisher per stream, each followed by a
//! notification on the paired event service so that subscribers blocked
//! on it wake at once.

use crate::sensors::yei::device::host_monotonic_ns;

use super::access::{refuse_foreign_file, Access};
use super::message::{PoseMessage, StatusMessage};
use super::service::{create_node, service_file, IpcConfig, IpcError, Message, Services, Stream};
use iceoryx2::node::Node;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;

use super::service::Ipc;

/// Sends one stream's samples and wakes its subscribers.
pub struct StreamPublisher<T: Message> {
    service: String,
    publisher: Publisher<Ipc, T, ()>,
    notifier: Notifier<Ipc>,
    next_sequence: u64,
    /// Whether the last attempt to connect new subscribers failed (said once).
    connect_failed: bool,
    // Keeps the service's static config alive as long as the ports.
    _services: Services<T>,
}

impl<T: Message> StreamPublisher<T> {
    fn open(config: &IpcConfig, node: &Node<Ipc>, name: String) -> Result<Self, IpcError> {
        let services = Services::<T>::open(config, node, &name, false)?;
        // The service file must be the daemon's own: another user's means
        // the name was taken before it. (Its dynamic config in /dev/shm is
        // created with it, exclusively, by the same process.)
        refuse_foreign_file(&service_file(config, &services.file_stem()))?;
        let (publisher, notifier) = services.publisher()?;
        Ok(Self {
            service: name,
            publisher,
            notifier,
            next_sequence: 0,
            connect_failed: false,
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
        // Connect new subscribers first: when one cannot be reached (its
        // files are closed to the daemon), iceoryx2 would fail this send
        // for everyone; this way the others still get the sample.
        match self.publisher.update_connections() {
            Ok(()) => self.connect_failed = false,
            Err(e) if !self.connect_failed => {
                self.connect_failed = true;
                tracing::warn!(
                    "{}: a new subscriber cannot be connected ({e:?}); publishing to the others \
                     (a subscriber outside the publishing group, or one whose files are closed \
                     to the daemon)",
                    self.service
                );
            }
            Err(_) => {}
        }
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
    access: Access,
    // Dropped last: the ports above belong to it.
    _node: Node<Ipc>,
}

impl PosePublisher {
    /// Opens (or creates) the three services and their ports, for the
    /// daemon's user and the publishing group only (`config.group`; see
    /// src/publish/README.md, "Who may read"). Refuses a root directory or
    /// service files of another user.
    pub fn open(config: &IpcConfig) -> Result<Self, IpcError> {
        let access = Access::for_publisher(config)?;
        let node = create_node(config)?;
        let prefix = &config.service_prefix;
        let publisher = Self {
            pose: StreamPublisher::open(config, &node, Stream::Pose.service_name(prefix))?,
            pose_fast: StreamPublisher::open(config, &node, Stream::PoseFast.service_name(prefix))?,
            status: StreamPublisher::open(config, &node, Stream::Status.service_name(prefix))?,
            access,
            _node: node,
        };
        publisher.narrow_new_files()?;
        Ok(publisher)
    }

    /// Gives the files the daemon created since the last call (segments
    /// of new subscribers' connections) to the publishing group and takes
    /// them from everyone else; returns how many changed. Call it now and
    /// then (the daemon does once per status period).
    pub fn narrow_new_files(&self) -> Result<usize, IpcError> {
        self.access.narrow_own_files()
    }

    /// The group that may subscribe.
    pub fn group_name(&self) -> Option<&str> {
        self.access.group().map(|g| g.name.as_str())
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
            PublisherNode {
                access: self.access,
                _node: self._node,
            },
        )
    }
}

/// The iceoryx2 node behind split publishers; keep it alive as long as
/// they are used.
pub struct PublisherNode {
    access: Access,
    _node: Node<Ipc>,
}

impl PublisherNode {
    /// [`PosePublisher::narrow_new_files`].
    pub fn narrow_new_files(&self) -> Result<usize, IpcError> {
        self.access.narrow_own_files()
    }
}
