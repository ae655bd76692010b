//! The handles this library gave out and has not freed. Every entry point
//! looks its handle up before touching it, so that a destroyed, doubly
//! destroyed or foreign pointer (a model passed as an encoder, a Fortran
//! `type(c_ptr)` never set) gets `GSENC_STATUS_INVALID_ARGUMENT` instead of
//! undefined behaviour. An address reused by a newer handle of the same kind
//! cannot be told apart; that is the limit of "where detectable".

use crate::status::{fail, gsenc_status, Failure};
use std::collections::BTreeMap;
use std::sync::Mutex;

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
}

static LIVE: Mutex<BTreeMap<usize, Kind>> = Mutex::new(BTreeMap::new());

fn live() -> std::sync::MutexGuard<'static, BTreeMap<usize, Kind>> {
    // A panic while the lock was held left the map itself consistent.
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

/// Records a handle just made by `Box::into_raw`.
pub(crate) fn register<T>(p: *const T, kind: Kind) {
    live().insert(p as usize, kind);
}

/// Forgets a handle about to be freed; false when it was not live (then it
/// must not be freed).
pub(crate) fn release<T>(p: *const T, kind: Kind) -> bool {
    let mut map = live();
    if map.get(&(p as usize)) == Some(&kind) {
        map.remove(&(p as usize));
        true
    } else {
        false
    }
}

/// Fails unless `p` is a live handle of `kind`.
pub(crate) fn check<T>(p: *const T, kind: Kind, what: &str) -> Result<(), Failure> {
    if p.is_null() {
        return fail(gsenc_status::NullPointer, format!("{what}: {} is NULL", kind.name()));
    }
    match live().get(&(p as usize)) {
        Some(&k) if k == kind => Ok(()),
        Some(&k) => fail(gsenc_status::InvalidArgument, format!("{what}: the handle is a {}, not a {}", k.name(), kind.name())),
        None => fail(
            gsenc_status::InvalidArgument,
            format!("{what}: not a live {} (destroyed already, or never created by gsenc)", kind.name()),
        ),
    }
}
