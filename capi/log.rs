//! gsenc's log for C and Fortran hosts. By default nothing is printed: a
//! library linked into every rank of a job must not print on each. With
//! `GSENC_LOG` set (tracing's filter syntax: `warn`, `info`,
//! `gsenc=debug`), gsenc's events at that level go to the standard error,
//! one line each: why an `auto` step fell back to the CPU, an encoder about
//! to share its rank's only CPU with the solver, relocations at `debug`.
//! Set once per process, at the first call into the library that reads it.

use std::io::IsTerminal;
use std::sync::Once;

/// The variable that turns the log on.
pub const LOG_VARIABLE: &str = "GSENC_LOG";

/// Starts the log if `GSENC_LOG` asks for one and no other subscriber
/// (a Rust host's own) is set; a second call does nothing.
pub(crate) fn init() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let Some(filter) = std::env::var(LOG_VARIABLE).ok().filter(|v| !v.trim().is_empty()) else { return };
        // A filter that does not parse logs gsenc's warnings, and says so.
        let (filter, bad) = match tracing_subscriber::EnvFilter::try_new(&filter) {
            Ok(f) => (f, None),
            Err(e) => (tracing_subscriber::EnvFilter::new("gsenc=warn"), Some(format!("{LOG_VARIABLE}={filter:?} is not a filter ({e}); logging warnings"))),
        };
        let set = tracing_subscriber::fmt().with_writer(std::io::stderr).with_env_filter(filter).with_ansi(std::io::stderr().is_terminal()).try_init().is_ok();
        if let (true, Some(bad)) = (set, bad) {
            tracing::warn!("{bad}");
        }
    });
}
