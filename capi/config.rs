//! The encoder's configuration as C sees it: one struct that starts with its
//! own size, filled with defaults by `gsenc_config_init`.

use crate::ffi::{c_str, read_sized};
use crate::status::{fail, gsenc_status, guard, Failure};
use gsenc::backend::select::{BackendChoice, BackendKind};
use gsenc::encode::{EncodeConfig, Schedule, TargetPsnr, WarmStart};
use gsenc::field::{Bounds, Transform, ValueRange};
use gsenc::format::quantize::CentreCoding;
use gsenc::format::Payload;
use gsenc::render::{ColorMap, View, ViewKind, DEFAULT_OPACITY};
use gsenc::series::placement::{parse_cpu_list, Priority, ThreadPlacement};
use gsenc::series::queue::WhenFull;
use gsenc::series::{SeriesConfig, SeriesRange};
use std::os::raw::c_char;

/// Schedules (`gsenc_config.schedule`).
pub const GSENC_SCHEDULE_FULL: i32 = 0;
pub const GSENC_SCHEDULE_MATCHED: i32 = 1;
pub const GSENC_SCHEDULE_SHORT: i32 = 2;
/// Matched's cost at five times the paper's learning rate, with gsenc's
/// training points and objective (METHOD.md "Schedules").
pub const GSENC_SCHEDULE_TUNED: i32 = 3;
/// Full's iterations and points, trained as tuned: about 1.2x full's cost
/// (METHOD.md "Schedules").
pub const GSENC_SCHEDULE_TUNED_FULL: i32 = 4;
/// Warm starts of steps after a field's first (`gsenc_config.warm_start`).
pub const GSENC_WARM_OFF: i32 = 0;
pub const GSENC_WARM_COARSE: i32 = 1;
pub const GSENC_WARM_DENSE: i32 = 2;
/// The previous model, repaired where it misses the new step, or a fresh
/// seeding, whichever validates best; stops when the validation PSNR stops
/// rising (`warm_iterations`, or the schedule's, being the cap).
pub const GSENC_WARM_AUTO: i32 = 3;
/// Value transforms (`gsenc_config.transform`).
pub const GSENC_TRANSFORM_LINEAR: i32 = 0;
pub const GSENC_TRANSFORM_LOG10: i32 = 1;
/// Stored payloads (`gsenc_config.payload`).
pub const GSENC_PAYLOAD_F32: i32 = 0;
pub const GSENC_PAYLOAD_8BIT: i32 = 1;
pub const GSENC_PAYLOAD_8BIT_U16: i32 = 2;
/// Each parameter group at the fewest bits that keep the PSNR within
/// 0.1 dB of float32, measured per model (METHOD.md "Payloads").
pub const GSENC_PAYLOAD_PACKED: i32 = 3;
/// What a push does when the queue is full (`gsenc_config.when_full`):
/// wait, drop the step (`GSENC_STATUS_SKIPPED`), or return
/// `GSENC_STATUS_BUSY` having queued nothing.
pub const GSENC_QUEUE_BLOCK: i32 = 0;
pub const GSENC_QUEUE_SKIP: i32 = 1;
pub const GSENC_QUEUE_BUSY: i32 = 2;
/// Whether models store their support (`gsenc_config.support`): where the
/// data lie above the objective's mask, so that the model decodes its fitted
/// outside elsewhere (0 where the data are truly empty; the default), or
/// not, for the paper's models exactly.
pub const GSENC_SUPPORT_STORED: i32 = 0;
pub const GSENC_SUPPORT_NONE: i32 = 1;
/// Which backend encodes (`gsenc_config.backend`): a hardware GPU when
/// there is one, else the CPU (falling back to the CPU if the GPU fails);
/// the CPU; the GPU or `GSENC_STATUS_DEVICE` at create (`GSENC_ADAPTER`
/// names a software adapter such as llvmpipe). `GSENC_BACKEND` overrides.
pub const GSENC_BACKEND_AUTO: i32 = 0;
pub const GSENC_BACKEND_CPU: i32 = 1;
pub const GSENC_BACKEND_GPU: i32 = 2;
/// Where models go (`gsenc_config.output_format`).
pub const GSENC_OUTPUT_FOLDER: i32 = 0;
pub const GSENC_OUTPUT_HDF5: i32 = 1;
/// A picture of every step (`gsenc_config.preview`): none, an axis slice,
/// or a volume rendering, written as `FIELD_STEP.png` beside the models
/// (in `output_dir`, or beside the HDF5 store) on the encoder's thread.
pub const GSENC_PREVIEW_NONE: i32 = 0;
pub const GSENC_PREVIEW_SLICE: i32 = 1;
pub const GSENC_PREVIEW_VOLUME: i32 = 2;
/// How eagerly the encoder's threads take a CPU the solver wants
/// (`gsenc_config.encoder_priority`): as the solver's threads, at nice 19,
/// or only when no other thread wants it (Linux's `SCHED_IDLE`: an encoder
/// that shares a busy solver's only core then waits for the solver's idle
/// time, and its queue's `when_full` decides what a push does meanwhile).
pub const GSENC_PRIORITY_NORMAL: i32 = 0;
pub const GSENC_PRIORITY_LOW: i32 = 1;
pub const GSENC_PRIORITY_IDLE: i32 = 2;

/// `gsenc_config.output_format`, checked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum OutputFormat {
    Folder,
    Hdf5,
}

/// Everything an encoder is created with. Set `struct_size` to
/// `sizeof(gsenc_config)` and call `gsenc_config_init` before changing
/// fields; later versions only append fields, which older callers then
/// leave at their defaults.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
#[allow(non_camel_case_types)]
pub struct gsenc_config {
    /// `sizeof(gsenc_config)` as the caller was compiled with.
    pub struct_size: usize,
    /// Number of Gaussians per field and step (default 32000). One whose
    /// training would take more memory than the process can (about 800
    /// bytes a Gaussian and 12 a voxel of the step's lattice) fails that
    /// step with `GSENC_STATUS_INVALID_ARGUMENT`.
    pub budget: u64,
    /// `GSENC_SCHEDULE_*` of first and independent steps (default matched).
    pub schedule: i32,
    /// `GSENC_WARM_*` (default auto).
    pub warm_start: i32,
    /// Iterations (at most 10^7, as `warm_iterations`) and points per
    /// iteration (at most 2^24), checked at create; 0 keeps the schedule's.
    pub iterations: u32,
    pub points: u32,
    /// `GSENC_TRANSFORM_*` applied before normalising (default linear).
    pub transform: i32,
    /// Non-zero: `value_min`..`value_max` (transformed units) for every step;
    /// zero: the range of each field's first step (default).
    pub fixed_range: i32,
    pub value_min: f64,
    pub value_max: f64,
    /// Reference grid dims for particles and cells (default 128^3).
    pub dims: [u32; 3],
    /// Non-zero: particles and cells are deposited in `bounds_min`..
    /// `bounds_max` (world units); zero: in the box of each field's first step.
    pub has_bounds: i32,
    pub bounds_min: [f64; 3],
    pub bounds_max: [f64; 3],
    /// `GSENC_PAYLOAD_*` of written models (default float32).
    pub payload: i32,
    /// Threads of the encoder's own pool, beside the solver's (default 1;
    /// give it the cores the solver leaves free); 0: one per CPU the encoder
    /// may use (those `encoder_cpus` names, else every CPU the creating
    /// thread may run on). More
    /// than 8 a core (at least 64) is refused (`GSENC_STATUS_INVALID_ARGUMENT`):
    /// the model does not depend on the count, and such a number is a mistake.
    pub threads: u32,
    /// Seeds of the seeding draws (0) and of point sampling (1).
    pub seed_init: u64,
    pub seed_sample: u64,
    /// MPI rank stored in the models (0).
    pub rank: u32,
    /// `GSENC_SUPPORT_*` (default stored). This field fills what was
    /// padding, so every other offset is unchanged.
    pub support: i32,
    /// Where every model goes, per `output_format`: a folder of
    /// `FIELD_STEP.gsm` files (`FIELD_STEP_rRANK.gsm` on ranks other than
    /// 0), or an HDF5 store file. NULL (default) keeps models in memory
    /// only. Copied at create, a relative path made absolute against the
    /// working folder of that moment (a later `chdir` does not move it);
    /// an empty one is `GSENC_STATUS_INVALID_ARGUMENT`. An HDF5 store is
    /// held, under HDF5's file lock, from create to destroy: a create on a
    /// store that another process holds fails with `GSENC_STATUS_IO`, and
    /// other processes read it after destroy (or with
    /// `HDF5_USE_FILE_LOCKING=FALSE`, as of its last write).
    pub output_dir: *const c_char,
    /// Iterations of a warm-started step; 0 keeps the regime's (1000
    /// coarse, 1500 dense; auto: at most the schedule's).
    pub warm_iterations: u32,
    /// `GSENC_QUEUE_*`: what a push does when the queue's memory is taken
    /// (default block).
    pub when_full: i32,
    /// Bytes of pushed copies the queue may hold, queued and running steps
    /// together (default 1 GiB). A step larger than this is still taken
    /// when the queue is empty.
    pub queue_bytes: u64,
    /// `GSENC_OUTPUT_*`: a folder of model files (default) or an HDF5
    /// store (needs a gsenc built with HDF5; written on the caller's thread
    /// in `gsenc_wait`, `gsenc_poll` and destroy, since HDF5 is not
    /// thread-safe and the host may use it too; for an MPI encoder, by rank
    /// 0 for every rank, at each push, `gsenc_wait` and destroy).
    pub output_format: i32,
    /// Encoders made by `gsenc_encoder_create_mpi`: voxels each rank's
    /// piece reaches past its own region (default 8), so that neighbouring
    /// pieces overlap and blend. Ignored by a serial encoder.
    pub halo: u32,
    /// `GSENC_BACKEND_*` (default auto).
    pub backend: i32,
    /// Which hardware GPU (`gsenc devices` lists them); -1 (default): GPU 0,
    /// or under MPI the rank's node-local rank modulo the node's GPUs.
    pub gpu_index: i32,
    /// `GSENC_PREVIEW_*` (default none); needs `output_dir`. A bad slice,
    /// camera or size is `GSENC_STATUS_INVALID_ARGUMENT` at create.
    pub preview: i32,
    /// Slice: the axis (0 x, 1 y, 2 z; default 2) and where along it, a
    /// fraction of the lattice in [0, 1] (default 0.5).
    pub preview_axis: i32,
    pub preview_at: f64,
    /// Volume camera: degrees around z from the +x side (default 30) and
    /// above the x-y plane, in [-90, 90] (default 25).
    pub preview_azimuth: f64,
    pub preview_elevation: f64,
    /// Image size in pixels, 16 to 8192 each (default 512 x 512).
    pub preview_width: u32,
    pub preview_height: u32,
    /// A quality instead of a budget: non-zero, the voxel PSNR (dB, as
    /// stored) each field's first step is encoded to, `budget` being then
    /// the most primitives it may choose (0: one per 32 voxels that hold
    /// data); later steps keep the budget they inherit and change it only
    /// when they miss the target. 0 (default): `budget` exactly. Read the
    /// budget chosen and the PSNR reached with `gsenc_model_info`.
    pub target_psnr: f64,
    /// The CPUs the encoder's threads run on, as `taskset` writes a list
    /// (`"8-15"`, `"2,3,6-7"`), or by position in the creating thread's own
    /// set (`"@1"`: its second CPU, the same setting for every rank of a
    /// job whose ranks are bound to CPUs of their own); each must be one
    /// the creating thread may run on. NULL (default): the creating
    /// thread's own set, which under an MPI binding may be the solver's one
    /// core (create then logs a warning, shown with `GSENC_LOG=warn`). The
    /// environment's `GSENC_ENCODER_CPUS` overrides it. Copied at create.
    /// Linux only: elsewhere anything but NULL is
    /// `GSENC_STATUS_INVALID_ARGUMENT`.
    pub encoder_cpus: *const c_char,
    /// `GSENC_PRIORITY_*` of the encoder's threads (default normal); the
    /// environment's `GSENC_ENCODER_PRIORITY` (`normal`, `low`, `idle`)
    /// overrides it. Linux only, as `encoder_cpus`.
    pub encoder_priority: i32,
}

/// The bytes of `gsenc_config` this version reads.
pub(crate) const CONFIG_SIZE: usize = std::mem::size_of::<gsenc_config>();

impl gsenc_config {
    fn defaults() -> gsenc_config {
        gsenc_config {
            struct_size: CONFIG_SIZE,
            budget: 32_000,
            schedule: GSENC_SCHEDULE_MATCHED,
            warm_start: GSENC_WARM_AUTO,
            iterations: 0,
            points: 0,
            transform: GSENC_TRANSFORM_LINEAR,
            fixed_range: 0,
            value_min: 0.0,
            value_max: 1.0,
            dims: [128; 3],
            has_bounds: 0,
            bounds_min: [0.0; 3],
            bounds_max: [1.0; 3],
            payload: GSENC_PAYLOAD_F32,
            threads: 1,
            seed_init: 0,
            seed_sample: 1,
            rank: 0,
            support: GSENC_SUPPORT_STORED,
            output_dir: std::ptr::null(),
            warm_iterations: 0,
            when_full: GSENC_QUEUE_BLOCK,
            queue_bytes: 1 << 30,
            output_format: GSENC_OUTPUT_FOLDER,
            halo: 8,
            backend: GSENC_BACKEND_AUTO,
            gpu_index: -1,
            preview: GSENC_PREVIEW_NONE,
            preview_axis: 2,
            preview_at: 0.5,
            preview_azimuth: 30.0,
            preview_elevation: 25.0,
            preview_width: 512,
            preview_height: 512,
            target_psnr: 0.0,
            encoder_cpus: std::ptr::null(),
            encoder_priority: GSENC_PRIORITY_NORMAL,
        }
    }
}

/// Fills `*config` with the defaults above. `config->struct_size` must be
/// set first (to `sizeof(gsenc_config)`). Thread-safe.
///
/// # Safety
/// `config` is NULL or a `gsenc_config` the caller owns, aligned, whose
/// `struct_size` is set; this version's bytes of it are written.
#[no_mangle]
pub unsafe extern "C" fn gsenc_config_init(config: *mut gsenc_config) -> gsenc_status {
    guard(|| {
        if config.is_null() {
            return fail(gsenc_status::NullPointer, "gsenc_config_init: config is NULL");
        }
        // SAFETY: non-null, and the caller owns at least `struct_size` bytes there.
        let size = unsafe { (*config).struct_size };
        if size < CONFIG_SIZE {
            return fail(
                gsenc_status::StructSize,
                format!("gsenc_config_init: struct_size is {size}, this gsenc needs {CONFIG_SIZE}; set it to sizeof(gsenc_config)"),
            );
        }
        // SAFETY: as above; only this version's bytes are written.
        unsafe { config.write(gsenc_config::defaults()) };
        Ok(())
    })
}

/// A checked copy of a caller's configuration.
pub(crate) struct Settings {
    /// Everything that decides the models, their payload and rank included.
    pub series: SeriesConfig,
    pub dims: [usize; 3],
    pub bounds: Option<Bounds>,
    pub threads: usize,
    pub when_full: WhenFull,
    pub queue_bytes: usize,
    pub output_format: OutputFormat,
    #[cfg_attr(not(feature = "mpi"), allow(dead_code))]
    pub halo: usize,
    /// The backend; under MPI its GPU index is set per rank at create.
    pub backend: BackendChoice,
    /// The folder or store models go to.
    pub output: Option<std::path::PathBuf>,
    /// The picture drawn of every step, if any (`output` is then set).
    pub preview: Option<View>,
    /// Where the encoder's threads run (before the environment's say).
    pub placement: ThreadPlacement,
    /// Final job states the queue keeps for `gsenc_poll` (not in the C
    /// config: [`gsenc::series::queue::KEPT_STATES`]; tests set fewer).
    pub kept_states: usize,
}

impl Settings {
    /// # Safety
    /// `c` points to a caller's `gsenc_config` of at least `struct_size` bytes.
    pub unsafe fn from_c(c: *const gsenc_config) -> Result<Settings, Failure> {
        // SAFETY: per the contract.
        let c = unsafe { read_sized(c, "config") }?;
        let bad = |what: String| Failure(gsenc_status::InvalidArgument, what);
        let schedule = match c.schedule {
            GSENC_SCHEDULE_FULL => Schedule::Full,
            GSENC_SCHEDULE_MATCHED => Schedule::Matched,
            GSENC_SCHEDULE_SHORT => Schedule::Short,
            GSENC_SCHEDULE_TUNED => Schedule::Tuned,
            GSENC_SCHEDULE_TUNED_FULL => Schedule::TunedFull,
            s => return Err(bad(format!("unknown schedule {s}"))),
        };
        let warm = match c.warm_start {
            GSENC_WARM_OFF => WarmStart::Off,
            GSENC_WARM_COARSE => WarmStart::Coarse,
            GSENC_WARM_DENSE => WarmStart::Dense,
            GSENC_WARM_AUTO => WarmStart::Auto,
            w => return Err(bad(format!("unknown warm start {w}"))),
        };
        let transform = match c.transform {
            GSENC_TRANSFORM_LINEAR => Transform::Linear,
            GSENC_TRANSFORM_LOG10 => Transform::Log10,
            t => return Err(bad(format!("unknown transform {t}"))),
        };
        let payload = match c.payload {
            GSENC_PAYLOAD_F32 => Payload::Float32,
            GSENC_PAYLOAD_8BIT => Payload::Bits8(CentreCoding::Float16),
            GSENC_PAYLOAD_8BIT_U16 => Payload::Bits8(CentreCoding::Fixed16),
            GSENC_PAYLOAD_PACKED => Payload::Packed,
            p => return Err(bad(format!("unknown payload {p}"))),
        };
        let budget = usize::try_from(c.budget).map_err(|_| bad(format!("budget {} is too large", c.budget)))?;
        let target = match c.target_psnr {
            0.0 => None,
            t => Some(TargetPsnr::new(t).map_err(|e| bad(format!("target_psnr: {e}")))?),
        };
        if budget == 0 && target.is_none() {
            return Err(bad("budget must be at least 1 (or set target_psnr)".into()));
        }
        let range = if c.fixed_range != 0 {
            SeriesRange::Fixed(ValueRange::new(c.value_min, c.value_max, transform)?)
        } else {
            SeriesRange::FirstStep(transform)
        };
        let mut encode = EncodeConfig::new(budget, schedule);
        encode.target = target;
        encode.iterations = (c.iterations > 0).then_some(c.iterations as usize);
        encode.points = (c.points > 0).then_some(c.points as usize);
        encode.seed_init = c.seed_init;
        encode.seed_sample = c.seed_sample;
        if c.dims.contains(&0) {
            return Err(bad(format!("dims {:?} must be positive", c.dims)));
        }
        let bounds = (c.has_bounds != 0).then_some(Bounds { min: c.bounds_min, max: c.bounds_max });
        if let Some(b) = bounds {
            if (0..3).any(|a| !(b.min[a].is_finite() && b.max[a].is_finite() && b.max[a] > b.min[a])) {
                return Err(bad(format!("bounds {:?}..{:?} are not a box", b.min, b.max)));
            }
        }
        let when_full = match c.when_full {
            GSENC_QUEUE_BLOCK => WhenFull::Block,
            GSENC_QUEUE_SKIP => WhenFull::Skip,
            GSENC_QUEUE_BUSY => WhenFull::Busy,
            w => return Err(bad(format!("unknown when_full {w} (GSENC_QUEUE_BLOCK, _SKIP, _BUSY)"))),
        };
        let store_support = match c.support {
            GSENC_SUPPORT_STORED => true,
            GSENC_SUPPORT_NONE => false,
            v => return Err(bad(format!("unknown support {v} (GSENC_SUPPORT_STORED, _NONE)"))),
        };
        let output_format = match c.output_format {
            GSENC_OUTPUT_FOLDER => OutputFormat::Folder,
            GSENC_OUTPUT_HDF5 => OutputFormat::Hdf5,
            f => return Err(bad(format!("unknown output_format {f} (GSENC_OUTPUT_FOLDER, _HDF5)"))),
        };
        let kind = match c.backend {
            GSENC_BACKEND_AUTO => BackendKind::Auto,
            GSENC_BACKEND_CPU => BackendKind::Cpu,
            GSENC_BACKEND_GPU => BackendKind::Gpu,
            b => return Err(bad(format!("unknown backend {b} (GSENC_BACKEND_AUTO, _CPU, _GPU)"))),
        };
        let gpu_index = match c.gpu_index {
            -1 => None,
            i if i >= 0 => Some(i as usize),
            i => return Err(bad(format!("gpu_index {i} must be -1 (default) or a GPU's index"))),
        };
        let queue_bytes = usize::try_from(c.queue_bytes).ok().filter(|&b| b > 0);
        let Some(queue_bytes) = queue_bytes else {
            return Err(bad(format!("queue_bytes {} must be positive", c.queue_bytes)));
        };
        // 0 is resolved by the queue, which knows the placement.
        let threads = c.threads as usize;
        let output = match c.output_dir.is_null() {
            true => None,
            false => {
                // SAFETY: a non-null `output_dir` is a NUL-terminated string.
                let given = unsafe { c_str(c.output_dir, "output_dir")? };
                // Made absolute now: a host that changes its working folder
                // later (into a run folder, say) still has its models where
                // it asked at create.
                Some(std::path::absolute(&given).map_err(|e| bad(format!("output_dir '{given}': {e}")))?)
            }
        };
        let preview = match c.preview {
            GSENC_PREVIEW_NONE => None,
            kind @ (GSENC_PREVIEW_SLICE | GSENC_PREVIEW_VOLUME) => {
                let view_kind = if kind == GSENC_PREVIEW_SLICE {
                    if !(0..=2).contains(&c.preview_axis) {
                        return Err(bad(format!("preview_axis {} must be 0 (x), 1 (y) or 2 (z)", c.preview_axis)));
                    }
                    ViewKind::Slice { axis: c.preview_axis as usize, at: c.preview_at }
                } else {
                    ViewKind::Volume { azimuth: c.preview_azimuth, elevation: c.preview_elevation, opacity: DEFAULT_OPACITY }
                };
                let view = View::new(view_kind, c.preview_width as usize, c.preview_height as usize, ColorMap::default()).map_err(|e| bad(format!("preview: {e}")))?;
                if output.is_none() {
                    return Err(bad("preview needs output_dir: the pictures are written beside the models".into()));
                }
                Some(view)
            }
            p => return Err(bad(format!("unknown preview {p} (GSENC_PREVIEW_NONE, _SLICE, _VOLUME)"))),
        };
        let cpus = match c.encoder_cpus.is_null() {
            true => None,
            // SAFETY: a non-null `encoder_cpus` is a NUL-terminated string.
            false => Some(parse_cpu_list(&unsafe { c_str(c.encoder_cpus, "encoder_cpus") }?).map_err(|e| bad(format!("encoder_cpus is not a CPU list: {e}")))?),
        };
        let priority = match c.encoder_priority {
            GSENC_PRIORITY_NORMAL => Priority::Normal,
            GSENC_PRIORITY_LOW => Priority::Low,
            GSENC_PRIORITY_IDLE => Priority::Idle,
            p => return Err(bad(format!("unknown encoder_priority {p} (GSENC_PRIORITY_NORMAL, _LOW, _IDLE)"))),
        };
        let mut series = SeriesConfig::new(encode, warm, range);
        series.validation_points = 0; // no per-iteration log in situ: gsenc_poll reports progress
        series.warm_iterations = (c.warm_iterations > 0).then_some(c.warm_iterations as usize);
        series.payload = payload;
        series.rank = c.rank;
        series.store_support = store_support;
        Ok(Settings {
            series,
            dims: c.dims.map(|d| d as usize),
            bounds,
            threads,
            when_full,
            queue_bytes,
            output_format,
            halo: c.halo as usize,
            backend: BackendChoice { kind, gpu_index, brick: None },
            output,
            preview,
            placement: ThreadPlacement { cpus, priority },
            kept_states: gsenc::series::queue::KEPT_STATES,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every schedule constant reads as the schedule of its name; others are refused.
    #[test]
    fn schedule_constants_read_as_their_schedules() {
        let named = [(GSENC_SCHEDULE_FULL, "full"), (GSENC_SCHEDULE_MATCHED, "matched"), (GSENC_SCHEDULE_SHORT, "short"), (GSENC_SCHEDULE_TUNED, "tuned"), (GSENC_SCHEDULE_TUNED_FULL, "tuned-full")];
        assert_eq!(named.len(), Schedule::ALL.len());
        for (code, name) in named {
            assert_eq!(read(gsenc_config { schedule: code, ..gsenc_config::defaults() }).series.encode.schedule.name(), name);
        }
        let e = refusal(gsenc_config { schedule: 5, ..gsenc_config::defaults() }, "schedule 5");
        assert!(e.1.contains("unknown schedule 5"), "{}", e.1);
    }

    /// `c` (a whole config of this version) read, or its failure.
    fn try_read(c: gsenc_config) -> Result<Settings, Failure> {
        // SAFETY: a whole config of this version; its pointers are NULL or
        // NUL-terminated strings the caller keeps.
        unsafe { Settings::from_c(&c) }
    }

    /// The settings `c` reads as; a refusal fails the test with its message.
    fn read(c: gsenc_config) -> Settings {
        try_read(c).unwrap_or_else(|f| panic!("refused: {}", f.1))
    }

    /// How `c` is refused; being read fails the test, naming `what`.
    fn refusal(c: gsenc_config, what: &str) -> Failure {
        try_read(c).err().unwrap_or_else(|| panic!("'{what}' was read"))
    }

    /// Every other enumeration's constants read as the values they name,
    /// and each field's numbers take effect as given.
    #[test]
    fn every_constant_reads_as_what_it_names() {
        let d = gsenc_config::defaults;
        for (code, warm) in [(GSENC_WARM_OFF, WarmStart::Off), (GSENC_WARM_COARSE, WarmStart::Coarse), (GSENC_WARM_DENSE, WarmStart::Dense), (GSENC_WARM_AUTO, WarmStart::Auto)] {
            assert_eq!(read(gsenc_config { warm_start: code, ..d() }).series.warm, warm);
        }
        for (code, payload) in [
            (GSENC_PAYLOAD_F32, Payload::Float32),
            (GSENC_PAYLOAD_8BIT, Payload::Bits8(CentreCoding::Float16)),
            (GSENC_PAYLOAD_8BIT_U16, Payload::Bits8(CentreCoding::Fixed16)),
            (GSENC_PAYLOAD_PACKED, Payload::Packed),
        ] {
            assert_eq!(read(gsenc_config { payload: code, ..d() }).series.payload, payload);
        }
        for (code, transform) in [(GSENC_TRANSFORM_LINEAR, Transform::Linear), (GSENC_TRANSFORM_LOG10, Transform::Log10)] {
            assert_eq!(read(gsenc_config { transform: code, ..d() }).series.range, SeriesRange::FirstStep(transform));
            let fixed = read(gsenc_config { transform: code, fixed_range: 1, value_min: 0.5, value_max: 4.0, ..d() });
            assert_eq!(fixed.series.range, SeriesRange::Fixed(ValueRange { vmin: 0.5, vmax: 4.0, transform }));
        }
        for (code, when) in [(GSENC_QUEUE_BLOCK, WhenFull::Block), (GSENC_QUEUE_SKIP, WhenFull::Skip), (GSENC_QUEUE_BUSY, WhenFull::Busy)] {
            assert_eq!(read(gsenc_config { when_full: code, ..d() }).when_full, when);
        }
        for (code, format) in [(GSENC_OUTPUT_FOLDER, OutputFormat::Folder), (GSENC_OUTPUT_HDF5, OutputFormat::Hdf5)] {
            assert_eq!(read(gsenc_config { output_format: code, ..d() }).output_format, format);
        }
        for (code, stored) in [(GSENC_SUPPORT_STORED, true), (GSENC_SUPPORT_NONE, false)] {
            assert_eq!(read(gsenc_config { support: code, ..d() }).series.store_support, stored);
        }
        for (code, kind) in [(GSENC_BACKEND_AUTO, BackendKind::Auto), (GSENC_BACKEND_CPU, BackendKind::Cpu), (GSENC_BACKEND_GPU, BackendKind::Gpu)] {
            assert_eq!(read(gsenc_config { backend: code, ..d() }).backend.kind, kind);
        }
        for (code, priority) in [(GSENC_PRIORITY_NORMAL, Priority::Normal), (GSENC_PRIORITY_LOW, Priority::Low), (GSENC_PRIORITY_IDLE, Priority::Idle)] {
            assert_eq!(read(gsenc_config { encoder_priority: code, ..d() }).placement.priority, priority);
        }
        let s = read(gsenc_config {
            budget: 777,
            iterations: 90,
            points: 5000,
            warm_iterations: 40,
            seed_init: 11,
            seed_sample: 12,
            rank: 3,
            dims: [5, 6, 7],
            has_bounds: 1,
            bounds_min: [-1.0, 0.0, 2.0],
            bounds_max: [1.0, 0.5, 3.0],
            threads: 2,
            queue_bytes: 4096,
            halo: 3,
            gpu_index: 1,
            ..d()
        });
        let e = &s.series.encode;
        assert_eq!((e.budget, e.iterations, e.points, e.seed_init, e.seed_sample), (777, Some(90), Some(5000), 11, 12));
        assert_eq!((s.series.warm_iterations, s.series.rank, s.dims), (Some(40), 3, [5, 6, 7]));
        assert_eq!(s.bounds, Some(Bounds { min: [-1.0, 0.0, 2.0], max: [1.0, 0.5, 3.0] }));
        assert_eq!((s.threads, s.queue_bytes, s.halo, s.backend.gpu_index), (2, 4096, 3, Some(1)));
        let s = read(d());
        assert_eq!((s.series.encode.iterations, s.series.encode.points, s.series.warm_iterations, s.bounds, s.backend.gpu_index), (None, None, None, None, None));
    }

    /// A field that holds no value of its kind is refused at create, the
    /// message naming the field or the value.
    #[test]
    fn a_field_without_a_value_of_its_kind_is_refused_by_name() {
        let d = gsenc_config::defaults;
        let nan = f64::NAN;
        for (c, says) in [
            (gsenc_config { warm_start: 4, ..d() }, "unknown warm start 4"),
            (gsenc_config { transform: 2, ..d() }, "unknown transform 2"),
            (gsenc_config { payload: 9, ..d() }, "unknown payload 9"),
            (gsenc_config { when_full: 3, ..d() }, "unknown when_full 3"),
            (gsenc_config { output_format: -1, ..d() }, "unknown output_format -1"),
            (gsenc_config { encoder_priority: 3, ..d() }, "unknown encoder_priority 3"),
            (gsenc_config { gpu_index: -2, ..d() }, "gpu_index -2"),
            (gsenc_config { queue_bytes: 0, ..d() }, "queue_bytes 0 must be positive"),
            (gsenc_config { dims: [4, 0, 4], ..d() }, "dims [4, 0, 4] must be positive"),
            (gsenc_config { fixed_range: 1, value_min: 2.0, value_max: 2.0, ..d() }, "value range"),
            (gsenc_config { fixed_range: 1, value_min: nan, value_max: 2.0, ..d() }, "value range"),
            (gsenc_config { has_bounds: 1, bounds_min: [0.0, 1.0, 0.0], bounds_max: [1.0, 1.0, 1.0], ..d() }, "are not a box"),
            (gsenc_config { has_bounds: 1, bounds_min: [0.0, 0.0, 2.0], bounds_max: [1.0, 1.0, 1.0], ..d() }, "are not a box"),
            (gsenc_config { has_bounds: 1, bounds_min: [nan, 0.0, 0.0], ..d() }, "are not a box"),
            (gsenc_config { has_bounds: 1, bounds_max: [1.0, f64::INFINITY, 1.0], ..d() }, "are not a box"),
            (gsenc_config { preview: GSENC_PREVIEW_SLICE, preview_axis: -1, ..d() }, "preview_axis -1"),
        ] {
            let f = refusal(c, says);
            assert_eq!(f.0, gsenc_status::InvalidArgument, "{says}: {}", f.1);
            assert!(f.1.contains(says), "wanted '{says}', got {}", f.1);
        }
        // Without a fixed range, its values are not looked at; without
        // bounds, neither are theirs.
        read(gsenc_config { value_min: nan, value_max: nan, ..d() });
        read(gsenc_config { bounds_min: [nan; 3], ..d() });
    }
}
