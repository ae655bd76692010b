//! A model: its primitives and everything needed to decode them, decoding
//! on any lattice (whole, a sub-box, or streamed in slabs), its stored
//! support ([`support`]) with what it decodes outside ([`outside`]), and the
//! PSNR scores of a decode ([`metrics`]).

pub mod metrics;
pub mod outside;
pub mod support;

pub use outside::Outside;
pub use support::Support;

use crate::backend::{Backend, Lattice};
use crate::error::{Error, Result};
use crate::field::{Grid, IndexBox, IndexFrame, ValueRange};
use crate::format::packed::Precision;
use crate::math::kernel::Primitive;

/// Decoding metadata stored with every model.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelMeta {
    /// Index frame of the reference grid: dims, world origin of its box, voxels per world unit.
    pub frame: IndexFrame,
    /// Normalisation of the field (per field and time series).
    pub range: ValueRange,
    pub field: String,
    pub step: u64,
    /// Schedule name and the iterations and points actually used.
    pub schedule: String,
    pub iterations: u32,
    pub points: u32,
    pub seed_init: u64,
    pub seed_sample: u64,
    /// Simulation time of the step, when the caller gave one.
    pub time: Option<f64>,
    /// MPI rank that encoded this piece of the domain (0 for serial runs).
    pub rank: u32,
    /// Voxel PSNR of the stored model against its reference at encode time,
    /// when it was measured (after any 8-bit quantisation).
    pub encode_psnr: Option<f64>,
    /// Why the encode ran on the CPU although a GPU was chosen (`auto`
    /// fell back after a device error); `None` when it ran where chosen.
    pub fell_back: Option<String>,
    /// How an `auto` warm-started step began; `None` for every other encode.
    pub warm: Option<WarmRecord>,
    /// The bits per parameter group the packed payload needs for this
    /// model, as its encode measured them (`encode::precision`) or as read
    /// from a packed file; `None`: not measured (packed at the default).
    pub precision: Option<Precision>,
    /// What a target-PSNR encode learned of its data's curve (the one its
    /// corrections went by): a series' warm steps correct their budget
    /// with it, a resumed series too; `None` for an encode to a budget.
    pub curve: Option<Curve>,
}

/// What a target-PSNR search learned of a dataset (`encode::target`): dB
/// of PSNR per doubling of the budget (full-length encodes) and per
/// doubling of the iterations.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Curve {
    pub per_budget_doubling: f64,
    pub per_iteration_doubling: f64,
}

impl Curve {
    /// The two slopes in the order every stored form keeps them (the model
    /// file, the store's `target_curve`, `gsenc info`): per budget doubling,
    /// then per iteration doubling.
    pub fn slopes(&self) -> [f64; 2] {
        [self.per_budget_doubling, self.per_iteration_doubling]
    }

    /// The curve of [`Curve::slopes`] as stored.
    pub fn from_slopes([per_budget_doubling, per_iteration_doubling]: [f64; 2]) -> Curve {
        Curve { per_budget_doubling, per_iteration_doubling }
    }

    /// A curve as an encode makes one: both slopes finite, the budget's
    /// positive and the iterations' not negative. A stored one that is not
    /// was corrupted.
    pub fn is_valid(&self) -> bool {
        self.per_budget_doubling.is_finite() && self.per_budget_doubling > 0.0 && self.per_iteration_doubling.is_finite() && self.per_iteration_doubling >= 0.0
    }
}

/// The start an `auto` warm-started step took (METHOD.md "Warm start").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WarmTaken {
    /// The previous step's model as it was.
    Kept,
    /// The previous model with `moved` primitives re-seeded where it missed.
    Repaired,
    /// A fresh seeding from the step's own samples.
    Fresh,
}

impl WarmTaken {
    pub const ALL: [WarmTaken; 3] = [WarmTaken::Kept, WarmTaken::Repaired, WarmTaken::Fresh];

    pub fn from_name(s: &str) -> Result<WarmTaken> {
        crate::error::by_name(&WarmTaken::ALL, WarmTaken::name, s, "warm start taken")
    }

    pub fn name(self) -> &'static str {
        match self {
            WarmTaken::Kept => "kept",
            WarmTaken::Repaired => "repaired",
            WarmTaken::Fresh => "fresh",
        }
    }

    /// The model file's code (FORMAT.md).
    pub fn code(self) -> u8 {
        self as u8
    }

    pub fn from_code(c: u8) -> Option<WarmTaken> {
        WarmTaken::ALL.get(c as usize).copied()
    }
}

/// What an `auto` warm start did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WarmRecord {
    pub taken: WarmTaken,
    /// Primitives the repair moved: 0 with `Kept`; with `Fresh`, those of
    /// the repaired start that lost to the fresh seeding.
    pub moved: u32,
}

impl ModelMeta {
    /// Metadata of a model over `frame` and `range`, the rest unset: field
    /// "scalar", step 0, no schedule, rank 0, time and PSNR unknown.
    pub fn new(frame: IndexFrame, range: ValueRange) -> ModelMeta {
        ModelMeta {
            frame,
            range,
            field: "scalar".into(),
            step: 0,
            schedule: String::new(),
            iterations: 0,
            points: 0,
            seed_init: 0,
            seed_sample: 0,
            time: None,
            rank: 0,
            encode_psnr: None,
            fell_back: None,
            warm: None,
            precision: None,
            curve: None,
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Model {
    pub meta: ModelMeta,
    pub params: Vec<Primitive>,
    /// Where the field holds data, on the reference lattice; `None`:
    /// everywhere (the paper's model, or a field with no empty voxel).
    pub support: Option<Support>,
}

/// Refuses a streamed decode's slab of `voxels` (at least one z layer,
/// however few voxels a slab was asked to hold: a lattice of [2^32, 1, 1]
/// has a layer of 16 GiB) when this process cannot hold it now, at
/// `bytes_a_voxel` while it decodes and the two copies of its f32 values
/// that a consumer keeps beside it (the tool's write-behind: one being
/// filled, one being written). Without it such a slab was reserved (Linux
/// promises memory it may not have) and the process killed as it wrote it.
pub(crate) fn check_slab(voxels: usize, bytes_a_voxel: u64) -> Result<()> {
    let bytes = (voxels as u64).saturating_mul(bytes_a_voxel + 8);
    crate::memory::check_large(&format!("decoding slabs of {voxels} voxels (a z layer at least; decode fewer voxels a layer, or a sub-box)"), bytes)
}

/// An empty buffer with room for a whole decode of `voxels` f32 values
/// ([`Model::decode_box`], [`crate::domain::global::GlobalField::decode`]),
/// refused when this process cannot hold it now rather than reserved (Linux
/// promises memory it may not have, and kills the process as it is written).
pub(crate) fn decode_buffer(voxels: usize) -> Result<Vec<f32>> {
    crate::memory::check_large(&format!("a decode of {voxels} voxels"), 4 * voxels as u64)?;
    let mut out = Vec::new();
    out.try_reserve_exact(voxels).map_err(|_| Error::arg(format!("cannot allocate {voxels} voxels")))?;
    Ok(out)
}

/// Default most voxels decoded at once by [`Model::decode_streaming`]: 64 MB of f32.
pub const DEFAULT_SLAB_VOXELS: usize = 1 << 24;

/// Points a run of [`Model::evaluate_into`] evaluates at once (its scratch
/// takes 20 bytes a point).
pub const EVALUATE_RUN: usize = 1 << 16;
/// Largest lattice a decode accepts (2^34 voxels, 64 GiB of float32).
const MAX_DECODE_VOXELS: usize = 1 << 34;

impl Model {
    pub fn len(&self) -> usize {
        self.params.len()
    }

    pub fn is_empty(&self) -> bool {
        self.params.is_empty()
    }

    /// Decodes `V_eval` (normalised, in `[0, 1]`) on a lattice of `dims`
    /// covering the model's box; the reference dims when `None`.
    pub fn decode(&self, backend: &mut dyn Backend, dims: Option<[usize; 3]>) -> Result<Grid> {
        let out_dims = self.lattice_dims(dims)?;
        self.decode_box(backend, out_dims, IndexBox::whole(out_dims))
    }

    /// Decodes the part `region` of the lattice of `dims` (see [`Model::decode`]).
    pub fn decode_box(&self, backend: &mut dyn Backend, dims: [usize; 3], region: IndexBox) -> Result<Grid> {
        let dims = self.lattice_dims(Some(dims))?;
        region.check_within(dims)?;
        let n: usize = region.dims().iter().product();
        let mut out = decode_buffer(n)?;
        out.resize(n, 0.0);
        self.decode_lattice(backend, &self.sub_lattice(dims, region), &mut out)?;
        Grid::new(region.dims(), out)
    }

    /// Decodes `region` of the lattice of `dims` in slabs of whole z layers,
    /// at most `slab_voxels` voxels each (at least one layer), and hands
    /// every slab (x fastest) to `sink` in order. Memory stays at one slab
    /// plus the model's per-primitive state, whatever the lattice's size.
    pub fn decode_streaming(
        &self,
        backend: &mut dyn Backend,
        dims: [usize; 3],
        region: IndexBox,
        slab_voxels: usize,
        sink: &mut dyn FnMut(&[f32]) -> Result<()>,
    ) -> Result<()> {
        let dims = self.lattice_dims(Some(dims))?;
        region.check_within(dims)?;
        let rd = region.dims();
        let layer = rd[0] * rd[1];
        let layers = (slab_voxels / layer).max(1);
        let mut buf = Vec::new();
        let mut z = region.lo[2];
        while z < region.hi[2] {
            let z1 = (z + layers).min(region.hi[2]);
            let slab = IndexBox { lo: [region.lo[0], region.lo[1], z], hi: [region.hi[0], region.hi[1], z1] };
            let n = layer * (z1 - z);
            if buf.len() != n {
                buf.clear();
                check_slab(n, 4)?;
                buf.try_reserve_exact(n).map_err(|_| Error::arg(format!("cannot allocate a slab of {n} voxels")))?;
                buf.resize(n, 0.0);
            }
            self.decode_lattice(backend, &self.sub_lattice(dims, slab), &mut buf)?;
            sink(&buf)?;
            z = z1;
        }
        Ok(())
    }

    /// The decoded value at every point of `lattice` (in the index frame of
    /// the reference): `V_eval` of the primitives, blended with the
    /// support's outside by its factor when the model has one
    /// ([`Support::blend`]). Every decode goes through here (the encoder's
    /// scoring, [`crate::encode::stored::decode_as_stored`], does the same
    /// in two steps, fitting the outside between them).
    pub fn decode_lattice(&self, backend: &mut dyn Backend, lattice: &Lattice, out: &mut [f32]) -> Result<()> {
        backend.decode_lattice(&self.params, lattice, out)?;
        if let Some(s) = &self.support {
            s.apply(lattice, out);
        }
        Ok(())
    }

    /// The decoded value (normalised) at world points, each finite: what a
    /// decode gives at a voxel centre, anywhere in space. A point's value
    /// depends on the model and that point alone, to the bit: not on the
    /// other points of the call, their number or order, nor the thread
    /// count ([`Backend::evaluate_each`]). The answer is reserved fallibly
    /// (an error, not an abort, when it cannot fit).
    pub fn evaluate(&self, backend: &mut dyn Backend, points: &[[f64; 3]]) -> Result<Vec<f32>> {
        let mut out = Vec::new();
        out.try_reserve_exact(points.len()).map_err(|_| Error::arg(format!("cannot allocate the values of {} points", points.len())))?;
        out.resize(points.len(), 0.0);
        self.evaluate_into(backend, points, &mut out)?;
        Ok(out)
    }

    /// [`Model::evaluate`] into `out` (one value a point), in runs of
    /// [`EVALUATE_RUN`] points, so that what it holds besides the caller's
    /// arrays is bounded however many points there are (the runs change no
    /// value: each point's is its own).
    pub fn evaluate_into(&self, backend: &mut dyn Backend, points: &[[f64; 3]], out: &mut [f32]) -> Result<()> {
        if out.len() != points.len() {
            return Err(Error::arg(format!("{} points, room for {} values", points.len(), out.len())));
        }
        if let Some(i) = points.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
            return Err(Error::data(format!("point {i} is not finite")));
        }
        let f = &self.meta.frame;
        let run = points.len().clamp(1, EVALUATE_RUN);
        let (mut index, mut rho, mut num) = (Vec::with_capacity(run), vec![0.0; run], vec![0.0; run]);
        for (points, out) in points.chunks(run).zip(out.chunks_mut(run)) {
            index.clear();
            index.extend(points.iter().map(|&p| f.world_to_index(p).map(|u| u as f32)));
            let n = points.len();
            backend.evaluate_each(&self.params, &index, &mut rho[..n], &mut num[..n])?;
            for (i, o) in out.iter_mut().enumerate() {
                *o = self.value_at(index[i], rho[i], num[i]);
            }
        }
        Ok(())
    }

    /// The decoded value at index-frame points, from their `(rho, n)`.
    pub fn value_at(&self, u: [f32; 3], rho: f32, n: f32) -> f32 {
        let v = crate::math::loss::v_eval(rho, n);
        match &self.support {
            Some(s) => s.blend(v, s.factor(u)),
            None => v,
        }
    }

    /// `dims` (the model's own when `None`), refused when a decode onto
    /// them has no voxel or more than it decodes.
    pub(crate) fn lattice_dims(&self, dims: Option<[usize; 3]>) -> Result<[usize; 3]> {
        let out_dims = dims.unwrap_or(self.meta.frame.dims);
        if out_dims.contains(&0) {
            return Err(Error::arg(format!("decode dims must be positive, got {out_dims:?}")));
        }
        let n = out_dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
        n.filter(|&n| n <= MAX_DECODE_VOXELS).ok_or_else(|| Error::arg(format!("decode dims {out_dims:?} are too large")))?;
        Ok(out_dims)
    }

    /// The voxel centres of `region` of the lattice of `dims` over the model's box.
    fn sub_lattice(&self, dims: [usize; 3], region: IndexBox) -> Lattice {
        let whole = Lattice::resampled(self.meta.frame.dims, dims);
        let mut l = Lattice { dims: region.dims(), ..whole };
        for a in 0..3 {
            // In f64, so that a slab starts exactly where the whole lattice has it.
            let step = self.meta.frame.dims[a] as f64 / dims[a] as f64;
            l.origin[a] = ((region.lo[a] as f64 + 0.5) * step - 0.5) as f32;
        }
        l
    }
}
