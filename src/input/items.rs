//! The common form of particles and cells on their way into the encoder:
//! each input item, in the index frame, becomes at most one sample and at
//! most one splat of the deposit (METHOD.md "Samples", "Reference grid").

use crate::field::IndexFrame;
use crate::input::deposit::Splat;

/// One input item in the index frame.
pub(crate) struct Item {
    pub u: [f64; 3],
    /// The sample's initial scale `h` (voxels).
    pub sample_scale: f64,
    /// The sample's importance `m` in the caller's units.
    pub importance: f64,
    /// Whether `u` lies inside the bounds (only then is the item a sample).
    pub inside: bool,
    /// Its share of the deposit, `None` when it reaches no voxel.
    pub splat: Option<Splat>,
    /// True when the splat is the nearest-voxel fallback.
    pub nearest: bool,
}

/// An input form that turns into samples and splats, item by item.
pub(crate) trait Conversion: Sync {
    fn item_count(&self) -> usize;
    fn item(&self, j: usize, frame: &IndexFrame, value: f32) -> Item;
}
