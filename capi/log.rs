//! gsenc's log for C and Fortran hosts. By default nothing is printed: a
//! library linked into every rank of a job must not print on each. With
//! `GSENC_LOG` set (tracing's filter syntax: `warn`, `info`,
//! `gsenc=debug`), gsenc's events at that level go to the standard error,
//! one line each, after `gsenc[rank R]` (the rank of the latest encoder
//! the process created, so that the ranks of a job can be told apart): why
//! an `auto` step fell back to the CPU, an encoder about to share its
//! rank's only CPU with the solver, relocations at `debug`. Set once per
//! process, at the first call into the library that reads it.

use std::io::{IsTerminal, Write};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Once;

/// The variable that turns the log on.
pub(crate) const LOG_VARIABLE: &str = "GSENC_LOG";

/// The rank each line names.
static RANK: AtomicU32 = AtomicU32::new(0);

/// The rank the log's lines name from now on (an encoder's, at create).
pub(crate) fn set_rank(rank: u32) {
    RANK.store(rank, Ordering::Relaxed);
}

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
        let set = tracing_subscriber::fmt()
            .with_writer(|| RankLine(Vec::new()))
            .with_env_filter(filter)
            .with_ansi(std::io::stderr().is_terminal())
            .try_init()
            .is_ok();
        if let (true, Some(bad)) = (set, bad) {
            tracing::warn!("{bad}");
        }
    });
}

/// One event's line, written to the standard error in one call with its
/// rank in front when dropped (lines of several threads do not mix).
struct RankLine(Vec<u8>);

impl Write for RankLine {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for RankLine {
    fn drop(&mut self) {
        if !self.0.is_empty() {
            let mut line = format!("gsenc[rank {}] ", RANK.load(Ordering::Relaxed)).into_bytes();
            line.extend_from_slice(&self.0);
            let _ = std::io::stderr().lock().write_all(&line);
        }
    }
}
