//! The encoder handle's life cycle: create (serial, or one rank's over MPI),
//! destroy, and what a push does once its data are copied: queue the job
//! (collectively across ranks for an MPI encoder) and, for an HDF5 store,
//! append finished models on the caller's thread.
//!
//! Pushed arrays are copied before the push returns, so the caller may
//! reuse its buffers at once; a worker thread of the encoder encodes them
//! (`gsenc::series::queue::BackgroundEncoder`). Calls on one encoder from
//! several threads run one at a time (`handles`); different encoders are
//! independent.

use crate::config::{gsenc_config, OutputFormat, Settings};
use crate::ffi::time_of;
use crate::handles::Kind;
use crate::status::{fail, gsenc_status, guard, Failure};
use gsenc::domain::halo::Kind as DataKind;
use gsenc::input::{Placement, StepData};
use gsenc::io::preview::Previewed;
use gsenc::io::ModelFolder;
use gsenc::model::Model;
use gsenc::series::queue::{BackgroundEncoder, CallerStores, Job, ModelSink, Pushed, QueueConfig};

/// A step's data as a push copied it. `finite`: the copy already found
/// every value finite (a grid, checked row by row while each row was in
/// cache: `ffi::copy_grid`), so that the queue does not read the whole copy
/// back from memory to check it again.
pub(crate) struct Copied {
    pub(crate) data: StepData,
    pub(crate) finite: bool,
}

impl Copied {
    /// Data whose values the queue checks (particles, cells).
    pub(crate) fn unchecked(data: StepData) -> Copied {
        Copied { data, finite: false }
    }
}

/// Opaque encoder; create with `gsenc_encoder_create`, free with
/// `gsenc_encoder_destroy`.
pub struct gsenc_encoder {
    pub(crate) settings: Settings,
    pub(crate) queue: BackgroundEncoder,
    /// The HDF5 store models go to, written on the caller's thread at the
    /// synchronising calls (`gsenc_wait`, `gsenc_poll`, destroy).
    #[cfg(feature = "hdf5")]
    pub(crate) store: Option<gsenc::io::store::Store>,
    /// Set by `gsenc_encoder_create_mpi`: pushes are collective, each rank
    /// encodes its piece of the domain.
    #[cfg(feature = "mpi")]
    pub(crate) ranks: Option<gsenc::domain::mpi::Decomposition>,
}

/// Keeps models in memory only (no output configured).
struct KeepInMemory;

impl ModelSink for KeepInMemory {
    fn store(&mut self, _: &Model) -> gsenc::Result<Option<String>> {
        Ok(Some(String::new()))
    }
}

/// Creates an encoder from `*config` (read, not kept) into `*out`.
/// On failure `*out` is NULL. Thread-safe.
///
/// # Safety
/// `config` is NULL or an initialised `gsenc_config` whose strings (NULL
/// or NUL-terminated) are readable during the call; `out` is NULL or
/// writable.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_create(config: *const gsenc_config, out: *mut *mut gsenc_encoder) -> gsenc_status {
    // SAFETY: per this function's contract.
    guard(|| unsafe { create_into(config, out, "gsenc_encoder_create", |s| gsenc_encoder::new(s?, true)) })
}

/// `gsenc_encoder_create` with `tweak` applied to the settings first: for
/// tests of settings the C config does not carry.
///
/// # Safety
/// As for `gsenc_encoder_create`.
#[cfg(test)]
pub(crate) unsafe fn create_tweaked(config: *const gsenc_config, out: *mut *mut gsenc_encoder, tweak: impl FnOnce(&mut Settings)) -> gsenc_status {
    // SAFETY: per this function's contract.
    guard(|| {
        unsafe {
            create_into(config, out, "gsenc_encoder_create", |s| {
                let mut s = s?;
                tweak(&mut s);
                gsenc_encoder::new(s, true)
            })
        }
    })
}

/// Creates an encoder by `make` from `*config` into `*out` (NULL on
/// failure) and registers its handle. `make` is called also when the
/// arguments were refused (with that failure), so that an MPI rank takes
/// part in the create's collectives whatever its arguments.
///
/// # Safety
/// `config` is NULL or a caller's config of at least its `struct_size`
/// bytes; `out` is NULL or the caller's handle slot.
unsafe fn create_into(
    config: *const gsenc_config,
    out: *mut *mut gsenc_encoder,
    what: &str,
    make: impl FnOnce(Result<Settings, Failure>) -> Result<gsenc_encoder, Failure>,
) -> Result<(), Failure> {
    let settings = if out.is_null() {
        fail(gsenc_status::NullPointer, format!("{what}: out is NULL"))
    } else {
        // SAFETY: non-null pointer to the caller's handle slot.
        unsafe { *out = std::ptr::null_mut() };
        // SAFETY: the caller passes a config of at least its struct_size bytes.
        unsafe { Settings::from_c(config) }.map_err(|Failure(status, why)| Failure(status, format!("{what}: {why}")))
    };
    let raw = Box::into_raw(Box::new(make(settings)?));
    crate::handles::register(raw, Kind::Encoder);
    // SAFETY: as above.
    unsafe { *out = raw };
    Ok(())
}

/// Creates one rank's encoder of a domain-decomposed run, over the
/// communicator whose Fortran handle is `comm` (`MPI_Comm_c2f(comm)` in C;
/// `integer :: comm` in Fortran), so that this header needs no `mpi.h`.
/// **Collective** over `comm`, as are every push and
/// `gsenc_encoder_destroy` of the encoder it makes (and `gsenc_wait` when
/// it writes an HDF5 store); `gsenc_poll` and the other calls are local. MPI must be initialised at
/// `MPI_THREAD_FUNNELED` or above, and collective calls must come from the
/// thread that initialised it (the encoder's own threads never call MPI).
/// The communicator is duplicated here and the duplicate freed at destroy;
/// the caller's is never freed.
///
/// Each rank pushes its own part of the domain; at a field's first step the
/// ranks agree one global lattice (a grid's spacing, or `dims` over
/// `bounds` or the union of every rank's particles or cells), each rank's
/// piece of it (its data's box grown by `config.halo` voxels) and the value
/// range, fixed for the series. Every push then sends each rank the data its
/// piece needs, and the rank encodes `config.budget` Gaussians over it.
/// Models go to `output_dir` as `FIELD_STEP.gsm` (rank 0) and
/// `FIELD_STEP_rRANK.gsm`, with rank 0's step index `FIELD_STEP.gsi`;
/// `gsenc decode FIELD_STEP.gsi` gives the global field. With
/// `GSENC_OUTPUT_HDF5` they go to one store, `output_dir` its file, which
/// rank 0 alone opens and writes: each rank's models as
/// `/<field>/<step>/rank_<r>` and each step's index as
/// `/<field>/<step>/index`. Every collective call (a push, `gsenc_wait`,
/// destroy) sends rank 0 the models each rank finished since the last one
/// and writes them there; a failed write is that step's failure on the
/// rank that encoded it (reported by its next `gsenc_wait`, or by
/// `gsenc_poll`). `gsenc_poll` writes nothing on an MPI encoder: a step
/// it calls done may reach the store at the next collective call. A step
/// index rank 0 cannot write (a full disk; a store that holds that step's
/// index) fails rank 0's push, its message saying so, though the step was
/// queued on every rank and its models are encoded and written as any
/// other's: the failure is the index's alone. Ranks pushing
/// different fields, steps or forms get `GSENC_STATUS_MPI` together, as
/// do the others when a rank's arguments or data are refused (that rank
/// gets its own error): here, or at a push (each particle or cell is
/// checked before it goes to the pieces it reaches). A rank may push no
/// particles or cells but at a field's first step (its piece is where its
/// data are at that step).
/// `GSENC_STATUS_MPI` too when this gsenc was built without MPI.
///
/// # Safety
/// As for `gsenc_encoder_create`; `comm` is a communicator's Fortran
/// handle (an invalid one is MPI's error, which MPI's error handler
/// decides).
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_create_mpi(config: *const gsenc_config, comm: i32, out: *mut *mut gsenc_encoder) -> gsenc_status {
    // SAFETY: per this function's contract.
    guard(|| unsafe { create_into(config, out, "gsenc_encoder_create_mpi", |settings| create_mpi(settings, comm)) })
}

#[cfg(feature = "mpi")]
fn create_mpi(settings: Result<Settings, Failure>, comm: i32) -> Result<gsenc_encoder, Failure> {
    use gsenc::domain::mpi::{Decomposition, DecompositionConfig};
    use gsenc::series::SeriesRange;
    let cfg = match &settings {
        Ok(s) => DecompositionConfig { dims: s.dims, bounds: s.bounds, halo: s.halo, range: s.series.range },
        // Never used: this rank only takes part in the agreement below.
        Err(_) => DecompositionConfig { dims: [1; 3], bounds: None, halo: 0, range: SeriesRange::FirstStep(gsenc::field::Transform::Linear) },
    };
    let ranks = Decomposition::from_fortran(comm, cfg)?;
    // A rank whose arguments were refused fails here with the others,
    // which would otherwise wait for it in the collectives below.
    let agreed = ranks.agree_all(settings.is_ok(), "to read its arguments");
    let mut settings = match (settings, agreed) {
        (Err(mine), _) => return Err(mine),
        (Ok(_), Err(other)) => return Err(other.into()),
        (Ok(s), Ok(())) => s,
    };
    settings.series.rank = ranks.rank() as u32;
    settings.backend = settings.backend.for_node_rank(ranks.node_rank());
    // Every rank writes the same way (a store makes some calls collective),
    // only rank 0 opens an HDF5 store, and every rank fails if one did.
    let writes = settings.output.as_ref().map_or(0, |_| 1 + settings.output_format as u64);
    ranks.agree_same(writes, "outputs (none, a folder, an HDF5 store)")?;
    let made = gsenc_encoder::new(settings, ranks.rank() == 0);
    let agreed = ranks.agree_all(made.is_ok(), "to create its encoder");
    let mut enc = match (made, agreed) {
        (Err(mine), _) => return Err(mine),
        (Ok(_), Err(other)) => return Err(other.into()),
        (Ok(enc), Ok(())) => enc,
    };
    enc.ranks = Some(ranks);
    Ok(enc)
}

#[cfg(not(feature = "mpi"))]
fn create_mpi(_: Result<Settings, Failure>, _: i32) -> Result<gsenc_encoder, Failure> {
    fail(gsenc_status::Mpi, "this gsenc was built without MPI (cargo feature mpi; CMake -DGSENC_CARGO_FEATURES=mpi)")
}

/// Drains the queue (every pushed step is encoded and written; call
/// `gsenc_encoder_cancel` first to drop them instead), then frees the
/// encoder and everything it holds. Failures of the drained jobs are not
/// reported: call `gsenc_wait` first to see them. NULL, and a handle
/// destroyed already, are ignored; other calls with it afterwards fail with
/// `GSENC_STATUS_INVALID_ARGUMENT`. A call on it in flight on another thread
/// is waited for first.
/// Collective for an encoder of `gsenc_encoder_create_mpi` (it frees the
/// duplicated communicator). In a process forked from the one that created
/// the encoder, frees nothing and writes nothing (its thread and its store
/// are the parent's); every other call with it there fails with
/// `GSENC_STATUS_CALL_ORDER`.
///
/// # Safety
/// `encoder` may be any value: only a live encoder handle is freed.
#[no_mangle]
pub unsafe extern "C" fn gsenc_encoder_destroy(encoder: *mut gsenc_encoder) {
    crate::handles::release(encoder, Kind::Encoder, || {
        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            // SAFETY: made by Box::into_raw in gsenc_encoder_create, and live
            // until now (released, so never freed twice, and no call holds it).
            let mut enc = unsafe { Box::from_raw(encoder) };
            if enc.queue.started_elsewhere().is_some() {
                // A forked child: the encoder's thread is its parent's, and
                // so is its store, which closing here would write to.
                std::mem::forget(enc);
                return;
            }
            let _ = enc.queue.wait(None);
            enc.flush(true);
            drop(enc); // the queue's drop joins its idle worker
        }));
    });
}

/// Runs `f` on the live encoder `encoder`, no other call using it meanwhile
/// (a call from another thread waits for this one).
pub(crate) fn with_encoder<R>(encoder: *mut gsenc_encoder, what: &str, f: impl FnOnce(&mut gsenc_encoder) -> Result<R, Failure>) -> Result<R, Failure> {
    crate::handles::hold(encoder, Kind::Encoder, what, true, || {
        // SAFETY: a live handle from gsenc_encoder_create, held alone.
        let enc = unsafe { &mut *encoder };
        match enc.queue.started_elsewhere() {
            Some(why) => fail(gsenc_status::CallOrder, format!("{what}: {why}")),
            None => f(enc),
        }
    })
}

impl gsenc_encoder {
    /// An encoder of `settings`; `opens_store`: whether this process opens
    /// the HDF5 store, when that is the output (rank 0 of an MPI run).
    fn new(settings: Settings, opens_store: bool) -> Result<gsenc_encoder, Failure> {
        crate::log::set_rank(settings.series.rank);
        let sink: Box<dyn ModelSink> = match (&settings.output, settings.output_format) {
            (None, _) => Box::new(KeepInMemory),
            (Some(dir), OutputFormat::Folder) => Box::new(ModelFolder { dir: dir.clone(), payload: settings.series.payload }),
            (Some(_), OutputFormat::Hdf5) => Box::new(CallerStores),
        };
        // Previews go into the models' folder, or beside the HDF5 store.
        let sink: Box<dyn ModelSink> = match (settings.preview, &settings.output) {
            (Some(view), Some(out)) => {
                let dir = match settings.output_format {
                    OutputFormat::Folder => out.clone(),
                    OutputFormat::Hdf5 => out.parent().map(|p| p.to_path_buf()).unwrap_or_default(),
                };
                Box::new(Previewed::new(sink, view, dir))
            }
            _ => sink,
        };
        #[cfg(feature = "hdf5")]
        let store = match (&settings.output, settings.output_format) {
            (Some(path), OutputFormat::Hdf5) if opens_store => Some(gsenc::io::store::Store::open_append(path)?),
            _ => None,
        };
        #[cfg(not(feature = "hdf5"))]
        let _ = opens_store;
        #[cfg(not(feature = "hdf5"))]
        if settings.output.is_some() && settings.output_format == OutputFormat::Hdf5 {
            return fail(
                gsenc_status::InvalidArgument,
                "this gsenc was built without HDF5 (cargo feature hdf5); write a folder of model files",
            );
        }
        let queue = BackgroundEncoder::new(
            QueueConfig {
                series: settings.series.clone(),
                max_bytes: settings.queue_bytes,
                when_full: settings.when_full,
                threads: settings.threads,
                backend: settings.backend,
                placement: settings.placement.clone(),
                kept_states: settings.kept_states,
            },
            sink,
        )?;
        Ok(gsenc_encoder {
            settings,
            queue,
            #[cfg(feature = "hdf5")]
            store,
            #[cfg(feature = "mpi")]
            ranks: None,
        })
    }

    pub(crate) fn push(&mut self, field: String, step: u64, time: f64, copied: Copied) -> Result<(), Failure> {
        let queue_bytes = self.settings.queue_bytes;
        let full = || format!("field '{field}' step {step}: the queue is full (queue_bytes {queue_bytes})");
        let job = Job { field: field.clone(), step, time: time_of(time), data: copied.data, range: None };
        match self.push_job(job, copied.finite)? {
            Pushed::Queued => Ok(()),
            Pushed::Skipped => fail(gsenc_status::Skipped, format!("{}; the step was skipped", full())),
            Pushed::Busy => fail(gsenc_status::Busy, format!("{}; nothing was queued, push it again later", full())),
        }
    }

    /// Pushes the step this rank `made` (its checked and copied data), or
    /// reports the failure that stopped it before it had data. For an MPI
    /// encoder the failure is also this rank's part of the ranks' push
    /// (`Decomposition::refuse`), so that every rank's push of the step
    /// fails together instead of the others waiting for this one.
    /// An MPI encoder writing a store first stores what the ranks finished
    /// (`flush_ranks`, collective like the push); a serial encoder writes
    /// nothing here.
    pub(crate) fn push_made(&mut self, field: &str, step: u64, time: f64, kind: DataKind, made: Result<Copied, Failure>) -> Result<(), Failure> {
        #[cfg(feature = "mpi")]
        if self.ranks.is_some() {
            self.flush_ranks();
        }
        let failure = match made {
            Ok(data) => return self.push(field.to_owned(), step, time, data),
            Err(f) => f,
        };
        #[cfg(feature = "mpi")]
        if let Some(ranks) = self.ranks.as_mut() {
            ranks.refuse(field, step, kind, gsenc::Error::arg(&failure.1));
        }
        let _ = kind;
        Err(failure)
    }

    /// Continues a field's series from the model the caller `read` (see
    /// `gsenc_encoder_resume`). For an MPI encoder a model this rank could
    /// not read is also its part of the ranks' resume, so that all of them
    /// fail together instead of the others waiting for this one.
    pub(crate) fn resume(&mut self, read: Result<Model, Failure>) -> Result<(), Failure> {
        #[cfg(feature = "mpi")]
        if let Some(ranks) = self.ranks.as_mut() {
            let failure = match read {
                Ok(model) => return Ok(ranks.resume(&self.queue, Ok(model))?),
                Err(f) => f,
            };
            let _ = ranks.resume(&self.queue, Err(gsenc::Error::arg(&failure.1)));
            return Err(failure);
        }
        Ok(self.queue.resume(read?)?)
    }

    /// Queues a job: on this encoder alone, or across the ranks (then rank 0
    /// also writes the step's index: beside the models, or into the store).
    /// `finite`: the copy already found every value finite (`Copied`).
    fn push_job(&mut self, job: Job, finite: bool) -> Result<Pushed, Failure> {
        #[cfg(feature = "mpi")]
        if let Some(ranks) = self.ranks.as_mut() {
            let (field, step) = (job.field.clone(), job.step);
            let done = ranks.push(&self.queue, job, &|rank| gsenc::format::model_file_name(&field, step, rank))?;
            if let (Some(index), Some(out), Pushed::Queued) = (done.index, self.settings.output.as_ref(), done.pushed) {
                let queued = |e: gsenc::Error| {
                    e.in_context(&format!("field '{field}' step {step} was queued on every rank, but rank 0 could not write its step index"))
                };
                match self.settings.output_format {
                    OutputFormat::Folder => {
                        gsenc::io::write_atomic(out.join(gsenc::format::step_index_file_name(&field, step)), index.to_json().as_bytes()).map_err(queued)?
                    }
                    #[cfg(feature = "hdf5")]
                    OutputFormat::Hdf5 => {
                        if let Some(store) = self.store.as_mut() {
                            store.append_step_index(&index).map_err(queued)?;
                        }
                    }
                    #[cfg(not(feature = "hdf5"))]
                    OutputFormat::Hdf5 => {}
                }
            }
            return Ok(done.pushed);
        }
        Ok(if finite { self.queue.push_finite(job)? } else { self.queue.push(job)? })
    }

    /// Appends the models the worker left for the caller's thread (HDF5).
    /// An MPI encoder does so only at its collective calls (`collective`),
    /// every rank's models through rank 0; otherwise it leaves them.
    pub(crate) fn flush(&mut self, collective: bool) {
        #[cfg(feature = "mpi")]
        if self.ranks.is_some() {
            if collective {
                self.flush_ranks();
            }
            return;
        }
        let _ = collective;
        #[cfg(feature = "hdf5")]
        if let Some(store) = self.store.as_mut() {
            let payload = self.settings.series.payload;
            for m in self.queue.take_finished() {
                self.queue.set_stored(&m.meta.field, m.meta.step, append(store, &m, payload));
            }
        }
    }

    /// Every rank's finished models stored by rank 0 (`to_root`); each
    /// rank records what became of its own. Collective; nothing to do but
    /// for an HDF5 store.
    #[cfg(feature = "mpi")]
    fn flush_ranks(&mut self) {
        if self.settings.output.is_none() || self.settings.output_format != OutputFormat::Hdf5 {
            return;
        }
        let Some(ranks) = self.ranks.as_mut() else { return };
        let mine = self.queue.take_finished();
        #[cfg(feature = "hdf5")]
        let stored = {
            let payload = self.settings.series.payload;
            let mut put = self.store.as_mut().map(|store| move |m: &Model| append(store, m, payload));
            ranks.store_on_root(&mine, put.as_mut().map(|p| p as gsenc::domain::to_root::StoreOne))
        };
        #[cfg(not(feature = "hdf5"))]
        let stored = ranks.store_on_root(&mine, None);
        match stored {
            Ok(verdicts) => mine.iter().zip(verdicts).for_each(|(m, v)| self.queue.set_stored(&m.meta.field, m.meta.step, v)),
            Err(e) => mine.iter().for_each(|m| self.queue.set_stored(&m.meta.field, m.meta.step, Err(e.in_context("storing through rank 0")))),
        }
    }

    pub(crate) fn placement(&self) -> Placement {
        Placement::new(self.settings.dims, self.settings.bounds)
    }

    /// Made by `gsenc_encoder_create_mpi`: its pushes are one rank's part.
    pub(crate) fn is_mpi(&self) -> bool {
        #[cfg(feature = "mpi")]
        return self.ranks.is_some();
        #[cfg(not(feature = "mpi"))]
        false
    }
}

/// Appends `m` to `store`: where it went (`FILE:/field/step/rank_r`).
#[cfg(feature = "hdf5")]
fn append(store: &mut gsenc::io::store::Store, m: &Model, payload: gsenc::format::Payload) -> gsenc::Result<String> {
    store.append(m, payload)?;
    Ok(format!("{}:{}", store.path().display(), gsenc::io::store::EntryKey::of(&m.meta).path()))
}

