//! The thread pool the core works on, one per process.
//!
//! Why not rayon's global pool: it is created once per address space (a static) with its worker
//! threads. `fork` copies the static but not the threads, so in a child forked after the parent
//! used the package (a DataLoader's workers after `ds[0]`, multiprocessing with fork) the first
//! parallel call queued its work on the inherited pool and waited for workers that do not exist:
//! it hung forever in `rayon_core::registry::Registry::in_worker_cold` (`LockLatch::wait`).
//! Here every call runs on a pool of this process, keyed on its pid: a forked child sees another
//! pid and builds its own (the parent's, whose threads it does not have, is left alone, never
//! dropped). Thread count: `RAYON_NUM_THREADS` or every core, as before; outputs do not depend
//! on it.

use std::sync::{Arc, Mutex};

use pyo3::PyResult;
use rayon::ThreadPool;

use crate::errors::err;

/// The pool of the process whose pid it holds.
static POOL: Mutex<Option<(u32, Arc<ThreadPool>)>> = Mutex::new(None);

/// This process's pool, built on first use (in a forked child: on its first use there).
fn pool() -> PyResult<Arc<ThreadPool>> {
    let pid = std::process::id();
    let mut slot = POOL.lock().unwrap_or_else(|p| p.into_inner());
    if let Some((owner, pool)) = slot.as_ref()
        && *owner == pid
    {
        return Ok(pool.clone());
    }
    if let Some((_, inherited)) = slot.take() {
        // A forked child: the parent's pool has no threads here. Dropping it would signal
        // threads that do not exist; it is forgotten instead (a few hundred bytes).
        std::mem::forget(inherited);
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .thread_name(|i| format!("noisecal-{i}"))
        .build()
        .map_err(|e| err(format!("cannot start noisecal's worker threads: {e}")))?;
    let pool = Arc::new(pool);
    *slot = Some((pid, pool.clone()));
    Ok(pool)
}

/// Runs `f` on this process's pool: every parallel loop of the core inside `f` uses it.
pub fn run<T: Send>(f: impl FnOnce() -> PyResult<T> + Send) -> PyResult<T> {
    pool()?.install(f)
}
