/*
 * echo_pose: a minimal C consumer of rigslam's pose messages.
 *
 * It shows the only thing a C or C++ program needs from rigslam: the
 * layout in include/rigslam/pose_message.h. The transport is iceoryx2; its
 * C binding (iceoryx2-ffi, built with CMake from the iceoryx2 sources) hands
 * a subscriber a `const void *` to each sample's payload, which is a
 * `const rigslam_pose_message_t *`. This file does not link that binding
 * (the project does not build it); `main` below reads the same bytes from a
 * file or stdin instead, which is also how the project's test drives it:
 *
 *     gcc -std=c11 -Wall -Iinclude examples/c/echo_pose.c -o echo_pose
 *     ./echo_pose poses.bin        # raw rigslam_pose_message_t records
 *
 * With the iceoryx2 C binding the receive loop is (see src/publish/README.md):
 *
 *     open the publish-subscribe service "rigslam/pose" with payload type
 *       details (FIXED_SIZE, RIGSLAM_POSE_TYPE_NAME,
 *       sizeof(rigslam_pose_message_t), alignof(rigslam_pose_message_t)),
 *     open the event service of the same name and create a listener,
 *     loop: wait on the listener (timed wait) -> then receive every sample
 *       (iox2_subscriber_receive), cast iox2_sample_payload's pointer and
 *       call print_pose() below, drop the sample.
 *
 * The poses are for the daemon's user and its group only (`usermod -aG
 * rigslam USER`); `./echo_pose --check-access /run/rigslam/iceoryx2` shows
 * what rigslam_access.h tells a reader that is not allowed in.
 */
#include "rigslam_access.h" /* first: it asks for _GNU_SOURCE */
#include <inttypes.h>
#include <stdio.h>
#include <string.h>

#include "rigslam/pose_message.h"

static const char *state_name(uint32_t state) {
    switch (state) {
    case RIGSLAM_TRACKING_STATE_INITIALIZING:
        return "initializing";
    case RIGSLAM_TRACKING_STATE_TRACKING:
        return "tracking";
    case RIGSLAM_TRACKING_STATE_LOST:
        return "lost";
    default:
        return "unknown";
    }
}

/* Prints one pose; returns 0, or -1 for a layout this program does not know. */
static int print_pose(const rigslam_pose_message_t *m) {
    if (m->layout_version != RIGSLAM_POSE_LAYOUT_VERSION) {
        fprintf(stderr, "layout version %" PRIu32 ", expected %u\n", m->layout_version,
                RIGSLAM_POSE_LAYOUT_VERSION);
        return -1;
    }
    printf("seq=%" PRIu64 " t_ns=%" PRId64 " state=%s p=%.9g,%.9g,%.9g q_xyzw=%.9g,%.9g,%.9g,%.9g "
           "v=%.9g,%.9g,%.9g",
           m->sequence, m->t_ns, state_name(m->tracking_state), m->position_world_m[0],
           m->position_world_m[1], m->position_world_m[2], m->orientation_world_body_xyzw[0],
           m->orientation_world_body_xyzw[1], m->orientation_world_body_xyzw[2],
           m->orientation_world_body_xyzw[3], m->velocity_world_m_s[0], m->velocity_world_m_s[1],
           m->velocity_world_m_s[2]);
    if (m->flags & RIGSLAM_POSE_FLAG_COVARIANCE_VALID) {
        /* Row-major: (row 0, col 0) is x variance, (3, 3) rotation about x. */
        printf(" var_x=%.9g var_rx=%.9g cov_z_ry=%.9g", m->covariance[0], m->covariance[6 * 3 + 3],
               m->covariance[6 * 2 + 4]);
    } else {
        printf(" cov=unknown");
    }
    if (m->flags & RIGSLAM_POSE_FLAG_MAP_CORRECTED) {
        /* The relative stage's pose (odom) and the map <- odom transform. */
        printf(" odom_p=%.9g,%.9g,%.9g world_odom_t=%.9g,%.9g,%.9g", m->position_odom_m[0],
               m->position_odom_m[1], m->position_odom_m[2], m->translation_world_odom_m[0],
               m->translation_world_odom_m[1], m->translation_world_odom_m[2]);
    }
    printf("%s\n", (m->flags & RIGSLAM_POSE_FLAG_IMU_PROPAGATED) ? " imu_propagated" : "");
    return 0;
}

int main(int argc, char **argv) {
    FILE *in = stdin;
    if (argc == 3 && strcmp(argv[1], "--check-access") == 0) {
        /* What a reader does before (or after a failed) iox2_node_builder_create():
         * say plainly when a permission keeps it from the daemon's root path. */
        char why[1024];
        int rc = rigslam_explain_access(argv[2], why, sizeof why);
        if (rc != 0) {
            fprintf(stderr, "%s\n", rc > 0 ? why : "permission denied (message too long)");
            return 1;
        }
        printf("%s: open to this process\n", argv[2]);
        return 0;
    }
    if (argc > 2) {
        fprintf(stderr,
                "usage: %s [FILE]  (raw rigslam_pose_message_t records; stdin when absent)\n"
                "       %s --check-access ROOT_PATH  (may this process read the daemon's poses?)\n",
                argv[0], argv[0]);
        return 2;
    }
    if (argc == 2 && (in = fopen(argv[1], "rb")) == NULL) {
        perror(argv[1]);
        return 1;
    }
    rigslam_pose_message_t m;
    size_t n;
    while ((n = fread(&m, 1, sizeof m, in)) == sizeof m) {
        if (print_pose(&m) != 0) {
            return 1;
        }
    }
    if (n != 0) {
        fprintf(stderr, "truncated record: %zu of %zu bytes\n", n, sizeof m);
        return 1;
    }
    return 0;
}
