//! The one module with `unsafe`: process-level allocator settings and read-only file mappings.
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

/// Maps a whole file read-only (MCAP recordings are read through the page cache instead of
/// copied into buffers).
///
/// Inputs are treated as immutable for the duration of a run, as by every reader of
/// memory-mapped files: if another process truncates the file while it is mapped, reading the
/// lost pages raises SIGBUS. Callers check lengths against the mapping, never against an
/// earlier `stat`.
pub fn map_readonly(file: &std::fs::File) -> std::io::Result<memmap2::Mmap> {
    // SAFETY: the mapping is read-only and private to this process; the only hazard is the
    // file changing underneath it, which the contract above rules out (and which would make
    // any reader's results meaningless).
    unsafe { memmap2::Mmap::map(file) }
}

/// Drops the resident pages of `map[offset..offset + len]` (rounded out to whole pages) so
/// a sequential pass over a multi-GB mapping keeps a flat resident set: file-backed pages a
/// process has touched count in its RSS until the kernel reclaims them. The data stays
/// readable; touching it again reads it back from the file.
pub fn release_mapped(map: &memmap2::Mmap, offset: usize, len: usize) {
    #[cfg(unix)]
    {
        let offset = offset.min(map.len());
        let len = len.min(map.len() - offset);
        if len == 0 {
            return;
        }
        // SAFETY: MADV_DONTNEED on a read-only file mapping only discards clean page-cache
        // references; later reads fault the same file contents back in, so no data visible
        // through `map` changes. (It is "unchecked" in memmap2 because on private *writable*
        // mappings it would discard modifications, which a read-only `Mmap` cannot have.)
        let _ =
            unsafe { map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, offset, len) };
    }
    #[cfg(not(unix))]
    let _ = (map, offset, len);
}
