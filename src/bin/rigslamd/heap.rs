//! The daemon's heap: one malloc arena for all its threads.
//!
//! glibc gives a thread that finds the heap busy an arena of its own (up
//! to eight per core), and memory freed in one arena serves only that
//! arena's later allocations. The frame path, the map solve and the map
//! save allocate and free large buffers on different threads, so the free
//! space ends up spread over several arenas and the resident size moves
//! up by steps of a few MiB over a long run, without a leak. With one
//! arena, a 30-minute soak of laps on one core stays at one resident size
//! from minute 10 to minute 30, 6 MiB below the default's, and the frame
//! to pose latency is no worse (docs/results/map-places-2026-11-29.md).

/// Asks glibc for a single arena. Must run before the daemon starts its
/// threads. Returns false where it could not be set (another C library),
/// which only costs memory.
pub fn one_arena() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only changes the allocator's tuning; it is
        // called before any other thread exists.
        unsafe { libc::mallopt(libc::M_ARENA_MAX, 1) == 1 }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_takes_the_single_arena() {
        assert!(super::one_arena());
    }
}
