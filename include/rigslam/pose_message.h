/*
 * rigslam published messages, for C and C++ readers.
 *
 * The payloads of the iceoryx2 services `rigslam/pose`, `rigslam/pose_fast`
 * (rigslam_pose_message_t) and `rigslam/status` (rigslam_status_message_t),
 * byte for byte as the Rust types rigslam::publish::{PoseMessage,
 * StatusMessage, QueueFill} lay them out (#[repr(C)], 64-bit little-endian
 * Linux, natural alignment, no padding). The static asserts below fail the
 * compile if a compiler lays them out otherwise, and a Rust test reads the
 * numbers in those asserts and checks them against the Rust types, so the
 * two cannot drift apart silently.
 *
 * iceoryx2 type names (what a C binding passes as the payload type name
 * when it opens the service): "rigslam_pose_message_v2" and
 * "rigslam_status_message_v3"; type variant FIXED_SIZE; size and alignment
 * as asserted here. Each service is paired with an event service of the
 * same name, notified after every sample.
 *
 * Frames and units: world W is gravity-aligned (z up) once initialised;
 * body B is the IMU frame. As REP-105 names them, W is `map` (where the
 * absolute stage places the robot; a correction may move the pose in it)
 * and O is `odom` (the relative stage's frame, in which the pose is
 * continuous); T_world_odom joins them. Without the absolute stage they
 * are one frame. Times are int64 nanoseconds on the host's
 * CLOCK_MONOTONIC (dataset time on replay for t_ns).
 */
#ifndef RIGSLAM_POSE_MESSAGE_H
#define RIGSLAM_POSE_MESSAGE_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define RIGSLAM_POSE_LAYOUT_VERSION 2u
#define RIGSLAM_STATUS_LAYOUT_VERSION 3u
#define RIGSLAM_POSE_TYPE_NAME "rigslam_pose_message_v2"
#define RIGSLAM_STATUS_TYPE_NAME "rigslam_status_message_v3"

/* tracking_state values */
#define RIGSLAM_TRACKING_STATE_INITIALIZING 0u /* no metric pose yet */
#define RIGSLAM_TRACKING_STATE_TRACKING 1u     /* pose is metric and tracked */
#define RIGSLAM_TRACKING_STATE_LOST 2u         /* tracking failed: do not use */

/* flags bits */
#define RIGSLAM_POSE_FLAG_COVARIANCE_VALID (1u << 0) /* else covariance is all NaN */
#define RIGSLAM_POSE_FLAG_VELOCITY_VALID (1u << 1)
#define RIGSLAM_POSE_FLAG_IMU_PROPAGATED (1u << 2) /* pose_fast: propagated with the IMU */
/* the absolute stage runs: position_world_m is its map-frame position; the
 * odom fields hold the relative stage's pose and T_world_odom (else they
 * repeat the world pose and the identity) */
#define RIGSLAM_POSE_FLAG_MAP_CORRECTED (1u << 3)

/* One pose of the body (IMU) frame in the world frame. */
typedef struct rigslam_pose_message {
    uint32_t layout_version; /* RIGSLAM_POSE_LAYOUT_VERSION; reject others */
    uint32_t tracking_state; /* RIGSLAM_TRACKING_STATE_* */
    uint32_t flags;          /* RIGSLAM_POSE_FLAG_* */
    uint32_t reserved;       /* zero */
    int64_t t_ns;            /* time the pose refers to, ns */
    int64_t published_t_ns;  /* CLOCK_MONOTONIC when sent, ns */
    uint64_t sequence;       /* +1 per sample on this service; a gap = missed samples */
    double position_world_m[3];            /* x, y, z of the body origin in W, m */
    double orientation_world_body_xyzw[4]; /* R_world_body, Hamilton, order x, y, z, w */
    double velocity_world_m_s[3];          /* body origin velocity in W, m/s */
    /* 6x6 pose covariance, row-major: entry (i, j) is covariance[6 * i + j],
     * over (dx, dy, dz, drx, dry, drz): position error in W (m), then rotation
     * error as a rotation vector about W's axes (rad), R_true = Exp(dr) R_est
     * (fixed axes, as ROS PoseWithCovariance). Units m^2, m rad, rad^2. */
    double covariance[36];
    double position_odom_m[3];            /* x, y, z of the body origin in O, m */
    double orientation_odom_body_xyzw[4]; /* R_odom_body, Hamilton, x, y, z, w */
    double translation_world_odom_m[3];   /* T_world_odom: O's origin in W, m */
    double rotation_world_odom_xyzw[4];   /* T_world_odom's rotation, x, y, z, w */
} rigslam_pose_message_t;

/* sensor_health bits */
#define RIGSLAM_HEALTH_CAMERA_STREAMING (1u << 0)
#define RIGSLAM_HEALTH_IMU_STREAMING (1u << 1)
#define RIGSLAM_HEALTH_IMU_RECONNECTING (1u << 2)
#define RIGSLAM_HEALTH_CAMERA_STALLED (1u << 3)
#define RIGSLAM_HEALTH_TIMESTAMP_JUMP (1u << 4)
#define RIGSLAM_HEALTH_STAGE_STUCK (1u << 5)
/* the estimated noise sits at a bound: the declared noise is far off */
#define RIGSLAM_HEALTH_NOISE_AT_BOUND (1u << 6)
/* the online camera-IMU estimate is far from the calibration file */
#define RIGSLAM_HEALTH_CALIBRATION_DRIFT (1u << 7)

#define RIGSLAM_STATUS_MAX_QUEUES 8

/* The queue in front of one pipeline stage. */
typedef struct rigslam_queue_fill {
    uint8_t name[16];  /* ASCII, NUL-padded, not NUL-terminated when 16 long */
    uint32_t len;      /* items waiting */
    uint32_t capacity; /* bound of the queue */
} rigslam_queue_fill_t;

/* The daemon's health, about once a second. */
typedef struct rigslam_status_message {
    uint32_t layout_version; /* RIGSLAM_STATUS_LAYOUT_VERSION */
    uint32_t sensor_health;  /* RIGSLAM_HEALTH_* */
    uint32_t queue_count;    /* entries of queues[] in use */
    uint32_t reserved;       /* zero */
    int64_t t_ns;            /* CLOCK_MONOTONIC when taken, ns */
    int64_t published_t_ns;  /* CLOCK_MONOTONIC when sent, ns */
    uint64_t sequence;
    /* per second over the status period, or since the stream's first
     * arrival when it began in the period; NaN: one arrival so far, rate
     * not known yet; 0: none came */
    double camera_rate_hz;
    double imu_rate_hz;
    double pose_rate_hz;
    uint64_t camera_drops; /* since start */
    uint64_t imu_drops;
    uint64_t pose_drops;
    double latency_p50_us; /* frame arrival to pose published */
    double latency_p99_us;
    rigslam_queue_fill_t queues[RIGSLAM_STATUS_MAX_QUEUES];
    /* multipliers on the declared noise the estimator weighs with,
     * estimated online (1: as declared; NaN: no estimate) */
    double imu_noise_scale_gyro;
    double imu_noise_scale_accel;
    double pixel_noise_scale;
    /* the online camera-IMU refinement: distance of camera 0's pose from
     * the calibration file (deg, m) and the frames' time offset beyond the
     * file's time shift (s); NaN: not refined */
    double camera_imu_rotation_deg;
    double camera_imu_translation_m;
    double camera_imu_time_offset_s;
} rigslam_status_message_t;

#if defined(__cplusplus)
#define RIGSLAM_STATIC_ASSERT static_assert
#define RIGSLAM_ALIGNOF alignof
#else
#define RIGSLAM_STATIC_ASSERT _Static_assert
#define RIGSLAM_ALIGNOF _Alignof
#endif

/* Layout contract. The Rust test `publish_layout` parses these lines. */
RIGSLAM_STATIC_ASSERT(sizeof(rigslam_pose_message_t) == 520, "pose size");
RIGSLAM_STATIC_ASSERT(RIGSLAM_ALIGNOF(rigslam_pose_message_t) == 8, "pose alignment");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, layout_version) == 0, "pose layout_version");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, tracking_state) == 4, "pose tracking_state");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, flags) == 8, "pose flags");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, reserved) == 12, "pose reserved");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, t_ns) == 16, "pose t_ns");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, published_t_ns) == 24, "pose published_t_ns");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, sequence) == 32, "pose sequence");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, position_world_m) == 40, "pose position_world_m");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, orientation_world_body_xyzw) == 64, "pose orientation");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, velocity_world_m_s) == 96, "pose velocity_world_m_s");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, covariance) == 120, "pose covariance");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, position_odom_m) == 408, "pose position_odom_m");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, orientation_odom_body_xyzw) == 432, "pose orientation_odom");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, translation_world_odom_m) == 464, "pose translation_world_odom_m");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_pose_message_t, rotation_world_odom_xyzw) == 488, "pose rotation_world_odom");

RIGSLAM_STATIC_ASSERT(sizeof(rigslam_queue_fill_t) == 24, "queue fill size");
RIGSLAM_STATIC_ASSERT(RIGSLAM_ALIGNOF(rigslam_queue_fill_t) == 4, "queue fill alignment");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_queue_fill_t, name) == 0, "queue fill name");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_queue_fill_t, len) == 16, "queue fill len");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_queue_fill_t, capacity) == 20, "queue fill capacity");

RIGSLAM_STATIC_ASSERT(sizeof(rigslam_status_message_t) == 344, "status size");
RIGSLAM_STATIC_ASSERT(RIGSLAM_ALIGNOF(rigslam_status_message_t) == 8, "status alignment");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, layout_version) == 0, "status layout_version");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, sensor_health) == 4, "status sensor_health");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, queue_count) == 8, "status queue_count");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, reserved) == 12, "status reserved");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, t_ns) == 16, "status t_ns");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, published_t_ns) == 24, "status published_t_ns");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, sequence) == 32, "status sequence");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, camera_rate_hz) == 40, "status camera_rate_hz");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, imu_rate_hz) == 48, "status imu_rate_hz");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, pose_rate_hz) == 56, "status pose_rate_hz");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, camera_drops) == 64, "status camera_drops");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, imu_drops) == 72, "status imu_drops");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, pose_drops) == 80, "status pose_drops");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, latency_p50_us) == 88, "status latency_p50_us");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, latency_p99_us) == 96, "status latency_p99_us");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, queues) == 104, "status queues");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, imu_noise_scale_gyro) == 296, "status imu_noise_scale_gyro");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, imu_noise_scale_accel) == 304, "status imu_noise_scale_accel");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, pixel_noise_scale) == 312, "status pixel_noise_scale");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, camera_imu_rotation_deg) == 320, "status camera_imu_rotation_deg");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, camera_imu_translation_m) == 328, "status camera_imu_translation_m");
RIGSLAM_STATIC_ASSERT(offsetof(rigslam_status_message_t, camera_imu_time_offset_s) == 336, "status camera_imu_time_offset_s");

#ifdef __cplusplus
} /* extern "C" */
#endif

#endif /* RIGSLAM_POSE_MESSAGE_H */
