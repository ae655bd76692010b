//! Values: the optional transform, the normalisation to `[0, 1]` of one
//! field's series (METHOD.md "Frames and units"), and the finite-value checks.

use crate::error::{Error, Result};
use rayon::prelude::*;

/// Values a task of the parallel conversions maps.
const RUN: usize = 1 << 14;

/// Optional transform applied to raw values before normalisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Transform {
    Linear = 0,
    /// `log10(x)`, for fields spanning decades; requires positive values.
    Log10 = 1,
}

impl Transform {
    pub fn from_code(c: u32) -> Option<Transform> {
        match c {
            0 => Some(Transform::Linear),
            1 => Some(Transform::Log10),
            _ => None,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Transform::Linear => "linear",
            Transform::Log10 => "log10",
        }
    }
    pub fn from_name(name: &str) -> Option<Transform> {
        [Transform::Linear, Transform::Log10].into_iter().find(|t| t.name() == name)
    }
}

/// The normalisation `v = (T(x) - vmin) / (vmax - vmin)` clamped to `[0, 1]`,
/// with `[vmin, vmax]` in transformed units. One per field and time series.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ValueRange {
    pub vmin: f64,
    pub vmax: f64,
    pub transform: Transform,
}

/// Normalised values and how many fell outside the range (and were clamped).
#[derive(Clone, Debug)]
pub struct Normalized {
    pub values: Vec<f32>,
    pub clamped: usize,
}

impl ValueRange {
    pub fn new(vmin: f64, vmax: f64, transform: Transform) -> Result<ValueRange> {
        if !(vmin.is_finite() && vmax.is_finite()) || vmax <= vmin {
            return Err(Error::arg(format!("value range [{vmin:?}, {vmax:?}] must be finite with max > min")));
        }
        // A width past f64's range (e.g. [-1e308, 1e308]) would normalise
        // every value to 0 and decode it as 0 x inf, NaN.
        if !(vmax - vmin).is_finite() {
            return Err(Error::arg(format!("value range [{vmin:?}, {vmax:?}] is wider than a float64 can hold")));
        }
        Ok(ValueRange { vmin, vmax, transform })
    }

    fn apply(transform: Transform, x: f64) -> f64 {
        match transform {
            Transform::Linear => x,
            Transform::Log10 => x.log10(),
        }
    }

    /// The range of the (transformed) data itself. Fails on non-finite values,
    /// non-positive values under log10, empty or constant data.
    pub fn from_data(values: &[f32], transform: Transform) -> Result<ValueRange> {
        check_finite(values)?;
        if values.is_empty() {
            return Err(Error::data("no values"));
        }
        if transform == Transform::Log10 {
            if let Some(pos) = values.iter().position(|&v| v <= 0.0) {
                return Err(Error::data(format!(
                    "log10 transform needs positive values; value {:?} at index {pos}",
                    values[pos]
                )));
            }
        }
        let (lo, hi) = values
            .par_iter()
            .map(|&v| {
                let t = Self::apply(transform, v as f64);
                (t, t)
            })
            .reduce(|| (f64::INFINITY, f64::NEG_INFINITY), |a, b| (a.0.min(b.0), a.1.max(b.1)));
        if hi <= lo {
            return Err(Error::data(format!("field is constant ({lo:?}); give a value range explicitly")));
        }
        ValueRange::new(lo, hi, transform)
    }

    /// Normalises raw values, counting those clamped into `[0, 1]`.
    pub fn normalize(&self, values: &[f32]) -> Result<Normalized> {
        check_finite(values)?;
        let scale = 1.0 / (self.vmax - self.vmin);
        let (vmin, tr) = (self.vmin, self.transform);
        let out: Vec<(f32, bool)> = values
            .par_iter()
            .map(|&x| {
                let t = if tr == Transform::Log10 && x <= 0.0 { f64::NEG_INFINITY } else { Self::apply(tr, x as f64) };
                let v = (t - vmin) * scale;
                let c = v.clamp(0.0, 1.0);
                (c as f32, c != v)
            })
            .collect();
        let clamped = out.iter().filter(|x| x.1).count();
        Ok(Normalized { values: out.into_iter().map(|x| x.0).collect(), clamped })
    }

    /// Maps a normalised value back to data units.
    pub fn denormalize(&self, v: f32) -> f64 {
        match self.transform {
            Transform::Linear => self.unscale(v),
            Transform::Log10 => 10f64.powf(self.unscale(v)),
        }
    }

    /// [`ValueRange::denormalize`] of every value, in place, as float32,
    /// in parallel runs: what a decode writes in data units. The transform
    /// is chosen once for the slice. Chosen per value, in a loop the
    /// compiler may compute `10^t` for a linear range as well (the call has
    /// no side effect) and keep the linear value, which cost a decode's
    /// conversion a `powf` a voxel (docs/BENCHMARKS.md "The decode's rows as
    /// vectors").
    pub fn denormalize_all(&self, values: &mut [f32]) {
        self.denormalize_runs(None, values);
    }

    /// `src` (normalised) into `dst` (as long) as a decode writes it: in
    /// data units, the values of [`ValueRange::denormalize_all`], or kept
    /// normalised; one parallel pass, no copy before it.
    pub fn output_into(&self, normalized: bool, src: &[f32], dst: &mut [f32]) {
        assert_eq!(src.len(), dst.len(), "output_into: {} values into {}", src.len(), dst.len());
        if normalized {
            dst.par_chunks_mut(RUN).zip(src.par_chunks(RUN)).for_each(|(d, s)| d.copy_from_slice(s));
        } else {
            self.denormalize_runs(Some(src), dst);
        }
    }

    /// [`ValueRange::denormalize`] of `src` (or of `dst` itself) into `dst`.
    fn denormalize_runs(&self, src: Option<&[f32]>, dst: &mut [f32]) {
        fn map(src: Option<&[f32]>, dst: &mut [f32], f: impl Fn(f32) -> f64 + Sync) {
            match src {
                None => dst.par_chunks_mut(RUN).for_each(|run| run.iter_mut().for_each(|v| *v = f(*v) as f32)),
                Some(src) => dst.par_chunks_mut(RUN).zip(src.par_chunks(RUN)).for_each(|(d, s)| d.iter_mut().zip(s).for_each(|(v, &x)| *v = f(x) as f32)),
            }
        }
        match self.transform {
            Transform::Linear => map(src, dst, |v| self.unscale(v)),
            Transform::Log10 => map(src, dst, |v| 10f64.powf(self.unscale(v))),
        }
    }

    /// A normalised value on the (transformed) data's scale.
    #[inline(always)]
    fn unscale(&self, v: f32) -> f64 {
        self.vmin + v as f64 * (self.vmax - self.vmin)
    }
}

/// Fails with the position of the first NaN or infinite value.
/// [`check_finite`] on the calling thread alone, for the caller's side of
/// the background queue: a push must not wake a rayon pool (the host's, or
/// the global one the encoder's threads compete with).
pub fn check_finite_serial(values: &[f32]) -> Result<()> {
    // Whole chunks first; the position is looked up only on failure.
    if values.chunks(4096).all(all_finite) {
        return Ok(());
    }
    let pos = values.iter().position(|v| !v.is_finite()).expect("a non-finite value was seen");
    Err(not_finite(values, pos))
}

/// Whether every value is finite, tested without an early exit so that the
/// test vectorises (`all`, which stops at the first failure, does not: 0.63
/// against 0.32 ms for a 128^3 field here). For slices that fit the caches;
/// [`check_finite_serial`] cuts a large one into chunks of them.
pub fn all_finite(values: &[f32]) -> bool {
    values.iter().fold(true, |ok, v| ok & v.is_finite())
}

pub fn check_finite(values: &[f32]) -> Result<()> {
    if let Some(pos) = values.par_iter().position_first(|v| !v.is_finite()) {
        return Err(not_finite(values, pos));
    }
    Ok(())
}

/// Names the value and its index; an infinity may have been a finite
/// float64 input that float32, the precision of every field, cannot hold
/// (a raw f64 file, a C or Python caller's double array), so the message
/// says so.
fn not_finite(values: &[f32], pos: usize) -> Error {
    let v = values[pos];
    let why = if v.is_infinite() { format!(" (as float32: an input beyond ±{:e} is infinite)", f32::MAX) } else { String::new() };
    Error::data(format!("value {v} at index {pos} is not finite{why}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The slice's mapping is the value's, bit for bit, for both transforms
    /// and over several parallel runs (the last one short).
    #[test]
    fn every_value_of_a_slice_maps_as_it_does_alone() {
        let values: Vec<f32> = (0..40_003).map(|i| ((i as f32) * 0.618_034).fract()).chain([0.0, 1.0, 0.5]).collect();
        for range in [ValueRange { vmin: 2.0, vmax: 12.5, transform: Transform::Linear }, ValueRange { vmin: -3.0, vmax: 4.25, transform: Transform::Log10 }] {
            let mut all = values.clone();
            range.denormalize_all(&mut all);
            let want: Vec<u32> = values.iter().map(|&v| (range.denormalize(v) as f32).to_bits()).collect();
            assert!(all.iter().map(|v| v.to_bits()).eq(want.iter().copied()), "{range:?}");
            assert_eq!(all[values.len() - 2], range.denormalize(1.0) as f32);
            // Into another slice (garbage before): the same bits; kept
            // normalised, the values themselves.
            for normalized in [false, true] {
                let mut into = vec![f32::NAN; values.len()];
                range.output_into(normalized, &values, &mut into);
                let want = if normalized { values.iter().map(|v| v.to_bits()).collect() } else { want.clone() };
                assert!(into.iter().map(|v| v.to_bits()).eq(want), "{range:?}, normalized {normalized}");
            }
        }
    }

    /// Both checks find the first non-finite value wherever it lies (the
    /// first or last of a chunk, the last of a short tail), and pass
    /// finite values, subnormals and the extremes among them.
    #[test]
    fn the_finite_checks_find_the_first_bad_value() {
        let mut v: Vec<f32> = (0..10_000).map(|i| i as f32 * 0.5 - 100.0).collect();
        v[17] = f32::MIN_POSITIVE / 4.0;
        (v[18], v[19]) = (f32::MAX, f32::MIN);
        assert!(check_finite_serial(&v).is_ok() && check_finite(&v).is_ok());
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            for at in [0, 1, 4095, 4096, 8191, 9999] {
                let mut w = v.clone();
                w[at] = bad;
                if at + 5 < w.len() {
                    w[at + 5] = bad;
                }
                for e in [check_finite_serial(&w).unwrap_err(), check_finite(&w).unwrap_err()] {
                    assert!(e.to_string().contains(&format!("at index {at} ")), "{bad} at {at}: {e}");
                    // An infinity says what float32 holds; a NaN does not.
                    assert_eq!(e.to_string().contains("as float32: an input beyond ±3.4028235e38 is infinite"), bad.is_infinite(), "{e}");
                }
            }
        }
    }

    #[test]
    fn normalize_clamps_and_counts() {
        let r = ValueRange::new(0.0, 10.0, Transform::Linear).unwrap();
        let n = r.normalize(&[-1.0, 0.0, 5.0, 10.0, 12.0]).unwrap();
        assert_eq!(n.values, vec![0.0, 0.0, 0.5, 1.0, 1.0]);
        assert_eq!(n.clamped, 2);
        assert!(r.normalize(&[f32::NAN]).is_err());
        // Refused by what is wrong, with what the user can do about it
        // (not by the range check behind, whose message says less).
        let e = ValueRange::from_data(&[1.0, 1.0], Transform::Linear).unwrap_err().to_string();
        assert!(e.contains("field is constant (1.0); give a value range explicitly"), "{e}");
        let e = ValueRange::from_data(&[1.0, 0.0], Transform::Log10).unwrap_err().to_string();
        assert!(e.contains("log10 transform needs positive values; value 0.0 at index 1"), "{e}");
        // Large and small values in exponent form, not forty digits.
        let e = ValueRange::from_data(&[-9.2e19, 1.0], Transform::Log10).unwrap_err().to_string();
        assert!(e.contains("value -9.2e19 at index 0"), "{e}");
        let e = ValueRange::from_data(&[3.4e38; 2], Transform::Linear).unwrap_err().to_string();
        assert!(e.contains("field is constant (3.3999999521443642e38)"), "{e}");
        let l = ValueRange::from_data(&[1.0, 1000.0], Transform::Log10).unwrap();
        assert_eq!((l.vmin, l.vmax), (0.0, 3.0));
    }

    /// A range is refused unless its ends and its width are finite and its
    /// width positive; the widest accepted one decodes its ends finitely.
    #[test]
    fn a_range_needs_a_finite_positive_width() {
        for (lo, hi) in [(1.0, 1.0), (2.0, 1.0), (f64::NAN, 1.0), (0.0, f64::INFINITY), (-1e308, 1e308), (-f64::MAX, 0.0 + f64::MAX)] {
            let e = ValueRange::new(lo, hi, Transform::Linear).unwrap_err().to_string();
            assert!(e.contains("value range"), "[{lo}, {hi}]: {e}");
        }
        let wide = ValueRange::new(-f64::MAX / 2.0, f64::MAX / 2.0, Transform::Linear).unwrap();
        for v in [0.0, 0.5, 1.0] {
            assert!(wide.denormalize(v).is_finite(), "{v}");
        }
        assert_eq!(wide.normalize(&[f32::MAX, 0.0]).unwrap().values, vec![0.5, 0.5]);
    }
}
