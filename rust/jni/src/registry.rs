//! Handles: a Kotlin `NoisecalSession` holds a `jlong` id, never a pointer. Live sessions sit in
//! a global map from id to `Arc<Mutex<NativeSession>>`; ids count up from 1 and are never reused,
//! so a closed, stale, zero or forged handle is detected (an exception), never dereferenced.
//!
//! The map's lock is held only to look an id up or to insert/remove one; each session has its own
//! lock, so one session's long push does not block another's. `close` removes the id at once, then
//! waits for a call running on another thread to finish and takes the session out of its slot; a
//! call that looked the id up just before finds the slot empty (closed handle).

use std::collections::HashMap;
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, OnceLock};

use crate::error::{BoundaryError, Result};
use crate::session::NativeSession;

type Shared = Arc<Mutex<Option<NativeSession>>>;

fn map() -> &'static Mutex<HashMap<i64, Shared>> {
    static MAP: OnceLock<Mutex<HashMap<i64, Shared>>> = OnceLock::new();
    MAP.get_or_init(|| Mutex::new(HashMap::new()))
}

static NEXT_ID: AtomicI64 = AtomicI64::new(1);

/// The map, even if a panic poisoned its lock (the map itself is always consistent: inserts and
/// removes cannot panic half-way).
fn lock_map() -> MutexGuard<'static, HashMap<i64, Shared>> {
    map().lock().unwrap_or_else(|p| p.into_inner())
}

/// Registers a session and returns its handle (≥ 1).
pub fn insert(session: NativeSession) -> i64 {
    let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
    lock_map().insert(id, Arc::new(Mutex::new(Some(session))));
    id
}

/// Runs `f` on the live session `handle`, holding its lock.
pub fn with<T>(handle: i64, f: impl FnOnce(&mut NativeSession) -> Result<T>) -> Result<T> {
    let shared = lock_map().get(&handle).cloned().ok_or(BoundaryError::ClosedHandle(handle))?;
    // A poisoned session lock means a call panicked half-way through changing it: its state
    // cannot be trusted, so it is refused (close it and restore from a checkpoint).
    let mut guard = shared.lock().map_err(|_| BoundaryError::Poisoned(handle))?;
    let session = guard.as_mut().ok_or(BoundaryError::ClosedHandle(handle))?;
    f(session)
}

/// Removes `handle` and returns its session (the caller ends it), after any call running on it
/// has returned. A poisoned session (a call panicked inside it) is dropped: `Ok(None)`.
pub fn remove(handle: i64) -> Result<Option<NativeSession>> {
    let shared = lock_map().remove(&handle).ok_or(BoundaryError::ClosedHandle(handle))?;
    let mut guard = match shared.lock() {
        Ok(g) => g,
        Err(p) => {
            drop(p.into_inner().take());
            log::warn!("session {handle} closed after an internal error; its recording (if any) has no End record");
            return Ok(None);
        }
    };
    guard.take().map(Some).ok_or(BoundaryError::ClosedHandle(handle))
}

/// Number of live sessions (tests, leak checks).
pub fn live() -> usize {
    lock_map().len()
}
