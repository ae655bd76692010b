//! Decoding on the GPU: per slab of 8 lattice planes, the slab's
//! primitives, then each 8x8x8 brick's from the slab's list, then V_eval at
//! every lattice point of the brick (decode.wgsl). Mirrors cpu/mod.rs
//! `decode_lattice`. Two slabs are in flight: the next is on the device's
//! queue while the host copies the last one out.

use super::kernels::*;
use super::{count_u32, seq, words, GpuBackend};
use crate::backend::{check_len, Lattice};
use crate::error::Result;
use crate::math::kernel::Primitive;
use rayon::prelude::*;
use std::collections::VecDeque;

/// Bytes of a slab copied out of the mapped buffer by one task.
const COPY_RUN: usize = 1 << 20;

/// Slabs submitted before the oldest is read: the device decodes one while
/// the host copies the other into the caller's array.
const IN_FLIGHT: usize = 2;

/// What every slab of one decode shares.
struct Slabs {
    /// The uniforms of the whole lattice; each slab sets `counts`, `stage`
    /// and `bin`.
    base: Params,
    /// Lattice points of one z plane.
    layer: usize,
    dims_z: usize,
    /// Bricks of one slab, and of the lattice along z.
    ncells: u32,
    nbz: usize,
    /// Chunks of the primitives the slab's list is binned from.
    split: u32,
    n: u32,
}

impl Slabs {
    fn new(lattice: &Lattice, primitives: usize, bin_chunk: usize) -> Result<Slabs> {
        let d = lattice.dims;
        let bs = DECODE_BRICK;
        let [nbx, nby, nbz] = [d[0].div_ceil(bs), d[1].div_ceil(bs), d[2].div_ceil(bs)];
        let n = count_u32("primitives", primitives)?;
        let base = Params {
            grid_lo: [lattice.origin[0], lattice.origin[1], lattice.origin[2], 0.0],
            grid_step: [lattice.step[0], lattice.step[1], lattice.step[2], 0.0],
            grid_dims: [count_u32("bricks", nbx)?, count_u32("bricks", nby)?, count_u32("bricks", nbz)?, CELLS_LATTICE],
            lattice: [count_u32("points", d[0])?, count_u32("points", d[1])?, count_u32("points", d[2])?, bs as u32],
            counts: [n, 1, n, 0],
            ..Params::default()
        };
        Ok(Slabs { base, layer: d[0] * d[1], dims_z: d[2], ncells: count_u32("bricks", nbx * nby)?, nbz, split: bin_split(primitives, bin_chunk)?, n })
    }

    /// Lattice planes `z0..z0 + layers` of slab `bz`.
    fn planes(&self, bz: usize) -> (usize, usize) {
        let z0 = bz * DECODE_BRICK;
        (z0, DECODE_BRICK.min(self.dims_z - z0))
    }
}

/// A slab on the device's queue: which, the read-back slot it comes back
/// through, and the list capacity it ran with.
#[derive(Clone, Copy)]
struct InFlight {
    bz: usize,
    slot: usize,
    capacity: usize,
}

impl GpuBackend {
    /// `Backend::decode_lattice`: slab by slab of lattice bricks, the next
    /// slab submitted before the last one is read. A slab whose lists
    /// overflowed runs again with room for them, and so does the slab
    /// submitted after it, if its lists overflowed too.
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
        let slabs = Slabs::new(lattice, params.len(), self.bin_chunk)?;
        // Slabs to decode, in order; one whose lists overflowed goes back
        // to the front.
        let mut todo: VecDeque<usize> = (0..slabs.nbz).collect();
        let mut submitted = 0;
        let mut pending: Option<InFlight> = None;
        loop {
            let submit = match todo.pop_front() {
                Some(bz) => {
                    // The primitives' frames are computed with the first slab.
                    let slab = self.submit_slab(&slabs, bz, submitted % IN_FLIGHT, submitted == 0)?;
                    submitted += 1;
                    Some(slab)
                }
                None => None,
            };
            if let Some(slab) = pending {
                if !self.read_slab(&slabs, slab, out)? {
                    // The slab behind it ran with the same capacity: it is
                    // read too, and kept if its lists fitted.
                    if let Some(next) = submit {
                        if !self.read_slab(&slabs, next, out)? {
                            todo.push_front(next.bz);
                        }
                    }
                    todo.push_front(slab.bz);
                    pending = None;
                    continue;
                }
            }
            match submit {
                Some(s) => pending = Some(s),
                None => return Ok(()),
            }
        }
    }

    /// Records and submits slab `bz`: its list from every primitive,
    /// in chunks; each brick's from the slab's list whole; V_eval at the
    /// slab's lattice points; the slab and its lists' total copied to
    /// read-back slot `slot`. The lists may fill their whole buffer, which
    /// grows by more than the capacity asked for.
    fn submit_slab(&mut self, s: &Slabs, bz: usize, slot: usize, frames: bool) -> Result<InFlight> {
        let room = self.bufs.lists.ensure(&self.gpu, 4 * self.slab_capacity as u64, self.garbage)?.size() / 4;
        let slab = InFlight { bz, slot, capacity: room as usize };
        let (z0, layers) = s.planes(bz);
        let slab_p = Params { counts: [s.n, 1, s.n, 0], stage: [BIN_SLAB, bz as u32, z0 as u32, 0], bin: [s.split, 1, 0, 0], ..s.base };
        let brick_p = Params {
            counts: [s.n, s.ncells, count_u32("candidate slots", slab.capacity)?, 0],
            stage: [BIN_SLAB_BRICKS, bz as u32, z0 as u32, 0],
            bin: [1, s.split, 0, 0],
            ..s.base
        };
        let (n, ncells, split) = (s.n, s.ncells, s.split);
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
        b.coarse_cells.ensure(gpu, 32, g)?;
        b.slab.ensure(gpu, 4 * (s.layer * layers) as u64, g)?;
        timer.begin(slot);
        let [us1, us2] = &mut b.uniforms[slot];
        let (u1, u2) = (us1.upload(gpu, bytemuck::bytes_of(&slab_p), g)?.clone(), us2.upload(gpu, bytemuck::bytes_of(&brick_p), g)?.clone());
        binds.keep_while(b.made());
        gpu.scoped("a decode slab", || {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            let (params, hot, ranges) = (b.params.ensure(gpu, 0, false)?, b.hot.ensure(gpu, 0, false)?, b.ranges.ensure(gpu, 0, false)?);
            let (ident, ident_bounds, cells) = (b.identity.ensure(gpu, 0, false)?, b.identity_bounds.ensure(gpu, 0, false)?, b.coarse_cells.ensure(gpu, 0, false)?);
            let (sc, ss, sl) = (b.coarse_counts.ensure(gpu, 0, false)?, b.coarse_starts.ensure(gpu, 0, false)?, b.coarse_lists.ensure(gpu, 0, false)?);
            let (counts, starts, lists) = (b.counts.ensure(gpu, 0, false)?, b.starts.ensure(gpu, 0, false)?, b.lists.ensure(gpu, 0, false)?);
            let out = b.slab.ensure(gpu, 0, false)?;
            if frames {
                dispatch(gpu, &mut enc, timer, binds, &k.frames, &seq(&[&u1, params, hot, ranges]), groups_for(n as usize));
            }
            let slab_level = ListLevel { uniform: &u1, cells, counts: sc, starts: ss, lists: sl, groups: split };
            let brick_level = ListLevel { uniform: &u2, cells, counts, starts, lists, groups: ncells };
            bin_level(gpu, &mut enc, timer, binds, k, ranges, (ident, ident_bounds), &slab_level);
            bin_level(gpu, &mut enc, timer, binds, k, ranges, (sl, ss), &brick_level);
            dispatch(gpu, &mut enc, timer, binds, &k.decode, &seq(&[&u2, hot, starts, lists, out]), ncells);
            // The queue runs submissions in order, so the next slab's
            // passes, which reuse these buffers, start after this copy.
            let times = timer.resolve(&mut enc).unwrap_or((out, 0));
            b.readback[slot].record(gpu, &mut enc, &[(out, 4 * (s.layer * layers) as u64), (starts, 4 * (ncells as u64 + 1)), times])?;
            b.readback[slot].submit(gpu, enc);
            Ok(slab)
        })
    }

    /// Waits for slab `slab` and, when its lists fitted, copies it from
    /// the mapped buffer straight into its planes of `out`, on the pool's
    /// threads, and returns true. When they overflowed, makes room for them
    /// (the next slab submitted has it) and returns false.
    fn read_slab(&mut self, s: &Slabs, slab: InFlight, out: &mut [f32]) -> Result<bool> {
        let (z0, layers) = s.planes(slab.bz);
        let dest = bytemuck::cast_slice_mut::<f32, u8>(&mut out[z0 * s.layer..(z0 + layers) * s.layer]);
        let gpu = &self.gpu;
        let readback = &mut self.bufs.readback[slab.slot];
        let read = gpu.scoped("reading a decode slab", || {
            readback.read_with(gpu, |parts| {
                let total = words(parts[1]).last().copied().unwrap_or(0) as usize;
                if total <= slab.capacity {
                    dest.par_chunks_mut(COPY_RUN).zip(parts[0].par_chunks(COPY_RUN)).for_each(|(to, from)| to.copy_from_slice(from));
                }
                vec![bytemuck::bytes_of(&(total as u64)).to_vec(), parts[2].to_vec()]
            })
        });
        let read = self.timed(slab.slot, read)?;
        let total = bytemuck::pod_read_unaligned::<u64>(&read[0]) as usize;
        if total <= slab.capacity {
            return Ok(true);
        }
        // Twice the total: the slab behind this one ran with the same room,
        // so each overflow costs two slabs, and the lists grow slab by slab
        // from the field's edges to its middle. Within the adapter's
        // largest buffer, where the total alone still fits.
        let most = (self.gpu.limits.max_storage_buffer_binding_size.min(self.gpu.limits.max_buffer_size) / 4) as usize;
        self.slab_capacity = self.slab_capacity.max((2 * total).min(most).max(total));
        self.reruns += 1;
        Ok(false)
    }
}
