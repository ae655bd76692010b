//! The step index (`FIELD_STEP.gsi`): what rank 0 writes beside the per-rank
//! models of one step of a domain-decomposed run, so that a reader finds
//! every piece (docs/FORMAT.md "The step index").

use crate::error::{Error, Result};
use crate::field::{IndexBox, IndexFrame, Transform, ValueRange};
use crate::model::{Model, ModelMeta};

/// What rank 0 writes beside each step's per-rank models, so that a reader
/// finds every piece of the step: the rank count, each rank's model and its
/// box in the global lattice, the agreed range. Text (JSON), written next to
/// the models; model paths are relative to it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StepIndex {
    /// Always [`StepIndex::FORMAT`].
    pub format: String,
    pub version: u32,
    pub field: String,
    pub step: u64,
    pub time: Option<f64>,
    pub ranks: usize,
    /// Voxels each piece reaches past its rank's region (the blend's ramp).
    pub halo: usize,
    pub range: IndexRange,
    /// The global lattice: dims, lower corner, voxels per world unit.
    pub dims: [usize; 3],
    pub bmin: [f64; 3],
    pub gamma: f64,
    /// One entry per rank, in rank order.
    pub pieces: Vec<IndexPiece>,
}

/// The value range, as stored in a step index.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IndexRange {
    pub vmin: f64,
    pub vmax: f64,
    pub transform: String,
}

/// One rank's piece of a step.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IndexPiece {
    pub rank: u32,
    /// The model file, relative to the index.
    pub model: String,
    /// Its voxels `lo..hi` of the global lattice (its region plus halo).
    pub lo: [usize; 3],
    pub hi: [usize; 3],
    /// The same box in world units.
    pub world_min: [f64; 3],
    pub world_max: [f64; 3],
}

impl StepIndex {
    pub const FORMAT: &'static str = "gsenc-step-index";
    pub const VERSION: u32 = 1;

    /// The index of a step whose pieces are `boxes` of `global` (rank order),
    /// each in the model file `models[rank]`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(field: &str, step: u64, time: Option<f64>, range: &ValueRange, global: &IndexFrame, boxes: &[IndexBox], halo: usize, models: Vec<String>) -> StepIndex {
        let pieces = boxes
            .iter()
            .zip(models)
            .enumerate()
            .map(|(rank, (b, model))| {
                let f = global.sub_frame(b);
                IndexPiece {
                    rank: rank as u32,
                    model,
                    lo: b.lo,
                    hi: b.hi,
                    world_min: f.bmin,
                    world_max: f.world_box().max,
                }
            })
            .collect();
        StepIndex {
            format: Self::FORMAT.into(),
            version: Self::VERSION,
            field: field.into(),
            step,
            time,
            ranks: boxes.len(),
            halo,
            range: IndexRange { vmin: range.vmin, vmax: range.vmax, transform: range.transform.name().into() },
            dims: global.dims,
            bmin: global.bmin,
            gamma: global.gamma,
            pieces,
        }
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a step index serialises") + "\n"
    }

    /// Reads an index, refusing other JSON and newer versions.
    pub fn from_json(text: &str) -> Result<StepIndex> {
        let v: serde_json::Value = serde_json::from_str(text).map_err(|e| Error::format(format!("not a step index (JSON: {e})")))?;
        if v.get("format").and_then(|f| f.as_str()) != Some(Self::FORMAT) {
            return Err(Error::format("not a gsenc step index (no \"format\": \"gsenc-step-index\")"));
        }
        let version = v.get("version").and_then(|x| x.as_u64()).unwrap_or(0);
        if version > Self::VERSION as u64 {
            return Err(Error::Version(format!("step index version {version}; this gsenc reads up to {}", Self::VERSION)));
        }
        let index: StepIndex = serde_json::from_value(v).map_err(|e| Error::format(format!("step index: {e}")))?;
        if index.pieces.len() != index.ranks || index.pieces.iter().enumerate().any(|(i, p)| p.rank as usize != i) {
            return Err(Error::format("step index: the pieces do not list ranks 0..ranks once each"));
        }
        index.check_layout().map_err(|m| Error::format(format!("step index: {m}")))?;
        Ok(index)
    }

    /// What the decode trusts of an index beyond its shape: a lattice of
    /// whole voxels with a finite corner and a positive voxel size, a known
    /// transform and a range of max > min, at least one piece, each a
    /// non-empty box within the lattice. (Any halo is one: the blend's ramp
    /// only divides by it, and a run may ask for one wider than its
    /// lattice.)
    fn check_layout(&self) -> std::result::Result<(), String> {
        let voxels = self.dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
        if self.dims.contains(&0) || voxels.is_none() {
            return Err(format!("its lattice {:?} is empty or too large", self.dims));
        }
        if !self.frame().is_valid() {
            return Err(format!("its lattice has corner {:?} and {:?} voxels a world unit (finite, and positive voxels, wanted)", self.bmin, self.gamma));
        }
        let transform = Transform::from_name(&self.range.transform).ok_or_else(|| format!("unknown transform '{}'", self.range.transform))?;
        ValueRange::new(self.range.vmin, self.range.vmax, transform).map_err(|e| e.to_string())?;
        if self.pieces.is_empty() {
            return Err("it lists no pieces".into());
        }
        for p in &self.pieces {
            if (0..3).any(|a| p.lo[a] >= p.hi[a] || p.hi[a] > self.dims[a]) {
                return Err(format!("rank {}'s voxels {:?}..{:?} are not a box within the lattice {:?}", p.rank, p.lo, p.hi, self.dims));
            }
        }
        Ok(())
    }

    /// The global lattice's frame.
    pub fn frame(&self) -> IndexFrame {
        IndexFrame { dims: self.dims, bmin: self.bmin, gamma: self.gamma }
    }

    /// The global frame and every piece's box.
    pub fn layout(&self) -> (IndexFrame, Vec<IndexBox>) {
        (self.frame(), self.pieces.iter().map(|p| IndexBox { lo: p.lo, hi: p.hi }).collect())
    }

    /// Checks that `pieces` (the models of this index, in rank order) are
    /// the ones it names: field, step, rank, range and box.
    pub fn check_pieces(&self, pieces: &[Model]) -> Result<()> {
        self.check_piece_metas(&pieces.iter().map(|m| &m.meta).collect::<Vec<_>>())
    }

    /// [`StepIndex::check_pieces`] of the pieces' metadata alone.
    pub fn check_piece_metas(&self, pieces: &[&ModelMeta]) -> Result<()> {
        let global = self.frame();
        for (p, m) in self.pieces.iter().zip(pieces) {
            let what = || format!("the model of rank {} ({})", p.rank, p.model);
            if m.field != self.field || m.step != self.step || m.rank != p.rank {
                return Err(Error::data(format!(
                    "{} is field '{}' step {} rank {}, the index names field '{}' step {} rank {}",
                    what(), m.field, m.step, m.rank, self.field, self.step, p.rank
                )));
            }
            if (m.frame.gamma - self.gamma).abs() > 1e-12 * self.gamma || m.range.transform.name() != self.range.transform {
                return Err(Error::data(format!(
                    "{} has {:?} voxels a world unit and transform {}, the index {:?} and {}",
                    what(), m.frame.gamma, m.range.transform.name(), self.gamma, self.range.transform
                )));
            }
            let b = global.box_of(&m.frame)?;
            if b.lo != p.lo || b.hi != p.hi {
                return Err(Error::data(format!("{} covers voxels {:?}..{:?}, the index says {:?}..{:?}", what(), b.lo, b.hi, p.lo, p.hi)));
            }
            let differs = |a: f64, b: f64| (a - b).abs() > 1e-12 * a.abs().max(b.abs()).max(1e-300);
            if differs(m.range.vmin, self.range.vmin) || differs(m.range.vmax, self.range.vmax) {
                return Err(Error::data(format!("{} has another value range than the index", what())));
            }
        }
        Ok(())
    }
}
