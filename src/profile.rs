//! Task timings for the thread-scaling model (`benches/scaling_model.sh`).
//!
//! Built with the `task-profile` feature, an encode on one thread records
//! how long each task of each parallel pass takes and how long each serial
//! section takes, and writes them to the file that `GSENC_TASK_PROFILE`
//! names when its refinement loop ends. `benches/scaling_model.py` then
//! schedules those tasks on p workers to predict an iteration's time at p
//! threads: what keeps a pass from spreading over 16 cores (a serial
//! section, too few tasks, one long task) shows up on a 2-core machine.
//! Without the feature every function here is only the call it wraps.
//!
//! The file has one line per record, `pass<TAB>seconds`: a task of a
//! parallel pass (consecutive tasks of one pass are one run of it), a serial
//! section (negative seconds), or the end of an iteration (an empty pass).

#[cfg(feature = "task-profile")]
mod imp {
    use parking_lot::Mutex;
    use std::time::Instant;

    static LOG: Mutex<Vec<(&'static str, f64)>> = Mutex::new(Vec::new());

    fn record(pass: &'static str, seconds: f64) {
        LOG.lock().push((pass, seconds));
    }

    pub fn task<R>(pass: &'static str, f: impl FnOnce() -> R) -> R {
        let t = Instant::now();
        let r = f();
        record(pass, t.elapsed().as_secs_f64());
        r
    }

    pub fn serial<R>(pass: &'static str, f: impl FnOnce() -> R) -> R {
        let t = Instant::now();
        let r = f();
        record(pass, -t.elapsed().as_secs_f64());
        r
    }

    pub fn even<R>(pass: &'static str, tasks: usize, f: impl FnOnce() -> R) -> R {
        let t = Instant::now();
        let r = f();
        let each = t.elapsed().as_secs_f64() / tasks.max(1) as f64;
        for _ in 0..tasks.max(1) {
            record(pass, each);
        }
        r
    }

    pub fn iteration_end() {
        record("", 0.0);
    }

    pub fn write() -> std::io::Result<()> {
        let log = std::mem::take(&mut *LOG.lock());
        let Some(path) = std::env::var_os("GSENC_TASK_PROFILE") else { return Ok(()) };
        let text: String = log.iter().map(|(pass, s)| format!("{pass}\t{s:.9}\n")).collect();
        std::fs::write(path, text)
    }
}

#[cfg(not(feature = "task-profile"))]
mod imp {
    #[inline(always)]
    pub fn task<R>(_: &'static str, f: impl FnOnce() -> R) -> R {
        f()
    }

    #[inline(always)]
    pub fn serial<R>(_: &'static str, f: impl FnOnce() -> R) -> R {
        f()
    }

    #[inline(always)]
    pub fn even<R>(_: &'static str, _: usize, f: impl FnOnce() -> R) -> R {
        f()
    }

    #[inline(always)]
    pub fn iteration_end() {}

    #[inline(always)]
    pub fn write() -> std::io::Result<()> {
        Ok(())
    }
}

/// Runs one task of the parallel pass `pass` and records its time.
pub use imp::task;
/// Runs a serial section and records its time.
pub use imp::serial;
/// Runs a whole parallel pass of `tasks` equal tasks (where timing each
/// would cost more than the task) and records its time split among them.
pub use imp::even;
/// Marks the end of a refinement iteration.
pub use imp::iteration_end;
/// Writes the records to `GSENC_TASK_PROFILE` (when set) and forgets them.
pub use imp::write;
