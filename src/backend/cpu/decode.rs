//! The decode (`Backend::decode_lattice`): primitives splatted brick by
//! brick of the lattice; each z-slab of bricks is one parallel task that
//! writes its own slice of the output, so no sum depends on the thread
//! count.

use super::CpuBackend;
use crate::backend::csr::{csr, Keyed};
use crate::backend::{check_len, Lattice};
use crate::error::Result;
use crate::math::kernel::{Primitive, CUTOFF_D2};
use crate::math::loss::v_eval;
use rayon::prelude::*;

/// Edge of a decode brick in lattice voxels.
const DECODE_BRICK: usize = 8;

impl CpuBackend {
    /// [`crate::backend::Backend::decode_lattice`].
    pub(super) fn splat_lattice(&mut self, params: &[Primitive], lattice: &Lattice, out: &mut [f32]) -> Result<()> {
        check_len("out", out.len(), lattice.len())?;
        self.prep.update(params);
        let frames = &self.prep.frames;
        let dims = lattice.dims;
        // Each primitive's box in lattice indices (inclusive), or None when outside.
        let boxes: Vec<Option<[u32; 6]>> = frames
            .par_iter()
            .map(|f| {
                let mut r = [0u32; 6];
                for a in 0..3 {
                    let l = ((f.mu[a] - f.ext[a] - lattice.origin[a]) / lattice.step[a]).ceil();
                    let h = ((f.mu[a] + f.ext[a] - lattice.origin[a]) / lattice.step[a]).floor();
                    if !(h >= 0.0 && l <= (dims[a] - 1) as f32) || h < l {
                        return None;
                    }
                    r[a] = l.max(0.0) as u32;
                    r[a + 3] = h.min((dims[a] - 1) as f32) as u32;
                }
                Some(r)
            })
            .collect();
        let bs = DECODE_BRICK;
        let nlayers = dims[2].div_ceil(bs);
        let mut layer_pairs = vec![];
        for (g, b) in boxes.iter().enumerate() {
            if let Some(b) = b {
                for layer in b[2] as usize / bs..=b[5] as usize / bs {
                    layer_pairs.push((layer as u32, g as u32));
                }
            }
        }
        let (lstart, lcand) = csr(nlayers, vec![Keyed::from_pairs(nlayers, layer_pairs)]);
        let (nbx, nby) = (dims[0].div_ceil(bs), dims[1].div_ceil(bs));
        let slab_len = dims[0] * dims[1] * bs;
        out.par_chunks_mut(slab_len).enumerate().for_each(|(layer, slab)| {
            let cands = &lcand[lstart[layer] as usize..lstart[layer + 1] as usize];
            let z0 = layer * bs;
            let nz = slab.len() / (dims[0] * dims[1]);
            let mut pairs = vec![];
            for &g in cands {
                let b = boxes[g as usize].unwrap();
                for by in b[1] as usize / bs..=b[4] as usize / bs {
                    for bx in b[0] as usize / bs..=b[3] as usize / bs {
                        pairs.push(((bx + nbx * by) as u32, g));
                    }
                }
            }
            let (bstart, bcand) = csr(nbx * nby, vec![Keyed::from_pairs(nbx * nby, pairs)]);
            let mut rho = vec![0f32; bs * bs * bs];
            let mut num = vec![0f32; bs * bs * bs];
            for by in 0..nby {
                for bx in 0..nbx {
                    let (x0, y0) = (bx * bs, by * bs);
                    let (nx, ny) = (bs.min(dims[0] - x0), bs.min(dims[1] - y0));
                    rho.fill(0.0);
                    num.fill(0.0);
                    let id = bx + nbx * by;
                    for &g in &bcand[bstart[id] as usize..bstart[id + 1] as usize] {
                        let f = &frames[g as usize];
                        let a = f.scaled_axes();
                        let b = boxes[g as usize].unwrap();
                        let zr = (b[2] as usize).max(z0)..=(b[5] as usize).min(z0 + nz - 1);
                        let yr = (b[1] as usize).max(y0)..=(b[4] as usize).min(y0 + ny - 1);
                        let (i0, i1) = ((b[0] as usize).max(x0), (b[3] as usize).min(x0 + nx - 1));
                        for k in zr {
                            for j in yr.clone() {
                                let base = (j - y0) * bs + (k - z0) * bs * bs;
                                let p = lattice.point(i0, j, k);
                                let (dy, dz) = (p[1] - f.mu[1], p[2] - f.mu[2]);
                                let c = [0, 1, 2].map(|r| a[r][1] * dy + a[r][2] * dz);
                                let dx0 = p[0] - f.mu[0];
                                let row = base + i0 - x0..=base + i1 - x0;
                                // Branch-free over the row, so that it vectorises.
                                for (t, (r, n)) in rho[row.clone()].iter_mut().zip(num[row].iter_mut()).enumerate() {
                                    let dx = dx0 + t as f32 * lattice.step[0];
                                    let u0 = a[0][0] * dx + c[0];
                                    let u1 = a[1][0] * dx + c[1];
                                    let u2 = a[2][0] * dx + c[2];
                                    let d2 = u0 * u0 + u1 * u1 + u2 * u2;
                                    let e = crate::math::kernel::exp_neg_half(d2);
                                    let wk = f.w * if d2 < CUTOFF_D2 { e } else { 0.0 };
                                    *r += wk;
                                    *n += wk * f.s;
                                }
                            }
                        }
                    }
                    for k in 0..nz {
                        for j in 0..ny {
                            let row = x0 + dims[0] * (y0 + j + dims[1] * k);
                            for i in 0..nx {
                                let l = i + j * bs + k * bs * bs;
                                slab[row + i] = v_eval(rho[l], num[l]);
                            }
                        }
                    }
                }
            }
        });
        Ok(())
    }
}
