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
    RootPath { path: PathBuf, reason: String },
    #[error("service name {name:?} is not valid: {reason}")]
    ServiceName { name: String, reason: String },
    #[error("cannot create an iceoryx2 node: {reason}")]
    Node { reason: String },
    #[error("permission denied: {message}")]
    Permission { message: String },
    #[error("publish.group {name:?}: {reason}")]
    Group { name: String, reason: String },
    #[error(
        "{path:?} belongs to user {owner}, not to {user}, who would publish: only its owner \
         publishes there. If {owner} is not the daemon's user, another process took the \
         service name before the daemon, or a run as {owner} left it behind: stop that \
         process, remove it (`sudo rm -rf {path:?}`) and start the daemon again"
    )]
    Foreign {
        path: PathBuf,
        owner: String,
        user: String,
    },
    #[error(
        "service {service} does not exist: rigslamd is not running, or runs with another \
         root_path or service_prefix (it, not a subscriber, creates the services)"
    )]
    NotPublished { service: String },
    #[error("service {service}: {action}: {reason}")]
    Service {
        service: String,
        action: &'static str,
        reason: String,
    },
    #[error("service {service}: sample has layout version {found}, this build reads {expected}")]
    LayoutVersion {
        service: String,
        found: u32,
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
