//! Particle and cell input made ready for the encoder: the index frame, the
//! value range, the samples that seed the model and the deposited reference
//! grid that supervises it (SPEC.md "Frames and units", "Samples", "Reference
//! grid"). Grids need none of this: they are their own reference.

use crate::cells::Cells;
use crate::deposit::{deposit, lattice_len, DepositStats, Splat};
use crate::encoder::Target;
use crate::error::{Error, Result};
use crate::field::{Grid, IndexFrame, Transform, ValueRange};
use crate::particles::Particles;
use crate::samples::{Sample, SampleArrays, SampleSet};
use rayon::prelude::*;
use std::time::Instant;

/// An axis-aligned box in world units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Bounds {
    /// The smallest box holding every `(lo, hi)` corner pair.
    pub(crate) fn enclosing(boxes: impl ParallelIterator<Item = ([f64; 3], [f64; 3])>) -> Bounds {
        let empty = || Bounds { min: [f64::INFINITY; 3], max: [f64::NEG_INFINITY; 3] };
        boxes.fold(empty, |b, (lo, hi)| b.union(lo, hi)).reduce(empty, |a, b| a.union(b.min, b.max))
    }

    /// Dims with `longest` voxels along the box's longest axis and cubic
    /// voxels, so that an elongated box is not padded to a cube of empty space.
    pub fn fitted_dims(&self, longest: usize) -> Result<[usize; 3]> {
        let ext = [0, 1, 2].map(|a| self.max[a] - self.min[a]);
        if longest == 0 || ext.iter().any(|e| !(e.is_finite() && *e >= 0.0)) {
            return Err(Error::arg(format!("cannot fit {longest} voxels to the box {:?} .. {:?}", self.min, self.max)));
        }
        let emax = ext.iter().cloned().fold(0.0, f64::max);
        if emax <= 0.0 {
            return Err(Error::arg("the box is a single point; give bounds explicitly"));
        }
        Ok(ext.map(|e| ((e / emax * longest as f64).round() as usize).max(1)))
    }

    fn union(self, lo: [f64; 3], hi: [f64; 3]) -> Bounds {
        Bounds { min: [0, 1, 2].map(|a| self.min[a].min(lo[a])), max: [0, 1, 2].map(|a| self.max[a].max(hi[a])) }
    }
}

/// Where the reference grid lies: its dims, and its world bounds (those of the
/// data when `None`). Voxels are cubic: `gamma = min_a D_a / extent_a`, so the
/// lattice may extend past `bounds.max` on all but the tightest axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub dims: [usize; 3],
    pub bounds: Option<Bounds>,
}

/// How values are normalised to `[0, 1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RangeSpec {
    /// The range of the transformed data. Under `Log10` every value must be
    /// positive (otherwise an error names the first offender).
    FromData(Transform),
    /// A given range, as for every step of a time series. Values outside it
    /// are clamped and counted; under `Log10`, zero and negative values are
    /// floored to `vmin` (normalised 0), never NaN.
    Fixed(ValueRange),
}

impl RangeSpec {
    pub fn resolve(&self, values: &[f32]) -> Result<ValueRange> {
        match *self {
            RangeSpec::FromData(t) => ValueRange::from_data(values, t),
            RangeSpec::Fixed(r) => Ok(r),
        }
    }
}

/// What the encoder and the user need from particle or cell input.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub frame: IndexFrame,
    pub range: ValueRange,
    /// The deposit, normalised to `[0, 1]`: the supervision target.
    pub reference: Grid,
    /// Items inside the bounds, in input order.
    pub samples: SampleArrays,
    /// Values clamped into the range (only with a fixed range).
    pub clamped_values: usize,
    pub deposit: DepositStats,
}

impl Prepared {
    pub fn target(&self) -> Target<'_> {
        Target { reference: &self.reference, samples: &self.samples }
    }
}

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

/// Samples and deposit of SPH particles.
pub fn prepare_particles(p: &Particles, placement: &Placement, range: &RangeSpec) -> Result<Prepared> {
    p.validate()?;
    let bounds = placement.bounds.unwrap_or_else(|| p.bounds());
    prepare(p, p.values, placement.dims, bounds, range)
}

/// Samples and volume-weighted deposit of hexahedral cells.
pub fn prepare_cells(c: &Cells, placement: &Placement, range: &RangeSpec) -> Result<Prepared> {
    c.validate()?;
    let bounds = placement.bounds.unwrap_or_else(|| c.bounds());
    prepare(c, c.values, placement.dims, bounds, range)
}

fn prepare(items: &dyn Conversion, values: &[f32], dims: [usize; 3], bounds: Bounds, range: &RangeSpec) -> Result<Prepared> {
    lattice_len(dims)?;
    let frame = IndexFrame::from_bounds(dims, bounds.min, bounds.max).map_err(|e| match e {
        Error::InvalidArgument(m) => Error::arg(format!("{m}; give bounds explicitly when the data are flat on an axis")),
        other => other,
    })?;
    let range = range.resolve(values)?;
    let norm = range.normalize(values)?;
    let started = Instant::now();
    let converted: Vec<Item> = (0..items.item_count()).into_par_iter().map(|j| items.item(j, &frame, norm.values[j])).collect();

    let mut stats = DepositStats { items: converted.len(), ..Default::default() };
    let max_importance = converted.iter().filter(|it| it.inside).fold(0f64, |a, it| a.max(it.importance));
    let mut samples = SampleArrays::default();
    let mut splats = Vec::with_capacity(converted.len());
    for (it, &v) in converted.iter().zip(&norm.values) {
        stats.outside += !it.inside as usize;
        stats.outside_dropped += (!it.inside && it.splat.is_none()) as usize;
        stats.nearest_voxel += it.nearest as usize;
        if it.inside {
            samples.push(Sample {
                q: it.u.map(|c| c as f32),
                h: it.sample_scale as f32,
                v,
                // Importance only matters through ratios (m^0.6); dividing by
                // the largest keeps tiny masses or volumes representable in f32.
                m: if max_importance > 0.0 { (it.importance / max_importance) as f32 } else { 0.0 },
            });
        }
        splats.extend(it.splat);
    }
    drop(converted);
    if samples.is_empty() {
        return Err(Error::data(format!(
            "none of the {} items lies inside the bounds {:?} .. {:?}",
            stats.items, bounds.min, bounds.max
        )));
    }
    let (reference, deposit_stats) = deposit(dims, &splats, stats, started)?;
    tracing::info!(
        items = deposit_stats.items,
        outside = deposit_stats.outside,
        outside_dropped = deposit_stats.outside_dropped,
        nearest_voxel = deposit_stats.nearest_voxel,
        seconds = deposit_stats.seconds,
        "deposit done"
    );
    Ok(Prepared { frame, range, reference, samples, clamped_values: norm.clamped, deposit: deposit_stats })
}
