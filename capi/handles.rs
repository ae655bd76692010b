//! The handles this library gave out and has not freed. Every entry point
//! looks its handle up before touching it, so that a destroyed, doubly
//! destroyed or foreign pointer (a model passed as an encoder, a Fortran
//! `type(c_ptr)` never set) gets `GSENC_STATUS_INVALID_ARGUMENT` instead of
//! undefined behaviour. An address reused by a newer handle of the same kind
//! cannot be told apart; that is the limit of "where detectable".
//!
//! Each handle also has a lock that every call holds while it uses the
//! handle: an encoder's calls take it alone (calls from several threads,
//! such as pushes from an OpenMP loop over fields, run one at a time), a
//! model's calls share it, and destroy takes it alone after forgetting the
//! handle, so it waits for the calls in flight and frees nothing one of
//! them still reads. A call that was waiting for the lock when the handle
//! was destroyed finds it dead and fails.

use crate::status::{fail, gsenc_status, Failure};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, RwLock};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    Encoder,
    Model,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Encoder => "encoder",
            Kind::Model => "model",
        }
    }

    /// The name with its article ("an encoder").
    fn a(self) -> &'static str {
        match self {
            Kind::Encoder => "an encoder",
            Kind::Model => "a model",
        }
    }
}

/// The lock of one handle; `true` while the handle is alive.
type Life = Arc<RwLock<bool>>;

static LIVE: Mutex<BTreeMap<usize, (Kind, Life)>> = Mutex::new(BTreeMap::new());

fn live() -> std::sync::MutexGuard<'static, BTreeMap<usize, (Kind, Life)>> {
    // A panic while the lock was held left the map itself consistent.
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

/// Records a handle just made by `Box::into_raw`.
pub(crate) fn register<T>(p: *const T, kind: Kind) {
    live().insert(p as usize, (kind, Arc::new(RwLock::new(true))));
}

/// Forgets a live handle of `kind` (later calls with it fail), waits for
/// the calls in flight on it, and runs `free` before any call that waited
/// can look at it. Does nothing when `p` is not such a handle (then it must
/// not be freed).
pub(crate) fn release<T>(p: *const T, kind: Kind, free: impl FnOnce()) {
    let life = {
        let mut map = live();
        match map.get(&(p as usize)) {
            Some((k, _)) if *k == kind => map.remove(&(p as usize)).map(|(_, life)| life),
            _ => None,
        }
    };
    if let Some(life) = life {
        // A call that panicked while holding the lock was caught at its
        // entry point; the handle is freed all the same.
        let mut alive = life.write().unwrap_or_else(|e| e.into_inner());
        *alive = false;
        free();
    }
}

/// Runs `f` while `p`, a live handle of `kind`, is held: alone when
/// `alone` (an encoder's calls), else beside the other shared calls.
pub(crate) fn hold<T, R>(p: *const T, kind: Kind, what: &str, alone: bool, f: impl FnOnce() -> Result<R, Failure>) -> Result<R, Failure> {
    if p.is_null() {
        return fail(gsenc_status::NullPointer, format!("{what}: {} is NULL", kind.name()));
    }
    let life = match live().get(&(p as usize)) {
        Some((k, life)) if *k == kind => life.clone(),
        Some((k, _)) => {
            return fail(gsenc_status::InvalidArgument, format!("{what}: the handle is {}, not {}", k.a(), kind.a()))
        }
        None => {
            return fail(
                gsenc_status::InvalidArgument,
                format!("{what}: not a live {} (destroyed already, or never created by gsenc)", kind.name()),
            )
        }
    };
    let dead = || fail(gsenc_status::InvalidArgument, format!("{what}: the {} was destroyed while this call waited for it", kind.name()));
    if alone {
        let alive = life.write().unwrap_or_else(|e| e.into_inner());
        if !*alive {
            return dead();
        }
        f()
    } else {
        let alive = life.read().unwrap_or_else(|e| e.into_inner());
        if !*alive {
            return dead();
        }
        f()
    }
}

/// Whether a call holds `p` now (tests wait for this to start a call beside it).
#[cfg(test)]
pub(crate) fn held<T>(p: *const T) -> bool {
    let life = live().get(&(p as usize)).map(|(_, life)| life.clone());
    life.is_some_and(|l| matches!(l.try_write(), Err(std::sync::TryLockError::WouldBlock)))
}

/// Whether `p` is a live handle of `kind` (the tests' random walks pass
/// one kind as the other and must know when the library has to refuse it).
#[cfg(test)]
pub(crate) fn is_live<T>(p: *const T, kind: Kind) -> bool {
    live().get(&(p as usize)).is_some_and(|(k, _)| *k == kind)
}
