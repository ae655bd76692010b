//! One rank's side of a domain-decomposed encode, on the simulation's own
//! MPI (cargo feature `mpi`).
//!
//! Each rank keeps its own background queue and model per field and step;
//! this layer agrees, on the caller's thread and at the field's first step,
//! one global lattice (the voxel size and corner every rank uses), each
//! rank's piece of it (its own region grown by a halo) and the value range,
//! then at every push sends each rank the data its piece needs
//! ([`crate::domain::halo`]). The background worker never calls MPI, so
//! `MPI_THREAD_FUNNELED` suffices.
//!
//! The library never initialises or finalises MPI and never frees the
//! caller's communicator: it works on a duplicate, made at create and freed
//! on drop (both collective).

use crate::domain::halo::{self, Kind};
use crate::domain::resume;
use crate::error::{Error, Result};
use crate::field::{Bounds, IndexBox, IndexFrame, Transform, ValueRange};
use crate::format::StepIndex;
use crate::input::StepData;
use crate::memory;
use crate::model::Model;
use crate::series::queue::{BackgroundEncoder, Job, Pushed};
use crate::series::SeriesRange;
use mpi::collective::SystemOperation;
use mpi::datatype::{Partition, PartitionMut};
use mpi::environment::Threading;
use mpi::ffi;
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use std::collections::BTreeMap;
use std::mem::ManuallyDrop;

/// How the ranks place their pieces.
#[derive(Clone, Debug)]
pub struct DecompositionConfig {
    /// Voxels of the global lattice of particles and cells (grids bring
    /// their own spacing).
    pub dims: [usize; 3],
    /// The global box of particles and cells; `None`: the union of every
    /// rank's data at the field's first step.
    pub bounds: Option<Bounds>,
    /// Voxels each piece reaches past its rank's own region.
    pub halo: usize,
    /// The series' range: given, or agreed from every rank's first step.
    pub range: SeriesRange,
}

/// A field's decomposition, fixed at its first step.
struct Layout {
    kind: Kind,
    global: IndexFrame,
    /// Every rank's piece, in rank order.
    pieces: Vec<IndexBox>,
    range: ValueRange,
}

/// What a collective push did.
pub struct Distributed {
    pub pushed: Pushed,
    /// On rank 0: the step's index, for the caller to write beside the models.
    pub index: Option<StepIndex>,
}

/// One rank of a decomposed encode: its duplicate of the communicator and
/// the layouts of its fields.
pub struct Decomposition {
    /// Freed on drop unless MPI is finalised by then.
    comm: ManuallyDrop<SimpleCommunicator>,
    rank: usize,
    size: usize,
    node_rank: usize,
    /// Only the main thread may call MPI (`MPI_THREAD_FUNNELED`).
    funneled: bool,
    cfg: DecompositionConfig,
    fields: BTreeMap<String, Layout>,
    /// Fields resumed and not pushed since: every rank's piece and the
    /// range, for the first push to rebuild the layout from
    /// ([`Decomposition::resume`]).
    resumed: BTreeMap<String, (Vec<IndexFrame>, ValueRange)>,
}

/// Checks that MPI is initialised, not finalised, and at
/// `MPI_THREAD_FUNNELED` or above; returns whether it is exactly funneled.
fn check_environment() -> Result<bool> {
    if !mpi::environment::is_initialized() {
        return Err(Error::Mpi("MPI is not initialised: call MPI_Init_thread (MPI_THREAD_FUNNELED or above) before gsenc".into()));
    }
    if mpi::environment::is_finalized() {
        return Err(Error::Mpi("MPI is already finalised".into()));
    }
    match mpi::environment::threading_support() {
        Threading::Single => Err(Error::Mpi(
            "MPI provides MPI_THREAD_SINGLE; gsenc encodes on its own threads and needs MPI_THREAD_FUNNELED or above (MPI_Init_thread)".into(),
        )),
        Threading::Funneled => Ok(true),
        _ => Ok(false),
    }
}

/// FNV-1a, to compare what the ranks pushed in one `u64`: a push of a
/// `kind` (`Kind as u8`), or a resume ([`RESUME`]).
fn fingerprint(field: &str, step: u64, what: u8) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for b in field.bytes().chain(step.to_le_bytes()).chain([what]) {
        h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// A push of `field` step `step` as `kind` in words: the step
/// (`field 'rho' step 3`), the push (`... as a grid`), and its fingerprint.
fn labels(field: &str, step: u64, kind: Kind) -> (String, String, u64) {
    let what = format!("field '{field}' step {step}");
    let pushed = format!("{what} as {}", kind_name(kind));
    (what, pushed, fingerprint(field, step, kind as u8))
}

/// A resume's mark in its [`fingerprint`], apart from every `Kind`.
const RESUME: u8 = 0xff;

fn kind_name(kind: Kind) -> &'static str {
    match kind {
        Kind::Grid => "a grid",
        Kind::Particles => "particles",
        Kind::CellBoxes => "cells as boxes",
        Kind::CellVolumes => "cells as hexahedra",
    }
}

impl Decomposition {
    /// Duplicates `comm` (collective over it).
    pub fn new(comm: &impl Communicator, cfg: DecompositionConfig) -> Result<Decomposition> {
        let funneled = check_environment()?;
        Self::with(comm.duplicate(), funneled, cfg)
    }

    /// Duplicates the communicator whose Fortran handle is `handle`
    /// (`MPI_Comm_c2f` in C, `integer :: comm` in Fortran); collective.
    pub fn from_fortran(handle: i32, cfg: DecompositionConfig) -> Result<Decomposition> {
        let funneled = check_environment()?;
        // SAFETY: MPI is initialised; f2c of any integer is defined (an
        // invalid one gives MPI_COMM_NULL or an MPI error).
        let raw = unsafe { ffi::RSMPI_Comm_f2c(handle) };
        // SAFETY: reads an MPI constant.
        if raw == unsafe { ffi::RSMPI_COMM_NULL } {
            return Err(Error::Mpi(format!("communicator handle {handle} is MPI_COMM_NULL")));
        }
        let mut dup = raw;
        // SAFETY: `raw` is the caller's live communicator; the duplicate is
        // ours, and only ours is ever freed.
        let rc = unsafe { ffi::MPI_Comm_dup(raw, &mut dup) };
        if rc != 0 {
            return Err(Error::Mpi(format!("MPI_Comm_dup failed with code {rc}")));
        }
        // SAFETY: a live intra-communicator we own.
        let comm = unsafe { SimpleCommunicator::from_raw(dup) };
        Self::with(comm, funneled, cfg)
    }

    fn with(comm: SimpleCommunicator, funneled: bool, cfg: DecompositionConfig) -> Result<Decomposition> {
        if cfg.dims.contains(&0) {
            return Err(Error::arg(format!("dims {:?} must be positive", cfg.dims)));
        }
        let (rank, size) = (comm.rank() as usize, comm.size() as usize);
        // The ranks that share this node's memory, in rank order.
        let node_rank = comm.split_shared(rank as i32).rank() as usize;
        Ok(Decomposition { comm: ManuallyDrop::new(comm), rank, size, node_rank, funneled, cfg, fields: BTreeMap::new(), resumed: BTreeMap::new() })
    }

    pub fn rank(&self) -> usize {
        self.rank
    }

    /// This rank's place among the ranks of its node (what picks its GPU).
    pub fn node_rank(&self) -> usize {
        self.node_rank
    }

    pub fn size(&self) -> usize {
        self.size
    }

    /// The decomposition's own duplicate of the caller's communicator.
    pub(super) fn comm(&self) -> &SimpleCommunicator {
        &self.comm
    }

    /// Whether every rank's step of the same collective call (`what`, in
    /// words: "to create its encoder") went well (`ok`): an `Mpi` error
    /// naming the first rank that failed otherwise (a failing rank reports
    /// its own error instead). Collective.
    pub fn agree_all(&self, ok: bool, what: &str) -> Result<()> {
        self.check_thread()?;
        let mine = [if ok { u64::MAX } else { self.rank as u64 }];
        let mut first = [0u64];
        self.comm.all_reduce_into(&mine[..], &mut first[..], SystemOperation::min());
        match first[0] {
            u64::MAX => Ok(()),
            r => Err(Error::Mpi(format!("rank {r} failed {what} (its own error says why)"))),
        }
    }

    /// Whether every rank gave the same `value` of a setting (`what`, in
    /// words); an `Mpi` error on every rank when not. Collective.
    pub fn agree_same(&self, value: u64, what: &str) -> Result<()> {
        self.check_thread()?;
        let mine = [value, !value];
        let mut all = [0u64; 2];
        self.comm.all_reduce_into(&mine[..], &mut all[..], SystemOperation::max());
        match all == mine {
            true => Ok(()),
            false => Err(Error::Mpi(format!("the ranks gave different {what}; every rank must give the same"))),
        }
    }

    pub(super) fn check_thread(&self) -> Result<()> {
        check_environment()?;
        if self.funneled {
            let mut main = 0;
            // SAFETY: MPI is initialised (checked above).
            unsafe { ffi::MPI_Is_thread_main(&mut main) };
            if main == 0 {
                return Err(Error::Mpi("MPI is at MPI_THREAD_FUNNELED and this is not its main thread: call gsenc's collective functions from the thread that initialised MPI".into()));
            }
        }
        Ok(())
    }

    /// Every rank's `local` outcome, in one allreduce that also compares
    /// `key` (what this rank is doing; `pushed` says it in words) across
    /// the ranks: different keys give every rank an `Mpi` error; otherwise
    /// the first failing rank gets its own error, the others an `Mpi` error
    /// naming it (it `refused` something). Collective.
    fn agree<T>(&self, local: Result<T>, key: u64, pushed: &str, refused: &str) -> Result<T> {
        let mine = [if local.is_err() { self.rank as u64 + 1 } else { 0 }, key, !key];
        let mut all = [0u64; 3];
        self.comm.all_reduce_into(&mine[..], &mut all[..], SystemOperation::max());
        if all[1] != key || all[2] != !key {
            return Err(Error::Mpi(format!(
                "the ranks pushed different steps: this rank pushed {pushed}, another a different field, step or form; every rank must push the same ones in the same order"
            )));
        }
        match (local, all[0]) {
            (Err(e), _) => Err(e),
            (Ok(_), r) if r > 0 => Err(Error::Mpi(format!("rank {} refused {refused} (its own error says why); no rank queued the step", r - 1))),
            (Ok(v), _) => Ok(v),
        }
    }

    /// Pushes one field of one step: collective over the communicator,
    /// every rank with its own part of the domain. Checks that all ranks
    /// push the same field, step and form, agrees the layout at the field's
    /// first step, sends each rank what its piece needs, and queues the
    /// piece on `queue` (all ranks queue, skip or refuse it together).
    /// `model_file(rank)` names each rank's model in the step index.
    pub fn push(&mut self, queue: &BackgroundEncoder, job: Job, model_file: &dyn Fn(u32) -> String) -> Result<Distributed> {
        self.check_thread()?;
        let kind = Kind::of(&job.data);
        let (what, pushed, key) = labels(&job.field, job.step, kind);
        // A resumed field's first push rebuilds its layout from the pieces.
        let local = queue.check(&job).and_then(|()| self.resumed_layout(&job.field, kind)).and_then(|resumed| {
            let stats = self.check_local(&job, kind, resumed.as_ref())?;
            Ok((stats, resumed))
        });
        let (stats, resumed) = self.agree(local, key, &pushed, &format!("its data for {what}"))?;
        if let Some(layout) = resumed {
            self.resumed.remove(&job.field);
            self.fields.insert(job.field.clone(), layout);
        } else if !self.fields.contains_key(&job.field) {
            let layout = self.agree_layout(&job.data, kind, stats, &what)?;
            self.fields.insert(job.field.clone(), layout);
        }
        let layout = &self.fields[&job.field];
        let piece = layout.pieces[self.rank];
        // What this rank sends each piece, counted, and what it will receive,
        // checked against its memory before either buffer is allocated.
        let routing = halo::plan(&job.data, &layout.global, &layout.pieces).and_then(|r| Ok((mpi_counts(r.lens(), &what, "send")?, r)));
        let mut recv_counts = vec![0i32; self.size];
        let none = vec![0i32; self.size];
        self.comm.all_to_all_into(routing.as_ref().map_or(&none[..], |(c, _)| &c[..]), &mut recv_counts[..]);
        let fits = routing.and_then(|(counts, r)| {
            let received: Vec<usize> = recv_counts.iter().map(|&c| c as usize).collect();
            mpi_counts(&received, &what, "receive")?;
            let bytes = halo::exchange_bytes(kind, r.total(), received.iter().sum(), &piece);
            memory::check_fits(&format!("{what}: exchanging this rank's piece"), bytes)?;
            Ok((counts, r))
        });
        let (counts, routing) = self.agree(fits, key, &pushed, &format!("to exchange its data of {what}"))?;
        let send = halo::fill(&job.data, &layout.global, &layout.pieces, &routing);
        let received = self.exchange(send, &counts, &recv_counts);
        let received: Vec<&[f64]> = received.0.iter().map(|r| &received.1[r.clone()]).collect();
        let joined = halo::join(kind, &received, &layout.global, &piece);
        // All ranks decide about a full queue together.
        let room = joined.as_ref().map_or(true, |d| queue.has_room(d.bytes()));
        let mut all_room = [0u64];
        self.comm.all_reduce_into(&[room as u64][..], &mut all_room[..], SystemOperation::min());
        let data = joined?;
        let index = (self.rank == 0).then(|| {
            let models = (0..self.size as u32).map(model_file).collect();
            StepIndex::new(&job.field, job.step, job.time, &layout.range, &layout.global, &layout.pieces, self.cfg.halo, models)
        });
        let range = Some(layout.range);
        let pushed = queue.push_checked(Job { data, range, ..job }, all_room[0] == 1)?;
        Ok(Distributed { pushed, index })
    }

    /// Takes part in the ranks' push of `field` step `step` (of `kind`) that
    /// this rank failed before it had data to push (`why`: a copy it could
    /// not take, an array of its own that was refused): every rank's push
    /// fails together, this rank's with `why`, the others' naming this rank,
    /// instead of the others waiting for it in the collective.
    pub fn refuse(&mut self, field: &str, step: u64, kind: Kind, why: Error) -> Error {
        if let Err(e) = self.check_thread() {
            return e;
        }
        let (what, pushed, key) = labels(field, step, kind);
        match self.agree::<()>(Err(why), key, &pushed, &format!("its data for {what}")) {
            Err(e) => e,
            Ok(()) => Error::Mpi(format!("{what}: a refused push was agreed")),
        }
    }

    /// Continues `model`'s field from it on this rank, each rank with its
    /// own piece's model of the same field and step (a restart from a
    /// checkpoint, on the ranks, `dims`, `bounds` and `halo` of the run that
    /// stored them): the ranks gather each other's pieces and range, from
    /// which the field's first push rebuilds the layout the series had
    /// ([`crate::domain::resume`]), so that its pieces, step indexes and
    /// models continue the unbroken run's. `model` is `Err` on a rank that
    /// could not read its own: every rank fails together then. Collective.
    pub fn resume(&mut self, queue: &BackgroundEncoder, model: Result<Model>) -> Result<()> {
        self.check_thread()?;
        let local = model.and_then(|m| {
            if self.fields.contains_key(&m.meta.field) || self.resumed.contains_key(&m.meta.field) {
                return Err(Error::arg(format!("field '{}' has begun on this encoder already; resume a field before its first push", m.meta.field)));
            }
            queue.check_resume(&m)?;
            Ok(m)
        });
        // A rank that failed reports its own error; the others name it.
        let all = self.agree_all(local.is_ok(), "to resume its series");
        let model = local?;
        all?;
        let (field, step) = (model.meta.field.clone(), model.meta.step);
        let what = format!("field '{field}' step {step}");
        self.agree(Ok(()), fingerprint(&field, step, RESUME), &format!("{what} to resume from"), "")?;
        let mine = resume::to_wire(&model.meta.frame, &model.meta.range);
        let mut all = vec![0f64; resume::WIRE_LEN * self.size];
        self.comm.all_gather_into(&mine[..], &mut all[..]);
        // Every rank checks the same gathered words: errors come on all.
        // (The lattice is rebuilt and checked at the first push, whose form
        // says how: a grid's, or that of particles and cells.)
        let (frames, range) = resume::from_wire(&all).map_err(|e| e.in_context(&format!("resuming {what}")))?;
        let resumed = queue.resume(model);
        let all = self.agree_all(resumed.is_ok(), "to resume its series");
        resumed?;
        all?;
        self.resumed.insert(field, (frames, range));
        Ok(())
    }

    /// The layout of a resumed field not pushed since, rebuilt for its
    /// first push, of `kind`; `None` for every other field.
    fn resumed_layout(&self, field: &str, kind: Kind) -> Result<Option<Layout>> {
        let Some((frames, range)) = self.resumed.get(field) else { return Ok(None) };
        let (global, pieces) = resume::lattice_of_pieces(frames, kind == Kind::Grid, self.cfg.dims, self.cfg.bounds)
            .map_err(|e| e.in_context(&format!("field '{field}' resumed")))?;
        Ok(Some(Layout { kind, global, pieces, range: *range }))
    }

    /// What this rank checks alone before the first collective: the form
    /// matches the field's (its `layout`, or the one it has), a grid sits
    /// on the field's lattice; and, at the first step, that it has data
    /// and their local value range.
    fn check_local(&self, job: &Job, kind: Kind, layout: Option<&Layout>) -> Result<[f64; 2]> {
        if let Some(l) = layout.or(self.fields.get(&job.field)) {
            if l.kind != kind {
                return Err(Error::arg(format!(
                    "field '{}' came as {} at its first step, now as {}",
                    job.field,
                    kind_name(l.kind),
                    kind_name(kind)
                )));
            }
            if let StepData::Grid { frame, .. } = &job.data {
                halo::grid_box(&l.global, frame)?;
            }
            return Ok([0.0; 2]);
        }
        let values = halo::data_values(&job.data);
        if values.is_empty() {
            // Its piece of the lattice would be where its data are.
            return Err(Error::data(format!(
                "field '{}' step {}: this rank has no {} at the field's first step; every rank needs some there (a rank's piece is where its data are), and may have none at later steps",
                job.field,
                job.step,
                if kind == Kind::Particles { "particles" } else { "cells" }
            )));
        }
        let transform = match self.cfg.range {
            SeriesRange::Fixed(_) => return Ok([0.0; 2]),
            SeriesRange::FirstStep(t) => t,
        };
        if transform == Transform::Log10 {
            if let Some(v) = values.iter().find(|&&v| v <= 0.0) {
                return Err(Error::data(format!("log10 transform needs positive values; got {v:?}")));
            }
        }
        let t = |v: f32| if transform == Transform::Log10 { (v as f64).log10() } else { v as f64 };
        Ok(values.iter().fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], &v| [lo.min(t(v)), hi.max(t(v))]))
    }

    /// The global lattice, every rank's piece and the range of a field,
    /// from every rank's first step. Collective.
    fn agree_layout(&self, data: &StepData, kind: Kind, local_range: [f64; 2], what: &str) -> Result<Layout> {
        let b = halo::data_bounds(data);
        let spacing = match data {
            StepData::Grid { frame, .. } => 1.0 / frame.gamma,
            _ => 0.0,
        };
        // Minima of everything: maxima travel negated.
        let mine = [b.min[0], b.min[1], b.min[2], -b.max[0], -b.max[1], -b.max[2], local_range[0], -local_range[1], spacing, -spacing];
        let mut all = [0f64; 10];
        self.comm.all_reduce_into(&mine[..], &mut all[..], SystemOperation::min());
        let (gmin, gmax) = ([all[0], all[1], all[2]], [-all[3], -all[4], -all[5]]);
        // Every rank computes the same from the same reduced numbers, so
        // these errors come on all ranks together.
        let range = match self.cfg.range {
            SeriesRange::Fixed(r) => r,
            SeriesRange::FirstStep(t) => ValueRange::new(all[6], -all[7], t)
                .map_err(|_| Error::data(format!("{what}: the field is constant ({:?}) on every rank; give a value range", all[6])))?,
        };
        let global = match kind {
            Kind::Grid => {
                let (smin, smax) = (all[8], -all[9]);
                if (smax - smin) > 1e-9 * smin {
                    return Err(Error::Mpi(format!("{what}: the ranks' grids have spacings from {smin} to {smax}; they must share one")));
                }
                let gamma = 1.0 / smin;
                let dims = std::array::from_fn(|a| ((gmax[a] - gmin[a]) * gamma).round().max(1.0) as usize);
                IndexFrame { dims, bmin: gmin, gamma }
            }
            _ => {
                let (lo, hi) = self.cfg.bounds.map_or((gmin, gmax), |b| (b.min, b.max));
                IndexFrame::from_bounds(self.cfg.dims, lo, hi)?
            }
        };
        let piece = match data {
            StepData::Grid { frame, .. } => halo::grid_box(&global, frame).map(|g| {
                let lo = std::array::from_fn(|a| g.lo[a].saturating_sub(self.cfg.halo));
                let hi = std::array::from_fn(|a| (g.hi[a] + self.cfg.halo).min(global.dims[a]));
                IndexBox { lo, hi }
            }),
            _ => {
                // This rank's region, clipped to the global box.
                let g = global.world_box();
                let lo = std::array::from_fn(|a| b.min[a].clamp(g.min[a], g.max[a]));
                let hi = std::array::from_fn(|a| b.max[a].clamp(g.min[a], g.max[a]));
                Ok(global.covering_box(lo, hi, self.cfg.halo))
            }
        };
        let mine: Vec<i64> = match &piece {
            Ok(p) => p.lo.iter().chain(&p.hi).map(|&v| v as i64).chain([1]).collect(),
            Err(_) => vec![0, 0, 0, 0, 0, 0, 0],
        };
        let mut all = vec![0i64; 7 * self.size];
        self.comm.all_gather_into(&mine[..], &mut all[..]);
        let piece = piece?;
        if let Some(r) = all.chunks_exact(7).position(|c| c[6] == 0) {
            return Err(Error::Mpi(format!("{what}: rank {r}'s grid is not on the lattice of the others (its own error says why)")));
        }
        let pieces: Vec<IndexBox> = all
            .chunks_exact(7)
            .map(|c| IndexBox { lo: std::array::from_fn(|a| c[a] as usize), hi: std::array::from_fn(|a| c[3 + a] as usize) })
            .collect();
        debug_assert_eq!(pieces[self.rank], piece);
        Ok(Layout { kind, global, pieces, range })
    }

    /// Sends `counts[r]` values of `send` (piece after piece) to rank `r`;
    /// returns what each rank sent here (`recv_counts[r]` values), as ranges
    /// of one buffer. `send` is freed before the answer. Collective.
    fn exchange(&self, send: Vec<f64>, counts: &[i32], recv_counts: &[i32]) -> (Vec<std::ops::Range<usize>>, Vec<f64>) {
        let displs = |c: &[i32]| c.iter().scan(0i32, |at, &n| Some(std::mem::replace(at, *at + n))).collect::<Vec<i32>>();
        let total: usize = recv_counts.iter().map(|&c| c as usize).sum();
        let mut recv = vec![0f64; total];
        let (sd, rd) = (displs(counts), displs(recv_counts));
        {
            let partition = Partition::new(&send[..], counts, &sd[..]);
            let mut into = PartitionMut::new(&mut recv[..], recv_counts, &rd[..]);
            self.comm.all_to_all_varcount_into(&partition, &mut into);
        }
        let ranges = rd.iter().zip(recv_counts).map(|(&d, &c)| d as usize..(d + c) as usize).collect();
        (ranges, recv)
    }
}

/// `lens` values, one count per rank, as MPI's `int` counts, refused when
/// their sum (a displacement) passes `i32::MAX`; `way` is "send" or
/// "receive".
fn mpi_counts(lens: &[usize], what: &str, way: &str) -> Result<Vec<i32>> {
    let total = lens.iter().fold(0usize, |a, &n| a.saturating_add(n));
    if i32::try_from(total).is_err() {
        return Err(Error::arg(format!("{what}: {total} values to {way} in one step, more than MPI's 2^31 - 1")));
    }
    Ok(lens.iter().map(|&n| n as i32).collect())
}

impl Drop for Decomposition {
    /// Frees the duplicate (collective), unless MPI is finalised by now
    /// (then freeing is not allowed; the handle dies with MPI).
    fn drop(&mut self) {
        if mpi::environment::is_finalized() {
            return;
        }
        // SAFETY: taken once, here.
        drop(unsafe { ManuallyDrop::take(&mut self.comm) });
    }
}
