//! Publishing: poses and status to other processes over iceoryx2 shared
//! memory (src/publish/README.md).
//!
//! Three services, each a publish-subscribe service paired with an event
//! service of the same name, notified after every sample so that a
//! subscriber sleeps in the kernel until there is something to read:
//!
//! - `rigslam/pose`: a [`PoseMessage`] per processed frame,
//! - `rigslam/pose_fast`: a [`PoseMessage`] per IMU sample, propagated,
//! - `rigslam/status`: a [`StatusMessage`] with rates, drops, latencies,
//!   sensor health and queue fill.
//!
//! The messages are `#[repr(C)]` and declared again for C and C++ readers
//! in `include/rigslam/pose_message.h`; README.md beside this file shows a
//! consumer in both languages.

mod access;
mod group;
mod ipc_config;
mod message;
mod publisher;
mod service;
mod subscriber;

pub use access::{publishing_group, ROOT_MODE};
pub use group::Group;
pub use message::*;
pub use publisher::{PosePublisher, PublisherNode, StreamPublisher};
pub use service::{
    cleanup_dead_nodes, Ipc, IpcConfig, IpcError, Message, Stream, DEFAULT_SERVICE_PREFIX,
    MAX_SUBSCRIBER_BUFFER,
};
pub use subscriber::{
    PoseSubscriber, SampleCheck, StatusSubscriber, Subscription, DEFAULT_SUBSCRIBER_BUFFER,
};
