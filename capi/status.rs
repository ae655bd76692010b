//! Status codes, the thread-local last-error message, and the guard every C
//! entry point runs its body in: it turns errors and panics into a status,
//! so nothing unwinds into C and nothing is printed (unless `GSENC_LOG`
//! asks: `log.rs`, started here at the first call).

use gsenc::error::Error;
use std::cell::RefCell;
use std::os::raw::c_char;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// What a call did. Values are fixed and only ever appended to.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[allow(non_camel_case_types)]
pub enum gsenc_status {
    /// Success.
    Ok = 0,
    /// A required pointer argument was NULL.
    NullPointer = 1,
    /// An argument is out of range (budget, dims, an unknown enum value).
    InvalidArgument = 2,
    /// Input data are unusable: NaN or infinite values, empty arrays.
    InvalidData = 3,
    /// A file is not a gsenc model, or is truncated or corrupted.
    Format = 4,
    /// A model file written by a newer, incompatible gsenc.
    Version = 5,
    /// A file could not be read or written (missing folder, full disk).
    Io = 6,
    /// Functions called in the wrong order (encode with nothing pushed, a
    /// model asked of a field never encoded).
    CallOrder = 7,
    /// A struct's `struct_size` is smaller than this library needs.
    StructSize = 8,
    /// A bug in gsenc (a caught panic); the message says where.
    Internal = 9,
    /// The queue is full and the policy is `GSENC_QUEUE_BUSY`: nothing was
    /// queued; push the step again later.
    Busy = 10,
    /// The queue was full and the policy is `GSENC_QUEUE_SKIP`: this step
    /// was dropped (its job says `GSENC_JOB_SKIPPED`); the next one is
    /// warm-started from the field's last encoded step.
    Skipped = 11,
    /// The work was cancelled (`gsenc_encoder_cancel`).
    Cancelled = 12,
    /// MPI: this gsenc was built without it, MPI is not initialised or
    /// already finalised, its thread level is below `MPI_THREAD_FUNNELED`,
    /// a collective call came from another thread, or the ranks' calls
    /// disagree (different fields, steps or forms pushed; another rank's
    /// data refused). Every rank of the call gets this status together.
    Mpi = 13,
    /// The GPU backend failed: no adapter (with `GSENC_BACKEND_GPU`), a lost
    /// device, or a model or batch beyond the device's limits or memory.
    /// With `GSENC_BACKEND_AUTO` a step falls back to the CPU instead.
    Device = 14,
}

thread_local! {
    static LAST_ERROR: RefCell<String> = const { RefCell::new(String::new()) };
}

/// A failed call: its status and message.
pub(crate) struct Failure(pub gsenc_status, pub String);

impl From<Error> for Failure {
    fn from(e: Error) -> Failure {
        let status = match &e {
            Error::InvalidArgument(_) => gsenc_status::InvalidArgument,
            Error::InvalidData(_) => gsenc_status::InvalidData,
            Error::Format(_) => gsenc_status::Format,
            Error::Version(_) => gsenc_status::Version,
            Error::Io { .. } | Error::Hdf5 { .. } => gsenc_status::Io,
            Error::Cancelled(_) => gsenc_status::Cancelled,
            Error::Mpi(_) => gsenc_status::Mpi,
            Error::Device(_) => gsenc_status::Device,
        };
        Failure(status, e.to_string())
    }
}

pub(crate) fn fail<T>(status: gsenc_status, msg: impl Into<String>) -> Result<T, Failure> {
    Err(Failure(status, msg.into()))
}

/// Runs `body`, records its error (or panic) as the thread's last error and
/// returns its status. Success leaves the last error as it was.
pub(crate) fn guard(body: impl FnOnce() -> Result<(), Failure>) -> gsenc_status {
    crate::log::init();
    let outcome = catch_unwind(AssertUnwindSafe(body)).unwrap_or_else(|panic| {
        let what = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        Err(Failure(gsenc_status::Internal, format!("internal error (please report): {what}")))
    });
    match outcome {
        Ok(()) => gsenc_status::Ok,
        Err(Failure(status, msg)) => {
            set_last_error(msg);
            status
        }
    }
}

/// Records `msg` as the calling thread's last error.
pub(crate) fn set_last_error(msg: String) {
    LAST_ERROR.with(|e| *e.borrow_mut() = msg);
}

/// Copies `text` into the caller's `buf` (at most `len` bytes, always
/// NUL-terminated when `len > 0`, truncated to fit); returns its full
/// length without the NUL.
///
/// # Safety
/// `buf` is NULL or holds `len` writable bytes.
pub(crate) unsafe fn copy_c_string(text: &str, buf: *mut c_char, len: usize) -> usize {
    if !buf.is_null() && len > 0 {
        let n = text.len().min(len - 1);
        // SAFETY: the caller gives `len` writable bytes at `buf`.
        unsafe {
            std::ptr::copy_nonoverlapping(text.as_ptr().cast::<c_char>(), buf, n);
            *buf.add(n) = 0;
        }
    }
    text.len()
}

/// Copies the calling thread's last error message into `buf` (at most
/// `len` bytes, always NUL-terminated when `len > 0`) and returns the
/// message's full length without the NUL, so that `gsenc_last_error(NULL, 0)`
/// sizes the buffer. Empty when no call of this thread has failed.
/// Thread-safe: each thread has its own message.
///
/// # Safety
/// `buf` is NULL or holds `len` writable bytes.
#[no_mangle]
pub unsafe extern "C" fn gsenc_last_error(buf: *mut c_char, len: usize) -> usize {
    catch_unwind(|| {
        LAST_ERROR.with(|e| {
            // SAFETY: the caller gives `len` writable bytes at `buf`, or NULL.
            unsafe { copy_c_string(&e.borrow(), buf, len) }
        })
    })
    .unwrap_or(0)
}

/// The calling thread's last error message, for the crate's tests of
/// calls that fail (through `gsenc_last_error`, as C reads it).
#[cfg(test)]
pub(crate) fn last_error_text() -> String {
    let mut buf = vec![0u8; 512];
    // SAFETY: a writable buffer of its length.
    let n = unsafe { gsenc_last_error(buf.as_mut_ptr().cast(), buf.len()) };
    String::from_utf8_lossy(&buf[..n.min(buf.len() - 1)]).into_owned()
}

/// A static, NUL-terminated name of a status ("GSENC_STATUS_IO"); never
/// freed by the caller. Unknown values give "GSENC_STATUS_UNKNOWN". Thread-safe.
#[no_mangle]
pub extern "C" fn gsenc_status_string(status: i32) -> *const c_char {
    let s: &'static str = match status {
        0 => "GSENC_STATUS_OK\0",
        1 => "GSENC_STATUS_NULL_POINTER\0",
        2 => "GSENC_STATUS_INVALID_ARGUMENT\0",
        3 => "GSENC_STATUS_INVALID_DATA\0",
        4 => "GSENC_STATUS_FORMAT\0",
        5 => "GSENC_STATUS_VERSION\0",
        6 => "GSENC_STATUS_IO\0",
        7 => "GSENC_STATUS_CALL_ORDER\0",
        8 => "GSENC_STATUS_STRUCT_SIZE\0",
        9 => "GSENC_STATUS_INTERNAL\0",
        10 => "GSENC_STATUS_BUSY\0",
        11 => "GSENC_STATUS_SKIPPED\0",
        12 => "GSENC_STATUS_CANCELLED\0",
        13 => "GSENC_STATUS_MPI\0",
        14 => "GSENC_STATUS_DEVICE\0",
        _ => "GSENC_STATUS_UNKNOWN\0",
    };
    s.as_ptr().cast()
}

/// Records `message` as the calling thread's last error, for language
/// bindings (the Fortran module) that refuse an argument before calling
/// into gsenc; C callers have no use for it. NULL records an empty message.
/// Thread-safe: each thread has its own message.
///
/// # Safety
/// `message` is NULL or a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn gsenc_set_last_error(message: *const c_char) {
    let _ = catch_unwind(|| {
        let msg = match message.is_null() {
            true => String::new(),
            // SAFETY: a non-null `message` is NUL-terminated.
            false => unsafe { std::ffi::CStr::from_ptr(message) }.to_string_lossy().into_owned(),
        };
        set_last_error(msg);
    });
}
