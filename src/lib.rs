//! gsenc: encode 3D scalar fields into a fixed budget of scalar-carrying
//! anisotropic Gaussians, and decode them at any resolution.
//!
//! The method is the sample-based fixed-budget encoder of the reference paper,
//! with every open choice pinned down by `SPEC.md`. Layers, from the inside out:
//! - [`kernel`], [`loss`]: the one mathematical definition of a primitive, its
//!   kernel, the objective and their gradients;
//! - [`backend`]: evaluators of that math ([`backend::cpu::CpuBackend`]);
//! - [`particles`], [`cells`], [`deposit`], [`reference`]: particle and cell
//!   input turned into samples and a deposited reference grid;
//! - [`samples`], [`seeding`], [`points`], [`optim`], [`relocate`], [`encoder`]:
//!   the encoder itself, on memory only;
//! - [`series`], [`queue`]: time series with warm starts, and the background
//!   queue that encodes them beside a running simulation;
//! - [`global`], [`halo`], `mpi` (feature `mpi`): per-rank pieces of a
//!   decomposed domain, the data each needs, and one global model from them;
//! - [`model`], [`format`], [`metrics`]: models, their file format and scores;
//! - [`io`]: files (raw arrays, VTK ImageData, crash-safe writes), used by the
//!   command-line tool and the C API, never by the core.
//!
//! ```no_run
//! use gsenc::{backend::cpu::CpuBackend, encoder::*, field::*, samples::GridSamples};
//! let raw = Grid::new([32, 32, 32], vec![0.5; 32 * 32 * 32]).unwrap();
//! let range = ValueRange::new(0.0, 1.0, Transform::Linear).unwrap();
//! let reference = Grid::new(raw.dims, range.normalize(&raw.values).unwrap().values).unwrap();
//! let samples = GridSamples { grid: &reference };
//! let target = Target { reference: &reference, samples: &samples };
//! let cfg = EncodeConfig::new(1000, Schedule::Short);
//! let out = encode(&target, &cfg, None, &mut CpuBackend::new(), &mut |_| {}).unwrap();
//! assert_eq!(out.params.len(), 1000);
//! ```

pub mod backend;
pub mod cells;
pub mod deposit;
pub mod encoder;
pub mod error;
pub mod field;
pub mod format;
pub mod global;
pub mod halo;
pub mod io;
pub mod kernel;
pub mod loss;
pub mod metrics;
pub mod model;
pub mod optim;
pub mod particles;
pub mod points;
pub mod quantize;
pub mod reference;
pub mod relocate;
pub mod rng;
pub mod samples;
pub mod seeding;
pub mod queue;
pub mod series;
#[cfg(feature = "mpi")]
pub mod mpi;

#[path = "../capi/mod.rs"]
pub mod capi;

pub use error::{Error, Result};

/// The library version, `major.minor.patch`.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
