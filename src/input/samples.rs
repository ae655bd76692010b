//! The sample interface (METHOD.md "Samples"): every input form becomes
//! samples `(q, h, v, m)` in the index frame of the reference grid.

use crate::field::Grid;

/// One sample: position `q` (index frame), initial scale `h` (voxels),
/// normalised value `v` in `[0, 1]` and importance `m`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub q: [f32; 3],
    pub h: f32,
    pub v: f32,
    pub m: f32,
}

/// A set of samples, read by index so that a grid's voxels need not be copied.
pub trait SampleSet: Sync {
    fn len(&self) -> usize;
    fn get(&self, i: usize) -> Sample;
    /// Sample `i`'s position: `get(i).q`, which a set may find without
    /// reading the rest of the sample (training draws need only this).
    fn position(&self, i: usize) -> [f32; 3] {
        self.get(i).q
    }
    /// Asks the cache for what [`SampleSet::position`] reads of sample `i`
    /// (nothing by default; a grid's positions read no memory).
    fn prefetch_position(&self, _i: usize) {}
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// True when all importances are equal; the importance stream is then a
    /// uniform draw (as for grid voxels, where `m = 1`).
    fn uniform_importance(&self) -> bool {
        false
    }
}

/// A normalised grid's voxels as samples: `q` = voxel centre, `h = 0.5`,
/// `m = 1`. The grid must hold normalised values (a reference grid).
impl SampleSet for Grid {
    fn len(&self) -> usize {
        self.values.len()
    }
    #[inline]
    fn get(&self, i: usize) -> Sample {
        Sample { q: self.centre(i), h: 0.5, v: self.values[i], m: 1.0 }
    }
    #[inline]
    fn position(&self, i: usize) -> [f32; 3] {
        self.centre(i)
    }
    fn uniform_importance(&self) -> bool {
        true
    }
}

/// Samples held as arrays (particles and cells).
#[derive(Clone, Debug, Default)]
pub struct SampleArrays {
    pub q: Vec<[f32; 3]>,
    pub h: Vec<f32>,
    pub v: Vec<f32>,
    pub m: Vec<f32>,
}

impl SampleArrays {
    pub fn push(&mut self, s: Sample) {
        self.q.push(s.q);
        self.h.push(s.h);
        self.v.push(s.v);
        self.m.push(s.m);
    }
}

impl SampleSet for SampleArrays {
    fn len(&self) -> usize {
        self.q.len()
    }
    fn get(&self, i: usize) -> Sample {
        Sample { q: self.q[i], h: self.h[i], v: self.v[i], m: self.m[i] }
    }
    fn position(&self, i: usize) -> [f32; 3] {
        self.q[i]
    }
    fn prefetch_position(&self, i: usize) {
        crate::field::prefetch(&self.q, i);
    }
    fn uniform_importance(&self) -> bool {
        self.m.windows(2).all(|w| w[0] == w[1])
    }
}
