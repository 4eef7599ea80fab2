//! The CPU compute threads. The flex backend's element-wise ops and matmuls, and anerf's own kernels, fan
//! out on rayon's global pool. Started from a thread outside the pool, every such op is injected into the
//! pool while its caller sleeps until a worker finishes it: two thread hand-offs per op, and a training
//! step of the `fast` preset issues thousands of ops of a few hundred microseconds each. Started on a
//! worker, the same ops fork and join in place, the caller working on its share.

/// Stack size of the pool's threads, bytes: the usual main-thread 8 MiB, since whole commands run there.
pub const WORKER_STACK_BYTES: usize = 8 << 20;

/// Builds rayon's global pool with [`WORKER_STACK_BYTES`] stacks and rayon's default thread count (one
/// per core, or `RAYON_NUM_THREADS`). Call once, before any parallel work; fails when the pool exists.
pub fn init_pool() -> Result<(), rayon::ThreadPoolBuildError> {
    rayon::ThreadPoolBuilder::new()
        .stack_size(WORKER_STACK_BYTES)
        .build_global()
}

/// Runs `f` on a worker of rayon's global pool (in place when called from one) and returns its result.
pub fn on_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| f())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn work_runs_on_a_pool_worker_and_nests_in_place() {
        assert_eq!(
            rayon::current_thread_index(),
            None,
            "tests start outside the pool"
        );
        let (outer, inner) = on_pool(|| {
            let outer = rayon::current_thread_index();
            (outer, on_pool(rayon::current_thread_index))
        });
        assert!(outer.is_some(), "on_pool runs its work on a worker");
        assert_eq!(inner, outer, "a nested call stays on the same worker");
    }
}
