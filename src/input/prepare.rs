//! Input made ready for the encoder, whatever its form: the index frame, the
//! value range, the samples that seed the model and the reference grid that
//! supervises it (METHOD.md "Frames and units", "Samples", "Reference grid").
//! A grid is its own reference and its voxels are its samples; particles and
//! cells become samples and a deposit, item by item.

use crate::error::{Error, Result};
use crate::field::{Bounds, Grid, IndexFrame, Transform, ValueRange};
use crate::input::cells::Cells;
use crate::input::deposit::{deposit, lattice_len, DepositStats, Splat};
use crate::input::items::{Conversion, Item};
use crate::input::particles::Particles;
use crate::input::samples::{Sample, SampleArrays, SampleSet};
use crate::input::Target;
use rayon::prelude::*;
use std::time::Instant;

/// Where the reference grid lies: its dims, and its world bounds (those of the
/// data when `None`). Voxels are cubic: `gamma = min_a D_a / extent_a`, so the
/// lattice may extend past `bounds.max` on all but the tightest axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub dims: [usize; 3],
    pub bounds: Option<Bounds>,
    /// Per axis, whether the lattice goes on past its low and its high face
    /// (a domain piece's faces towards other pieces: `domain::halo`). An
    /// item near such a face whose deposit misses this lattice lies beyond
    /// the face, in the larger lattice, and is not put into this lattice's
    /// nearest voxel as an item at the lattice's own edge is.
    pub continues: [[bool; 2]; 3],
}

impl Placement {
    /// A lattice of `dims` over `bounds` (the data's when `None`) that is
    /// the whole of its domain.
    pub fn new(dims: [usize; 3], bounds: Option<Bounds>) -> Placement {
        Placement { dims, bounds, continues: [[false; 2]; 3] }
    }

    /// A piece of a larger lattice (it goes on past a face).
    pub fn is_piece(&self) -> bool {
        self.continues != [[false; 2]; 3]
    }

    /// The placement from `dims`, or from `fit_dims` voxels along the longest
    /// axis of `bounds` (those of the data, asked for only then); exactly one
    /// of the two must be given.
    pub fn resolve(dims: Option<[usize; 3]>, fit_dims: Option<usize>, bounds: Option<Bounds>, data_bounds: impl FnOnce() -> Bounds) -> Result<Placement> {
        let dims = match (dims, fit_dims) {
            (Some(_), Some(_)) => return Err(Error::arg("give the dims or the voxels along the longest axis (fit dims), not both")),
            (Some(d), None) => d,
            (None, Some(n)) => bounds.unwrap_or_else(data_bounds).fitted_dims(n)?,
            (None, None) => return Err(Error::arg("give the dims (x, y, z) or the voxels along the longest axis (fit dims)")),
        };
        Ok(Placement::new(dims, bounds))
    }
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
    /// A given `[lo, hi]` range (in data units) or the data's own, under
    /// `log10` or not.
    pub fn of(range: Option<[f64; 2]>, log10: bool) -> Result<RangeSpec> {
        let transform = if log10 { Transform::Log10 } else { Transform::Linear };
        Ok(match range {
            Some([lo, hi]) => RangeSpec::Fixed(ValueRange::new(lo, hi, transform)?),
            None => RangeSpec::FromData(transform),
        })
    }

    pub fn resolve(&self, values: &[f32]) -> Result<ValueRange> {
        match *self {
            RangeSpec::FromData(t) => ValueRange::from_data(values, t),
            RangeSpec::Fixed(r) => Ok(r),
        }
    }
}

/// One field of one step as the caller holds it, in data units.
#[derive(Clone, Copy)]
pub enum Input<'a> {
    /// A regular grid over `frame`.
    Grid { values: &'a Grid, frame: IndexFrame },
    /// SPH particles, deposited on `placement` and seeded from the particles.
    Particles { particles: &'a Particles<'a>, placement: Placement },
    /// SPH particles deposited as for `Particles`, then encoded as a grid:
    /// seeded from the deposit's voxels instead of the particles.
    ParticleDeposit { particles: &'a Particles<'a>, placement: Placement },
    /// Hexahedral cells, deposited on `placement` (volume-weighted).
    Cells { cells: &'a Cells<'a>, placement: Placement },
}

impl<'a> Input<'a> {
    /// What the encode is seeded from, once prepared.
    pub fn form(&self) -> Form {
        match self {
            Input::Grid { .. } | Input::ParticleDeposit { .. } => Form::Grid,
            Input::Particles { .. } => Form::Particles,
            Input::Cells { .. } => Form::Cells,
        }
    }

    /// The same input deposited in `bounds` (when given) whatever its
    /// placement says: every step of a series uses its first step's box.
    pub fn with_bounds(self, bounds: Option<Bounds>) -> Input<'a> {
        let Some(b) = bounds else { return self };
        let place = |p: Placement| Placement { bounds: Some(b), ..p };
        match self {
            Input::Grid { .. } => self,
            Input::Particles { particles, placement } => Input::Particles { particles, placement: place(placement) },
            Input::ParticleDeposit { particles, placement } => Input::ParticleDeposit { particles, placement: place(placement) },
            Input::Cells { cells, placement } => Input::Cells { cells, placement: place(placement) },
        }
    }
}

/// What a prepared input seeds the model from. Particles also run the
/// `full` schedule longer (METHOD.md "Schedules").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Form {
    /// The reference grid's voxels (a grid, or a deposit encoded as a grid).
    Grid,
    Particles,
    Cells,
}

/// An input ready for the encoder.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub form: Form,
    pub frame: IndexFrame,
    pub range: ValueRange,
    /// Normalised to `[0, 1]`: the supervision target (a grid itself, or the
    /// deposit of particles or cells).
    pub reference: Grid,
    /// Particles or cells inside the bounds, in input order; `None` when the
    /// reference's voxels are the samples.
    pub samples: Option<SampleArrays>,
    /// The world box particles or cells were deposited in (`None` for grids).
    pub bounds: Option<Bounds>,
    /// Values clamped into the range (only with a fixed range).
    pub clamped_values: usize,
    /// What the deposit saw and cost (particles and cells).
    pub deposit: Option<DepositStats>,
}

impl Prepared {
    pub fn target(&self) -> Target<'_> {
        let samples: &dyn SampleSet = match &self.samples {
            Some(s) => s,
            None => &self.reference,
        };
        Target { reference: &self.reference, samples }
    }

    /// Particles or cells whose centres lie outside the bounds (they seed
    /// nothing; their support is clipped).
    pub fn outside_items(&self) -> usize {
        self.deposit.as_ref().map_or(0, |d| d.outside)
    }
}

/// The frame, range, reference and samples of any input.
pub fn prepare(input: &Input, range: &RangeSpec) -> Result<Prepared> {
    match *input {
        Input::Grid { values, frame } => {
            if values.dims != frame.dims {
                return Err(Error::arg(format!("grid of {:?} voxels, frame of {:?}", values.dims, frame.dims)));
            }
            if !frame.is_valid() {
                return Err(Error::arg(format!("grid corner {:?} and voxel size {:?} must be finite, the voxel size positive", frame.bmin, 1.0 / frame.gamma)));
            }
            let range = range.resolve(&values.values)?;
            let norm = range.normalize(&values.values)?;
            Ok(Prepared {
                form: Form::Grid,
                frame,
                range,
                reference: Grid::new(values.dims, norm.values)?,
                samples: None,
                bounds: None,
                clamped_values: norm.clamped,
                deposit: None,
            })
        }
        Input::Particles { particles, placement } => prepare_particles(particles, &placement, range),
        Input::ParticleDeposit { particles, placement } => {
            let p = prepare_particles(particles, &placement, range)?;
            Ok(Prepared { form: Form::Grid, samples: None, ..p })
        }
        Input::Cells { cells, placement } => prepare_cells(cells, &placement, range),
    }
}

/// `frame` grown by one voxel past each face where the lattice goes on
/// (`Placement::continues`), or `None` where it goes on past none. An item
/// smaller than a voxel within half a voxel of a face deposits at most one
/// voxel past it, so one voxel of the larger lattice is enough to tell
/// whether its deposit lies there.
fn widened(frame: &IndexFrame, continues: [[bool; 2]; 3]) -> Option<IndexFrame> {
    if continues == [[false; 2]; 3] {
        return None;
    }
    Some(IndexFrame {
        dims: std::array::from_fn(|a| frame.dims[a] + continues[a][0] as usize + continues[a][1] as usize),
        bmin: std::array::from_fn(|a| frame.bmin[a] - continues[a][0] as u8 as f64 / frame.gamma),
        gamma: frame.gamma,
    })
}

/// Scales the deposit's weights (masses, volumes) by the power of two that
/// brings the largest near 1. The deposit uses them only through ratios
/// (`num / den`), and a power of two changes no bit of those, but their
/// sums can no longer overflow (cells of volume 1e308 gave inf / inf) or
/// underflow (volumes of 1e-300).
fn scale_weights(splats: &mut [Splat]) {
    let top = splats.iter().fold(0f64, |a, s| a.max(s.m));
    if top > 0.0 && top.is_finite() {
        let scale = 2f64.powi(-(top.log2().floor() as i32));
        splats.iter_mut().for_each(|s| s.m *= scale);
    }
}

/// Samples and deposit of SPH particles.
pub fn prepare_particles(p: &Particles, placement: &Placement, range: &RangeSpec) -> Result<Prepared> {
    // A piece of a larger lattice may receive none (see `prepare_items`).
    if placement.is_piece() { p.validate_each(false)? } else { p.validate()? }
    let bounds = placement.bounds.unwrap_or_else(|| p.bounds());
    prepare_items(Form::Particles, p, p.values, placement, bounds, range)
}

/// Samples and volume-weighted deposit of hexahedral cells.
pub fn prepare_cells(c: &Cells, placement: &Placement, range: &RangeSpec) -> Result<Prepared> {
    if placement.is_piece() { c.validate_each(false)? } else { c.validate()? }
    let bounds = placement.bounds.unwrap_or_else(|| c.bounds());
    prepare_items(Form::Cells, c, c.values, placement, bounds, range)
}

fn prepare_items(form: Form, items: &dyn Conversion, values: &[f32], placement: &Placement, bounds: Bounds, range: &RangeSpec) -> Result<Prepared> {
    let dims = placement.dims;
    lattice_len(dims)?;
    let frame = IndexFrame::from_bounds(dims, bounds.min, bounds.max).map_err(|e| match e {
        Error::InvalidArgument(m) => Error::arg(format!("{m}; give bounds explicitly when the data are flat on an axis")),
        other => other,
    })?;
    let range = range.resolve(values)?;
    let norm = range.normalize(values)?;
    let started = Instant::now();
    let beyond = widened(&frame, placement.continues);
    let converted: Vec<Item> = (0..items.item_count())
        .into_par_iter()
        .map(|j| {
            let it = items.item(j, &frame, norm.values[j]);
            match &beyond {
                // A fallback whose deposit lands on the widened lattice lies
                // past a face where the lattice goes on: none here.
                Some(wide) if it.nearest && !items.item(j, wide, norm.values[j]).nearest => Item { splat: None, nearest: false, ..it },
                _ => it,
            }
        })
        .collect();

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
    scale_weights(&mut splats);
    // A piece of a decomposed field may hold no item's centre (its rank's
    // particles moved away, or it had none since the first step) and only
    // the reach of its neighbours' items, or nothing at all: its deposit
    // is what reaches it, and its voxels seed it as a grid's do. A lattice
    // that is its whole domain holding none is a mistake of its bounds.
    if samples.is_empty() && !placement.is_piece() {
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
    Ok(Prepared {
        form,
        frame,
        range,
        reference,
        samples: (!samples.is_empty()).then_some(samples),
        bounds: Some(bounds),
        clamped_values: norm.clamped,
        deposit: Some(deposit_stats),
    })
}
