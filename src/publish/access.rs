//! Who may open the published streams: the daemon's user, and the users
//! of the publishing group (`publish.group`). How it is enforced and what
//! it cannot prevent: README.md beside this file, "Who may read".
//!
//! iceoryx2 is built with its `dev_permissions` feature, so whatever it
//! creates is readable and writable by every user (a subscriber of
//! another user can always reach the daemon's files and the daemon the
//! subscriber's). This module narrows that:
//!
//! - the root directory is the daemon's, group-owned by the publishing
//!   group, mode 0770: users outside the group cannot reach the service
//!   and node files nor the event sockets in it;
//! - every process narrows the files it created itself (in the root and
//!   in `/dev/shm`) to the group of the root's `services` directory and
//!   drops the bits for others; payload segments (`*.data`, written by the
//!   daemon alone) become 0640, `services` 0750 (no one else creates a
//!   service there);
//! - the daemon refuses a root, a `services` directory or a service file
//!   that belongs to another user (squatting, or stale files of an
//!   earlier run as another user).

use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};

use super::group::{
    effective_gid, effective_uid, group_by_gid, group_by_name, process_has_group,
    user_listed_in_group, user_name, Group,
};
use super::ipc_config::{IpcConfig, IpcError};

/// Where POSIX shared memory lives on Linux (`shm_open`).
pub const SHM_DIR: &str = "/dev/shm";
/// iceoryx2's root directory when none is configured.
const DEFAULT_ROOT: &str = "/tmp/iceoryx2";
/// The mode of the root directory: the daemon and the group, nobody else.
pub const ROOT_MODE: u32 = 0o770;
/// iceoryx2's prefix of every file name (its default config).
const FILE_PREFIX: &str = "iox2_";
/// iceoryx2's node counter, meant for every user of the machine: left alone.
const GLOBAL_SUFFIX: &str = ".global_mgmt";
/// Payload segments: only their creator (the daemon) writes them.
const DATA_SUFFIX: &str = ".data";
const SERVICES_DIR: &str = "services";
const NODES_DIR: &str = "nodes";

/// What a process does on the instance, which decides what it narrows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Role {
    Publisher,
    Subscriber,
}

/// The access settings of one process on one iceoryx2 instance.
#[derive(Debug, Clone)]
pub(crate) struct Access {
    role: Role,
    /// The root directory: the configured one, or iceoryx2's default.
    root: PathBuf,
    /// Whether the root is configured, so the daemon's own (iceoryx2's
    /// default is shared with every other iceoryx2 program).
    dedicated: bool,
    /// The group the files are given; `None`: keep the creator's group.
    group: Option<Group>,
}

/// iceoryx2's root directory for `config`.
pub(crate) fn effective_root(config: &IpcConfig) -> PathBuf {
    config
        .root_path
        .clone()
        .unwrap_or_else(|| PathBuf::from(DEFAULT_ROOT))
}

fn permission(message: String) -> IpcError {
    IpcError::Permission { message }
}

/// The group the daemon publishes to: `publish.group`, else its own
/// effective (primary) group. The daemon must be in it, or it cannot give
/// its files that group.
pub fn publishing_group(config: &IpcConfig) -> Result<Group, IpcError> {
    let Some(name) = &config.group else {
        return Ok(group_by_gid(effective_gid()));
    };
    let group = group_by_name(name)
        .map_err(|reason| IpcError::Group {
            name: name.clone(),
            reason,
        })?
        .ok_or_else(|| IpcError::Group {
            name: name.clone(),
            reason: format!(
                "no such group: create it (`groupadd {name}`) and add the readers \
                 (`usermod -aG {name} USER`), or set publish.group to an existing group"
            ),
        })?;
    if effective_uid() != 0 && !process_has_group(group.gid) {
        let me = user_name(effective_uid());
        return Err(IpcError::Group {
            name: name.clone(),
            reason: format!(
                "the daemon's user {me} is not in this group, so it cannot give its files \
                 to it: `usermod -aG {name} {me}` and restart the daemon"
            ),
        });
    }
    Ok(group)
}

impl Access {
    /// The daemon's side: makes the root directory the daemon's, the
    /// group's and nobody else's, and refuses what another user put there.
    pub(crate) fn for_publisher(config: &IpcConfig) -> Result<Self, IpcError> {
        let group = publishing_group(config)?;
        if let Some(root) = &config.root_path {
            prepare_root(root, &group)?;
            refuse_foreign_services(root)?;
        }
        Ok(Self {
            role: Role::Publisher,
            root: effective_root(config),
            dedicated: config.root_path.is_some(),
            group: Some(group),
        })
    }

    /// A subscriber's side: says plainly when the root is closed to this
    /// user, and finds the group its own files must have for the daemon
    /// to reach them (the group of the daemon's `services` directory).
    pub(crate) fn for_subscriber(config: &IpcConfig) -> Result<Self, IpcError> {
        let root = effective_root(config);
        check_reachable(&root)?;
        let group = std::fs::metadata(root.join(SERVICES_DIR))
            .ok()
            .map(|meta| group_by_gid(meta.gid()));
        Ok(Self {
            role: Role::Subscriber,
            root,
            dedicated: config.root_path.is_some(),
            group,
        })
    }

    /// Whether the services belong to another user (a daemon running as
    /// someone else): then this process must never create them.
    pub(crate) fn services_of_another_user(&self) -> bool {
        std::fs::metadata(self.root.join(SERVICES_DIR)).is_ok_and(|m| m.uid() != effective_uid())
    }

    /// When this user was taken out of the daemon's group after it
    /// subscribed: what to tell it (it keeps what it opened; the kernel
    /// checks access at open, and group membership is read at login).
    pub(crate) fn membership_lost(&self) -> Option<String> {
        let group = self.group.as_ref()?;
        let uid = effective_uid();
        let owner = std::fs::metadata(self.root.join(SERVICES_DIR)).ok()?.uid();
        if !self.dedicated || owner == uid || uid == 0 || user_listed_in_group(uid, group.gid) {
            return None;
        }
        Some(format!(
            "user {} is no longer in group {}: this subscription goes on until it is closed, \
             a new one will be refused (`sudo usermod -aG {} {}` to stay a reader)",
            user_name(uid),
            group.name,
            group.name,
            user_name(uid)
        ))
    }

    /// The group files are narrowed to, if any.
    pub(crate) fn group(&self) -> Option<&Group> {
        self.group.as_ref()
    }

    /// Narrows the files this process owns on the instance (see the
    /// module comment); returns how many were changed. Files that vanish
    /// meanwhile are skipped.
    pub(crate) fn narrow_own_files(&self) -> Result<usize, IpcError> {
        let mut changed = self.narrow_tree(&self.root, 0)?;
        let shm = std::fs::read_dir(SHM_DIR).map_err(|e| IpcError::RootPath {
            path: SHM_DIR.into(),
            reason: format!("cannot list it: {e}"),
        })?;
        for entry in shm.flatten() {
            let name = entry.file_name();
            let name = name.as_bytes();
            if name.starts_with(FILE_PREFIX.as_bytes()) && !name.ends_with(GLOBAL_SUFFIX.as_bytes())
            {
                // Whoever owns a payload segment created it to publish:
                // the group reads, never writes.
                let read_only = name.ends_with(DATA_SUFFIX.as_bytes());
                changed += self.narrow(&entry.path(), read_only, None)?;
            }
        }
        Ok(changed)
    }

    fn narrow_tree(&self, dir: &Path, depth: usize) -> Result<usize, IpcError> {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return Ok(0);
        };
        let mut changed = 0;
        for entry in entries.flatten() {
            let path = entry.path();
            let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
            let dir_mode = if depth == 0
                && self.dedicated
                && self.role == Role::Publisher
                && entry.file_name() == SERVICES_DIR
            {
                Some(0o750)
            } else {
                None
            };
            changed += self.narrow(&path, false, dir_mode)?;
            if is_dir && depth < 3 {
                changed += self.narrow_tree(&path, depth + 1)?;
            }
        }
        Ok(changed)
    }

    /// One file: the group, then the mode without the bits for others
    /// (and without group write when `read_only`), or `mode` when given.
    /// Only files of this process's user.
    fn narrow(&self, path: &Path, read_only: bool, mode: Option<u32>) -> Result<usize, IpcError> {
        let Ok(meta) = std::fs::symlink_metadata(path) else {
            return Ok(0);
        };
        if meta.uid() != effective_uid() || meta.file_type().is_symlink() {
            return Ok(0);
        }
        let mut changed = false;
        if let Some(group) = &self.group {
            if meta.gid() != group.gid {
                chgrp(path, group)?;
                changed = true;
            }
        }
        let old = meta.mode() & 0o7777;
        // iceoryx2 marks a file it is still setting up by its mode (0200,
        // 0600): taking bits away keeps such a mode, adding none.
        let new = match mode {
            Some(m) => m,
            None if read_only => old & !0o027,
            None => old & !0o007,
        };
        if new != old {
            match std::fs::set_permissions(path, std::fs::Permissions::from_mode(new)) {
                Ok(()) => changed = true,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(e) => {
                    return Err(permission(format!(
                        "cannot set mode {new:o} on {}: {e}",
                        path.display()
                    )))
                }
            }
        }
        Ok(usize::from(changed))
    }
}

fn chgrp(path: &Path, group: &Group) -> Result<(), IpcError> {
    let c_path = std::ffi::CString::new(path.as_os_str().as_bytes())
        .map_err(|_| permission(format!("{}: path contains a NUL byte", path.display())))?;
    // SAFETY: a valid C string; uid -1 keeps the owner.
    let rc = unsafe { libc::lchown(c_path.as_ptr(), u32::MAX, group.gid) };
    if rc == 0 {
        return Ok(());
    }
    let e = std::io::Error::last_os_error();
    if e.kind() == std::io::ErrorKind::NotFound {
        return Ok(());
    }
    Err(permission(format!(
        "cannot give {} to group {}: {e} (the process must be in group {} and allowed to \
         call chown; under systemd, run it with Group={} so nothing needs changing)",
        path.display(),
        group.name,
        group.name,
        group.name
    )))
}

/// Creates the root directory if needed, refuses one of another user,
/// gives it to the group with mode 0770 and checks the file system kept
/// both (some do not store permission bits).
fn prepare_root(root: &Path, group: &Group) -> Result<(), IpcError> {
    let bad = |reason: String| IpcError::RootPath {
        path: root.to_path_buf(),
        reason,
    };
    std::fs::create_dir_all(root).map_err(|e| bad(format!("cannot create it: {e}")))?;
    let meta = std::fs::metadata(root).map_err(|e| bad(format!("cannot read it: {e}")))?;
    if !meta.is_dir() {
        return Err(bad("is not a directory".into()));
    }
    refuse_foreign(root, &meta)?;
    if meta.gid() != group.gid {
        chgrp(root, group)?;
    }
    std::fs::set_permissions(root, std::fs::Permissions::from_mode(ROOT_MODE))
        .map_err(|e| bad(format!("cannot set mode {ROOT_MODE:o}: {e}")))?;
    let meta = std::fs::metadata(root).map_err(|e| bad(format!("cannot read it: {e}")))?;
    check_kept(root, meta.mode() & 0o7777, meta.gid(), group)
}

/// Whether the file system stored the mode and group just set.
pub(crate) fn check_kept(root: &Path, mode: u32, gid: u32, group: &Group) -> Result<(), IpcError> {
    if mode & 0o777 != ROOT_MODE || gid != group.gid {
        return Err(IpcError::RootPath {
            path: root.to_path_buf(),
            reason: format!(
                "its file system does not keep permission bits (mode {:o}, group {} after \
                 setting mode {ROOT_MODE:o}, group {}), so access by group cannot be enforced: \
                 put publish.root_path on tmpfs or ext4, e.g. /run/rigslam/iceoryx2",
                mode & 0o7777,
                group_by_gid(gid).name,
                group.name
            ),
        });
    }
    Ok(())
}

fn refuse_foreign(path: &Path, meta: &std::fs::Metadata) -> Result<(), IpcError> {
    let me = effective_uid();
    if meta.uid() != me {
        return Err(IpcError::Foreign {
            path: path.to_path_buf(),
            owner: user_name(meta.uid()),
            user: user_name(me),
        });
    }
    Ok(())
}

/// The `services` and `nodes` directories and every service file must
/// be the daemon's: another user's means someone created the services
/// before the daemon (to publish in its place) or left them behind.
fn refuse_foreign_services(root: &Path) -> Result<(), IpcError> {
    for dir in [SERVICES_DIR, NODES_DIR] {
        let path = root.join(dir);
        if let Ok(meta) = std::fs::symlink_metadata(&path) {
            refuse_foreign(&path, &meta)?;
        }
    }
    if let Ok(entries) = std::fs::read_dir(root.join(SERVICES_DIR)) {
        for entry in entries.flatten() {
            if let Ok(meta) = entry.metadata() {
                refuse_foreign(&entry.path(), &meta)?;
            }
        }
    }
    Ok(())
}

/// A file the daemon created must be its own; see [`refuse_foreign_services`].
pub(crate) fn refuse_foreign_file(path: &Path) -> Result<(), IpcError> {
    match std::fs::symlink_metadata(path) {
        Ok(meta) => refuse_foreign(path, &meta),
        Err(_) => Ok(()),
    }
}

/// Whether this process (its effective ids) may access `path` as `wanted`.
fn accessible(path: &Path, wanted: libc::c_int) -> bool {
    let Ok(c_path) = std::ffi::CString::new(path.as_os_str().as_bytes()) else {
        return true;
    };
    // SAFETY: a valid C string; checks with the effective ids.
    unsafe { libc::faccessat(libc::AT_FDCWD, c_path.as_ptr(), wanted, libc::AT_EACCESS) == 0 }
}

/// Says why a root directory is closed to this process, naming the
/// group of the first directory on its path that is closed (the root,
/// or the runtime directory above it) and how to join it.
fn check_reachable(root: &Path) -> Result<(), IpcError> {
    let mut closed = None;
    let mut parent: Option<&Path> = None;
    for dir in root.ancestors().collect::<Vec<_>>().into_iter().rev() {
        let Ok(meta) = std::fs::metadata(dir) else {
            // Not there (yet): iceoryx2 creates it, which needs write
            // access to the last directory that is.
            return match parent {
                Some(p) if !accessible(p, libc::W_OK | libc::X_OK) => {
                    let m = std::fs::metadata(p).ok();
                    Err(permission(format!(
                        "cannot create {}: {} (user {}, group {}, mode {:o}) is not writable by \
                         {}; start the daemon first (it creates its root), or choose a \
                         root_path under a directory this user may write",
                        root.display(),
                        p.display(),
                        m.as_ref().map_or("?".into(), |m| user_name(m.uid())),
                        m.as_ref()
                            .map_or("?".into(), |m| group_by_gid(m.gid()).name),
                        m.as_ref().map_or(0, |m| m.mode() & 0o7777),
                        user_name(effective_uid())
                    )))
                }
                _ => Ok(()),
            };
        };
        parent = Some(dir);
        let wanted = if dir == root {
            libc::R_OK | libc::W_OK | libc::X_OK
        } else {
            libc::X_OK
        };
        if !accessible(dir, wanted) {
            closed = Some((dir.to_path_buf(), meta));
            break;
        }
    }
    let Some((dir, meta)) = closed else {
        return Ok(());
    };
    let uid = effective_uid();
    let me = user_name(uid);
    let group = group_by_gid(meta.gid());
    let owner = user_name(meta.uid());
    let join = if user_listed_in_group(uid, group.gid) {
        format!(
            "{me} is in group {g} but this process is not yet: log in again (or run it \
             with `sg {g} -c ...`)",
            g = group.name
        )
    } else {
        format!(
            "{me} is not in group {g}: an administrator adds it with \
             `sudo usermod -aG {g} {me}`, then log in again",
            g = group.name
        )
    };
    Err(permission(format!(
        "the poses in {} are for user {owner} and group {} only ({} has mode {:o}); {join}",
        root.display(),
        group.name,
        dir.display(),
        meta.mode() & 0o7777
    )))
}

/// Says that iceoryx2 refused because of permissions, when it did: the
/// error names the root and the group to join.
pub(crate) fn explain_refusal(config: &IpcConfig, reason: &str) -> Option<IpcError> {
    if !reason.contains("Permission") {
        return None;
    }
    let root = effective_root(config);
    if let Err(e) = check_reachable(&root) {
        return Some(e);
    }
    let group = std::fs::metadata(root.join(SERVICES_DIR))
        .map(|m| group_by_gid(m.gid()).name)
        .unwrap_or_else(|_| "the daemon's group".into());
    Some(permission(format!(
        "iceoryx2 was refused access to a file under {} or {SHM_DIR} ({reason}); the \
         poses are for the daemon's group {group}: `sudo usermod -aG {group} {}`, then \
         log in again",
        root.display(),
        user_name(effective_uid())
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_system_that_drops_the_mode_is_named() {
        let group = Group {
            name: "rigslam".into(),
            gid: 4242,
        };
        let root = Path::new("/mnt/usb/iceoryx2");
        check_kept(root, 0o770, 4242, &group).expect("kept");
        let err = check_kept(root, 0o755, 0, &group).expect_err("vfat-like");
        let text = err.to_string();
        assert!(text.contains("/mnt/usb/iceoryx2"), "{text}");
        assert!(text.contains("does not keep permission bits"), "{text}");
        assert!(text.contains("tmpfs"), "{text}");
    }

    #[test]
    fn a_group_that_does_not_exist_is_named_with_the_fix() {
        let config = IpcConfig {
            group: Some("rsl_no_such_group_xyz".into()),
            ..IpcConfig::default()
        };
        let text = publishing_group(&config)
            .expect_err("missing group")
            .to_string();
        assert!(text.contains("rsl_no_such_group_xyz"), "{text}");
        assert!(text.contains("groupadd"), "{text}");
    }

    #[test]
    fn the_default_group_is_the_process_group() {
        let group = publishing_group(&IpcConfig::default()).expect("own group");
        assert_eq!(group.gid, effective_gid());
    }
}
