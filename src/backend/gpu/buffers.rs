//! Device buffers that grow with the work and are kept between calls, and
//! the read-back of results.
//!
//! With `garbage` set (the tests set it) every buffer is filled with 0xFF
//! bytes before each call: NaN as a float, `u32::MAX` as an index. wgpu
//! zeroes new buffers, so a kernel that reads what no pass wrote would pass
//! unnoticed without it.

use super::device::Gpu;
use super::points::SLOTS;
use super::staged::Staged;
use crate::error::{Error, Result};

/// The size of a buffer that replaces one of `have` bytes (if any) to hold
/// `bytes`: grown by half again, in whole 16 bytes, within the adapter's
/// largest buffer, or an error naming `label` when `bytes` exceed it.
pub(super) fn grown(gpu: &Gpu, label: &str, have: Option<u64>, bytes: u64) -> Result<u64> {
    let bytes = bytes.max(16).next_multiple_of(16);
    let limit = gpu.limits.max_storage_buffer_binding_size.min(gpu.limits.max_buffer_size);
    if bytes > limit {
        return Err(Error::Device(format!(
            "'{label}' needs {:.1} MiB in one buffer, '{}' allows {:.1} MiB: use fewer primitives or points per call, or the CPU backend",
            bytes as f64 / (1 << 20) as f64,
            gpu.adapter.name,
            limit as f64 / (1 << 20) as f64
        )));
    }
    let grown = have.map_or(0, |h| h + h / 2);
    Ok(bytes.max(grown).min(limit).next_multiple_of(16).min(limit))
}

/// A storage buffer kept at least as large as the largest request so far.
pub struct Slot {
    label: &'static str,
    usage: wgpu::BufferUsages,
    buf: Option<wgpu::Buffer>,
    /// Buffers this slot has made.
    made: u64,
}

impl Slot {
    pub fn storage(label: &'static str) -> Slot {
        Slot::with_usage(label, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC)
    }

    /// A uniform buffer, rewritten call after call (`Slot::upload`).
    pub fn uniform(label: &'static str) -> Slot {
        Slot::with_usage(label, wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST)
    }

    fn with_usage(label: &'static str, usage: wgpu::BufferUsages) -> Slot {
        Slot { label, usage, buf: None, made: 0 }
    }

    /// The buffer, grown (by half again) to hold `bytes`, and filled with
    /// garbage when `garbage` is set.
    pub fn ensure(&mut self, gpu: &Gpu, bytes: u64, garbage: bool) -> Result<&wgpu::Buffer> {
        let bytes = bytes.max(16).next_multiple_of(16);
        if self.buf.as_ref().is_none_or(|b| b.size() < bytes) {
            let size = grown(gpu, self.label, self.buf.as_ref().map(|b| b.size()), bytes)?;
            self.made += 1;
            self.buf = Some(gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(self.label),
                size,
                usage: self.usage,
                mapped_at_creation: false,
            }));
        }
        let buf = self.buf.as_ref().expect("created above");
        if garbage {
            gpu.queue.write_buffer(buf, 0, &vec![0xFF; buf.size() as usize]);
        }
        Ok(buf)
    }

    /// [`Slot::ensure`], then `data` written at its start.
    pub fn upload(&mut self, gpu: &Gpu, data: &[u8], garbage: bool) -> Result<&wgpu::Buffer> {
        let buf = self.ensure(gpu, data.len() as u64, garbage)?;
        if !data.is_empty() {
            gpu.write(buf, data);
        }
        Ok(buf)
    }
}

/// Regions of device buffers copied into one mappable buffer at the end of
/// a command encoder, read after that submission finishes (and only it:
/// a later submission may still run).
pub struct Readback {
    staging: Slot,
    parts: Vec<(u64, u64)>,
    submission: Option<wgpu::SubmissionIndex>,
    /// How long the last `read` waited for the device and the map.
    pub waited: std::time::Duration,
}

impl Default for Readback {
    fn default() -> Self {
        Readback {
            staging: Slot::with_usage("gsenc readback", wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST),
            parts: vec![],
            submission: None,
            waited: std::time::Duration::ZERO,
        }
    }
}

impl Readback {
    /// Records copies of `(buffer, bytes)` regions (each from offset 0) into
    /// the staging buffer.
    pub fn record(&mut self, gpu: &Gpu, enc: &mut wgpu::CommandEncoder, regions: &[(&wgpu::Buffer, u64)]) -> Result<()> {
        let total: u64 = regions.iter().map(|&(_, n)| n.next_multiple_of(8)).sum();
        let staging = self.staging.ensure(gpu, total, false)?;
        self.parts.clear();
        let mut at = 0;
        for &(buf, n) in regions {
            if n > 0 {
                enc.copy_buffer_to_buffer(buf, 0, staging, at, n);
            }
            self.parts.push((at, n));
            at += n.next_multiple_of(8);
        }
        Ok(())
    }

    /// Submits `enc`, whose end `record` wrote.
    pub fn submit(&mut self, gpu: &Gpu, enc: wgpu::CommandEncoder) {
        self.submitted(gpu.queue.submit([enc.finish()]));
    }

    /// The recorded copies were submitted as `index` (with other calls'
    /// commands, perhaps): `read` waits for it.
    pub fn submitted(&mut self, index: wgpu::SubmissionIndex) {
        self.submission = Some(index);
    }

    /// Waits for the submission and returns the recorded regions' bytes.
    pub fn read(&mut self, gpu: &Gpu) -> Result<Vec<Vec<u8>>> {
        self.read_with(gpu, |parts| parts.iter().map(|p| p.to_vec()).collect())
    }

    /// Waits for the submission and hands the recorded regions, as mapped,
    /// to `take` (which copies what it keeps: the decode's slab goes
    /// straight into the caller's array).
    pub fn read_with<T>(&mut self, gpu: &Gpu, take: impl FnOnce(&[&[u8]]) -> T) -> Result<T> {
        let end = self.parts.iter().map(|&(at, n)| at + n).max().unwrap_or(0).max(8).next_multiple_of(8);
        let staging = self.staging.buf.as_ref().expect("recorded before read");
        let slice = staging.slice(0..end);
        let done = std::sync::Arc::new(parking_lot::Mutex::new(None));
        let d = done.clone();
        slice.map_async(wgpu::MapMode::Read, move |r| *d.lock() = Some(r));
        let waiting = std::time::Instant::now();
        let waited = gpu.wait_for(self.submission.take(), || done.lock().is_some());
        self.waited = waiting.elapsed();
        waited?;
        match done.lock().take() {
            Some(Ok(())) => {}
            Some(Err(e)) => return Err(Error::Device(format!("reading results back: {e}"))),
            None => return Err(Error::Device("reading results back: the map never completed".into())),
        }
        let out = {
            let view = slice.get_mapped_range().map_err(|e| Error::Device(format!("reading results back: {e}")))?;
            let parts: Vec<&[u8]> = self.parts.iter().map(|&(at, n)| &view[at as usize..(at + n) as usize]).collect();
            take(&parts)
        };
        staging.unmap();
        Ok(out)
    }
}

/// Every device buffer the backend keeps between calls.
pub(super) struct Buffers {
    pub(super) params: Slot,
    pub(super) hot: Slot,
    pub(super) ranges: Slot,
    pub(super) identity: Slot,
    pub(super) identity_bounds: Slot,
    pub(super) counts: Slot,
    pub(super) starts: Slot,
    pub(super) lists: Slot,
    pub(super) brick_points: Slot,
    /// The forward pass's pieces of bricks (points.rs `Upload::pieces`).
    pub(super) pieces: Slot,
    pub(super) points: Slot,
    pub(super) occupied: Slot,
    pub(super) rho_n: Slot,
    pub(super) terms: Slot,
    pub(super) partial: Slot,
    pub(super) grad: Slot,
    /// Resident training: Adam's moments, the regularisers' values.
    pub(super) moments: Slot,
    pub(super) reg_terms: Slot,
    pub(super) loss: Slot,
    /// The first level of binning: the coarse cells' boxes (training; the
    /// decode binds it as bin.wgsl's `cells`, which its slab stages never
    /// read).
    pub(super) coarse_cells: Slot,
    pub(super) coarse_counts: Slot,
    pub(super) coarse_starts: Slot,
    pub(super) coarse_lists: Slot,
    /// Training's levels from bit rows: per (child, chunk of its parent's
    /// list) the chunk's entries, then their place (bin_rows.wgsl).
    pub(super) chunk_counts: Slot,
    /// The dense map of the coarse grid and the root block's box, where
    /// the coarse cells are made from bit rows (points.rs `Coarse`).
    pub(super) coarse_map: Slot,
    pub(super) root: Slot,
    pub(super) slab: Slot,
    /// Resident training: set by a step whose lists overflowed, so that
    /// the steps queued after it change nothing either (points.rs).
    pub(super) poison: Slot,
    /// One per call that may be in flight at once (`points::SLOTS`);
    /// a call made while nothing is in flight uses the first.
    pub(super) readback: [Readback; SLOTS],
    /// A point call's two uniform blocks (its own and its coarse level's),
    /// one pair per read-back slot: rewritten call after call, so that the
    /// call binds the same buffers as the one before and its bind groups
    /// are kept (`kernels::BindGroups`).
    pub(super) uniforms: [[Slot; 2]; SLOTS],
    /// A point call's uploads, one per read-back slot: never bound, so not
    /// counted by `made`.
    pub(super) staged: [Staged; SLOTS],
}

impl Buffers {
    /// Buffers made so far by every slot: a bind group made before names
    /// only buffers made before it (`kernels::BindGroups`).
    pub(super) fn made(&self) -> u64 {
        let slots = [
            &self.params, &self.hot, &self.ranges, &self.identity, &self.identity_bounds, &self.counts, &self.starts,
            &self.lists, &self.brick_points, &self.pieces, &self.points, &self.occupied, &self.rho_n, &self.terms, &self.partial,
            &self.grad, &self.moments, &self.reg_terms, &self.loss, &self.coarse_cells, &self.coarse_counts, &self.coarse_starts,
            &self.coarse_lists, &self.chunk_counts, &self.coarse_map, &self.root, &self.slab, &self.poison,
        ];
        slots.into_iter().chain(self.uniforms.iter().flatten()).map(|s| s.made).sum()
    }
}

impl Default for Buffers {
    fn default() -> Self {
        Buffers {
            params: Slot::storage("params"),
            hot: Slot::storage("hot"),
            ranges: Slot::storage("ranges"),
            identity: Slot::storage("identity"),
            identity_bounds: Slot::storage("identity bounds"),
            counts: Slot::storage("counts"),
            starts: Slot::storage("starts"),
            lists: Slot::storage("candidate lists"),
            brick_points: Slot::storage("brick points"),
            pieces: Slot::storage("forward pieces"),
            points: Slot::storage("points"),
            occupied: Slot::storage("occupied"),
            rho_n: Slot::storage("rho n"),
            terms: Slot::storage("terms"),
            partial: Slot::storage("partial sums"),
            grad: Slot::storage("gradient"),
            moments: Slot::storage("moments"),
            reg_terms: Slot::storage("regulariser terms"),
            loss: Slot::storage("loss"),
            coarse_cells: Slot::storage("coarse cells"),
            coarse_counts: Slot::storage("coarse counts"),
            coarse_starts: Slot::storage("coarse starts"),
            coarse_lists: Slot::storage("coarse lists"),
            chunk_counts: Slot::storage("chunk counts"),
            coarse_map: Slot::storage("coarse cell map"),
            root: Slot::storage("root block"),
            slab: Slot::storage("slab values"),
            poison: Slot::storage("poison"),
            readback: Default::default(),
            uniforms: std::array::from_fn(|_| [Slot::uniform("params"), Slot::uniform("coarse params")]),
            staged: Default::default(),
        }
    }
}
