//! The compute pipelines of the GPU backend, the uniform block they share,
//! and the helpers that bind and dispatch them. Each WGSL file is compiled
//! with `math.wgsl` (the shared math) prepended.

use super::device::Gpu;
use super::seq;
use super::timer::Timer;
use crate::error::Result;
use crate::math::loss::{LossWeights, PointNorm};
use std::collections::HashMap;

const MATH: &str = include_str!("shaders/math.wgsl");

/// `Params` of math.wgsl: what every pass of one backend call reads.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Params {
    pub grid_lo: [f32; 4],
    pub grid_step: [f32; 4],
    pub grid_dims: [u32; 4],
    pub lattice: [u32; 4],
    pub counts: [u32; 4],
    pub loss: [f32; 4],
    pub stage: [u32; 4],
    pub optim: [f32; 4],
    pub reg: [f32; 4],
    pub coarse: [u32; 4],
    pub bin: [u32; 4],
    pub objective: [f32; 4],
    pub split: [u32; 4],
    pub rows: [u32; 4],
}

impl Params {
    /// Sets what the loss kernels read of the objective for a batch of
    /// reference values `vref`: `loss` (the batch's normalisers, as loss.rs
    /// `PointNorm` computes them, and the weights of L_val and L_cov) and
    /// `objective` (the fidelity weight's constant and slope, the
    /// anisotropy ratio of L_aniso).
    pub fn set_objective(&mut self, vref: &[f32], w: &LossWeights) {
        let norm = PointNorm::new(vref, w);
        self.loss = [norm.inv_weight_sum, norm.inv_count, w.val, w.cov];
        self.objective = [w.fidelity[0], w.fidelity[1], w.aniso_ratio, 0.0];
    }
}

/// math.wgsl `CELLS_*`: how a primitive's box maps to grid cells.
pub const CELLS_TRAINING: u32 = 0;
pub const CELLS_LATTICE: u32 = 1;
/// math.wgsl `BIN_*`: which cells a bin pass fills.
pub const BIN_LISTED: u32 = 0;
pub const BIN_SLAB: u32 = 1;
pub const BIN_SLAB_BRICKS: u32 = 2;
/// The most source entries one workgroup of a bin pass tests: a level that
/// bins from every primitive splits each cell's source into chunks of this
/// size, one workgroup each, so that a few coarse cells still fill the GPU.
pub const BIN_CHUNK: usize = 4096;

/// Chunks of `chunk` entries a bin pass over a source list of `len`
/// entries splits it into.
pub fn bin_split(len: usize, chunk: usize) -> Result<u32> {
    super::count_u32("bin chunks", len.div_ceil(chunk.max(1)).max(1))
}

/// Points a workgroup of the forward pass evaluates (forward.wgsl `PTS`
/// at a time): a brick's points are cut into pieces of this many, one
/// workgroup each, so that a few dense bricks still fill the GPU. Each
/// point's sums do not depend on the piece it falls in.
pub const FORWARD_PIECE: usize = 8;
/// The most threads that reduce one primitive's slots by default
/// (reduce.wgsl: each finds the slot of every team-th brick of its range,
/// the first adds them in brick order); a team is a power of two up to
/// 128. The sums do not depend on it.
pub const REDUCE_TEAM: u32 = 8;
/// The reduction's threads that the default team aims at: a team of
/// `REDUCE_THREADS / primitives` (down to a power of two, 1 to
/// `REDUCE_TEAM`). On the H200 (2026-12-04, `benches/gpu_split.sh`) a team
/// of 8 reduced hydrogen's 4,096 primitives in half the time of 1, while 1
/// beat 8 at 32,000 (0.074 against 0.108 ms an iteration) and at 200,000
/// (0.219 against 0.586 ms): once the primitives alone fill the GPU, a
/// team's extra threads mostly idle.
pub const REDUCE_THREADS: usize = 32_768;

/// The default reduction team for `primitives` (see [`REDUCE_THREADS`]).
pub fn reduce_team_for(primitives: usize) -> u32 {
    let team = (REDUCE_THREADS / primitives.max(1)).clamp(1, REDUCE_TEAM as usize);
    1 << team.ilog2()
}
/// Workgroups of the backward pass per brick: slice `s` of a brick takes
/// its candidates' chunks `s`, `s + BACKWARD_SLICES`, ... (128 candidates a
/// chunk, a thread each); each pair's sums are one thread's whatever the
/// slice. The host does not know a brick's candidates when it records the
/// pass (the lists are made on the device), so every brick gets as many.
pub const BACKWARD_SLICES: u32 = 8;

/// decode.wgsl `BS`: edge of a decode brick in lattice points.
pub const DECODE_BRICK: usize = 8;
/// Threads per workgroup of the per-primitive kernels (frames, reduce).
const THREADS: u32 = 128;
/// The most workgroups along one dispatch axis (WebGPU's limit).
const MAX_GROUPS: u32 = 65535;

/// A compiled kernel and the name its times are reported under.
pub struct Kernel {
    pub label: &'static str,
    pub pipeline: wgpu::ComputePipeline,
}

/// The three kernels of bin_rows.wgsl.
pub struct RowKernels {
    pub count: Kernel,
    pub total: Kernel,
    pub fill: Kernel,
}

pub struct Kernels {
    pub frames: Kernel,
    pub count: Kernel,
    pub fill: Kernel,
    /// bin_rows.wgsl at the coarse level and at the brick level: the same
    /// pipelines, timed under names of their own.
    pub cells: RowKernels,
    pub bricks: RowKernels,
    pub scan: Kernel,
    pub forward: Kernel,
    pub backward: Kernel,
    pub reduce: Kernel,
    pub step: Kernel,
    pub loss: Kernel,
    pub decode: Kernel,
}

impl Kernels {
    pub fn new(gpu: &Gpu) -> Result<Kernels> {
        gpu.scoped("compiling the kernels", || {
            let module = |name: &str, src: &str| {
                gpu.device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(name),
                    source: wgpu::ShaderSource::Wgsl(format!("{MATH}\n{src}").into()),
                })
            };
            let pipeline = |m: &wgpu::ShaderModule, label: &'static str, entry: &str| Kernel {
                label,
                pipeline: gpu.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(label),
                    layout: None,
                    module: m,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                }),
            };
            let bin = module("bin.wgsl", include_str!("shaders/bin.wgsl"));
            let rows = module("bin_rows.wgsl", include_str!("shaders/bin_rows.wgsl"));
            let bricks = RowKernels {
                count: pipeline(&rows, "bin bricks count", "count"),
                total: pipeline(&rows, "bin bricks total", "total"),
                fill: pipeline(&rows, "bin bricks fill", "fill"),
            };
            let as_cells = |k: &Kernel, label| Kernel { label, pipeline: k.pipeline.clone() };
            let cells = RowKernels {
                count: as_cells(&bricks.count, "bin cells count"),
                total: as_cells(&bricks.total, "bin cells total"),
                fill: as_cells(&bricks.fill, "bin cells fill"),
            };
            let reduce = module("reduce.wgsl", include_str!("shaders/reduce.wgsl"));
            Ok(Kernels {
                frames: pipeline(&module("frames.wgsl", include_str!("shaders/frames.wgsl")), "frames", "main"),
                count: pipeline(&bin, "bin count", "count"),
                fill: pipeline(&bin, "bin fill", "fill"),
                cells,
                bricks,
                scan: pipeline(&module("scan.wgsl", include_str!("shaders/scan.wgsl")), "scan", "main"),
                forward: pipeline(&module("forward.wgsl", include_str!("shaders/forward.wgsl")), "forward", "main"),
                backward: pipeline(&module("backward.wgsl", include_str!("shaders/backward.wgsl")), "backward", "main"),
                reduce: pipeline(&reduce, "reduce", "main"),
                step: pipeline(&reduce, "reduce adam", "step"),
                loss: pipeline(&module("loss.wgsl", include_str!("shaders/loss.wgsl")), "loss", "main"),
                decode: pipeline(&module("decode.wgsl", include_str!("shaders/decode.wgsl")), "decode", "main"),
            })
        })
    }
}

/// The bind groups of the dispatches so far, kept for dispatches that bind
/// the same buffers to the same kernel: a training step binds the buffers
/// of the step before it, and each bind group is a descriptor set that the
/// driver allocates and writes. Forgotten when the backend's buffers have
/// grown since ([`BindGroups::keep_while`]: a kept group would hold a
/// replaced buffer's memory), and past `BindGroups::MOST` of them.
#[derive(Default)]
pub struct BindGroups {
    kept: HashMap<(&'static str, Vec<(u32, wgpu::Buffer)>), wgpu::BindGroup>,
    /// `Buffers::made()` when `kept` was last emptied.
    made: u64,
    /// Bind groups made (rather than found kept) so far.
    pub created: u64,
}

impl BindGroups {
    const MOST: usize = 256;

    /// Forgets every kept bind group unless `buffers_made` (the backend's
    /// `Buffers::made()`, read before recording a call) is what it was.
    pub fn keep_while(&mut self, buffers_made: u64) {
        if buffers_made != self.made || self.kept.len() >= Self::MOST {
            self.kept.clear();
            self.made = buffers_made;
        }
    }

    /// The bind group of `buffers` for `kernel`: a kept one, or a new one.
    fn get(&mut self, gpu: &Gpu, kernel: &Kernel, buffers: &[(u32, &wgpu::Buffer)]) -> wgpu::BindGroup {
        let key = (kernel.label, buffers.iter().map(|&(binding, b)| (binding, b.clone())).collect::<Vec<_>>());
        if let Some(group) = self.kept.get(&key) {
            return group.clone();
        }
        let entries: Vec<wgpu::BindGroupEntry> =
            buffers.iter().map(|&(binding, b)| wgpu::BindGroupEntry { binding, resource: b.as_entire_binding() }).collect();
        let group = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &kernel.pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        self.created += 1;
        self.kept.insert(key, group.clone());
        group
    }
}

/// Records one dispatch of `pipeline` with each `(binding, buffer)` bound
/// in group 0 (the bindings its entry point uses, no more), over `groups`
/// workgroups (split over two axes past WebGPU's 65535 a side; the kernels
/// rebuild the linear index). The bind group comes from `binds` when an
/// earlier dispatch made it.
/// The pass is timed by `timer` (under the kernel's label) when it can.
pub fn dispatch(
    gpu: &Gpu,
    enc: &mut wgpu::CommandEncoder,
    timer: &mut Timer,
    binds: &mut BindGroups,
    kernel: &Kernel,
    buffers: &[(u32, &wgpu::Buffer)],
    groups: u32,
) {
    if groups == 0 {
        return;
    }
    let group = binds.get(gpu, kernel, buffers);
    let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some(kernel.label), timestamp_writes: timer.writes(kernel.label) });
    pass.set_pipeline(&kernel.pipeline);
    pass.set_bind_group(0, &group, &[]);
    let x = groups.min(MAX_GROUPS);
    pass.dispatch_workgroups(x, groups.div_ceil(x), 1);
}

/// One level of the two-level lists of `bin.wgsl`: the uniform that names
/// the level, its cells, the counts, starts and lists that the count, scan
/// and fill kernels write there, and the workgroups of its count and fill.
pub struct ListLevel<'a> {
    pub uniform: &'a wgpu::Buffer,
    pub cells: &'a wgpu::Buffer,
    pub counts: &'a wgpu::Buffer,
    pub starts: &'a wgpu::Buffer,
    pub lists: &'a wgpu::Buffer,
    pub groups: u32,
}

/// Records one level of `bin.wgsl`: count, scan and fill of `l`'s cells
/// from the source lists `src` (entries) and `src_starts`: every
/// primitive (`ident`, `ident_bounds`) or the cells of the level before
/// (its lists and starts). The decode's two levels are two of these.
#[allow(clippy::too_many_arguments)]
pub fn bin_level(
    gpu: &Gpu,
    enc: &mut wgpu::CommandEncoder,
    timer: &mut Timer,
    binds: &mut BindGroups,
    k: &Kernels,
    ranges: &wgpu::Buffer,
    (src, src_starts): (&wgpu::Buffer, &wgpu::Buffer),
    l: &ListLevel,
) {
    dispatch(gpu, enc, timer, binds, &k.count, &seq(&[l.uniform, ranges, src, src_starts, l.cells, l.counts]), l.groups);
    dispatch(gpu, enc, timer, binds, &k.scan, &seq(&[l.uniform, l.counts, l.starts]), 1);
    dispatch(gpu, enc, timer, binds, &k.fill, &[(0, l.uniform), (1, ranges), (2, src), (3, src_starts), (4, l.cells), (6, l.starts), (7, l.lists)], l.groups);
}

/// Source entries a workgroup of a bit-row level aims at (bin_rows.wgsl:
/// a chunk of one parent's list).
pub const ROW_CHUNK: usize = 512;
/// The fewest workgroups the brick level aims at, so that a few coarse
/// cells (hydrogen 64³ has one) still give a GPU work to spread.
pub const BRICK_GROUPS: usize = 512;
/// The most chunks a coarse cell's list is cut into.
pub const MAX_BRICK_CHUNKS: usize = 256;
/// The most chunks the primitives are cut into at the coarse level.
pub const MAX_CELL_CHUNKS: usize = 4096;

/// Chunks each coarse cell's list is cut into at the brick level, for
/// about `coarse_entries` entries in the lists of `coarse_cells` cells.
/// The lists do not depend on it.
pub fn brick_chunks_for(coarse_entries: usize, coarse_cells: usize) -> u32 {
    let cells = coarse_cells.max(1);
    let k = coarse_entries.div_ceil(cells * ROW_CHUNK).max(BRICK_GROUPS.div_ceil(cells));
    k.clamp(1, MAX_BRICK_CHUNKS) as u32
}

/// Chunks the primitives are cut into where the coarse level is made from
/// bit rows (one root block): about `ROW_CHUNK` primitives a workgroup.
pub fn cell_chunks_for(primitives: usize) -> u32 {
    primitives.div_ceil(ROW_CHUNK).clamp(1, MAX_CELL_CHUNKS) as u32
}

/// A level of the training binning made from bit rows (bin_rows.wgsl): its
/// uniform (`P.rows`), the source lists and starts, the parents' boxes,
/// the dense map of child cells, the per (child, chunk) counts, the
/// children's counts, starts and lists, how many children there are and
/// the workgroups of its count and fill (parents times chunks).
pub struct RowLevel<'a> {
    pub uniform: &'a wgpu::Buffer,
    pub src: &'a wgpu::Buffer,
    pub src_starts: &'a wgpu::Buffer,
    pub parents: &'a wgpu::Buffer,
    pub child_map: &'a wgpu::Buffer,
    pub chunk_counts: &'a wgpu::Buffer,
    pub counts: &'a wgpu::Buffer,
    pub starts: &'a wgpu::Buffer,
    pub lists: &'a wgpu::Buffer,
    pub children: u32,
    pub groups: u32,
}

/// Records a level of the training binning from bit rows: each child's
/// entries of its parent's list (bin_rows.wgsl `count`, `total`, scan.wgsl
/// over the children's totals, `fill`), timed under `k`'s names.
#[allow(clippy::too_many_arguments)]
pub fn bin_rows(gpu: &Gpu, enc: &mut wgpu::CommandEncoder, timer: &mut Timer, binds: &mut BindGroups, k: &RowKernels, scan: &Kernel, ranges: &wgpu::Buffer, l: &RowLevel) {
    // `count` and `fill` share their walk over the bit rows (bin_rows.wgsl
    // `rows`), so both bind every buffer of it; `count` writes only the
    // per (child, chunk) counts.
    let rows = [(0, l.uniform), (1, ranges), (2, l.src), (3, l.src_starts), (4, l.parents), (5, l.child_map), (6, l.chunk_counts), (8, l.starts), (9, l.lists)];
    dispatch(gpu, enc, timer, binds, &k.count, &rows, l.groups);
    dispatch(gpu, enc, timer, binds, &k.total, &[(0, l.uniform), (6, l.chunk_counts), (7, l.counts)], l.children);
    dispatch(gpu, enc, timer, binds, scan, &seq(&[l.uniform, l.counts, l.starts]), 1);
    dispatch(gpu, enc, timer, binds, &k.fill, &rows, l.groups);
}

/// Workgroups for one thread per item of the per-primitive kernels.
pub fn groups_for(items: usize) -> u32 {
    (items as u32).div_ceil(THREADS)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default team: 8 for hydrogen's 4,096 primitives and fewer, one
    /// thread a primitive at 32,000 and 200,000 (the rows the H200 timed),
    /// a power of two between, and the reduction's threads never more than
    /// `REDUCE_THREADS` once a primitive has a thread of its own.
    #[test]
    fn the_default_team_follows_the_primitive_count() {
        for (n, want) in [(0, 8), (1, 8), (4096, 8), (4097, 4), (6000, 4), (10_000, 2), (16_384, 2), (16_385, 1), (32_000, 1), (200_000, 1)] {
            assert_eq!(reduce_team_for(n), want, "{n} primitives");
        }
        for n in 1..70_000 {
            let t = reduce_team_for(n);
            assert!(t.is_power_of_two() && (1..=REDUCE_TEAM).contains(&t), "{n}: team {t}");
            assert!(t == 1 || n * t as usize <= REDUCE_THREADS, "{n}: team {t} makes {} threads", n * t as usize);
        }
    }

    /// The brick level's chunks: at least `BRICK_GROUPS` workgroups while
    /// the cells are few (hydrogen 64³: one cell, the most chunks),
    /// about `ROW_CHUNK` entries a workgroup where the lists are long (RM
    /// 256³ at 200,000 primitives: 64 cells, about 1.1 million entries),
    /// one chunk a cell where the cells alone are enough, never none.
    #[test]
    fn the_brick_levels_chunks_follow_the_lists() {
        for ((entries, cells), want) in [((5_000, 1), 256), ((0, 0), 256), ((1_100_000, 64), 34), ((65_536, 8), 64), ((200_000, 4_096), 1), ((0, 100_000), 1)] {
            assert_eq!(brick_chunks_for(entries, cells), want, "{entries} entries in {cells} cells");
        }
        for cells in [1, 3, 64, 700] {
            for entries in (0..3_000_000).step_by(99_991) {
                let k = brick_chunks_for(entries, cells) as usize;
                assert!((1..=MAX_BRICK_CHUNKS).contains(&k), "{entries} entries in {cells} cells: {k}");
                assert!(k == MAX_BRICK_CHUNKS || k * cells >= BRICK_GROUPS, "{entries} entries in {cells} cells: {k} chunks");
                assert!(k == MAX_BRICK_CHUNKS || entries.div_ceil(k * cells) <= ROW_CHUNK, "{entries} entries in {cells} cells: {k} chunks");
            }
        }
        // The coarse level from bit rows: chunks of at most `ROW_CHUNK`
        // primitives, up to `MAX_CELL_CHUNKS`.
        for (n, want) in [(0, 1), (1, 1), (512, 1), (513, 2), (4096, 8), (200_000, 391), (10_000_000, 4096)] {
            assert_eq!(cell_chunks_for(n), want, "{n} primitives");
        }
    }
}
