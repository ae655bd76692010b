//! The staging of a point call's uploads: its points, bricks and uniform
//! blocks written into one mapped buffer, and copied from there to their
//! device buffers at the start of the call's command buffer.

use super::buffers::grown;
use super::device::Gpu;
use crate::error::{Error, Result};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// What a call writes before its passes (its points, bricks and uniform
/// blocks): written into a mapped staging buffer of its own, which copies
/// at the start of the call's command buffer carry to each destination.
///
/// Each `Queue::write_buffer` takes staging memory of its own (on native
/// backends a new buffer, made and destroyed by the driver), so a step
/// that wrote its nine buffers made nine. This buffer is made once
/// and mapped again after each submission (wgpu maps it once the device
/// is done with it, which reading the call's results back waits for), so
/// a steady step makes none. The copies run on the device before the
/// call's first pass, where queue writes ran just before it, so a call
/// reads the same bytes either way.
#[derive(Default)]
pub struct Staged {
    buf: Option<wgpu::Buffer>,
    /// Set by the map callback: `buf` is mapped and may be written.
    mapped: Arc<AtomicBool>,
    /// `buf` was written and unmapped for this call: map it again once
    /// the call is submitted (`Staged::remap`).
    to_remap: bool,
    made: u64,
}

impl Staged {
    /// Buffers it has made.
    pub fn made(&self) -> u64 {
        self.made
    }

    /// Writes each `(bytes, destination)` region (lengths in whole 4-byte
    /// words; the destination at least that large) and records, into
    /// `enc`, its copy to the destination's start; or, `per_buffer`, hands
    /// each region to the queue for its destination, one write each. Empty
    /// regions are skipped. `remap` must follow the submission of `enc`.
    pub fn record(&mut self, gpu: &Gpu, enc: &mut wgpu::CommandEncoder, regions: &[(&[u8], &wgpu::Buffer)], per_buffer: bool) -> Result<()> {
        self.to_remap = false;
        if let Some((data, _)) = regions.iter().find(|(d, _)| !(d.len() as u64).is_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT)) {
            return Err(Error::arg(format!("GPU backend: an upload of {} bytes, not whole words", data.len())));
        }
        if per_buffer {
            for &(data, dst) in regions.iter().filter(|(d, _)| !d.is_empty()) {
                gpu.write(dst, data);
            }
            return Ok(());
        }
        let total: u64 = regions.iter().map(|(d, _)| d.len() as u64).sum();
        if total == 0 {
            return Ok(());
        }
        // A buffer too small, or not mapped again yet (its call failed, or
        // the map is late), is replaced by one mapped at creation.
        let ready = self.buf.as_ref().is_some_and(|b| b.size() >= total) && self.mapped.load(Ordering::Acquire);
        if !ready {
            let size = grown(gpu, "staged uploads", self.buf.as_ref().map(|b| b.size()), total)?;
            self.made += 1;
            self.mapped = Arc::new(AtomicBool::new(true));
            self.buf = Some(gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("staged uploads"),
                size,
                usage: wgpu::BufferUsages::MAP_WRITE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: true,
            }));
        }
        let buf = self.buf.as_ref().expect("made above");
        self.mapped.store(false, Ordering::Release);
        {
            let mut view = buf.slice(0..total).get_mapped_range_mut().map_err(|e| Error::Device(format!("staging uploads: {e}")))?;
            let mut at = 0;
            for &(data, _) in regions {
                view.slice(at..at + data.len()).copy_from_slice(data);
                at += data.len();
            }
        }
        buf.unmap();
        self.to_remap = true;
        gpu.uploaded();
        let mut at = 0;
        for &(data, dst) in regions.iter().filter(|(d, _)| !d.is_empty()) {
            enc.copy_buffer_to_buffer(buf, at, dst, 0, data.len() as u64);
            at += data.len() as u64;
        }
        Ok(())
    }

    /// After the submission of the command buffer `record` wrote: asks for
    /// the buffer to be mapped again once the device is done with it.
    pub fn remap(&mut self) {
        if !std::mem::take(&mut self.to_remap) {
            return;
        }
        if let Some(buf) = &self.buf {
            let mapped = self.mapped.clone();
            buf.slice(..).map_async(wgpu::MapMode::Write, move |r| mapped.store(r.is_ok(), Ordering::Release));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::buffers::{Readback, Slot};
    use super::super::device::{adapters, DeviceRequest};
    use super::*;

    /// A device on the first adapter wgpu sees but the no-op one (lavapipe
    /// in CI; GSENC_REQUIRE_GPU=1 fails instead of skipping without one).
    fn gpu() -> Option<Gpu> {
        let Some(a) = adapters().into_iter().find(|a| a.name != "noop") else {
            assert_ne!(std::env::var("GSENC_REQUIRE_GPU").as_deref(), Ok("1"), "GSENC_REQUIRE_GPU=1 and wgpu sees no adapter");
            eprintln!("NOT RUN: wgpu sees no adapter");
            return None;
        };
        Some(Gpu::open(&DeviceRequest { index: None, name: Some(a.name) }).unwrap())
    }

    /// Staged uploads land in their destinations, over garbage, call after
    /// call: through the staging buffer mapped again after each submission
    /// (reused: no new buffer), through a new one when the last call was
    /// recorded and never submitted (its buffer left unmapped) or when a
    /// call outgrows it, and written buffer by buffer. Each round is read
    /// back and compared with the bytes it wrote.
    #[test]
    fn staged_uploads_land_whether_the_buffer_is_reused_or_replaced() {
        let Some(gpu) = gpu() else { return };
        let (mut a, mut b) = (Slot::storage("a"), Slot::storage("b"));
        let mut staged = Staged::default();
        let mut back = Readback::default();
        let words = |n: usize, seed: u32| -> Vec<u8> { (0..n as u32).flat_map(|i| (i.wrapping_mul(2_654_435_761) ^ seed).to_le_bytes()).collect() };
        let mut round = |staged: &mut Staged, x: &[u8], y: &[u8], per_buffer: bool, submit: bool| {
            let (da, db) = (a.ensure(&gpu, 4096, true).unwrap().clone(), b.ensure(&gpu, 4096, true).unwrap().clone());
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            staged.record(&gpu, &mut enc, &[(x, &da), (&[], &da), (y, &db)], per_buffer).unwrap();
            if !submit {
                return None;
            }
            back.record(&gpu, &mut enc, &[(&da, x.len() as u64), (&db, y.len() as u64)]).unwrap();
            back.submit(&gpu, enc);
            staged.remap();
            Some(back.read(&gpu).unwrap())
        };
        let check = |got: Option<Vec<Vec<u8>>>, x: &[u8], y: &[u8], what: &str| {
            let got = got.expect("submitted");
            assert!(got[0] == x && got[1] == y, "{what}: the destinations do not hold what was staged");
        };
        let (x, y) = (words(300, 1), words(17, 2));
        check(round(&mut staged, &x, &y, false, true), &x, &y, "the first call");
        assert_eq!(staged.made(), 1);
        let (x, y) = (words(250, 3), words(40, 4));
        check(round(&mut staged, &x, &y, false, true), &x, &y, "mapped again");
        assert_eq!(staged.made(), 1, "the staging buffer was not reused");
        round(&mut staged, &words(10, 5), &words(10, 6), false, false);
        let (x, y) = (words(200, 7), words(30, 8));
        check(round(&mut staged, &x, &y, false, true), &x, &y, "after a call never submitted");
        assert_eq!(staged.made(), 2, "a buffer left unmapped was reused");
        let (x, y) = (words(900, 9), words(100, 10));
        check(round(&mut staged, &x, &y, false, true), &x, &y, "grown");
        assert_eq!(staged.made(), 3);
        let uploads = gpu.uploads();
        let (x, y) = (words(64, 11), words(8, 12));
        check(round(&mut staged, &x, &y, true, true), &x, &y, "buffer by buffer");
        assert_eq!((staged.made(), gpu.uploads() - uploads), (3, 2));
        // A region not in whole words (copies move 4 bytes at a time) is
        // refused, either way, before anything is written or recorded.
        let dst = a.ensure(&gpu, 4096, false).unwrap().clone();
        for per_buffer in [false, true] {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            let e = staged.record(&gpu, &mut enc, &[(&words(4, 13), &dst), (&[1, 2, 3, 4, 5, 6], &dst)], per_buffer).unwrap_err();
            assert!(e.to_string().contains("6 bytes, not whole words"), "{e}");
            assert_eq!((staged.made(), gpu.uploads() - uploads), (3, 2), "per_buffer {per_buffer}: something was written");
        }
    }
}
