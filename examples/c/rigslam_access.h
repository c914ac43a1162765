/*
 * rigslam_access.h: tells a C or C++ reader plainly when permissions keep
 * it from rigslam's poses, instead of iceoryx2's generic error code.
 *
 * The poses are for the daemon's user and the members of its group
 * (`[publish] group`, by default the daemon's primary group `rigslam`);
 * src/publish/README.md, "Who may read", says how that is enforced.
 * Call rigslam_explain_access() with the daemon's root path before (or
 * after a failed) iox2_node_builder_create(): it walks the path as the
 * kernel will, and when a directory is closed to this process it writes a
 * sentence naming that directory's group and the `usermod -aG` line into
 * `why` and returns 1. It returns 0 when the path is open (or does not
 * exist yet), -1 when `why` is too small.
 *
 * POSIX only (Linux), C11, no allocation; header-only. Include it before
 * any system header: it defines _GNU_SOURCE for getgrouplist and
 * faccessat's AT_EACCESS.
 */
#ifndef RIGSLAM_ACCESS_H
#define RIGSLAM_ACCESS_H

#ifndef _GNU_SOURCE
#define _GNU_SOURCE /* getgrouplist, AT_EACCESS */
#endif
#include <fcntl.h>
#include <grp.h>
#include <pwd.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

/* Whether the user database lists `user` (primary group `primary`) in `gid`. */
static inline int rigslam_user_listed_in_group(const char *user, gid_t primary, gid_t gid) {
    gid_t groups[256];
    int n = 256;
    if (primary == gid) {
        return 1;
    }
    if (getgrouplist(user, primary, groups, &n) < 0) {
        return 0;
    }
    for (int i = 0; i < n; i++) {
        if (groups[i] == gid) {
            return 1;
        }
    }
    return 0;
}

static inline int rigslam_explain_access(const char *root, char *why, size_t why_len) {
    char prefix[4096];
    size_t len = strlen(root);
    if (len == 0 || len >= sizeof prefix) {
        return 0;
    }
    /* Each ancestor from "/" down, then the root itself (which needs rwx). */
    for (size_t end = 1; end <= len; end++) {
        if (end != len && root[end] != '/') {
            continue;
        }
        memcpy(prefix, root, end);
        prefix[end] = '\0';
        struct stat st;
        if (stat(prefix, &st) != 0) {
            return 0; /* not there (yet): iceoryx2 creates it or fails on its own */
        }
        int wanted = end == len ? (R_OK | W_OK | X_OK) : X_OK;
        if (faccessat(AT_FDCWD, prefix, wanted, AT_EACCESS) == 0) {
            continue;
        }
        /* getgrgid/getpwuid share static buffers: copy each answer at once. */
        char group_name[64], owner_name[64], user_name[64];
        struct group *g = getgrgid(st.st_gid);
        snprintf(group_name, sizeof group_name, "%s", g ? g->gr_name : "?");
        struct passwd *o = getpwuid(st.st_uid);
        snprintf(owner_name, sizeof owner_name, "%s", o ? o->pw_name : "?");
        struct passwd *me = getpwuid(geteuid());
        snprintf(user_name, sizeof user_name, "%s", me ? me->pw_name : "?");
        gid_t primary = me ? me->pw_gid : (gid_t)-1;
        int listed = me && rigslam_user_listed_in_group(user_name, primary, st.st_gid);
        int n;
        if (listed) {
            n = snprintf(why, why_len,
                         "permission denied: the poses in %s are for user %s and group %s only "
                         "(%s has mode %o); %s is in group %s but this process is not yet: log in "
                         "again (or run it with `sg %s -c ...`)",
                         root, owner_name, group_name, prefix, (unsigned)(st.st_mode & 07777),
                         user_name, group_name, group_name);
        } else {
            n = snprintf(why, why_len,
                         "permission denied: the poses in %s are for user %s and group %s only "
                         "(%s has mode %o); %s is not in group %s: an administrator adds it with "
                         "`sudo usermod -aG %s %s`, then log in again",
                         root, owner_name, group_name, prefix, (unsigned)(st.st_mode & 07777),
                         user_name, group_name, group_name, user_name);
        }
        return (n < 0 || (size_t)n >= why_len) ? -1 : 1;
    }
    return 0;
}

#endif /* RIGSLAM_ACCESS_H */
