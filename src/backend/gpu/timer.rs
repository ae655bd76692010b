//! Device time per kernel, from timestamp queries written at the start and
//! end of every compute pass, where the adapter has them (`TIMESTAMP_QUERY`).
//! Totals per kernel over the backend's life; read with the call's results,
//! so timing adds no wait of its own.

use super::device::Gpu;
use std::collections::BTreeMap;

/// Passes timed per submission (two queries each).
const MAX_PASSES: u32 = 64;

pub struct Timer {
    set: Option<wgpu::QuerySet>,
    resolve: Option<wgpu::Buffer>,
    /// Labels of this submission's timed passes, in order.
    labels: Vec<&'static str>,
    period_ns: f64,
    /// Per kernel: passes timed and seconds.
    totals: BTreeMap<&'static str, (u64, f64)>,
}

impl Timer {
    /// A timer, inert when the device was opened without timestamp queries.
    pub fn new(gpu: &Gpu) -> Timer {
        let on = gpu.device.features().contains(wgpu::Features::TIMESTAMP_QUERY);
        let set = on.then(|| {
            gpu.device.create_query_set(&wgpu::QuerySetDescriptor { label: Some("gsenc timestamps"), ty: wgpu::QueryType::Timestamp, count: 2 * MAX_PASSES })
        });
        let resolve = on.then(|| {
            gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("gsenc timestamps"),
                size: 16 * MAX_PASSES as u64,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        });
        Timer { set, resolve, labels: vec![], period_ns: gpu.queue.get_timestamp_period() as f64, totals: BTreeMap::new() }
    }

    /// The timestamp writes of the next pass, labelled `label`, while this
    /// submission has queries left.
    pub fn writes(&mut self, label: &'static str) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        let set = self.set.as_ref()?;
        let i = self.labels.len() as u32;
        if i >= MAX_PASSES {
            return None;
        }
        self.labels.push(label);
        Some(wgpu::ComputePassTimestampWrites { query_set: set, beginning_of_pass_write_index: Some(2 * i), end_of_pass_write_index: Some(2 * i + 1) })
    }

    /// Resolves this submission's queries; returns the buffer and the bytes
    /// to read back with the results (none when nothing was timed).
    pub fn resolve(&self, enc: &mut wgpu::CommandEncoder) -> Option<(&wgpu::Buffer, u64)> {
        let (set, buf) = (self.set.as_ref()?, self.resolve.as_ref()?);
        let n = self.labels.len() as u32;
        if n == 0 {
            return None;
        }
        enc.resolve_query_set(set, 0..2 * n, buf, 0);
        Some((buf, 16 * n as u64))
    }

    /// Adds the read-back timestamps to the totals and starts the next submission.
    pub fn record(&mut self, bytes: &[u8]) {
        let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(bytes);
        for (label, pair) in self.labels.iter().zip(ticks.chunks_exact(2)) {
            let t = self.totals.entry(label).or_default();
            t.0 += 1;
            t.1 += pair[1].saturating_sub(pair[0]) as f64 * self.period_ns * 1e-9;
        }
        self.labels.clear();
    }

    /// Drops this submission's labels (nothing was read back).
    pub fn discard(&mut self) {
        self.labels.clear();
    }

    /// Per kernel: passes timed and device seconds, since the backend opened.
    pub fn totals(&self) -> Vec<(String, u64, f64)> {
        self.totals.iter().map(|(k, &(n, s))| (k.to_string(), n, s)).collect()
    }
}
