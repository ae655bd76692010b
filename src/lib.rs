//! gsenc: encode 3D scalar fields into a fixed budget of scalar-carrying
//! anisotropic Gaussians, and decode them at any resolution.
//!
//! The method is the sample-based fixed-budget encoder of Martin, Insley,
//! Mateevitsi, Rizzi and Ma, "3D Field Data Reduction with Adaptive
//! Sample-Based Gaussian-Encoded Reconstruction"; `docs/METHOD.md` gives it
//! as this library implements it, with every constant and every choice the
//! paper leaves open. Layers, from the inside out; each uses only those
//! above it in this list:
//! - [`profile`]: task timings for the thread-scaling model (feature
//!   `task-profile`; without it, nothing but the calls it wraps);
//! - [`threads`]: the rayon pools the work runs on (fork-safe);
//! - [`memory`]: how much memory the process can still take, so that what
//!   cannot fit is refused before it is allocated (a failed allocation
//!   aborts the process);
//! - [`math`]: the one definition of a primitive, its kernel, the objective,
//!   their gradients, Adam, the random stream;
//! - [`field`]: grids, value ranges, index frames and boxes;
//! - [`backend`]: evaluators of that math ([`backend::cpu::CpuBackend`]);
//! - [`input`]: grids, SPH particles and hexahedral cells turned into samples
//!   and a reference grid (the deposit of particles and cells);
//! - [`model`]: a model, its decoding, and PSNR;
//! - [`render`]: pictures of a decoded grid (axis slices, volume
//!   renderings, colour maps) and the image PSNR and SSIM between two;
//! - [`format`](mod@format): the model file, its payloads, the step index, file names;
//! - [`encode`]: seeding, training points, relocation, the refinement loop,
//!   and the one encode [`encode::pipeline`] every caller goes through;
//! - [`series`]: time series with warm starts, and the background queue that
//!   encodes them beside a running simulation;
//! - [`domain`]: pieces of a decomposed domain: halo routing, the global
//!   field of a step, and MPI (feature `mpi`);
//! - [`io`]: files (raw arrays, VTK ImageData, crash-safe writes, folders of
//!   models, the HDF5 store with feature `hdf5`, charts).
//!
//! The C ABI (`capi/`, `libgsenc`) and the command-line tool (`cli/`) are
//! separate crates over this one.
//!
//! ```no_run
//! use gsenc::encode::{pipeline, EncodeConfig, Schedule};
//! use gsenc::field::{Grid, IndexFrame, Transform, ValueRange};
//! use gsenc::input::{Input, RangeSpec};
//! let values = (0..32 * 32 * 32).map(|i| (i % 32) as f32 / 31.0).collect();
//! let grid = Grid::new([32, 32, 32], values).unwrap();
//! let frame = IndexFrame::for_grid(grid.dims, [0.0; 3], 1.0).unwrap();
//! let range = RangeSpec::Fixed(ValueRange::new(0.0, 1.0, Transform::Linear).unwrap());
//! let request = pipeline::Request::new(EncodeConfig::new(1000, Schedule::Short));
//! let mut backend = gsenc::backend::cpu::CpuBackend::new();
//! let (_, encoded) = pipeline::encode(&Input::Grid { values: &grid, frame }, &range, &request, &mut backend, &mut |_| {}).unwrap();
//! assert_eq!(encoded.model.params.len(), 1000);
//! println!("{} dB as stored", encoded.psnr);
//! ```

pub mod backend;
pub mod domain;
pub mod encode;
pub mod error;
pub mod field;
pub mod format;
pub mod input;
pub mod io;
pub mod math;
pub mod memory;
pub mod profile;
pub mod model;
pub mod render;
pub mod series;
pub mod threads;

pub use error::{Error, Result};

/// The library version, `major.minor.patch`.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
