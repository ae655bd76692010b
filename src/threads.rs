//! The rayon pools gsenc's parallel work runs on. A call that names a
//! thread count runs on a pool of that many threads, started for it; one
//! that does not runs on the pool it is called from, if it is called from
//! one, or else on gsenc's default pool: one thread per CPU the process may
//! use (`RAYON_NUM_THREADS` sets another count), started by its first use.
//!
//! The default pool is gsenc's own, not rayon's global pool, because of
//! `fork`: a child process has only the thread that forked, so a pool
//! started before the fork has no threads in the child, and work handed to
//! it waits for ever. rayon's global pool cannot be replaced once started,
//! and Python's `multiprocessing` forks (its default on Linux before Python
//! 3.14): a script that decoded a model and then decoded others in a
//! `Pool`'s workers hung in every worker. The default pool remembers the
//! process that started it, and a forked child starts its own. (So a Rust
//! host's `ThreadPoolBuilder::build_global` does not size gsenc's work;
//! running it inside the host's own pool, or naming a count, does.)

use crate::error::{Error, Result};
use rayon::ThreadPool;
use std::sync::atomic::{AtomicPtr, Ordering};

/// Runs `f` on a pool of `threads` threads started for it (checked by
/// [`check_threads`]), or, when `None`, on the pool the caller runs on, or
/// else on the default pool (module docs). The work's results do not depend
/// on the pool (encodes and decodes give the same bits on any thread count).
pub fn with_threads<R: Send>(threads: Option<usize>, f: impl FnOnce() -> R + Send) -> Result<R> {
    match threads {
        None if rayon::current_thread_index().is_some() => Ok(f()),
        None => Ok(default_pool()?.install(f)),
        Some(t) => Ok(pool(Some(check_threads(t)?))?.install(f)),
    }
}

/// Checks a requested thread count: at least 1, and at most 8 for each core
/// this process may run on (at least 64). More threads than cores give the
/// same model (it does not depend on the thread count), only slower; far
/// more is a mistake or an uninitialised field, and rayon would start up to
/// 65,535 threads that each wait their turn (an 8^3 encode at 1,000 threads
/// took 42 s instead of 0.6 on 2 cores; at 100,000 it had not finished after
/// 5 minutes), so such a count is refused.
pub fn check_threads(threads: usize) -> Result<usize> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let most = (8 * cores).max(64);
    match threads {
        0 => Err(Error::arg("threads must be at least 1")),
        t if t > most => Err(Error::arg(format!(
            "threads {t} is more than {most} (8 for each of the {cores} cores this process may run on): \
             the model is the same with fewer, and the extra threads only wait"
        ))),
        t => Ok(t),
    }
}

/// A pool of `threads` threads (rayon's default count when `None`).
fn pool(threads: Option<usize>) -> Result<ThreadPool> {
    let mut b = rayon::ThreadPoolBuilder::new().thread_name(|i| format!("gsenc-{i}"));
    if let Some(t) = threads {
        b = b.num_threads(t);
    }
    b.build().map_err(|e| Error::arg(format!("cannot start {} threads: {e}", threads.map_or("the default pool's".into(), |t| t.to_string()))))
}

/// The default pool and the process that started it.
struct DefaultPool {
    process: u32,
    pool: ThreadPool,
}

/// The default pool this process (or the one it was forked from) uses. A
/// pool, once here, is never freed, so that a reference to it lives as long
/// as the process; a child's replacement leaves its parent's pool, whose
/// threads it does not have, unfreed. An atomic pointer rather than a
/// lock, which a fork could copy locked.
static DEFAULT: AtomicPtr<DefaultPool> = AtomicPtr::new(std::ptr::null_mut());

/// The default pool of this process: started on first use, and again in a
/// process forked from the one that started it.
fn default_pool() -> Result<&'static ThreadPool> {
    let process = std::process::id();
    loop {
        let now = DEFAULT.load(Ordering::Acquire);
        // SAFETY: a non-null pointer here came from `Box::into_raw` below and
        // is never freed.
        if let Some(d) = unsafe { now.as_ref() } {
            if d.process == process {
                return Ok(&d.pool);
            }
        }
        let fresh = Box::into_raw(Box::new(DefaultPool { process, pool: pool(None)? }));
        match DEFAULT.compare_exchange(now, fresh, Ordering::AcqRel, Ordering::Acquire) {
            // SAFETY: just made, now never freed.
            Ok(_) => return Ok(unsafe { &(*fresh).pool }),
            // Another thread of this process put its pool there first: this
            // one was never shared, and is stopped; take that one.
            // SAFETY: `fresh` came from `Box::into_raw` and nothing else has it.
            Err(_) => drop(unsafe { Box::from_raw(fresh) }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tests that look at the default pool's slot, one at a time.
    static SLOT: parking_lot::Mutex<()> = parking_lot::Mutex::new(());

    #[test]
    fn a_named_count_runs_on_that_many_threads() {
        assert_eq!(with_threads(Some(3), rayon::current_num_threads).unwrap(), 3);
        assert_eq!(with_threads(Some(1), rayon::current_num_threads).unwrap(), 1);
        assert!(with_threads(Some(0), || ()).is_err());
        assert!(with_threads(Some(1 << 20), || ()).is_err());
    }

    #[test]
    fn no_count_runs_on_the_callers_pool_or_the_default_one() {
        let _slot = SLOT.lock();
        // Inside a pool of 3: there.
        let inside = with_threads(Some(3), || with_threads(None, rayon::current_num_threads).unwrap()).unwrap();
        assert_eq!(inside, 3);
        // Outside any pool: the default pool, on one of its threads, the
        // same pool each time, not rayon's global pool.
        let (index, name) = with_threads(None, || (rayon::current_thread_index(), std::thread::current().name().map(String::from))).unwrap();
        assert!(index.is_some());
        assert!(name.is_some_and(|n| n.starts_with("gsenc-")), "runs on gsenc's default pool");
        let first = default_pool().unwrap() as *const ThreadPool;
        assert_eq!(default_pool().unwrap() as *const ThreadPool, first);
        assert_eq!(default_pool().unwrap().current_num_threads(), rayon::ThreadPoolBuilder::new().build().unwrap().current_num_threads());
    }

    #[test]
    fn a_pool_from_another_process_is_replaced() {
        let _slot = SLOT.lock();
        // As a fork leaves it: the pool of a process that is not this one.
        let foreign = Box::into_raw(Box::new(DefaultPool { process: std::process::id().wrapping_add(1), pool: pool(Some(1)).unwrap() }));
        DEFAULT.swap(foreign, Ordering::AcqRel);
        let ours = default_pool().unwrap();
        // SAFETY: `foreign` is never freed.
        assert!(!std::ptr::eq(ours, unsafe { &(*foreign).pool }), "the other process's pool is not used");
        assert_eq!(ours.current_num_threads(), rayon::ThreadPoolBuilder::new().build().unwrap().current_num_threads());
        assert!(std::ptr::eq(default_pool().unwrap(), ours), "and its replacement stays");
    }
}
