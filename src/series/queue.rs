//! The background queue: the solver hands a step over and goes on; a worker
//! thread encodes it beside the solver.
//!
//! `push` takes data the caller has already copied (a [`StepData`]), checks
//! it against the queue's memory budget and its policy when full, and
//! returns. One worker thread takes jobs in push order (so the steps of a
//! field arrive in order, as warm starts need) and runs each on the queue's
//! own rayon pool (never the global one a host may use): deposit, seeding or
//! warm start, refinement, then the [`ModelSink`], which stores the model.
//! The worker owns the backend, opened once at `new`: with a GPU backend the
//! pool has one thread, since the device does the heavy work.
//! A sink may instead leave models to the caller (`take_finished`), for
//! stores such as HDF5 that must be written from the caller's thread.
//!
//! Every job has a [`JobState`] the caller can poll. A failed job records
//! its error and the worker goes on with the next; `wait` reports each
//! failure once. Of the jobs that are final, the queue keeps the states of
//! the last [`QueueConfig::kept_states`] (and every failure `wait` has not
//! reported), so that a run of any length holds bounded memory and `wait`
//! scans a bounded map. A series restarted from a checkpoint is taken up
//! by `resume`, whose model reaches the worker through the same channel,
//! ahead of the field's pushes. Nothing here does I/O: sinks are the
//! caller's.

use crate::backend::select::BackendChoice;
use crate::backend::Backend;
use crate::encode::Cancel;
use crate::error::{Error, Result};
use crate::field::ValueRange;
use crate::format::check_field_name;
use crate::input::StepData;
use crate::model::Model;
use crate::series::placement::ThreadPlacement;
use crate::series::{SeriesConfig, SeriesEncoder};
use crossbeam_channel::{unbounded, Receiver, Sender};
use parking_lot::{Condvar, Mutex};
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::thread::JoinHandle;

/// What `push` does when the queue's memory budget is taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WhenFull {
    /// Wait until enough queued data has been encoded.
    Block,
    /// Drop this step (it is reported as skipped); the field's next step
    /// warm-starts from the last one encoded.
    Skip,
    /// Queue nothing and say so; the caller may push again later.
    Busy,
}

#[derive(Clone, Debug)]
pub struct QueueConfig {
    pub series: SeriesConfig,
    /// Bytes of pushed data the queue may hold, queued and running jobs
    /// together. A job larger than the whole budget is still taken when the
    /// queue is empty, so that no step can never be encoded.
    pub max_bytes: usize,
    pub when_full: WhenFull,
    /// Threads of the encode's own pool (one when the backend is a GPU);
    /// 0: one per CPU of the placement, or, where it names none, per CPU
    /// the creating thread may run on.
    pub threads: usize,
    /// Which backend the worker encodes with.
    pub backend: BackendChoice,
    /// The CPUs and priority of the worker and its pool's threads
    /// (`placement.rs`); `GSENC_ENCODER_CPUS` and `GSENC_ENCODER_PRIORITY`
    /// override it.
    pub placement: ThreadPlacement,
    /// States of final jobs kept for `poll`, the most recently final ones
    /// (at least 1; the C API's encoders keep [`KEPT_STATES`]).
    /// Older ones are dropped, but for failures `wait` has not reported
    /// yet.
    pub kept_states: usize,
}

/// Final job states the C API's queues keep: about 200 bytes each with
/// their place in the order, so under a megabyte, where keeping every
/// state grew the queue by about 160 bytes a step for as long as a run
/// lasted (docs/BENCHMARKS.md "A long series' job states").
pub const KEPT_STATES: usize = 4096;

/// One field of one step.
pub struct Job {
    pub field: String,
    pub step: u64,
    /// Simulation time, when known.
    pub time: Option<f64>,
    pub data: StepData,
    /// The value range of the field's series, when it was agreed elsewhere
    /// (across MPI ranks) rather than taken from this first step's data.
    pub range: Option<ValueRange>,
}

/// Where a job is.
#[derive(Clone, Debug)]
pub enum JobState {
    Queued,
    /// Being encoded: `iteration` of `iterations` (0 of 0 while depositing
    /// and seeding).
    Running { iteration: usize, iterations: usize },
    /// Encoded and stored by the sink at `location`.
    Written { psnr: f64, location: String },
    /// Encoded; the model waits in `take_finished` for the caller to store.
    Encoded { psnr: f64 },
    /// The encode failed (the field's series is as it was), or the store
    /// did (the step stays in the series: the next one warm-starts from it).
    Failed(Arc<Error>),
    /// Dropped by the `Skip` policy.
    Skipped,
    /// Dropped by `cancel`.
    Cancelled,
}

impl JobState {
    /// Whether the job will not change any more.
    pub fn is_final(&self) -> bool {
        !matches!(self, JobState::Queued | JobState::Running { .. })
    }
}

/// What `push` did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pushed {
    Queued,
    /// The queue was full and the policy is `Skip`: the step was dropped.
    Skipped,
    /// The queue was full and the policy is `Busy`: nothing was queued.
    Busy,
}

/// Stores finished models, on the worker thread.
pub trait ModelSink: Send {
    /// Stores `model`; returns where it went. `None`: leave the model to the
    /// caller's `take_finished` (a store that must be written from the
    /// caller's thread).
    fn store(&mut self, model: &Model) -> Result<Option<String>>;
}

/// A sink that stores nothing: every model goes to `take_finished`.
pub struct CallerStores;

impl ModelSink for CallerStores {
    fn store(&mut self, _: &Model) -> Result<Option<String>> {
        Ok(None)
    }
}

type Key = (String, u64);

#[derive(Default)]
struct State {
    jobs: BTreeMap<Key, JobState>,
    /// Jobs pushed and not final, and the bytes they hold.
    in_flight: usize,
    bytes: usize,
    /// The last step pushed per field (steps must increase).
    last_pushed: BTreeMap<String, u64>,
    /// The last model encoded per field, with its PSNR as stored.
    last: BTreeMap<String, (Model, f64)>,
    /// Models a `CallerStores`-style sink left to the caller.
    finished: Vec<Model>,
    /// Failures not yet reported by `wait`.
    unreported: Vec<Key>,
    /// Grid buffers of finished jobs, for the next pushes to copy into.
    recycled: Vec<Vec<f32>>,
    /// Jobs in the order they became final, each once, for dropping the
    /// oldest states beyond `kept` ([`QueueConfig::kept_states`]).
    settled: VecDeque<Key>,
    kept: usize,
    /// Jobs past their turn whose failure `wait` has not reported: dropped
    /// once it has.
    held: Vec<Key>,
    /// Per field, the last step whose state was dropped.
    dropped: BTreeMap<String, u64>,
    /// The worker has stopped ([`Stopping`]): nothing more is queued.
    stopped: bool,
}

impl State {
    /// Whether `bytes` more fit in `max_bytes` (a job is always taken when
    /// nothing is in flight, so that no step can never be encoded).
    fn fits(&self, bytes: usize, max_bytes: usize) -> bool {
        self.in_flight == 0 || self.bytes + bytes <= max_bytes
    }

    /// The kept grid buffer with room for `len` values, if any.
    fn kept_for(&self, len: usize) -> Option<usize> {
        self.recycled.iter().position(|b| b.capacity() >= len)
    }

    /// Refuses to resume `field` once a step of it was pushed or resumed.
    fn not_begun(&self, field: &str) -> Result<()> {
        match self.last_pushed.get(field) {
            Some(last) => Err(Error::arg(format!("field '{field}' has begun on this encoder already (its last step {last}); resume a field before its first push"))),
            None => Ok(()),
        }
    }

    /// Records job `key`'s final `state`, then drops the oldest final
    /// states beyond `kept`, holding a failure `wait` has not reported.
    fn settle(&mut self, key: Key, state: JobState) {
        debug_assert!(state.is_final());
        self.jobs.insert(key.clone(), state);
        self.settled.push_back(key);
        while self.settled.len() > self.kept {
            let Some(old) = self.settled.pop_front() else { break };
            if self.unreported.contains(&old) {
                self.held.push(old);
            } else {
                self.drop_state(old);
            }
        }
    }

    fn drop_state(&mut self, key: Key) {
        self.jobs.remove(&key);
        let last = self.dropped.entry(key.0).or_insert(key.1);
        *last = (*last).max(key.1);
    }

    /// `wait` has reported `key`'s failure: a state held past its turn for
    /// that goes now.
    fn reported(&mut self, key: &Key) {
        if let Some(i) = self.held.iter().position(|k| k == key) {
            let key = self.held.swap_remove(i);
            self.drop_state(key);
        }
    }
}

/// Buffers kept for reuse (beyond the queue's budget: at most this many
/// grids): enough for a push while one job runs and one waits.
const RECYCLED_BUFFERS: usize = 2;

/// An empty buffer with room for `len` values, every page of it written
/// once, so that a push that copies into it takes no page fault.
fn touched_buffer(len: usize) -> Vec<f32> {
    let mut b = crate::memory::with_pages(len);
    b.resize(len, 0.0);
    b.clear();
    b
}

struct Shared {
    state: Mutex<State>,
    /// Signalled whenever a job changes state or bytes are released.
    changed: Condvar,
    cancel: Cancel,
}

/// The background encoder of a set of fields' time series.
pub struct BackgroundEncoder {
    shared: Arc<Shared>,
    cfg: QueueConfig,
    jobs: Option<Sender<Work>>,
    worker: Option<JoinHandle<()>>,
    /// The process that started the worker (see [`Self::started_elsewhere`]).
    process: u32,
}

/// What the worker takes, in the order it was sent.
enum Work {
    Encode(Job),
    /// A field's series continues from this model (`resume`).
    Resume(Model),
    /// The worker panics outside a job's guard, as only a bug in the
    /// queue's own bookkeeping could make it: the tests' way to stop it.
    #[cfg(test)]
    Panic,
}

/// What the queue answers once its worker has stopped.
fn thread_stopped() -> Error {
    Error::arg("the encode thread has stopped")
}

/// Owns the worker's end of the channel. However the worker stops (a
/// panic outside a job's guard included), it drops the channel, so that
/// nothing more is sent, then fails every job not final (they will never be
/// encoded), frees their room and wakes `wait` and a blocked `push`, which
/// would otherwise wait for ever. As the queue's drop ends the worker no
/// job is left, and this changes nothing but `stopped`.
struct Stopping {
    shared: Arc<Shared>,
    work: Option<Receiver<Work>>,
}

impl Drop for Stopping {
    fn drop(&mut self) {
        drop(self.work.take());
        let mut st = self.shared.state.lock();
        st.stopped = true;
        let left: Vec<Key> = st.jobs.iter().filter(|(_, s)| !s.is_final()).map(|(k, _)| k.clone()).collect();
        for key in left {
            st.unreported.push(key.clone());
            st.settle(key, JobState::Failed(Arc::new(thread_stopped())));
        }
        st.in_flight = 0;
        st.bytes = 0;
        self.shared.changed.notify_all();
    }
}

impl BackgroundEncoder {
    /// Starts the worker and its pool of `cfg.threads` threads.
    pub fn new(cfg: QueueConfig, sink: Box<dyn ModelSink>) -> Result<BackgroundEncoder> {
        let placement = cfg.placement.clone().with_env()?;
        placement.check()?;
        let threads = match cfg.threads {
            0 => placement.cpus.as_ref().map_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()), Vec::len),
            t => t,
        };
        crate::threads::check_threads(threads)?;
        if cfg.max_bytes == 0 {
            return Err(Error::arg("the queue's memory budget must be positive"));
        }
        if cfg.kept_states == 0 {
            return Err(Error::arg("the queue must keep at least one final job state"));
        }
        let cancel = Cancel::default();
        let mut series_cfg = cfg.series.clone();
        series_cfg.encode.cancel = Some(cancel.clone());
        let series = SeriesEncoder::new(series_cfg)?;
        if let Some(warning) = placement.shared_cpu_warning() {
            tracing::warn!("{warning}");
        }
        let backend = cfg.backend.open()?;
        let threads = if backend.on_device() { 1 } else { threads };
        tracing::info!(backend = %backend.name(), threads, ?placement, "background encoder starts");
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("gsenc-encode-{i}"))
            .build()
            .map_err(|e| Error::arg(format!("cannot start {threads} encode threads: {e}")))?;
        // Every thread of the pool places itself (a broadcast runs on each
        // once), and so does the worker before it takes a job.
        pool.broadcast(|_| placement.apply()).into_iter().collect::<Result<()>>()?;
        let shared = Arc::new(Shared { state: Mutex::new(State { kept: cfg.kept_states, ..State::default() }), changed: Condvar::new(), cancel });
        let (tx, rx) = unbounded();
        let (placed_tx, placed) = crossbeam_channel::bounded(1);
        let worker = Worker { shared: shared.clone(), series, pool, sink, backend };
        let handle = std::thread::Builder::new()
            .name("gsenc-queue".into())
            .spawn(move || {
                let r = placement.apply();
                let ok = r.is_ok();
                let _ = placed_tx.send(r);
                if ok {
                    worker.run(rx)
                }
            })
            .map_err(|e| Error::arg(format!("cannot start the encode thread: {e}")))?;
        if let Err(e) = placed.recv().unwrap_or_else(|_| Err(Error::arg("the encode thread stopped as it started"))) {
            let _ = handle.join();
            return Err(e);
        }
        Ok(BackgroundEncoder { shared, cfg, jobs: Some(tx), worker: Some(handle), process: std::process::id() })
    }

    pub fn config(&self) -> &QueueConfig {
        &self.cfg
    }

    /// Why this encoder cannot work here, in a process forked from the one
    /// that started it: a child has only the thread that forked, so the
    /// worker and its pool do not run there, and a push would never be
    /// encoded, a `wait` never return (as they did before this check).
    /// `None` in the process that started it. `push`, `wait`, `cancel`,
    /// `resume` and `reserve` refuse such a child with this message;
    /// dropped there, the encoder frees nothing (see `Drop`).
    pub fn started_elsewhere(&self) -> Option<String> {
        let here = std::process::id();
        (here != self.process).then(|| {
            format!(
                "this encoder was started in process {} and this is process {here}, forked from it since: \
                 its encode thread did not follow the fork; start an encoder in this process",
                self.process
            )
        })
    }

    fn check_process(&self) -> Result<()> {
        self.started_elsewhere().map_or(Ok(()), |why| Err(Error::arg(why)))
    }

    /// Queues `job` (its data already copied), or applies the full-queue
    /// policy. Refuses at once what cannot be encoded: non-finite values,
    /// a particle or cell the encode would refuse (a smoothing length or
    /// size not positive, a negative mass), a step that does not follow
    /// the field's last pushed one.
    pub fn push(&self, job: Job) -> Result<Pushed> {
        self.check(&job)?;
        self.push_checked(job, true)
    }

    /// `push` of a job whose values the caller has found finite already:
    /// the C API checks a grid row by row as it copies it, while each row
    /// is in cache, where a check of the whole copy afterwards read it back
    /// from memory (1 ms of a 3.5 ms push of 128^3 on the 2-core VM). The
    /// rest of [`BackgroundEncoder::check`] still refuses what it refuses;
    /// the caller answers for the values (use `push` for data it has not
    /// checked).
    pub fn push_finite(&self, job: Job) -> Result<Pushed> {
        check_field_name(&job.field)?;
        self.check_order(&job)?;
        self.push_checked(job, true)
    }

    /// What `push` refuses before it queues anything: a bad field name,
    /// non-finite values or items the encode would refuse
    /// ([`StepData::check_each`]), a step that does not follow the field's
    /// last.
    pub fn check(&self, job: &Job) -> Result<()> {
        check_field_name(&job.field)?;
        job.data.check_each()?;
        self.check_order(job)
    }

    /// A step that does not follow the field's last is refused.
    fn check_order(&self, job: &Job) -> Result<()> {
        if let Some(&last) = self.shared.state.lock().last_pushed.get(&job.field) {
            if job.step <= last {
                return Err(Error::arg(format!(
                    "field '{}': step {} does not follow step {last} (steps of a field must increase)",
                    job.field, job.step
                )));
            }
        }
        Ok(())
    }

    /// Whether a job of `bytes` would be queued now without waiting.
    pub fn has_room(&self, bytes: usize) -> bool {
        self.shared.state.lock().fits(bytes, self.cfg.max_bytes)
    }

    /// `push` of a job that passed [`BackgroundEncoder::check`]. With
    /// `others_have_room` false the queue counts as full whatever its own
    /// room (the ranks of an MPI run decide together, so that all of them
    /// queue, skip or refuse the same step); `Block` then waits for its own.
    pub fn push_checked(&self, job: Job, others_have_room: bool) -> Result<Pushed> {
        self.check_process()?;
        let bytes = job.data.bytes();
        let key = (job.field.clone(), job.step);
        let mut st = self.shared.state.lock();
        let fits = |st: &State| st.fits(bytes, self.cfg.max_bytes);
        if st.stopped {
            return Err(thread_stopped());
        }
        if !fits(&st) || !others_have_room {
            match self.cfg.when_full {
                WhenFull::Block => {
                    while !fits(&st) {
                        self.shared.changed.wait(&mut st);
                    }
                    // Woken by a worker that stopped (which frees its room)?
                    if st.stopped {
                        return Err(thread_stopped());
                    }
                }
                WhenFull::Skip => {
                    st.last_pushed.insert(job.field.clone(), job.step);
                    st.settle(key, JobState::Skipped);
                    return Ok(Pushed::Skipped);
                }
                WhenFull::Busy => return Ok(Pushed::Busy),
            }
        }
        st.last_pushed.insert(job.field.clone(), job.step);
        st.jobs.insert(key.clone(), JobState::Queued);
        st.in_flight += 1;
        st.bytes += bytes;
        drop(st);
        let sent = self.jobs.as_ref().is_some_and(|tx| tx.send(Work::Encode(job)).is_ok());
        if !sent {
            // The worker stopped since the check above, and `Stopping`
            // fails this job with the others (once it has the lock, which
            // it takes after dropping the channel): this call reports it,
            // `wait` not again.
            let mut st = self.shared.state.lock();
            while !st.stopped {
                self.shared.changed.wait(&mut st);
            }
            st.unreported.retain(|k| k != &key);
            st.reported(&key);
            return Err(thread_stopped());
        }
        Ok(Pushed::Queued)
    }

    /// The state of `field`'s step `step`, if it was pushed and its state
    /// is kept (see [`QueueConfig::kept_states`] and [`Self::dropped`]).
    pub fn poll(&self, field: &str, step: u64) -> Option<JobState> {
        self.shared.state.lock().jobs.get(&(field.to_owned(), step)).cloned()
    }

    /// Whether `poll` finds no state for `field`'s step `step` because the
    /// queue has dropped it (a step of the field up to one whose state was
    /// dropped, and none kept): it was final before the last
    /// [`QueueConfig::kept_states`] jobs that became final, or was never
    /// pushed between steps that were.
    pub fn dropped(&self, field: &str, step: u64) -> bool {
        let st = self.shared.state.lock();
        !st.jobs.contains_key(&(field.to_owned(), step)) && st.dropped.get(field).is_some_and(|&last| step <= last)
    }

    /// What [`Self::resume`] refuses: a model without a field name or
    /// primitives, another rank's, one whose value range is not the
    /// configured one (a fixed range, or a transform), a field that has
    /// begun already, or any model once the encode thread has stopped (so
    /// that the ranks of an MPI run, which check first, resume together).
    pub fn check_resume(&self, model: &Model) -> Result<()> {
        self.check_process()?;
        self.cfg.series.check_resumable(model)?;
        let field = &model.meta.field;
        let st = self.shared.state.lock();
        st.not_begun(field)?;
        if st.stopped {
            return Err(thread_stopped());
        }
        Ok(())
    }

    /// Continues `model`'s field from it, the last step stored before the
    /// run stopped (a restart from a checkpoint): the field's next push
    /// must come after its step, and is warm-started from it on its lattice
    /// and value range, as if the series had not stopped (bit for bit when
    /// the model was stored as float32). `last` gives it until a step is
    /// encoded. Refuses what [`Self::check_resume`] refuses.
    pub fn resume(&self, model: Model) -> Result<()> {
        self.check_resume(&model)?;
        let (field, step) = (model.meta.field.clone(), model.meta.step);
        let psnr = model.meta.encode_psnr.unwrap_or(f64::NAN);
        let mut st = self.shared.state.lock();
        // Pushed from another thread since the check?
        st.not_begun(&field)?;
        // Sent under the lock, so that no push of the field can pass it.
        let sent = self.jobs.as_ref().is_some_and(|tx| tx.send(Work::Resume(model.clone())).is_ok());
        if !sent {
            return Err(thread_stopped());
        }
        st.last_pushed.insert(field.clone(), step);
        st.last.insert(field, (model, psnr));
        Ok(())
    }

    /// Blocks until every job (of `field`, or of every field) is final.
    /// Returns the first failure not reported before, naming its field and
    /// step; each failure is reported once.
    pub fn wait(&self, field: Option<&str>) -> Result<()> {
        self.check_process()?;
        let mut st = self.shared.state.lock();
        let pending = |st: &State| {
            st.jobs.iter().any(|((f, _), s)| field.is_none_or(|want| want == f) && !s.is_final())
        };
        while pending(&st) {
            self.shared.changed.wait(&mut st);
        }
        let Some(i) = st.unreported.iter().position(|(f, _)| field.is_none_or(|want| want == f)) else {
            return Ok(());
        };
        let key = st.unreported.remove(i);
        let failed = match st.jobs.get(&key) {
            Some(JobState::Failed(e)) => Err(e.in_context(&format!("field '{}' step {}", key.0, key.1))),
            _ => Ok(()),
        };
        st.reported(&key);
        failed
    }

    /// Drops every queued job and stops the running one at its next
    /// iteration; returns when the worker is idle. Their states become
    /// `Cancelled`; the fields' series stay at their last encoded steps.
    pub fn cancel(&self) -> Result<()> {
        self.check_process()?;
        self.shared.cancel.set(true);
        let mut st = self.shared.state.lock();
        while st.in_flight > 0 {
            self.shared.changed.wait(&mut st);
        }
        self.shared.cancel.set(false);
        Ok(())
    }

    /// The last model of `field` and its PSNR as stored.
    pub fn last(&self, field: &str) -> Option<(Model, f64)> {
        self.shared.state.lock().last.get(field).cloned()
    }

    /// Models the sink left to the caller, oldest first.
    pub fn take_finished(&self) -> Vec<Model> {
        std::mem::take(&mut self.shared.state.lock().finished)
    }

    /// Records what the caller did with a model from `take_finished`. The
    /// job keeps its place among the final states (it became final when it
    /// was encoded); where its state was dropped already, a failure is still
    /// recorded, for `wait` to report, and a success is not.
    pub fn set_stored(&self, field: &str, step: u64, stored: Result<String>) {
        let mut st = self.shared.state.lock();
        let key = (field.to_owned(), step);
        let kept = st.jobs.get(&key).map(|s| match s {
            JobState::Encoded { psnr } => *psnr,
            _ => f64::NAN,
        });
        match (stored, kept) {
            (Ok(location), Some(psnr)) => {
                st.jobs.insert(key, JobState::Written { psnr, location });
            }
            (Ok(_), None) => {}
            (Err(e), kept) => {
                st.unreported.push(key.clone());
                st.jobs.insert(key.clone(), JobState::Failed(Arc::new(e)));
                if kept.is_none() {
                    // Past its turn already: dropped once reported.
                    st.held.push(key);
                }
            }
        }
        self.shared.changed.notify_all();
    }

    /// An empty buffer with room for `len` values, recycled from a finished
    /// grid job, when one is large enough (a fresh 8 MB allocation costs the
    /// push its page faults, a third of a 128^3 push).
    pub fn recycled_buffer(&self, len: usize) -> Option<Vec<f32>> {
        let mut st = self.shared.state.lock();
        let i = st.kept_for(len)?;
        Some(st.recycled.swap_remove(i))
    }

    /// Readies a buffer for the next grid push of up to `len` values, its
    /// pages touched now: the first push of a series then copies into it as
    /// later pushes copy into buffers recycled from finished steps, instead
    /// of paying for a new buffer's page faults (on the H200 machine the
    /// first push of 128^3 took 7.4 ms, later ones 3.9–4.3 ms). Nothing to
    /// do when a kept buffer is large enough; otherwise a kept buffer too
    /// small for it makes room. The memory must fit (`memory::check_fits`).
    pub fn reserve(&self, len: usize) -> Result<()> {
        self.check_process()?;
        if len == 0 || self.shared.state.lock().kept_for(len).is_some() {
            return Ok(());
        }
        let bytes = (len as u64).checked_mul(4).filter(|&b| b <= isize::MAX as u64);
        let bytes = bytes.ok_or_else(|| Error::arg(format!("reserving a grid push's copy: {len} values do not fit in memory")))?;
        crate::memory::check_fits("reserving a grid push's copy", bytes)?;
        let buffer = touched_buffer(len);
        let mut st = self.shared.state.lock();
        if st.kept_for(len).is_some() {
            return Ok(());
        }
        if st.recycled.len() >= RECYCLED_BUFFERS {
            if let Some(smallest) = (0..st.recycled.len()).min_by_key(|&i| st.recycled[i].capacity()) {
                st.recycled.swap_remove(smallest);
            }
        }
        st.recycled.push(buffer);
        Ok(())
    }

    /// Bytes of pushed data the queue holds now.
    pub fn queued_bytes(&self) -> usize {
        self.shared.state.lock().bytes
    }
}

impl Drop for BackgroundEncoder {
    /// Drains: every queued job is encoded before the worker stops (call
    /// `cancel` first to drop them instead). In a process forked from the
    /// one that started it, leaves everything as it is: the worker is not
    /// there to be joined (a join would wait for ever), and its channel and
    /// state may have been copied in the middle of a change.
    fn drop(&mut self) {
        if self.started_elsewhere().is_some() {
            std::mem::forget(self.jobs.take());
            std::mem::forget(self.worker.take());
            return;
        }
        drop(self.jobs.take());
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
    }
}

/// The worker thread's side.
struct Worker {
    shared: Arc<Shared>,
    series: SeriesEncoder,
    pool: rayon::ThreadPool,
    sink: Box<dyn ModelSink>,
    backend: Box<dyn Backend>,
}

impl Worker {
    fn run(mut self, work: Receiver<Work>) {
        let stopping = Stopping { shared: self.shared.clone(), work: Some(work) };
        let work = stopping.work.as_ref().expect("the channel is dropped only with `stopping`");
        while let Ok(work) = work.recv() {
            let job = match work {
                Work::Encode(job) => job,
                Work::Resume(model) => {
                    self.resume(model);
                    continue;
                }
                #[cfg(test)]
                Work::Panic => panic!("the test stops the worker"),
            };
            self.prepare_spare(&job.data);
            let key = (job.field.clone(), job.step);
            let bytes = job.data.bytes();
            let state = if self.shared.cancel.is_set() {
                JobState::Cancelled
            } else {
                self.set(&key, JobState::Running { iteration: 0, iterations: 0 });
                // A panic in one job fails that job, not the queue.
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| self.encode(&job)))
                    .unwrap_or_else(|_| Err(Error::arg("internal error: the encode panicked (please report)")))
                    .unwrap_or_else(|e| match e {
                        Error::Cancelled(_) => JobState::Cancelled,
                        e => JobState::Failed(Arc::new(e)),
                    })
            };
            let mut st = self.shared.state.lock();
            if let StepData::Grid { grid, .. } = job.data {
                if st.recycled.len() < RECYCLED_BUFFERS {
                    st.recycled.push(grid.values);
                }
            }
            if matches!(state, JobState::Failed(_)) {
                st.unreported.push(key.clone());
            }
            st.settle(key, state);
            st.in_flight -= 1;
            st.bytes -= bytes;
            self.shared.changed.notify_all();
        }
    }

    /// Leaves a buffer for the next grid push while this job holds its
    /// own, its pages already faulted in here, on the encoder's thread:
    /// otherwise a push that arrives while the queue is busy pays for a
    /// fresh allocation (a third of a 128^3 push).
    fn prepare_spare(&self, data: &StepData) {
        let StepData::Grid { grid, .. } = data else { return };
        let len = grid.values.len();
        if self.shared.state.lock().kept_for(len).is_some() {
            return;
        }
        let spare = touched_buffer(len);
        let mut st = self.shared.state.lock();
        if st.recycled.len() < RECYCLED_BUFFERS {
            st.recycled.push(spare);
        }
    }

    /// Continues a field's series from `model` (`BackgroundEncoder::resume`
    /// checked it). Should the series refuse it all the same, the failure
    /// is the model's step's, for `wait` to report.
    fn resume(&mut self, model: Model) {
        let key = (model.meta.field.clone(), model.meta.step);
        if let Err(e) = self.series.resume(model) {
            let mut st = self.shared.state.lock();
            st.unreported.push(key.clone());
            st.settle(key, JobState::Failed(Arc::new(e)));
            self.shared.changed.notify_all();
        }
    }

    fn set(&self, key: &Key, state: JobState) {
        self.shared.state.lock().jobs.insert(key.clone(), state);
        self.shared.changed.notify_all();
    }

    /// Encodes one job on the pool and stores its model.
    fn encode(&mut self, job: &Job) -> Result<JobState> {
        let (series, shared, backend) = (&mut self.series, &self.shared, self.backend.as_mut());
        let key = (job.field.clone(), job.step);
        let (model, psnr) = self.pool.install(|| -> Result<(Model, f64)> {
            if let Some(range) = job.range {
                series.set_range(&job.field, range);
            }
            let r = job.data.with_input(|input| {
                series.encode_step(&job.field, job.step, job.time, input, &mut *backend, &mut |p| {
                    // Progress is cheap to record: one lock per iteration.
                    let running = JobState::Running { iteration: p.iteration, iterations: p.iterations };
                    shared.state.lock().jobs.insert(key.clone(), running);
                })
            })?;
            Ok((r.encoded.model, r.encoded.psnr))
        })?;
        // On the pool too: a sink may compute (a preview's decode and
        // rendering), and it must use the encoder's threads, not the solver's.
        let (pool, sink) = (&self.pool, &mut self.sink);
        let state = pool.install(|| sink.store(&model)).map(|stored| match stored {
            Some(location) => JobState::Written { psnr, location },
            None => {
                self.shared.state.lock().finished.push(model.clone());
                JobState::Encoded { psnr }
            }
        });
        // The field's last model also when the store failed (a full disk):
        // the series goes on from it, and the caller can still write it
        // elsewhere (`gsenc_encoder_write_model`).
        self.shared.state.lock().last.insert(job.field.clone(), (model, psnr));
        state
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encode::{EncodeConfig, Schedule, WarmStart};
    use crate::field::{Grid, IndexFrame, Transform};
    use crate::series::SeriesRange;
    use std::time::Duration;

    /// One unit of the queue's budget: a grid of field "a".
    const SMALL: [usize; 3] = [12, 10, 8];
    /// Two units: a grid of field "c".
    const LARGE: [usize; 3] = [24, 10, 8];

    fn job(field: &str, step: u64, dims: [usize; 3]) -> Job {
        let at = |i: usize| [i % dims[0], i / dims[0] % dims[1], i / (dims[0] * dims[1])];
        let values = (0..dims.iter().product::<usize>())
            .map(|i| {
                let [x, y, z] = at(i).map(|c| c as f32);
                (-(x - 5.0 - step as f32).powi(2) / 8.0 - (y - 4.0).powi(2) / 6.0 - (z - 3.0).powi(2) / 4.0).exp()
            })
            .collect();
        let grid = Grid::new(dims, values).unwrap();
        Job { field: field.into(), step, time: None, data: StepData::Grid { grid, frame: IndexFrame { dims, bmin: [0.0; 3], gamma: 1.0 } }, range: None }
    }

    fn config() -> QueueConfig {
        let mut c = EncodeConfig::new(20, Schedule::Short);
        c.iterations = Some(10);
        c.points = Some(128);
        let range = SeriesRange::Fixed(ValueRange::new(0.0, 1.0, Transform::Linear).unwrap());
        let mut series = SeriesConfig::new(c, WarmStart::Coarse, range);
        series.validation_points = 128;
        QueueConfig {
            series,
            max_bytes: 3 * SMALL.iter().product::<usize>() * 4,
            when_full: WhenFull::Block,
            threads: 1,
            backend: BackendChoice::cpu(),
            placement: Default::default(),
            kept_states: KEPT_STATES,
        }
    }

    /// Stores nothing, each model only once the test opens the gate.
    struct Gated(Receiver<()>);

    impl ModelSink for Gated {
        fn store(&mut self, _: &Model) -> Result<Option<String>> {
            let _ = self.0.recv();
            Ok(None)
        }
    }

    fn is_stopped(r: &Result<impl std::fmt::Debug>) -> bool {
        matches!(r, Err(Error::InvalidArgument(m)) if m == "the encode thread has stopped")
    }

    /// A worker that stops (here made to panic outside a job's guard, as
    /// only a bug could) fails the jobs queued behind it, frees their room,
    /// wakes a push blocked on it, and the queue refuses pushes and resumes
    /// from then on; nothing waits for ever and each failure is reported
    /// once. Every outcome is deterministic: "c" 1 (two units) cannot fit
    /// beside "c" 0 (two units) in the budget of three, so it waits until
    /// the worker has stopped, whenever that is.
    #[test]
    fn a_stopped_worker_fails_its_jobs_and_refuses_more() {
        // A model of field "b" that a working queue resumes.
        let working = BackgroundEncoder::new(config(), Box::new(CallerStores)).unwrap();
        working.push(job("b", 0, SMALL)).unwrap();
        working.wait(None).unwrap();
        let b = working.take_finished().pop().unwrap();
        let fresh = BackgroundEncoder::new(config(), Box::new(CallerStores)).unwrap();
        fresh.check_resume(&b).unwrap();

        let (open, gate) = crossbeam_channel::unbounded();
        let q = Arc::new(BackgroundEncoder::new(config(), Box::new(Gated(gate))).unwrap());
        assert_eq!(q.push(job("a", 0, SMALL)).unwrap(), Pushed::Queued);
        q.jobs.as_ref().unwrap().send(Work::Panic).unwrap();
        assert_eq!(q.push(job("c", 0, LARGE)).unwrap(), Pushed::Queued, "three units of three");
        let (blocked_tx, blocked) = crossbeam_channel::bounded(1);
        let q2 = q.clone();
        let pusher = std::thread::spawn(move || blocked_tx.send(q2.push(job("c", 1, LARGE))).unwrap());
        open.send(()).unwrap();

        // Each state is checked before `wait`, which would block on a job
        // left unfinished.
        let pushed = blocked.recv_timeout(Duration::from_secs(120)).expect("the blocked push returns");
        assert!(is_stopped(&pushed), "{pushed:?}");
        pusher.join().unwrap();
        assert!(matches!(q.poll("a", 0), Some(JobState::Encoded { .. })), "the job before the stop is encoded");
        assert_eq!(q.take_finished().len(), 1);
        assert!(matches!(q.poll("c", 0), Some(JobState::Failed(_))));
        assert!(q.poll("c", 1).is_none(), "the refused push left no state");
        assert_eq!(q.queued_bytes(), 0);
        assert!(q.has_room(usize::MAX));
        let waited = q.wait(None);
        assert!(matches!(&waited, Err(Error::InvalidArgument(m)) if m == "field 'c' step 0: the encode thread has stopped"), "{waited:?}");
        q.wait(None).unwrap();

        assert!(is_stopped(&q.push(job("a", 1, SMALL))));
        assert!(q.poll("a", 1).is_none());
        assert!(is_stopped(&q.check_resume(&b)));
        assert!(is_stopped(&q.resume(b.clone())));
        q.wait(None).unwrap();
        q.cancel().unwrap();
        // The drop joins a stopped worker.
        drop(Arc::into_inner(q).unwrap());
    }
}
