//! The encoder (METHOD.md "Seeding" through "Schedules"), on memory only.
//!
//! [`pipeline`] is the one path every caller takes (the command-line tool,
//! the series encoder, the background queue, hence the C API and MPI):
//! prepare the input, encode it (seeded or warm-started), score the model as
//! it will be stored, and build the model with its metadata ([`fixed`]). Below it:
//! [`config`] (budget, schedules, warm regimes), [`seeding`] (the three
//! streams), [`points`] (the stratified training points, the paper's or gsenc's rule), [`relocate`],
//! [`refine`] (the optimisation loop), [`validation`] (a fixed point set
//! scored along the way), [`precision`] (what the packed payload needs), [`stored`] (a model decoded
//! as its file will read),
//! [`target`] (the budget that reaches a PSNR, with [`insert`] growing a
//! model), and for `auto` warm starts [`repair`] (where the
//! previous model misses the new step) and [`plateau`] (when to stop).

pub mod config;
pub mod fixed;
pub mod insert;
pub mod pipeline;
pub mod plateau;
pub mod points;
pub mod precision;
pub mod refine;
pub mod relocate;
pub mod repair;
pub mod seeding;
pub mod stored;
pub mod target;
pub mod validation;

pub use config::{Cancel, EncodeConfig, PointRule, Schedule, TargetPsnr, WarmStart};
pub use refine::{encode, encode_validated, spatial_order, validate, EncodeOutput, LossTerms, Progress};
pub use validation::Validation;
