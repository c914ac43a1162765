//! Users and groups as the C library knows them (`/etc/passwd`,
//! `/etc/group`, NSS): the publishing group's id, the names to put in
//! messages, and whether this process or a user is in a group.

use std::ffi::{CStr, CString};

/// A group by name and id.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Group {
    /// Group name, as in `/etc/group`.
    pub name: String,
    /// Numeric group id.
    pub gid: u32,
}

/// Tries a `get*_r` lookup with a growing buffer. `call` fills the
/// record and returns the C library's error number (0: done, found or
/// not). Returns that number and the buffer, which the record's strings
/// point into: read them while it lives.
fn with_buffer(
    mut call: impl FnMut(&mut Vec<libc::c_char>) -> libc::c_int,
) -> (libc::c_int, Vec<libc::c_char>) {
    let mut buffer = vec![0 as libc::c_char; 1024];
    loop {
        let rc = call(&mut buffer);
        if rc == libc::ERANGE && buffer.len() < (1 << 20) {
            buffer.resize(buffer.len() * 4, 0);
            continue;
        }
        return (rc, buffer);
    }
}

fn group_from(raw: &libc::group) -> Group {
    // SAFETY: getgr*_r filled `raw` with a NUL-terminated name in the buffer.
    let name = unsafe { CStr::from_ptr(raw.gr_name) };
    Group {
        name: name.to_string_lossy().into_owned(),
        gid: raw.gr_gid,
    }
}

/// The group called `name`; `Ok(None)` when there is none.
pub fn group_by_name(name: &str) -> Result<Option<Group>, String> {
    let c_name = CString::new(name).map_err(|_| "contains a NUL byte".to_string())?;
    // SAFETY: plain C struct, filled by getgrnam_r before it is read.
    let mut raw: libc::group = unsafe { std::mem::zeroed() };
    let mut found: *mut libc::group = std::ptr::null_mut();
    let (rc, _buffer) = with_buffer(|buffer| unsafe {
        libc::getgrnam_r(
            c_name.as_ptr(),
            &mut raw,
            buffer.as_mut_ptr(),
            buffer.len(),
            &mut found,
        )
    });
    match rc {
        0 if found.is_null() => Ok(None),
        0 => Ok(Some(group_from(&raw))),
        e => Err(format!(
            "looking it up failed: {}",
            std::io::Error::from_raw_os_error(e)
        )),
    }
}

/// The group with id `gid`, named by its number when it has no name.
pub fn group_by_gid(gid: u32) -> Group {
    // SAFETY: as in group_by_name.
    let mut raw: libc::group = unsafe { std::mem::zeroed() };
    let mut found: *mut libc::group = std::ptr::null_mut();
    let (rc, _buffer) = with_buffer(|buffer| unsafe {
        libc::getgrgid_r(gid, &mut raw, buffer.as_mut_ptr(), buffer.len(), &mut found)
    });
    if rc == 0 && !found.is_null() {
        group_from(&raw)
    } else {
        Group {
            name: gid.to_string(),
            gid,
        }
    }
}

/// The login name of `uid` (its number when it has none) and its primary group id.
pub fn user(uid: u32) -> (String, Option<u32>) {
    // SAFETY: plain C struct, filled by getpwuid_r before it is read.
    let mut raw: libc::passwd = unsafe { std::mem::zeroed() };
    let mut found: *mut libc::passwd = std::ptr::null_mut();
    let (rc, _buffer) = with_buffer(|buffer| unsafe {
        libc::getpwuid_r(uid, &mut raw, buffer.as_mut_ptr(), buffer.len(), &mut found)
    });
    if rc == 0 && !found.is_null() {
        // SAFETY: NUL-terminated name in the buffer, which is still alive.
        let name = unsafe { CStr::from_ptr(raw.pw_name) };
        (name.to_string_lossy().into_owned(), Some(raw.pw_gid))
    } else {
        (uid.to_string(), None)
    }
}

/// The login name of `uid`.
pub fn user_name(uid: u32) -> String {
    user(uid).0
}

/// This process's effective user id.
pub fn effective_uid() -> u32 {
    // SAFETY: no arguments, cannot fail.
    unsafe { libc::geteuid() }
}

/// This process's effective group id.
pub fn effective_gid() -> u32 {
    // SAFETY: no arguments, cannot fail.
    unsafe { libc::getegid() }
}

/// Whether this process has `gid` as its effective or a supplementary group.
pub fn process_has_group(gid: u32) -> bool {
    if effective_gid() == gid {
        return true;
    }
    // SAFETY: first call asks for the count, the second fills a buffer of that size.
    let count = unsafe { libc::getgroups(0, std::ptr::null_mut()) };
    if count <= 0 {
        return false;
    }
    let mut groups = vec![0 as libc::gid_t; count as usize];
    let filled = unsafe { libc::getgroups(count, groups.as_mut_ptr()) };
    filled > 0 && groups[..filled as usize].contains(&gid)
}

/// Whether the user database lists `uid` in group `gid` (as primary or
/// supplementary group): what the next login of that user will have.
pub fn user_listed_in_group(uid: u32, gid: u32) -> bool {
    let (name, primary) = user(uid);
    let Some(primary) = primary else {
        return false;
    };
    if primary == gid {
        return true;
    }
    let Ok(c_name) = CString::new(name) else {
        return false;
    };
    let mut count: libc::c_int = 64;
    loop {
        let mut groups = vec![0 as libc::gid_t; count as usize];
        let mut n = count;
        // SAFETY: `groups` holds `n` entries; getgrouplist writes at most that many.
        let rc =
            unsafe { libc::getgrouplist(c_name.as_ptr(), primary, groups.as_mut_ptr(), &mut n) };
        if rc >= 0 {
            return groups[..n as usize].contains(&gid);
        }
        if n <= count || n > 65536 {
            return false;
        }
        count = n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn root_group_is_found_by_name_and_id() {
        let root = group_by_name("root").expect("lookup").expect("group root");
        assert_eq!(root.gid, 0);
        assert_eq!(group_by_gid(0).name, "root");
        assert_eq!(user_name(0), "root");
    }

    #[test]
    fn a_missing_group_is_none_not_an_error() {
        assert_eq!(
            group_by_name("rsl_no_such_group_xyz").expect("lookup"),
            None
        );
        assert!(group_by_name("a\0b").is_err());
    }

    #[test]
    fn this_process_has_its_own_group() {
        assert!(process_has_group(effective_gid()));
    }
}
