//! What publisher and subscriber must agree on: the iceoryx2 instance
//! (root path), the service names, the service settings, the errors.
//!
//! Both sides build their services with the same functions here, so the
//! settings of whichever side creates a service first always satisfy the
//! other (iceoryx2 refuses to open a service whose settings are smaller
//! than requested).

use std::fmt::Debug;
use std::path::{Path, PathBuf};

use iceoryx2::config::Config;
use iceoryx2::node::{Node, NodeBuilder, NodeState};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::{
    ipc_threadsafe, CallbackProgression, MessagingPattern, SemanticString, ServiceName,
    SignalHandlingMode, ZeroCopySend,
};
use iceoryx2::service::builder::event::EventOpenError;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;
use iceoryx2::service::service_hash::ServiceHash;

use super::access::{effective_root, explain_refusal};
use super::group::effective_uid;
pub use super::ipc_config::{IpcConfig, IpcError, DEFAULT_SERVICE_PREFIX};
use super::message::{PoseMessage, StatusMessage, POSE_LAYOUT_VERSION, STATUS_LAYOUT_VERSION};

/// The iceoryx2 service variant used throughout: its ports are `Send` and
/// `Sync`, so a publisher can live on the daemon's processing thread and a
/// subscriber on any thread (the plain `ipc::Service` ports are not `Send`).
pub type Ipc = ipc_threadsafe::Service;

/// Most samples a subscriber may queue (the service's bound; each
/// subscriber picks its own buffer up to this). Sized for a consumer of
/// `pose_fast` at 10 kHz that wakes every 10 ms.
pub const MAX_SUBSCRIBER_BUFFER: usize = 128;

/// The three published streams.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stream {
    /// `<prefix>/pose`: one [`PoseMessage`] per processed frame.
    Pose,
    /// `<prefix>/pose_fast`: [`PoseMessage`]s propagated with the IMU at its rate.
    PoseFast,
    /// `<prefix>/status`: [`StatusMessage`] about once a second.
    Status,
}

impl Stream {
    /// The last part of the service name.
    pub fn suffix(self) -> &'static str {
        match self {
            Stream::Pose => "pose",
            Stream::PoseFast => "pose_fast",
            Stream::Status => "status",
        }
    }

    /// The stream a service name's last part names (`pose`, `pose_fast`,
    /// `status`).
    pub fn from_suffix(suffix: &str) -> Option<Stream> {
        [Stream::Pose, Stream::PoseFast, Stream::Status]
            .into_iter()
            .find(|s| s.suffix() == suffix)
    }

    /// `<prefix>/<suffix>`. The paired event service has the same name
    /// (iceoryx2 tells services apart by name and messaging pattern).
    pub fn service_name(self, prefix: &str) -> String {
        format!("{prefix}/{}", self.suffix())
    }
}

/// A message type that travels on a stream. Sealed: the layouts are a
/// contract (see `include/rigslam/pose_message.h`), not an extension point.
pub trait Message: Debug + Copy + ZeroCopySend + Send + Sync + 'static + sealed::Sealed {
    /// The layout version this build writes and reads.
    const LAYOUT_VERSION: u32;
    /// The layout version of this sample.
    fn layout_version(&self) -> u32;
    /// The publisher's sequence number.
    fn sequence(&self) -> u64;
    /// Host `CLOCK_MONOTONIC` when published, ns.
    fn published_t_ns(&self) -> i64;
    /// Time the content refers to, ns.
    fn t_ns(&self) -> i64;
    /// Sets what the publisher owns: sequence and send time.
    fn stamp(&mut self, sequence: u64, published_t_ns: i64);
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for super::PoseMessage {}
    impl Sealed for super::StatusMessage {}
}

macro_rules! impl_message {
    ($ty:ty, $version:expr) => {
        impl Message for $ty {
            const LAYOUT_VERSION: u32 = $version;
            fn layout_version(&self) -> u32 {
                self.layout_version
            }
            fn sequence(&self) -> u64 {
                self.sequence
            }
            fn published_t_ns(&self) -> i64 {
                self.published_t_ns
            }
            fn t_ns(&self) -> i64 {
                self.t_ns
            }
            fn stamp(&mut self, sequence: u64, published_t_ns: i64) {
                self.sequence = sequence;
                self.published_t_ns = published_t_ns;
            }
        }
    };
}
impl_message!(PoseMessage, POSE_LAYOUT_VERSION);
impl_message!(StatusMessage, STATUS_LAYOUT_VERSION);

/// A node on the configured iceoryx2 instance. Signal handling is off:
/// the daemon owns SIGINT/SIGTERM (iceoryx2 would otherwise install its
/// own handlers).
pub(crate) fn create_node(config: &IpcConfig) -> Result<Node<Ipc>, IpcError> {
    let iox_config = iceoryx2_config(config)?;
    NodeBuilder::new()
        .config(&iox_config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(|e| {
            let reason = format!("{e:?}");
            explain_refusal(config, &reason).unwrap_or(IpcError::Node { reason })
        })
}

/// An iceoryx2 error of `action` on `service`, said as a permission
/// problem when it is one.
fn refused(config: &IpcConfig, service: &str, action: &'static str, e: impl Debug) -> IpcError {
    let reason = format!("{e:?}");
    explain_refusal(config, &reason).unwrap_or(IpcError::Service {
        service: service.to_string(),
        action,
        reason,
    })
}

/// Removes what processes that died without cleaning up (a daemon killed
/// with SIGKILL, a crashed subscriber) left on the configured instance:
/// their node entries, their ports on the services, their shared memory.
/// Returns (nodes cleaned, nodes that could not be).
///
/// Done on the node list, before this process creates a node of its own
/// (which would clean up silently), so the caller can say what it found.
pub fn cleanup_dead_nodes(config: &IpcConfig) -> Result<(u64, u64), IpcError> {
    let iox_config = iceoryx2_config(config)?;
    let mut dead = Vec::new();
    Node::<Ipc>::list(&iox_config, |state| {
        match state {
            NodeState::Dead(view) => dead.push(view),
            other => tracing::debug!("iceoryx2 node: {other:?}"),
        }
        CallbackProgression::Continue
    })
    .map_err(|e| IpcError::Node {
        reason: format!("listing the nodes: {e:?}"),
    })?;
    let (mut cleaned, mut failed) = (0, 0);
    for view in dead {
        match view.try_remove_stale_resources() {
            Ok(()) => cleaned += 1,
            Err(e) => {
                tracing::warn!("iceoryx2: cannot remove a dead node's resources: {e:?}");
                failed += 1;
            }
        }
    }
    Ok((cleaned, failed))
}

/// iceoryx2's defaults, not a system-wide iceoryx2.toml: the daemon's own
/// config decides the root path, and both sides must agree on it.
fn iceoryx2_config(config: &IpcConfig) -> Result<Config, IpcError> {
    let mut iox_config = Config::default();
    if let Some(root) = &config.root_path {
        iox_config.global.set_root_path(&root_path(root)?);
    }
    Ok(iox_config)
}

/// iceoryx2 wants an absolute directory path ending in a separator.
fn root_path(path: &Path) -> Result<iceoryx2::prelude::Path, IpcError> {
    let bad = |reason: String| IpcError::RootPath {
        path: path.to_path_buf(),
        reason,
    };
    if !path.is_absolute() {
        return Err(bad("must be absolute".into()));
    }
    let mut text = path
        .to_str()
        .ok_or_else(|| bad("is not UTF-8".into()))?
        .to_string();
    if !text.ends_with('/') {
        text.push('/');
    }
    iceoryx2::prelude::Path::new(text.as_bytes()).map_err(|e| bad(format!("{e:?}")))
}

pub(crate) fn service_name(name: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(name).map_err(|e| IpcError::ServiceName {
        name: name.to_string(),
        reason: format!("{e:?}"),
    })
}

/// iceoryx2 marks a service for destruction when its last user leaves,
/// and removes its files; a reader of the group is not allowed to remove
/// the daemon's, so after such a reader was the last, the service stays
/// marked and cannot be opened. The creator (the daemon's user) then
/// removes the service file, its own, and creates the service anew.
fn create_over_stale<R, E: Debug>(
    config: &IpcConfig,
    service: &ServiceName,
    pattern: MessagingPattern,
    mut attempt: impl FnMut() -> Result<R, E>,
) -> Result<R, E> {
    match attempt() {
        Err(e) if format!("{e:?}").contains("IsMarkedForDestruction") => {
            let hash = ServiceHash::new::<<Ipc as iceoryx2::service::Service>::ServiceNameHasher>(
                service, pattern,
            );
            let file = service_file(config, hash.as_str());
            let mine = std::fs::symlink_metadata(&file)
                .is_ok_and(|m| std::os::unix::fs::MetadataExt::uid(&m) == effective_uid());
            if !mine || std::fs::remove_file(&file).is_err() {
                return Err(e);
            }
            tracing::info!(
                "{}: removed {} left marked for destruction (its last user could not remove it)",
                service.as_str(),
                file.display()
            );
            attempt()
        }
        other => other,
    }
}

/// The static config file of the service with iceoryx2 hash `hash`.
pub(crate) fn service_file(config: &IpcConfig, hash: &str) -> PathBuf {
    effective_root(config)
        .join("services")
        .join(format!("iox2_{hash}.service"))
}

/// A publisher and the notifier that announces its samples.
pub(crate) type PublisherPorts<T> = (Publisher<Ipc, T, ()>, Notifier<Ipc>);
/// A subscriber and the listener it blocks on.
pub(crate) type SubscriberPorts<T> = (Subscriber<Ipc, T, ()>, Listener<Ipc>);

/// The publish-subscribe service and the paired event service of one
/// stream, as both sides open them.
pub(crate) struct Services<T: Message> {
    pub name: String,
    pub pubsub: iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, T, ()>,
    pub event: iceoryx2::service::port_factory::event::PortFactory<Ipc>,
}

impl<T: Message> Services<T> {
    /// Opens the stream's services; creates them too unless `open_only`
    /// (a subscriber of a daemon that runs as another user never creates
    /// them: that would be taking the name before the daemon).
    ///
    /// One publisher and one notifier at most: the daemon holds them, so
    /// no other process gets a publisher through iceoryx2 while it runs.
    pub fn open(
        config: &IpcConfig,
        node: &Node<Ipc>,
        name: &str,
        open_only: bool,
    ) -> Result<Self, IpcError> {
        let service = service_name(name)?;
        let pubsub_builder = || {
            node.service_builder(&service)
                .publish_subscribe::<T>()
                // A slow or dead subscriber loses its oldest samples; the
                // publisher never blocks on it.
                .enable_safe_overflow(true)
                .subscriber_max_buffer_size(MAX_SUBSCRIBER_BUFFER)
                .history_size(0)
                .max_publishers(1)
        };
        let pubsub = if open_only {
            pubsub_builder().open().map_err(|e| match e {
                PublishSubscribeOpenError::DoesNotExist => IpcError::NotPublished {
                    service: name.to_string(),
                },
                e => refused(config, name, "open publish-subscribe service", e),
            })?
        } else {
            create_over_stale(config, &service, MessagingPattern::PublishSubscribe, || {
                pubsub_builder().open_or_create()
            })
            .map_err(|e| refused(config, name, "open publish-subscribe service", e))?
        };
        let event_builder = || node.service_builder(&service).event().max_notifiers(1);
        let event = if open_only {
            event_builder().open().map_err(|e| match e {
                EventOpenError::DoesNotExist => IpcError::NotPublished {
                    service: name.to_string(),
                },
                e => refused(config, name, "open event service", e),
            })?
        } else {
            create_over_stale(config, &service, MessagingPattern::Event, || {
                event_builder().open_or_create()
            })
            .map_err(|e| refused(config, name, "open event service", e))?
        };
        Ok(Self {
            name: name.to_string(),
            pubsub,
            event,
        })
    }

    /// iceoryx2's hash of the service: its files are named after it.
    pub fn file_stem(&self) -> String {
        use iceoryx2::service::port_factory::PortFactory;
        self.pubsub.service_hash().as_str().to_string()
    }

    pub fn publisher(&self) -> Result<PublisherPorts<T>, IpcError> {
        let publisher = self
            .pubsub
            .publisher_builder()
            .create()
            .map_err(|e| IpcError::service(&self.name, "create publisher", e))?;
        let notifier = self
            .event
            .notifier_builder()
            .create()
            .map_err(|e| IpcError::service(&self.name, "create notifier", e))?;
        Ok((publisher, notifier))
    }

    pub fn subscriber(&self, buffer: usize) -> Result<SubscriberPorts<T>, IpcError> {
        let subscriber = self
            .pubsub
            .subscriber_builder()
            .buffer_size(buffer.clamp(1, MAX_SUBSCRIBER_BUFFER))
            .create()
            .map_err(|e| IpcError::service(&self.name, "create subscriber", e))?;
        let listener = self
            .event
            .listener_builder()
            .create()
            .map_err(|e| IpcError::service(&self.name, "create listener", e))?;
        Ok((subscriber, listener))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn service_names_follow_the_contract() {
        assert_eq!(Stream::Pose.service_name("rigslam"), "rigslam/pose");
        assert_eq!(
            Stream::PoseFast.service_name("rigslam"),
            "rigslam/pose_fast"
        );
        assert_eq!(Stream::Status.service_name("rigslam"), "rigslam/status");
        assert_eq!(Stream::from_suffix("pose_fast"), Some(Stream::PoseFast));
        assert_eq!(Stream::from_suffix("posefast"), None);
    }

    #[test]
    fn a_relative_root_path_is_refused() {
        let err = root_path(Path::new("run/rigslam")).expect_err("relative path");
        assert!(err.to_string().contains("absolute"), "{err}");
        let ok = root_path(Path::new("/run/rigslam/iceoryx2")).expect("absolute path");
        assert_eq!(ok.as_bytes(), b"/run/rigslam/iceoryx2/");
    }
}
