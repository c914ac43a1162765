//! Where the published services live and what they are called
//! ([`IpcConfig`]), and why opening or using one can fail ([`IpcError`]):
//! what the service set-up ([`super::service`]) and the access rules
//! ([`super::access`]) share.

use std::fmt::Debug;
use std::path::PathBuf;

/// The default service prefix: services are `rigslam/pose`, ...
pub const DEFAULT_SERVICE_PREFIX: &str = "rigslam";

/// Where the services live and what they are called. Publisher and
/// subscribers must use the same values to meet. Deserialises from a
/// config table (`service_prefix`, `root_path`, both optional).
#[derive(Debug, Clone, PartialEq, Eq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IpcConfig {
    /// First part of every service name: `<prefix>/pose`, `<prefix>/pose_fast`,
    /// `<prefix>/status`.
    pub service_prefix: String,
    /// iceoryx2's root directory for its service, node and socket files.
    /// `None` keeps iceoryx2's default (`/tmp/iceoryx2/`), which a systemd
    /// unit with `PrivateTmp=yes` hides from other processes: such a unit
    /// sets e.g. `/run/rigslam/iceoryx2/` (`RuntimeDirectory=rigslam`).
    /// Shared memory itself lives in `/dev/shm` either way.
    pub root_path: Option<PathBuf>,
    /// The group whose members may subscribe (`[publish] group`): the
    /// daemon gives it the root directory and its files. `None`: the
    /// daemon's own effective (primary) group, `rigslam` under the shipped
    /// unit. Only the daemon reads it; subscribers follow the root.
    pub group: Option<String>,
}

impl Default for IpcConfig {
    fn default() -> Self {
        Self {
            service_prefix: DEFAULT_SERVICE_PREFIX.to_string(),
            root_path: None,
            group: None,
        }
    }
}

/// Why a service could not be opened or used. Each names the service (or
/// root path) and what was being done.
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    #[error("iceoryx2 root path {path:?} is not usable: {reason}")]
    /// The iceoryx2 root directory (or `/dev/shm`) cannot be created, read, listed or given the
    /// publishing group and mode, or its file system does not keep permission bits.
    RootPath {
        /// The directory.
        path: PathBuf,
        /// What failed.
        reason: String,
    },
    #[error("service name {name:?} is not valid: {reason}")]
    /// The service name built from the configured prefix is not one iceoryx2 accepts.
    ServiceName {
        /// The rejected name.
        name: String,
        /// iceoryx2's objection.
        reason: String,
    },
    #[error("cannot create an iceoryx2 node: {reason}")]
    /// iceoryx2 refused to create this process's node.
    Node {
        /// iceoryx2's error.
        reason: String,
    },
    #[error("permission denied: {message}")]
    /// A file of the instance could not be given the publishing group or
    /// mode, or iceoryx2 was refused access to one.
    Permission {
        /// Names the file or the refused operation, and how to grant access.
        message: String,
    },
    #[error("publish.group {name:?}: {reason}")]
    /// `publish.group` names no group, or the daemon's user is not in it.
    Group {
        /// The configured group.
        name: String,
        /// Which of the two, and the command that fixes it.
        reason: String,
    },
    #[error(
        "{path:?} belongs to user {owner}, not to {user}, who would publish: only its owner \
         publishes there. If {owner} is not the daemon's user, another process took the \
         service name before the daemon, or a run as {owner} left it behind: stop that \
         process, remove it (`sudo rm -rf {path:?}`) and start the daemon again"
    )]
    /// A file or directory of the instance belongs to another user, so this process would not be
    /// its only publisher.
    Foreign {
        /// The file or directory.
        path: PathBuf,
        /// Its owner's user name.
        owner: String,
        /// The user this process runs as.
        user: String,
    },
    #[error(
        "service {service} does not exist: rigslamd is not running, or runs with another \
         root_path or service_prefix (it, not a subscriber, creates the services)"
    )]
    /// A subscriber opened a service that does not exist: the daemon is not running, or runs with
    /// another root path or service prefix (the daemon, not a subscriber, creates the services).
    NotPublished {
        /// The full service name.
        service: String,
    },
    #[error("service {service}: {action}: {reason}")]
    /// An iceoryx2 operation on a service failed.
    Service {
        /// The full service name.
        service: String,
        /// What was being done (e.g. opening or creating a publisher).
        action: &'static str,
        /// iceoryx2's error, formatted.
        reason: String,
    },
    #[error("service {service}: sample has layout version {found}, this build reads {expected}")]
    /// A sample's layout version differs from the one this build reads: the publisher and the
    /// subscriber are different builds.
    LayoutVersion {
        /// The full service name.
        service: String,
        /// Layout version found in the sample.
        found: u32,
        /// Layout version this build reads.
        expected: u32,
    },
}

impl IpcError {
    pub(crate) fn service(service: &str, action: &'static str, e: impl Debug) -> Self {
        IpcError::Service {
            service: service.to_string(),
            action,
            reason: format!("{e:?}"),
        }
    }
}
