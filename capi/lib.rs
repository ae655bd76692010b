//! The C ABI of gsenc (`libgsenc`, header `include/gsenc.h`): a thin layer
//! over the library's Rust API. Every function is `extern "C"`, returns a
//! `gsenc_status` (or nothing, for destroy), never unwinds into C (each body
//! runs in `status::guard`) and prints nothing unless `GSENC_LOG` asks
//! (`log`); the message of a failure is the calling thread's
//! `gsenc_last_error`.
//!
//! One file per concept of the C surface:
//! - `status`: codes, the thread's last error, the panic guard;
//! - `log`: gsenc's events on the standard error, when `GSENC_LOG` asks;
//! - `handles`: the live handles, so misused ones are refused;
//! - `ffi`: what every entry point shares (sized structs, strings, strided
//!   copies of the caller's arrays);
//! - `config`: the encoder's settings;
//! - `encoder`: the encoder's life cycle (create, MPI create, destroy);
//! - `inputs`: the grid, particle and cell forms and their pushes;
//! - `jobs`: following the queue (wait, poll, cancel) and its results;
//! - `resume`: a series taken up again after a restart;
//! - `model`: read a model file, decode it, evaluate it.
//!
//! The Fortran module `gsenc` (capi/gsenc.f90) binds these functions.
//! Inside this crate `gsenc::` is the library it wraps.

#![allow(non_camel_case_types)]

pub mod config;
pub mod encoder;
mod ffi;
mod handles;
mod log;
pub mod inputs;
pub mod jobs;
pub mod model;
pub mod resume;
pub mod status;

// The helpers the library's test suites share (tests/common/), once for
// both test modules below.
#[cfg(test)]
#[path = "../tests/common/mod.rs"]
mod common;
#[cfg(test)]
mod fortran_binding_tests;
#[cfg(test)]
mod header_text;
#[cfg(all(test, feature = "hdf5"))]
mod hdf5_tests;
#[cfg(test)]
mod null_tests;
#[cfg(test)]
mod thread_tests;
#[cfg(test)]
mod walk_tests;

pub use ffi::{GSENC_DTYPE_FLOAT32, GSENC_DTYPE_FLOAT64};

/// Major version of the library (changes break the ABI).
pub const GSENC_VERSION_MAJOR: u32 = 0;
/// Minor version (append-only additions).
pub const GSENC_VERSION_MINOR: u32 = 1;
/// Patch version.
pub const GSENC_VERSION_PATCH: u32 = 0;

/// The run-time library version as `major * 10000 + minor * 100 + patch`, to
/// compare with the compile-time `GSENC_VERSION_*` macros. Thread-safe.
#[no_mangle]
pub extern "C" fn gsenc_version() -> u32 {
    GSENC_VERSION_MAJOR * 10000 + GSENC_VERSION_MINOR * 100 + GSENC_VERSION_PATCH
}

/// The run-time library version as a static NUL-terminated string
/// ("0.1.0"); owned by the library, never freed by the caller. Thread-safe.
#[no_mangle]
pub extern "C" fn gsenc_version_string() -> *const std::os::raw::c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

#[cfg(test)]
mod tests {
    use super::config::*;
    use super::inputs::*;
    use super::jobs::*;
    use super::model::*;
    use super::status::gsenc_status;
    use std::mem::{offset_of, size_of};

    /// The ABI, frozen: sizes, offsets and values may only be appended to
    /// (x86_64 and aarch64 Linux, LP64).
    #[test]
    fn abi_is_pinned() {
        assert_eq!(size_of::<gsenc_config>(), 256);
        let c = [
            (offset_of!(gsenc_config, struct_size), 0),
            (offset_of!(gsenc_config, budget), 8),
            (offset_of!(gsenc_config, schedule), 16),
            (offset_of!(gsenc_config, warm_start), 20),
            (offset_of!(gsenc_config, iterations), 24),
            (offset_of!(gsenc_config, points), 28),
            (offset_of!(gsenc_config, transform), 32),
            (offset_of!(gsenc_config, fixed_range), 36),
            (offset_of!(gsenc_config, value_min), 40),
            (offset_of!(gsenc_config, value_max), 48),
            (offset_of!(gsenc_config, dims), 56),
            (offset_of!(gsenc_config, has_bounds), 68),
            (offset_of!(gsenc_config, bounds_min), 72),
            (offset_of!(gsenc_config, bounds_max), 96),
            (offset_of!(gsenc_config, payload), 120),
            (offset_of!(gsenc_config, threads), 124),
            (offset_of!(gsenc_config, seed_init), 128),
            (offset_of!(gsenc_config, seed_sample), 136),
            (offset_of!(gsenc_config, rank), 144),
            (offset_of!(gsenc_config, support), 148),
            (offset_of!(gsenc_config, output_dir), 152),
            (offset_of!(gsenc_config, warm_iterations), 160),
            (offset_of!(gsenc_config, when_full), 164),
            (offset_of!(gsenc_config, queue_bytes), 168),
            (offset_of!(gsenc_config, output_format), 176),
            (offset_of!(gsenc_config, halo), 180),
            (offset_of!(gsenc_config, backend), 184),
            (offset_of!(gsenc_config, gpu_index), 188),
            (offset_of!(gsenc_config, preview), 192),
            (offset_of!(gsenc_config, preview_axis), 196),
            (offset_of!(gsenc_config, preview_at), 200),
            (offset_of!(gsenc_config, preview_azimuth), 208),
            (offset_of!(gsenc_config, preview_elevation), 216),
            (offset_of!(gsenc_config, preview_width), 224),
            (offset_of!(gsenc_config, preview_height), 228),
            (offset_of!(gsenc_config, target_psnr), 232),
            (offset_of!(gsenc_config, encoder_cpus), 240),
            (offset_of!(gsenc_config, encoder_priority), 248),
        ];
        for (i, (got, want)) in c.iter().enumerate() {
            assert_eq!(got, want, "gsenc_config field {i}");
        }
        assert_eq!(size_of::<gsenc_grid>(), 104);
        assert_eq!(
            [offset_of!(gsenc_grid, dtype), offset_of!(gsenc_grid, data), offset_of!(gsenc_grid, extents), offset_of!(gsenc_grid, strides), offset_of!(gsenc_grid, origin), offset_of!(gsenc_grid, spacing)],
            [8, 16, 24, 48, 72, 96]
        );
        assert_eq!(size_of::<gsenc_particles>(), 96);
        assert_eq!(
            [offset_of!(gsenc_particles, count), offset_of!(gsenc_particles, positions), offset_of!(gsenc_particles, position_stride), offset_of!(gsenc_particles, position_component_stride), offset_of!(gsenc_particles, smoothing_length), offset_of!(gsenc_particles, smoothing_length_stride), offset_of!(gsenc_particles, mass), offset_of!(gsenc_particles, mass_stride), offset_of!(gsenc_particles, values), offset_of!(gsenc_particles, value_stride)],
            [16, 24, 32, 40, 48, 56, 64, 72, 80, 88]
        );
        assert_eq!(size_of::<gsenc_cells>(), 128);
        assert_eq!(
            [offset_of!(gsenc_cells, layout), offset_of!(gsenc_cells, count), offset_of!(gsenc_cells, centres), offset_of!(gsenc_cells, edges), offset_of!(gsenc_cells, points), offset_of!(gsenc_cells, point_count), offset_of!(gsenc_cells, connectivity), offset_of!(gsenc_cells, values), offset_of!(gsenc_cells, value_stride)],
            [12, 16, 24, 48, 72, 80, 104, 112, 120]
        );
        assert_eq!([GSENC_CELLS_BOXES, GSENC_CELLS_HEXAHEDRA], [0, 1]);
        assert_eq!(size_of::<gsenc_model_info>(), 128);
        assert_eq!(
            [offset_of!(gsenc_model_info, count), offset_of!(gsenc_model_info, dims), offset_of!(gsenc_model_info, origin), offset_of!(gsenc_model_info, spacing), offset_of!(gsenc_model_info, step), offset_of!(gsenc_model_info, time), offset_of!(gsenc_model_info, rank), offset_of!(gsenc_model_info, iterations), offset_of!(gsenc_model_info, warm_started), offset_of!(gsenc_model_info, encode_psnr), offset_of!(gsenc_model_info, fell_back), offset_of!(gsenc_model_info, warm_taken), offset_of!(gsenc_model_info, warm_moved)],
            [8, 16, 40, 64, 72, 80, 88, 92, 96, 104, 112, 116, 120]
        );
        assert_eq!([GSENC_WARM_TAKEN_NONE, GSENC_WARM_TAKEN_KEPT, GSENC_WARM_TAKEN_REPAIRED, GSENC_WARM_TAKEN_FRESH], [0, 1, 2, 3]);
        assert_eq!(size_of::<gsenc_status>(), 4);
        let statuses = [
            gsenc_status::Ok,
            gsenc_status::NullPointer,
            gsenc_status::InvalidArgument,
            gsenc_status::InvalidData,
            gsenc_status::Format,
            gsenc_status::Version,
            gsenc_status::Io,
            gsenc_status::CallOrder,
            gsenc_status::StructSize,
            gsenc_status::Internal,
            gsenc_status::Busy,
            gsenc_status::Skipped,
            gsenc_status::Cancelled,
            gsenc_status::Mpi,
            gsenc_status::Device,
        ];
        for (i, s) in statuses.iter().enumerate() {
            assert_eq!(*s as i32, i as i32);
        }
        assert_eq!([GSENC_SCHEDULE_FULL, GSENC_SCHEDULE_MATCHED, GSENC_SCHEDULE_SHORT, GSENC_SCHEDULE_TUNED, GSENC_SCHEDULE_TUNED_FULL], [0, 1, 2, 3, 4]);
        assert_eq!([GSENC_WARM_OFF, GSENC_WARM_COARSE, GSENC_WARM_DENSE, GSENC_WARM_AUTO], [0, 1, 2, 3]);
        assert_eq!([GSENC_TRANSFORM_LINEAR, GSENC_TRANSFORM_LOG10], [0, 1]);
        assert_eq!([GSENC_PAYLOAD_F32, GSENC_PAYLOAD_8BIT, GSENC_PAYLOAD_8BIT_U16, GSENC_PAYLOAD_PACKED], [0, 1, 2, 3]);
        assert_eq!([super::GSENC_DTYPE_FLOAT32, super::GSENC_DTYPE_FLOAT64], [0, 1]);
        assert_eq!([GSENC_QUEUE_BLOCK, GSENC_QUEUE_SKIP, GSENC_QUEUE_BUSY], [0, 1, 2]);
        assert_eq!([GSENC_OUTPUT_FOLDER, GSENC_OUTPUT_HDF5], [0, 1]);
        assert_eq!([GSENC_BACKEND_AUTO, GSENC_BACKEND_CPU, GSENC_BACKEND_GPU], [0, 1, 2]);
        assert_eq!([GSENC_SUPPORT_STORED, GSENC_SUPPORT_NONE], [0, 1]);
        assert_eq!([GSENC_PREVIEW_NONE, GSENC_PREVIEW_SLICE, GSENC_PREVIEW_VOLUME], [0, 1, 2]);
        assert_eq!([GSENC_PRIORITY_NORMAL, GSENC_PRIORITY_LOW, GSENC_PRIORITY_IDLE], [0, 1, 2]);
        assert_eq!(size_of::<gsenc_job>(), 32);
        assert_eq!(
            [offset_of!(gsenc_job, state), offset_of!(gsenc_job, iteration), offset_of!(gsenc_job, iterations), offset_of!(gsenc_job, error), offset_of!(gsenc_job, psnr)],
            [8, 12, 16, 20, 24]
        );
        assert_eq!(
            [GSENC_JOB_QUEUED, GSENC_JOB_RUNNING, GSENC_JOB_DONE, GSENC_JOB_FAILED, GSENC_JOB_SKIPPED, GSENC_JOB_CANCELLED],
            [0, 1, 2, 3, 4, 5]
        );
    }

    /// Every prototype of the header, frozen as the layouts and values
    /// above are: a function may be added (with its line here), never
    /// changed or removed. The header is read as text (`header_text.rs`).
    #[test]
    fn prototypes_are_pinned() {
        const PINNED: [&str; 28] = [
            "gsenc_status gsenc_config_init(gsenc_config *config)",
            "gsenc_status gsenc_encoder_cancel(gsenc_encoder *encoder)",
            "gsenc_status gsenc_encoder_create(const gsenc_config *config, gsenc_encoder **out)",
            "gsenc_status gsenc_encoder_create_mpi(const gsenc_config *config, int32_t comm, gsenc_encoder **out)",
            "void gsenc_encoder_destroy(gsenc_encoder *encoder)",
            "gsenc_status gsenc_encoder_last_step(gsenc_encoder *encoder, const char *field, uint64_t *step, double *psnr)",
            "gsenc_status gsenc_encoder_model_bytes(gsenc_encoder *encoder, const char *field, uint8_t *buffer, size_t capacity, size_t *size)",
            "gsenc_status gsenc_encoder_reserve(gsenc_encoder *encoder, uint64_t values)",
            "gsenc_status gsenc_encoder_resume(gsenc_encoder *encoder, const gsenc_model *model)",
            "gsenc_status gsenc_encoder_resume_stored(gsenc_encoder *encoder, const char *field, uint64_t step)",
            "gsenc_status gsenc_encoder_write_model(gsenc_encoder *encoder, const char *field, const char *path)",
            "size_t gsenc_last_error(char *buf, size_t len)",
            "gsenc_status gsenc_model_decode(const gsenc_model *model, const uint64_t *dims, float *out, uint64_t out_len)",
            "void gsenc_model_destroy(gsenc_model *model)",
            "gsenc_status gsenc_model_evaluate(const gsenc_model *model, const double *points, uint64_t count, float *out)",
            "gsenc_status gsenc_model_field(const gsenc_model *model, char *buf, size_t len, size_t *length)",
            "gsenc_status gsenc_model_info_get(const gsenc_model *model, gsenc_model_info *info)",
            "gsenc_status gsenc_model_read(const char *path, gsenc_model **out)",
            "gsenc_status gsenc_model_read_buffer(const uint8_t *data, size_t size, gsenc_model **out)",
            "gsenc_status gsenc_poll(gsenc_encoder *encoder, const char *field, uint64_t step, gsenc_job *job)",
            "gsenc_status gsenc_push_cells(gsenc_encoder *encoder, const char *field, uint64_t step, double time, const gsenc_cells *cells)",
            "gsenc_status gsenc_push_grid(gsenc_encoder *encoder, const char *field, uint64_t step, double time, const gsenc_grid *grid)",
            "gsenc_status gsenc_push_particles(gsenc_encoder *encoder, const char *field, uint64_t step, double time, const gsenc_particles *particles)",
            "void gsenc_set_last_error(const char *message)",
            "const char *gsenc_status_string(int32_t status)",
            "uint32_t gsenc_version(void)",
            "const char *gsenc_version_string(void)",
            "gsenc_status gsenc_wait(gsenc_encoder *encoder, const char *field)",
        ];
        let header: std::collections::BTreeSet<String> = crate::header_text::c_header().functions.into_values().map(|f| f.text).collect();
        let changed: Vec<&str> = PINNED.iter().copied().filter(|p| !header.contains(*p)).collect();
        assert!(changed.is_empty(), "pinned prototypes changed or removed: {changed:#?}");
        let added: Vec<&String> = header.iter().filter(|h| !PINNED.contains(&h.as_str())).collect();
        assert!(added.is_empty(), "prototypes not pinned yet (pin them here): {added:#?}");
    }

    /// A panic inside an entry point becomes GSENC_STATUS_INTERNAL with a
    /// message, never an unwind into C.
    #[test]
    fn panics_become_internal_errors() {
        let s = super::status::guard(|| panic!("boom"));
        assert_eq!(s, gsenc_status::Internal);
        let mut buf = [0 as std::os::raw::c_char; 128];
        let n = unsafe { super::status::gsenc_last_error(buf.as_mut_ptr(), buf.len()) };
        let msg = unsafe { std::ffi::CStr::from_ptr(buf.as_ptr()) }.to_str().unwrap();
        assert_eq!(n, msg.len());
        assert!(msg.contains("boom"), "{msg}");
    }

    #[test]
    fn version_macros_match_the_crate_version() {
        let v: Vec<u32> = env!("CARGO_PKG_VERSION").split('.').map(|x| x.parse().unwrap()).collect();
        assert_eq!(super::gsenc_version(), v[0] * 10000 + v[1] * 100 + v[2]);
        let s = unsafe { std::ffi::CStr::from_ptr(super::gsenc_version_string()) };
        assert_eq!(s.to_str().unwrap(), env!("CARGO_PKG_VERSION"));
        // The header's macros, as a C caller compiles them.
        let c = crate::header_text::c_header().constants;
        let macros = ["GSENC_VERSION_MAJOR", "GSENC_VERSION_MINOR", "GSENC_VERSION_PATCH"].map(|m| c[m]);
        assert_eq!(macros.to_vec(), v.iter().map(|&x| i64::from(x)).collect::<Vec<_>>());
    }
}
