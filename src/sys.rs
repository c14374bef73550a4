//! The one module with `unsafe`: process-level allocator settings.
#![allow(unsafe_code)]

/// Makes glibc's allocator return large buffers to the OS promptly.
///
/// Why: glibc raises its mmap threshold dynamically (up to 32 MiB) after large blocks are
/// freed, so later tile-sized buffers are carved from per-thread heaps and their pages stay
/// resident after being freed; with several worker threads this fragmentation added ~100 MiB
/// to the peak RSS of a 256 MiB run (292 → 188 MiB measured with a fixed threshold). A fixed
/// threshold (which also disables the dynamic adjustment) and few arenas keep RSS close to
/// live data. No-op on other platforms.
pub fn tame_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only changes allocator tuning parameters; it is called before the
        // pipeline starts its threads and takes plain integer arguments.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
            libc::mallopt(libc::M_TRIM_THRESHOLD, 8 << 20);
            libc::mallopt(libc::M_ARENA_MAX, 2);
        }
    }
}
