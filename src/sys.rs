//! The one module with `unsafe`: process-level allocator settings, read-only file mappings,
//! thread CPU clocks and hole punching in spill files.
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

/// Frees the file blocks of `len` bytes at `at` while the file keeps its length (the range
/// then reads as zeros). Best effort: a file system without hole punching keeps the blocks
/// until the file is truncated or removed.
#[cfg(target_os = "linux")]
pub fn punch_hole(f: &std::fs::File, at: u64, len: u64) {
    use std::os::fd::AsRawFd;
    let (Ok(at), Ok(len)) = (libc::off_t::try_from(at), libc::off_t::try_from(len)) else {
        return;
    };
    // SAFETY: a plain system call on a descriptor `f` keeps open; no memory is shared.
    unsafe {
        libc::fallocate(
            f.as_raw_fd(),
            libc::FALLOC_FL_PUNCH_HOLE | libc::FALLOC_FL_KEEP_SIZE,
            at,
            len,
        );
    }
}

/// See the Linux version: elsewhere the blocks stay until the file is truncated or removed.
#[cfg(not(target_os = "linux"))]
pub fn punch_hole(_f: &std::fs::File, _at: u64, _len: u64) {}

/// Heap accounting by memory domain: a global allocator that counts live and peak heap bytes
/// per domain. Each pipeline worker and its thread pool form one domain, so the heap a stage
/// grows on one tile is measured even while other workers run (summary.json `stages.*`).
///
/// Installed by the `tessera` binary (`#[global_allocator]`); without it every figure reads
/// zero and [`alloc::counting`] is false. The cost is two relaxed atomic operations per
/// allocation.
pub mod alloc {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;
    use std::sync::atomic::{AtomicBool, AtomicI64, Ordering};

    /// Domains: 0 is every thread that was not given one.
    pub const DOMAINS: usize = 65;

    /// A domain's counters, on a cache line of their own (workers count concurrently).
    #[repr(align(64))]
    struct Counters {
        live: AtomicI64,
        peak: AtomicI64,
    }

    #[allow(clippy::declare_interior_mutable_const)]
    const ZERO: Counters = Counters {
        live: AtomicI64::new(0),
        peak: AtomicI64::new(0),
    };
    static C: [Counters; DOMAINS] = [ZERO; DOMAINS];
    static ACTIVE: AtomicBool = AtomicBool::new(false);

    thread_local! {
        static DOMAIN: Cell<usize> = const { Cell::new(0) };
    }

    #[inline]
    fn domain() -> usize {
        DOMAIN.try_with(Cell::get).unwrap_or(0)
    }

    #[inline]
    fn grow(d: usize, by: usize) {
        let now = C[d].live.fetch_add(by as i64, Ordering::Relaxed) + by as i64;
        C[d].peak.fetch_max(now, Ordering::Relaxed);
    }

    #[inline]
    fn shrink(d: usize, by: usize) {
        C[d].live.fetch_sub(by as i64, Ordering::Relaxed);
    }

    /// The counting allocator (the system allocator underneath).
    pub struct Counting;

    // SAFETY: every call is forwarded unchanged to the system allocator; the counters are
    // plain atomics and the thread-local read neither allocates nor panics (`try_with`).
    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, l: Layout) -> *mut u8 {
            let p = System.alloc(l);
            if !p.is_null() {
                grow(domain(), l.size());
            }
            p
        }
        unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
            let p = System.alloc_zeroed(l);
            if !p.is_null() {
                grow(domain(), l.size());
            }
            p
        }
        unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
            System.dealloc(p, l);
            shrink(domain(), l.size());
        }
        unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
            let q = System.realloc(p, l, new);
            if !q.is_null() {
                let d = domain();
                if new >= l.size() {
                    grow(d, new - l.size());
                } else {
                    shrink(d, l.size() - new);
                }
            }
            q
        }
    }

    /// Marks the counting allocator as installed (the binary calls this at start).
    pub fn activate() {
        ACTIVE.store(true, Ordering::Relaxed);
    }

    /// Whether heap figures are measured (the counting allocator is installed).
    pub fn counting() -> bool {
        ACTIVE.load(Ordering::Relaxed)
    }

    /// Puts the calling thread's allocations in domain `d` (taken modulo [`DOMAINS`] − 1,
    /// plus one: domain 0 stays the unassigned threads').
    pub fn set_domain(d: usize) {
        let _ = DOMAIN.try_with(|c| c.set(1 + d % (DOMAINS - 1)));
    }

    /// The calling thread's domain.
    pub fn current_domain() -> usize {
        domain()
    }

    /// Heap growth of one domain over a section of work: peak live bytes during the section
    /// minus live bytes at its start. Memory allocated by one domain and freed by another
    /// shifts both domains' live counts, but not the growth measured within a section.
    pub struct Probe {
        d: usize,
        start: i64,
    }

    impl Probe {
        /// Starts measuring domain `d` (as returned by [`current_domain`]).
        pub fn start(d: usize) -> Probe {
            let d = d.min(DOMAINS - 1);
            let start = C[d].live.load(Ordering::Relaxed);
            C[d].peak.store(start, Ordering::Relaxed);
            Probe { d, start }
        }

        /// Peak growth since [`Probe::start`], bytes.
        pub fn peak_growth(&self) -> u64 {
            (C[self.d].peak.load(Ordering::Relaxed) - self.start).max(0) as u64
        }
    }
}

/// CPU time of the calling thread, seconds (Linux; elsewhere 0).
pub fn thread_cpu_seconds() -> f64 {
    #[cfg(target_os = "linux")]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: writes only to the local passed.
        if unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0 {
            return ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9;
        }
        0.0
    }
    #[cfg(not(target_os = "linux"))]
    {
        0.0
    }
}

/// CPU time of a set of threads, seconds (per-thread CPU clocks), Linux; elsewhere 0.
#[derive(Default)]
pub struct ThreadClocks {
    #[cfg(target_os = "linux")]
    threads: std::sync::Mutex<Vec<libc::pthread_t>>,
}

impl ThreadClocks {
    /// Adds the calling thread (call from the thread itself, e.g. a pool's start handler).
    pub fn register_current(&self) {
        #[cfg(target_os = "linux")]
        {
            // SAFETY: pthread_self has no preconditions.
            let me = unsafe { libc::pthread_self() };
            if let Ok(mut t) = self.threads.lock() {
                t.push(me);
            }
        }
    }

    /// Number of threads registered.
    pub fn len(&self) -> usize {
        #[cfg(target_os = "linux")]
        {
            self.threads.lock().map(|t| t.len()).unwrap_or(0)
        }
        #[cfg(not(target_os = "linux"))]
        {
            0
        }
    }

    /// True when no thread is registered.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Summed CPU time of the registered threads, seconds. The threads must be alive (a pool's
    /// threads are, while the pool is).
    pub fn cpu_seconds(&self) -> f64 {
        #[cfg(target_os = "linux")]
        {
            let Ok(threads) = self.threads.lock() else {
                return 0.0;
            };
            threads
                .iter()
                .map(|&t| {
                    let mut clock: libc::clockid_t = 0;
                    let mut ts = libc::timespec {
                        tv_sec: 0,
                        tv_nsec: 0,
                    };
                    // SAFETY: `t` is a live thread of this process (see above); both calls
                    // write only to the locals passed.
                    let ok = unsafe {
                        libc::pthread_getcpuclockid(t, &mut clock) == 0
                            && libc::clock_gettime(clock, &mut ts) == 0
                    };
                    if ok {
                        ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
                    } else {
                        0.0
                    }
                })
                .sum()
        }
        #[cfg(not(target_os = "linux"))]
        {
            0.0
        }
    }
}
