//! Decoding on the GPU: per slab of 8 lattice planes, the slab's
//! primitives, then each 8x8x8 brick's from the slab's list, then V_eval at
//! every lattice point of the brick (decode.wgsl). Mirrors cpu/mod.rs
//! `decode_lattice`.

use super::kernels::*;
use super::{count_u32, seq, words, GpuBackend};
use crate::backend::{check_len, Lattice};
use crate::error::Result;
use crate::math::kernel::Primitive;
use rayon::prelude::*;

/// Bytes of a slab copied out of the mapped buffer by one task.
const COPY_RUN: usize = 1 << 20;

impl GpuBackend {
    /// `Backend::decode_lattice`: slab by slab of lattice bricks.
    pub(super) fn decode(&mut self, params: &[Primitive], lattice: &Lattice, out: &mut [f32]) -> Result<()> {
        check_len("out", out.len(), lattice.len())?;
        if out.is_empty() {
            return Ok(());
        }
        if params.is_empty() {
            out.fill(0.0);
            return Ok(());
        }
        self.upload_params(params)?;
        let d = lattice.dims;
        let bs = DECODE_BRICK;
        let nbx = d[0].div_ceil(bs);
        let nby = d[1].div_ceil(bs);
        let nbz = d[2].div_ceil(bs);
        let n = count_u32("primitives", params.len())?;
        let base = Params {
            grid_lo: [lattice.origin[0], lattice.origin[1], lattice.origin[2], 0.0],
            grid_step: [lattice.step[0], lattice.step[1], lattice.step[2], 0.0],
            grid_dims: [count_u32("bricks", nbx)?, count_u32("bricks", nby)?, count_u32("bricks", nbz)?, CELLS_LATTICE],
            lattice: [count_u32("points", d[0])?, count_u32("points", d[1])?, count_u32("points", d[2])?, bs as u32],
            counts: [n, 1, n, 0],
            ..Params::default()
        };
        let layer = d[0] * d[1];
        let ncells = count_u32("bricks", nbx * nby)?;
        let split = bin_split(params.len(), self.bin_chunk)?;
        let mut frames_done = false;
        let mut bz = 0;
        while bz < nbz {
            let z0 = bz * bs;
            let layers = bs.min(d[2] - z0);
            // The slab's list from every primitive, in chunks; each brick's
            // from the slab's list whole.
            let slab_p = Params { counts: [n, 1, n, 0], stage: [BIN_SLAB, bz as u32, z0 as u32, 0], bin: [split, 1, 0, 0], ..base };
            let brick_p = Params {
                counts: [n, ncells, count_u32("candidate slots", self.slab_capacity)?, 0],
                stage: [BIN_SLAB_BRICKS, bz as u32, z0 as u32, 0],
                bin: [1, split, 0, 0],
                ..base
            };
            let g = self.garbage;
            let gpu = &self.gpu;
            let k = &self.kernels;
            let timer = &mut self.timer;
            let binds = &mut self.binds;
            let b = &mut self.bufs;
            b.coarse_counts.ensure(gpu, 4 * split as u64, g)?;
            b.coarse_starts.ensure(gpu, 4 * (split as u64 + 1), g)?;
            b.coarse_lists.ensure(gpu, 4 * n as u64, g)?;
            b.counts.ensure(gpu, 4 * ncells as u64, g)?;
            b.starts.ensure(gpu, 4 * (ncells as u64 + 1), g)?;
            b.lists.ensure(gpu, 4 * self.slab_capacity as u64, g)?;
            b.coarse_cells.ensure(gpu, 32, g)?;
            b.slab.ensure(gpu, 4 * (layer * layers) as u64, g)?;
            timer.begin(0);
            let [us1, us2] = &mut b.uniforms[0];
            let (u1, u2) = (us1.upload(gpu, bytemuck::bytes_of(&slab_p), g)?.clone(), us2.upload(gpu, bytemuck::bytes_of(&brick_p), g)?.clone());
            binds.keep_while(b.made());
            let dest = bytemuck::cast_slice_mut::<f32, u8>(&mut out[z0 * layer..(z0 + layers) * layer]);
            let capacity = self.slab_capacity;
            let read = gpu.scoped("a decode slab", || {
                let mut enc = gpu.device.create_command_encoder(&Default::default());
                let (params, hot, ranges) = (b.params.ensure(gpu, 0, false)?, b.hot.ensure(gpu, 0, false)?, b.ranges.ensure(gpu, 0, false)?);
                let (ident, ident_bounds, cells) = (b.identity.ensure(gpu, 0, false)?, b.identity_bounds.ensure(gpu, 0, false)?, b.coarse_cells.ensure(gpu, 0, false)?);
                let (sc, ss, sl) = (b.coarse_counts.ensure(gpu, 0, false)?, b.coarse_starts.ensure(gpu, 0, false)?, b.coarse_lists.ensure(gpu, 0, false)?);
                let (counts, starts, lists) = (b.counts.ensure(gpu, 0, false)?, b.starts.ensure(gpu, 0, false)?, b.lists.ensure(gpu, 0, false)?);
                let slab = b.slab.ensure(gpu, 0, false)?;
                if !frames_done {
                    dispatch(gpu, &mut enc, timer, binds, &k.frames, &seq(&[&u1, params, hot, ranges]), groups_for(n as usize));
                }
                // The slab's primitives, from all of them; each brick's,
                // from the slab's.
                let slab_level = ListLevel { uniform: &u1, cells, counts: sc, starts: ss, lists: sl, groups: split };
                let brick_level = ListLevel { uniform: &u2, cells, counts, starts, lists, groups: ncells };
                bin_level(gpu, &mut enc, timer, binds, k, ranges, (ident, ident_bounds), &slab_level);
                bin_level(gpu, &mut enc, timer, binds, k, ranges, (sl, ss), &brick_level);
                dispatch(gpu, &mut enc, timer, binds, &k.decode, &seq(&[&u2, hot, starts, lists, slab]), ncells);
                let times = timer.resolve(&mut enc).unwrap_or((slab, 0));
                b.readback[0].record(gpu, &mut enc, &[(slab, 4 * (layer * layers) as u64), (starts, 4 * (ncells as u64 + 1)), times])?;
                b.readback[0].submit(gpu, enc);
                b.readback[0].read_with(gpu, |parts| {
                    // The lists' total; the slab, when its lists fitted,
                    // from the mapped buffer straight into the caller's
                    // array, on the pool's threads; the times.
                    let total = words(parts[1]).last().copied().unwrap_or(0) as usize;
                    if total <= capacity {
                        dest.par_chunks_mut(COPY_RUN).zip(parts[0].par_chunks(COPY_RUN)).for_each(|(d, s)| d.copy_from_slice(s));
                    }
                    vec![bytemuck::bytes_of(&(total as u64)).to_vec(), parts[2].to_vec()]
                })
            });
            let read = self.timed(0, read)?;
            frames_done = true;
            let total = bytemuck::pod_read_unaligned::<u64>(&read[0]) as usize;
            if total > self.slab_capacity {
                self.slab_capacity = total + total / 4;
                self.reruns += 1;
                continue;
            }
            bz += 1;
        }
        Ok(())
    }
}
