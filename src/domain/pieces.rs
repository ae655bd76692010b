//! One global field from models of pieces of a domain (the per-rank models
//! of a domain-decomposed run).
//!
//! Pieces share one global index frame: the same voxel size and a lattice
//! whose origins differ by whole voxels, each piece covering its own part of
//! the domain plus a halo. The mixture is additive, so the global model is
//! every piece's primitives together, their centres moved into the global
//! frame; decoding it computes `sum n / max(sum rho, eps)` over all of
//! them. [`blend`] instead decodes each piece on its own box and blends the
//! pieces across their halos (what `gsenc decode` of a step index does:
//! kernels no longer leak past a piece's box). A step index
//! ([`crate::format::StepIndex`]) names the pieces of one step. No I/O here.

use crate::error::{Error, Result};
use crate::field::IndexFrame;
use crate::math::kernel::layout::MU;
use crate::field::{IndexBox, LATTICE_TOLERANCE};
use crate::model::{Model, Support};

/// The global model of `pieces`: one frame covering all of them, every
/// primitive of every piece. Pieces must be of the same field and step,
/// share the value range and the voxel size, and sit on one lattice.
pub fn merge(pieces: &[Model]) -> Result<Model> {
    merge_on(pieces, None)
}

/// [`merge`] onto the lattice `global` (a step index's), which may reach
/// past its pieces (particles in configured bounds wider than they fill):
/// the merged model's frame is `global`, each piece at its box of it, so
/// that the field's frame, its pieces' boxes and its decode's placement are
/// the index's. A piece off that lattice or reaching past it is refused.
pub fn merge_onto(pieces: &[Model], global: &IndexFrame) -> Result<Model> {
    merge_on(pieces, Some(global))
}

fn merge_on(pieces: &[Model], global: Option<&IndexFrame>) -> Result<Model> {
    let first = pieces.first().ok_or_else(|| Error::arg("no models to merge"))?;
    let gamma = first.meta.frame.gamma;
    for (i, p) in pieces.iter().enumerate() {
        let m = &p.meta;
        if m.field != first.meta.field || m.step != first.meta.step {
            return Err(Error::arg(format!(
                "piece {i} is field '{}' step {}, piece 0 is field '{}' step {}: merge pieces of one step",
                m.field, m.step, first.meta.field, first.meta.step
            )));
        }
        if m.range != first.meta.range {
            return Err(Error::arg(format!(
                "piece {i} has value range {:?}, piece 0 {:?}: the pieces of a field must share one range",
                m.range, first.meta.range
            )));
        }
        if ((m.frame.gamma - gamma) / gamma).abs() > 1e-9 {
            return Err(Error::arg(format!(
                "piece {i} has {} voxels per unit, piece 0 {gamma}: the pieces must share one voxel size",
                m.frame.gamma
            )));
        }
    }
    let bmin: [f64; 3] = match global {
        Some(g) => g.bmin,
        None => std::array::from_fn(|a| pieces.iter().map(|p| p.meta.frame.bmin[a]).fold(f64::INFINITY, f64::min)),
    };
    let mut dims = global.map_or([0usize; 3], |g| g.dims);
    let mut offsets = Vec::with_capacity(pieces.len());
    for (i, p) in pieces.iter().enumerate() {
        let f = &p.meta.frame;
        if let Some(g) = global {
            offsets.push(g.box_of(f).map_err(|e| Error::arg(format!("piece {i}: {e}")))?.lo);
            continue;
        }
        let mut offset = [0usize; 3];
        for a in 0..3 {
            let voxels = (f.bmin[a] - bmin[a]) * gamma;
            if (voxels - voxels.round()).abs() > LATTICE_TOLERANCE {
                return Err(Error::arg(format!(
                    "piece {i} starts {voxels} voxels from the others along axis {a}: the pieces must sit on one lattice"
                )));
            }
            offset[a] = voxels.round() as usize;
            dims[a] = dims[a].max(offset[a] + f.dims[a]);
        }
        offsets.push(offset);
    }
    let mut meta = first.meta.clone();
    meta.frame = IndexFrame { dims, bmin, gamma: global.map_or(gamma, |g| g.gamma) };
    meta.rank = 0;
    meta.encode_psnr = None;
    let mut params = Vec::with_capacity(pieces.iter().map(|p| p.params.len()).sum());
    for (p, offset) in pieces.iter().zip(&offsets) {
        params.extend(p.params.iter().map(|q| {
            let mut q = *q;
            for a in 0..3 {
                q[MU + a] += offset[a] as f32;
            }
            q
        }));
    }
    // One support over the union: each piece's own on its box (all of its
    // box for a piece without one); none at all when no piece has one.
    let support = pieces.iter().any(|p| p.support.is_some()).then(|| {
        let placed: Vec<_> = pieces
            .iter()
            .zip(&offsets)
            .map(|(p, o)| (p.support.as_ref(), IndexBox { lo: *o, hi: std::array::from_fn(|a| o[a] + p.meta.frame.dims[a]) }))
            .collect();
        Support::place(&placed, dims)
    });
    Ok(Model { meta, params, support })
}

/// The global field of a step's pieces on `region` of a lattice of
/// `out_dims` over the global frame, each piece decoded alone on its own
/// box and the pieces blended by a partition of unity: piece `p`'s weight is
/// 1 in its rank's own region and falls linearly to 0 across its halo
/// (`halo` voxels of the global lattice; no fall on sides that are the
/// domain's edge; with no halo, 1 over its box), and the value is
/// `sum w_p V_p / sum w_p`.
///
/// Why not the additive decode of [`merge`]: a piece's kernels reach up to
/// five standard deviations past its box, into neighbours' regions it never
/// saw, and where the field is faint (density below the decoder's floor)
/// those tails set the value; blending each piece only where it was fitted
/// removes them (docs/BENCHMARKS.md "MPI" compares the two).
pub fn blend(
    global: &IndexFrame,
    pieces: &[Model],
    boxes: &[IndexBox],
    halo: usize,
    out_dims: [usize; 3],
    region: IndexBox,
    backend: &mut dyn crate::backend::Backend,
) -> Result<crate::field::Grid> {
    if pieces.len() != boxes.len() || pieces.is_empty() {
        return Err(Error::arg("blend needs one box per piece"));
    }
    if (0..3).any(|a| region.lo[a] >= region.hi[a] || region.hi[a] > out_dims[a] || out_dims[a] == 0) {
        return Err(Error::arg(format!("region {:?}..{:?} is not inside the lattice of {out_dims:?}", region.lo, region.hi)));
    }
    let rd = region.dims();
    let n: usize = rd.iter().product();
    let mut sum = vec![0f64; n];
    let mut weight = vec![0f64; n];
    // Output voxel i along axis a has its centre at global index u = (i + 0.5) s - 0.5.
    let step: [f64; 3] = std::array::from_fn(|a| global.dims[a] as f64 / out_dims[a] as f64);
    let centre = |a: usize, i: usize| (i as f64 + 0.5) * step[a] - 0.5;
    for (piece, b) in pieces.iter().zip(boxes) {
        // Output voxels whose centres lie in the piece's box, its voxels'
        // extent [lo - 0.5, hi - 0.5] in global index coordinates (the
        // ramp's domain): centre(i) >= lo - 0.5 from i = ceil(lo / s - 0.5),
        // centre(i) <= hi - 0.5 to i = floor(hi / s - 0.5). Together the
        // boxes cover every output voxel, those of a finer lattice within
        // half a voxel of the domain's faces too.
        let mut lo = [0usize; 3];
        let mut hi = [0usize; 3];
        for a in 0..3 {
            let first = (b.lo[a] as f64 / step[a] - 0.5).ceil().max(region.lo[a] as f64) as usize;
            let end = ((b.hi[a] as f64 / step[a] - 0.5).floor() + 1.0).min(region.hi[a] as f64).max(0.0) as usize;
            (lo[a], hi[a]) = (first, end.max(first));
        }
        let dims = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
        if dims.contains(&0) {
            continue;
        }
        let lattice = crate::backend::Lattice {
            dims,
            origin: std::array::from_fn(|a| (centre(a, lo[a]) - b.lo[a] as f64) as f32),
            step: step.map(|s| s as f32),
        };
        let mut values = vec![0f32; dims.iter().product()];
        piece.decode_lattice(backend, &lattice, &mut values)?;
        let w: [Vec<f64>; 3] = std::array::from_fn(|a| (lo[a]..hi[a]).map(|i| ramp(b, global.dims, halo, a, centre(a, i))).collect());
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                let wjk = w[1][j] * w[2][k];
                for i in 0..dims[0] {
                    let wi = w[0][i] * wjk;
                    let at = (lo[0] + i - region.lo[0]) + rd[0] * ((lo[1] + j - region.lo[1]) + rd[1] * (lo[2] + k - region.lo[2]));
                    sum[at] += wi * values[i + dims[0] * (j + dims[1] * k)] as f64;
                    weight[at] += wi;
                }
            }
        }
    }
    let values = sum.iter().zip(&weight).map(|(&s, &w)| if w > 0.0 { (s / w) as f32 } else { 0.0 }).collect();
    crate::field::Grid::new(rd, values)
}

/// A piece's blend weight along axis `a` at global index coordinate `u`
/// (voxel centres at whole numbers) within its voxels' extent: 1 inside
/// its rank's region, falling to 0 across the halo at a side that borders
/// another rank (not at the domain's edge). Pieces without a halo only
/// abut: each weighs 1 over its whole extent, so that a point on their
/// common face (an output voxel's centre, at some resolutions) takes the
/// mean of the two instead of the weight 0 of both ramps there.
fn ramp(b: &IndexBox, global_dims: [usize; 3], halo: usize, a: usize, u: f64) -> f64 {
    if halo == 0 {
        return 1.0;
    }
    let t = halo as f64;
    let low = if b.lo[a] == 0 { 1.0 } else { ((u - (b.lo[a] as f64 - 0.5)) / t).clamp(0.0, 1.0) };
    let high = if b.hi[a] == global_dims[a] { 1.0 } else { (((b.hi[a] as f64 - 0.5) - u) / t).clamp(0.0, 1.0) };
    low.min(high)
}

/// [`blend`] at world points (each finite) instead of on a lattice: each
/// piece whose box holds a point (as `blend` counts it) evaluates it, and
/// the values are blended with the same weights; 0 where no piece does.
pub fn blend_points(
    global: &IndexFrame,
    pieces: &[Model],
    boxes: &[IndexBox],
    halo: usize,
    points: &[[f64; 3]],
    backend: &mut dyn crate::backend::Backend,
) -> Result<Vec<f32>> {
    if pieces.len() != boxes.len() || pieces.is_empty() {
        return Err(Error::arg("blend needs one box per piece"));
    }
    if let Some(i) = points.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
        return Err(Error::data(format!("point {i} is not finite")));
    }
    let u: Vec<[f64; 3]> = points.iter().map(|p| std::array::from_fn(|a| (p[a] - global.bmin[a]) * global.gamma - 0.5)).collect();
    let mut sum = vec![0f64; points.len()];
    let mut weight = vec![0f64; points.len()];
    for (piece, b) in pieces.iter().zip(boxes) {
        // A lattice decode gives a piece the voxel centres u within its
        // voxels' extent, lo - 0.5 <= u <= hi - 0.5.
        let inside: Vec<usize> = (0..points.len())
            .filter(|&i| (0..3).all(|a| u[i][a] >= b.lo[a] as f64 - 0.5 && u[i][a] <= b.hi[a] as f64 - 0.5))
            .collect();
        if inside.is_empty() {
            continue;
        }
        let values = piece.evaluate(backend, &inside.iter().map(|&i| points[i]).collect::<Vec<_>>())?;
        for (&i, v) in inside.iter().zip(values) {
            let w: f64 = (0..3).map(|a| ramp(b, global.dims, halo, a, u[i][a])).product();
            sum[i] += w * v as f64;
            weight[i] += w;
        }
    }
    Ok(sum.iter().zip(&weight).map(|(&s, &w)| if w > 0.0 { (s / w) as f32 } else { 0.0 }).collect())
}
