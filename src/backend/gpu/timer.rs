//! Device time per kernel, from timestamp queries written at the start and
//! end of every compute pass, where the adapter has them (`TIMESTAMP_QUERY`).
//! Totals per kernel over the backend's life; read with the call's results,
//! so timing adds no wait of its own. Each call that may be in flight at
//! once has its own query set. Beside it, [`Totals`], which also sums the
//! host's time in each phase of a call.

use super::device::Gpu;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// Passes timed per submission (two queries each).
const MAX_PASSES: u32 = 64;

/// One submission's queries: a call in flight keeps its own, so that the
/// next call's timestamps never overwrite what is still to be read.
struct Slot {
    set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    /// Labels of the submission's timed passes, in order.
    labels: Vec<&'static str>,
}

pub struct Timer {
    /// Empty when the device was opened without timestamp queries.
    slots: Vec<Slot>,
    /// The slot the passes being recorded write to.
    current: usize,
    period_ns: f64,
    /// Per kernel: passes timed and seconds.
    totals: Totals,
}

impl Timer {
    /// A timer with `slots` submissions in flight at once, inert when the
    /// device was opened without timestamp queries.
    pub fn new(gpu: &Gpu, slots: usize) -> Timer {
        let on = gpu.device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let slots = (0..if on { slots } else { 0 })
            .map(|_| Slot {
                set: gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                    label: Some("gsenc timestamps"),
                    ty: wgpu::QueryType::Timestamp,
                    count: 2 * MAX_PASSES,
                }),
                resolve: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("gsenc timestamps"),
                    size: 16 * MAX_PASSES as u64,
                    usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                }),
                labels: vec![],
            })
            .collect();
        Timer { slots, current: 0, period_ns: gpu.queue.get_timestamp_period() as f64, totals: Totals::default() }
    }

    /// The passes recorded next belong to a submission read back through
    /// slot `slot` (forgetting what that slot held).
    pub fn begin(&mut self, slot: usize) {
        self.current = slot;
        if let Some(s) = self.slots.get_mut(slot) {
            s.labels.clear();
        }
    }

    /// The timestamp writes of the next pass, labelled `label`, while this
    /// submission has queries left.
    pub fn writes(&mut self, label: &'static str) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        let s = self.slots.get_mut(self.current)?;
        let i = s.labels.len() as u32;
        if i >= MAX_PASSES {
            return None;
        }
        s.labels.push(label);
        Some(wgpu::ComputePassTimestampWrites { query_set: &s.set, beginning_of_pass_write_index: Some(2 * i), end_of_pass_write_index: Some(2 * i + 1) })
    }

    /// Resolves this submission's queries; returns the buffer and the bytes
    /// to read back with the results (none when nothing was timed).
    pub fn resolve(&self, enc: &mut wgpu::CommandEncoder) -> Option<(&wgpu::Buffer, u64)> {
        let s = self.slots.get(self.current)?;
        let n = s.labels.len() as u32;
        if n == 0 {
            return None;
        }
        enc.resolve_query_set(&s.set, 0..2 * n, &s.resolve, 0);
        Some((&s.resolve, 16 * n as u64))
    }

    /// Adds the timestamps read back through slot `slot` to the totals.
    pub fn record(&mut self, slot: usize, bytes: &[u8]) {
        let Some(s) = self.slots.get_mut(slot) else { return };
        let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(bytes);
        for (label, pair) in s.labels.iter().zip(ticks.chunks_exact(2)) {
            self.totals.add_seconds(label, pair[1].saturating_sub(pair[0]) as f64 * self.period_ns * 1e-9);
        }
        s.labels.clear();
    }

    /// Drops slot `slot`'s labels (nothing of it is read back).
    pub fn discard(&mut self, slot: usize) {
        if let Some(s) = self.slots.get_mut(slot) {
            s.labels.clear();
        }
    }

    /// Per kernel: passes timed and device seconds, since the backend opened.
    pub fn totals(&self) -> Vec<(String, u64, f64)> {
        self.totals.totals()
    }
}

/// Counts and seconds per label, summed over the backend's life: the
/// device's per kernel ([`Timer`]) and the host's per phase of a call
/// (`GpuBackend::host`).
#[derive(Default)]
pub struct Totals {
    totals: BTreeMap<&'static str, (u64, f64)>,
}

impl Totals {
    /// Adds one run of `label` that took `seconds`.
    pub fn add_seconds(&mut self, label: &'static str, seconds: f64) {
        let t = self.totals.entry(label).or_default();
        t.0 += 1;
        t.1 += seconds;
    }

    /// Adds one run of `label` that took `d`.
    pub fn add(&mut self, label: &'static str, d: Duration) {
        self.add_seconds(label, d.as_secs_f64());
    }

    /// Adds the time since `start` to `label` and returns now.
    pub fn lap(&mut self, label: &'static str, start: Instant) -> Instant {
        let now = Instant::now();
        self.add(label, now - start);
        now
    }

    /// Per label: runs and seconds.
    pub fn totals(&self) -> Vec<(String, u64, f64)> {
        self.totals.iter().map(|(k, &(n, s))| (k.to_string(), n, s)).collect()
    }
}
