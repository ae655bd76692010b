//! Time series: the series encoder, which warm-starts each step of a field
//! from its previous model ([`encoder`]), and the background queue that runs
//! it beside a simulation ([`queue`]).

pub mod encoder;
pub mod queue;

pub use encoder::{SeriesConfig, SeriesEncoder, SeriesRange, StepResult};
