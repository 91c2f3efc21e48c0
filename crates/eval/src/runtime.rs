//! Process-wide CPU settings for programs that train and score many models in parallel: one
//! unit of work per core on rayon's global pool, and candle's kernels single-threaded inside
//! each unit (docs/decisions/064-parallel-runs-and-candle-threads.md).
//!
//! candle 0.11 decides its intra-op threads from two environment variables: element-wise
//! kernels run on a spinning barrier pool of `CANDLE_NUM_THREADS` workers, and matrix products
//! split over `RAYON_NUM_THREADS` rayon tasks (default: the physical cores, re-read from
//! `/proc/cpuinfo` on every product). QUADFormer's and the baselines' tensors are too small for
//! either to pay off: with both set to 1 a QUADFormer fit trains 1.55× faster alone and 1.25×
//! faster two at a time. [`init_cpu_runtime`] sets both to 1 and builds the global rayon pool,
//! which the experiment runner uses for its units, with every available core.

use std::num::NonZeroUsize;

/// What [`init_cpu_runtime`] set up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CpuRuntime {
    /// Threads of rayon's global pool (parallel units of work).
    pub pool_threads: usize,
    /// Whether candle's kernels were made single-threaded (false: the user set the variables).
    pub single_threaded_kernels: bool,
    /// Whether the glibc allocator tuning took effect ([`nn_toolkit::tune_allocator`]).
    pub allocator_tuned: bool,
}

/// Makes candle's kernels single-threaded (`CANDLE_NUM_THREADS=1`, `RAYON_NUM_THREADS=1`)
/// unless the user set either variable, builds rayon's global pool with one thread per
/// available core for parallel units of work, and tunes glibc's allocator. Numbers do not
/// depend on any of it: candle's CPU results are bit-identical across thread counts
/// (docs/decisions/064-parallel-runs-and-candle-threads.md).
///
/// # Safety
/// Must be called at the start of `main`, before the program starts any thread: it writes the
/// process environment, which is only sound while no other thread can read it.
#[allow(unsafe_code)]
pub unsafe fn init_cpu_runtime() -> CpuRuntime {
    let cores = std::thread::available_parallelism().map_or(1, NonZeroUsize::get);
    let user_set = std::env::var_os("CANDLE_NUM_THREADS").is_some() || std::env::var_os("RAYON_NUM_THREADS").is_some();
    let mut pool_threads = cores;
    if user_set {
        pool_threads = std::env::var("RAYON_NUM_THREADS").ok().and_then(|s| s.parse().ok()).unwrap_or(cores);
    } else {
        // SAFETY: the caller guarantees that no other thread exists yet.
        unsafe {
            std::env::set_var("CANDLE_NUM_THREADS", "1");
            std::env::set_var("RAYON_NUM_THREADS", "1");
        }
    }
    // The pool is sized explicitly, so the variable set above only reaches candle. It fails
    // only if the pool already exists, in which case that pool is used as it is.
    let _ = rayon::ThreadPoolBuilder::new().num_threads(pool_threads.max(1)).build_global();
    CpuRuntime {
        pool_threads: rayon::current_num_threads(),
        single_threaded_kernels: !user_set,
        allocator_tuned: nn_toolkit::tune_allocator(),
    }
}
