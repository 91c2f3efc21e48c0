//! glibc allocator tuning for candle training on the CPU.
//!
//! candle allocates and frees a few megabytes per attention tensor on every step; with glibc's
//! default thresholds each such buffer is `mmap`ed, zeroed and `munmap`ed again, so much of a
//! training step is spent in page faults. Raising the mmap threshold to 32 MiB and the trim
//! threshold to 1 GiB keeps those buffers on the heap (measured 1.6× faster training steps with
//! candle 0.11 on a 2-core CPU).
//!
//! A thread other than the main one allocates from a per-thread arena made of 64 MiB heaps,
//! and glibc unmaps such a heap as soon as it is wholly free, whatever the trim
//! threshold (`heap_trim` in glibc's `malloc/arena.c`); the next tensor then faults fresh
//! pages in again. A top pad of 64 MiB keeps those heaps mapped: the tables stage of
//! `reproduce-tables`, whose fits run on worker threads, went from 158 M page faults and
//! 724 s of system time to 0.75 M and 7 s (docs/decisions/065-training-cost.md).

/// `mallopt` threshold above which glibc serves allocations with `mmap`: 32 MiB.
pub const MMAP_THRESHOLD_BYTES: i32 = 32 * 1024 * 1024;
/// `mallopt` threshold of free memory at the heap top before glibc trims it: 1 GiB.
pub const TRIM_THRESHOLD_BYTES: i32 = 1024 * 1024 * 1024;
/// `mallopt` padding glibc keeps free at the top of a heap, which also keeps a per-thread
/// arena's 64 MiB heaps mapped once they are empty: 64 MiB.
pub const TOP_PAD_BYTES: i32 = 64 * 1024 * 1024;

/// Applies the glibc malloc tuning for this process; returns whether it took effect.
///
/// Call it once near the start of a program that trains or scores with candle. It is a no-op
/// (returning `false`) on platforms other than Linux with glibc. It only changes allocator
/// thresholds and padding, never the results of a computation.
#[allow(unsafe_code)]
pub fn tune_allocator() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: `mallopt` only changes glibc's allocator parameters; it is thread-safe and
        // takes plain integers, and both parameters are documented for this purpose.
        let a = unsafe { libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) };
        // SAFETY: as above.
        let b = unsafe { libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) };
        // SAFETY: as above.
        let c = unsafe { libc::mallopt(libc::M_TOP_PAD, TOP_PAD_BYTES) };
        a == 1 && b == 1 && c == 1
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn tuning_applies_on_glibc() {
        let ok = super::tune_allocator();
        if cfg!(all(target_os = "linux", target_env = "gnu")) {
            assert!(ok);
        }
    }
}
