//! Time series: the series encoder, which warm-starts each step of a field
//! from its previous model ([`encoder`]), and the background queue that runs
//! it beside a simulation ([`queue`]) on the CPUs and at the priority its
//! [`placement`] names.

pub mod encoder;
pub mod placement;
pub mod queue;

pub use encoder::{SeriesConfig, SeriesEncoder, SeriesRange, StepResult};
