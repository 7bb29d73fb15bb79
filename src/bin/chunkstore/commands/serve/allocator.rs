//! What the server asks of the C allocator under `--memory-limit`, so that the process
//! stays near the limit for days. On Linux with glibc (Rust's allocator is glibc's
//! `malloc` there):
//!
//! - [`fix_mmap_threshold`]: blocks of 128 KiB and more are always mapped on their own and
//!   unmapped when freed. glibc otherwise raises this threshold each time such a block is
//!   freed, up to 32 MiB, after which the server's chunk-sized buffers (decompressed
//!   messages, compacted chunks, query batches) come from its per-thread heaps, where
//!   freed memory fragments and is not handed back. Measured with
//!   `benches/server_soak.py` (8 writers, 4 readers, 256 MiB, 90 s): peak RSS 466 MiB
//!   without, 361 MiB with.
//! - [`release_free_memory`] (`malloc_trim`), once a second: hands back the free pages in
//!   the middle of those heaps, which a query's batches leave behind.
//!
//! Elsewhere both do nothing.

/// See the module docs. Called once, at start, before the stores grow.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(
    unsafe_code,
    reason = "glibc's mallopt: a C call with two integers, no pointers, safe at any time"
)]
pub fn fix_mmap_threshold() {
    // SAFETY: mallopt takes two ints and touches only the allocator's own settings,
    // under its own lock; any thread may call it at any time.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 128 << 10);
    }
}

/// See the module docs.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(
    unsafe_code,
    reason = "glibc's malloc_trim: a C call with one integer, no pointers, safe at any time"
)]
pub fn release_free_memory() {
    // SAFETY: malloc_trim takes an int and works on the allocator's own free lists under
    // each arena's lock; any thread may call it at any time.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// See the module docs.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn fix_mmap_threshold() {}

/// See the module docs.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn release_free_memory() {}
