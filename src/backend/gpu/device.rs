//! The adapters wgpu sees, the choice among them, and one opened device with
//! its errors turned into [`Error::Device`] instead of panics.
//!
//! Rules (docs/DESIGN.md "GPU backend"): hardware adapters (discrete,
//! integrated, virtual GPUs) are numbered in the order wgpu lists them and
//! chosen by index; a software adapter (Mesa's llvmpipe) is never chosen by
//! index or by `auto`, only by name (`GSENC_ADAPTER=llvmpipe`), which is how
//! the tests run the GPU code on a machine without a GPU.

pub use crate::backend::select::AdapterSummary;
use crate::error::{Error, Result};
use parking_lot::Mutex;
use std::mem::ManuallyDrop;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};

/// Which adapter to open.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DeviceRequest {
    /// Index among the hardware adapters (default 0).
    pub index: Option<usize>,
    /// A part of the adapter's name (case-insensitive); any adapter with it,
    /// software ones included (`GSENC_ADAPTER`, read by `backend::select`).
    pub name: Option<String>,
}

/// The process's one wgpu instance, made on first use and kept for the
/// process's life: every enumeration and every device goes through it.
/// NVIDIA's Vulkan driver (580, on the H200) stops listing its GPU in a
/// process that has made 30 instances, however many it dropped, so a
/// simulation that opened an encoder per output step lost its GPU after 15
/// (docs/BENCHMARKS.md "A lent H200, 2026-12-04"). Refused in a process
/// forked from the one that made it ([`in_process`]).
fn instance() -> Result<&'static wgpu::Instance> {
    static INSTANCE: OnceLock<(u32, wgpu::Instance)> = OnceLock::new();
    let (made_in, instance) = INSTANCE.get_or_init(|| (std::process::id(), new_instance()));
    in_process(*made_in)?;
    Ok(instance)
}

/// An error in a process other than `made_in`, which connected to the
/// GPUs: one forked from it since. A driver's connection does not follow a
/// fork (the child has none of the driver's threads; a decode on lavapipe
/// there waited for ever), so the child neither uses its parent's devices
/// nor makes its own through its parent's instance. `auto` then runs on
/// the CPU.
fn in_process(made_in: u32) -> Result<()> {
    let here = std::process::id();
    if here == made_in {
        return Ok(());
    }
    Err(Error::Device(format!(
        "this process ({here}) was forked from process {made_in} after that one had connected to the GPUs, \
         and a GPU connection does not follow a fork: use the CPU backend here, or start this process \
         without forking (Python: multiprocessing's 'spawn')"
    )))
}

/// A new wgpu instance (only `instance` makes one).
fn new_instance() -> wgpu::Instance {
    INSTANCES_MADE.fetch_add(1, Ordering::Relaxed);
    #[allow(unused_mut)]
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    #[cfg(feature = "gpu-noop")]
    {
        desc.backends |= wgpu::Backends::NOOP;
        // Limits of a large GPU (wgpu's "maximally permissive" default
        // overflows its own validation).
        let mut noop = wgpu::NoopBackendOptions::enabled();
        noop.limits = Some(wgpu::Limits {
            max_storage_buffers_per_shader_stage: 16,
            max_storage_buffer_binding_size: (1 << 31) - 4,
            max_buffer_size: 1 << 34,
            max_compute_workgroup_storage_size: 1 << 15,
            max_compute_invocations_per_workgroup: 1024,
            max_compute_workgroup_size_x: 1024,
            ..wgpu::Limits::default()
        });
        desc.backend_options.noop = noop;
    }
    wgpu::Instance::new(desc)
}

/// The backends enumerated: wgpu's no-op device too in a build with the
/// `gpu-noop` feature (a software adapter, chosen only by its name).
fn backends() -> wgpu::Backends {
    let all = wgpu::Backends::VULKAN | wgpu::Backends::METAL | wgpu::Backends::DX12;
    #[cfg(feature = "gpu-noop")]
    let all = all | wgpu::Backends::NOOP;
    all
}

static INSTANCES_MADE: AtomicUsize = AtomicUsize::new(0);

/// How many wgpu instances this process has made: one at most, after the
/// first enumeration or device.
pub fn instances_made() -> usize {
    INSTANCES_MADE.load(Ordering::Relaxed)
}

fn is_software(info: &wgpu::AdapterInfo) -> bool {
    matches!(info.device_type, wgpu::DeviceType::Cpu)
}

/// Every compute-capable adapter, hardware ones first numbered in wgpu's order.
fn enumerate() -> Result<Vec<(AdapterSummary, wgpu::Adapter)>> {
    let all = pollster::block_on(instance()?.enumerate_adapters(backends()));
    let mut next = 0;
    Ok(all
        .into_iter()
        .map(|a| {
            let info = a.get_info();
            let index = (!is_software(&info)).then(|| {
                next += 1;
                next - 1
            });
            let s = AdapterSummary {
                index,
                name: info.name.clone(),
                api: format!("{:?}", info.backend),
                device_type: format!("{:?}", info.device_type),
                driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
            };
            (s, a)
        })
        .collect())
}

/// The adapters wgpu sees on this machine (none in a process that cannot
/// use them, forked from one that did: `in_process`).
pub fn adapters() -> Vec<AdapterSummary> {
    enumerate().map_or_else(|_| vec![], |all| all.into_iter().map(|(s, _)| s).collect())
}

fn choose(req: &DeviceRequest) -> Result<(AdapterSummary, wgpu::Adapter)> {
    let all = enumerate()?;
    let seen = if all.is_empty() {
        "wgpu sees no adapter (no Vulkan, Metal or DX12 driver)".to_string()
    } else {
        let names: Vec<String> = all.iter().map(|(s, _)| format!("'{}' ({})", s.name, s.device_type)).collect();
        format!("adapters seen: {}", names.join(", "))
    };
    if let Some(name) = &req.name {
        let want = name.to_lowercase();
        return all
            .into_iter()
            .find(|(s, _)| s.name.to_lowercase().contains(&want))
            .ok_or_else(|| Error::Device(format!("no adapter named like '{name}' (GSENC_ADAPTER); {}", seen)));
    }
    let index = req.index.unwrap_or(0);
    let hardware = all.iter().filter(|(s, _)| !s.software()).count();
    if hardware == 0 {
        return Err(Error::Device(format!(
            "no hardware GPU; {}. A software adapter runs only when named: GSENC_ADAPTER=llvmpipe",
            seen
        )));
    }
    if index >= hardware {
        return Err(Error::Device(format!("GPU index {index} asked, this machine has {hardware} ({})", seen)));
    }
    Ok(all.into_iter().find(|(s, _)| s.index == Some(index)).expect("index checked above"))
}

/// An opened device, its queue, and what it reported.
pub struct Gpu {
    /// Dropped with the `Gpu`, except in a forked process (see `Drop`).
    pub device: ManuallyDrop<wgpu::Device>,
    pub queue: ManuallyDrop<wgpu::Queue>,
    pub adapter: AdapterSummary,
    pub limits: wgpu::Limits,
    /// Set by wgpu when the device is lost, or by an error no scope caught.
    failure: Arc<Mutex<Option<String>>>,
    /// Wait for results by polling and sleeping instead of blocking in the
    /// driver (`GSENC_GPU_WAIT=sleep`; see [`Gpu::wait_for`]).
    sleepy_wait: bool,
    /// Uploads so far (`Gpu::uploaded`): writes to the queue, each with
    /// staging memory of its own, and fills of a mapped staging buffer;
    /// garbage fills not counted.
    uploads: std::sync::atomic::AtomicU64,
    /// The process that opened it ([`Gpu::in_its_process`]).
    process: u32,
}

/// The most storage buffers one kernel binds (reduce.wgsl `step`, the
/// reduction fused with the Adam step). WebGPU's default is 8; Vulkan,
/// Metal and DX12 GPUs offer more, and an adapter that does not is refused
/// when it is opened.
pub const STORAGE_BUFFERS: u32 = 10;

/// An error unless an adapter with `limits` can run every kernel.
fn enough_bindings(name: &str, limits: &wgpu::Limits) -> Result<()> {
    let have = limits.max_storage_buffers_per_shader_stage;
    if have < STORAGE_BUFFERS {
        return Err(Error::Device(format!("'{name}' lets a kernel bind {have} storage buffers; gsenc's kernels bind up to {STORAGE_BUFFERS}")));
    }
    Ok(())
}

/// `GSENC_GPU_TIMING=0` opens the device without timestamp queries: no
/// per-kernel times (`kernel_seconds` stays empty), the same results.
fn timing_from_env() -> bool {
    std::env::var("GSENC_GPU_TIMING").map_or(true, |v| v.trim() != "0")
}

impl Drop for Gpu {
    /// Closes the device, but in a process forked since it was opened:
    /// there closing it waits for the driver's threads, which are the
    /// parent's (on lavapipe, for ever), so the device is left as it is.
    fn drop(&mut self) {
        if self.in_its_process().is_ok() {
            // SAFETY: dropped once, here, and never used again.
            unsafe {
                ManuallyDrop::drop(&mut self.queue);
                ManuallyDrop::drop(&mut self.device);
            }
        }
    }
}

impl Gpu {
    /// Counts one upload ([`Gpu::uploads`]).
    pub fn uploaded(&self) {
        self.uploads.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }

    /// Hands `data` to the queue for the start of `buf`, counted as an upload.
    pub fn write(&self, buf: &wgpu::Buffer, data: &[u8]) {
        self.queue.write_buffer(buf, 0, data);
        self.uploaded();
    }

    /// Uploads so far: a steady training step makes one (staged.rs
    /// `Staged`), or one a buffer with `GSENC_GPU_UPLOAD=writes`.
    pub fn uploads(&self) -> u64 {
        self.uploads.load(std::sync::atomic::Ordering::Relaxed)
    }

    pub fn open(req: &DeviceRequest) -> Result<Gpu> {
        let (adapter_summary, adapter) = choose(req)?;
        // Everything the adapter offers: storage bindings of more than the
        // default 128 MiB, 32 KiB of workgroup memory where there is.
        let limits = adapter.limits();
        Gpu::open_with(adapter_summary, adapter, limits)
    }

    /// Opens `adapter` asking for `limits` (tests ask for less than it has).
    fn open_with(adapter_summary: AdapterSummary, adapter: wgpu::Adapter, limits: wgpu::Limits) -> Result<Gpu> {
        enough_bindings(&adapter_summary.name, &limits)?;
        let desc = wgpu::DeviceDescriptor {
            label: Some("gsenc"),
            // Per-kernel times (gpu/timer.rs) where the adapter has them,
            // unless GSENC_GPU_TIMING=0 (for measuring what they cost).
            required_features: if timing_from_env() { adapter.features() & wgpu::Features::TIMESTAMP_QUERY } else { wgpu::Features::empty() },
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::default(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc))
            .map_err(|e| Error::Device(format!("cannot open '{}': {e}", adapter_summary.name)))?;
        let failure = Arc::new(Mutex::new(None));
        let f = failure.clone();
        device.set_device_lost_callback(move |reason, msg| {
            f.lock().get_or_insert(format!("device lost ({reason:?}): {msg}"));
        });
        let f = failure.clone();
        device.on_uncaptured_error(Arc::new(move |e| {
            f.lock().get_or_insert(format!("{e}"));
        }));
        let sleepy_wait = std::env::var("GSENC_GPU_WAIT").is_ok_and(|v| v.trim() == "sleep");
        let (device, queue) = (ManuallyDrop::new(device), ManuallyDrop::new(queue));
        Ok(Gpu { device, queue, adapter: adapter_summary, limits, failure, sleepy_wait, uploads: Default::default(), process: std::process::id() })
    }

    /// An error in a process forked from the one that opened the device,
    /// where it cannot be used (`in_process`): every call of the GPU
    /// backend checks first.
    pub fn in_its_process(&self) -> Result<()> {
        in_process(self.process)
    }

    /// The first failure wgpu reported outside an error scope, if any: the
    /// device is then unusable. In a forked process, that one.
    pub fn check(&self) -> Result<()> {
        self.in_its_process()?;
        match self.failure.lock().as_ref() {
            Some(m) => Err(Error::Device(format!("'{}': {m}", self.adapter.name))),
            None => Ok(()),
        }
    }

    /// Runs `f` inside validation and out-of-memory error scopes and turns
    /// what they caught into an error.
    pub fn scoped<R>(&self, what: &str, f: impl FnOnce() -> Result<R>) -> Result<R> {
        self.check()?;
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = f();
        let v = pollster::block_on(validation.pop());
        let o = pollster::block_on(oom.pop());
        if let Some(e) = o {
            return Err(Error::Device(format!("{what}: out of device memory on '{}': {e}", self.adapter.name)));
        }
        if let Some(e) = v {
            return Err(Error::Device(format!("{what} on '{}': {e}", self.adapter.name)));
        }
        self.check()?;
        out
    }

    /// Waits until `done` says so, which a callback of the submission `index`
    /// sets when wgpu runs it. By default this blocks in the driver until
    /// the submission ends. With `GSENC_GPU_WAIT=sleep` the thread instead
    /// asks wgpu every 100 us and sleeps between asks: for measuring whether
    /// a driver that spins while it blocks takes a core from a solver beside
    /// the encoder (docs/BENCHMARKS.md "A lent GPU machine in one call").
    /// Either way, results and models are the same.
    pub fn wait_for(&self, index: Option<wgpu::SubmissionIndex>, done: impl Fn() -> bool) -> Result<()> {
        if !self.sleepy_wait {
            return self.wait(index);
        }
        loop {
            self.device
                .poll(wgpu::PollType::Poll)
                .map_err(|e| Error::Device(format!("waiting for '{}': {e}", self.adapter.name)))?;
            self.check()?;
            if done() {
                return Ok(());
            }
            std::thread::sleep(std::time::Duration::from_micros(100));
        }
    }

    /// Waits for the submission `index` (every submission so far when
    /// `None`); later submissions may still run.
    pub fn wait(&self, index: Option<wgpu::SubmissionIndex>) -> Result<()> {
        self.device
            .poll(wgpu::PollType::Wait { submission_index: index, timeout: None })
            .map_err(|e| Error::Device(format!("waiting for '{}': {e}", self.adapter.name)))?;
        self.check()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::gpu::kernels::Kernels;

    /// `STORAGE_BUFFERS` is what the kernels need, no less and no more:
    /// every kernel compiles on a device opened with that many storage
    /// buffers a kernel, and not on one with one fewer, which `open`
    /// refuses. Runs on any adapter wgpu sees (lavapipe in CI;
    /// GSENC_REQUIRE_GPU=1 fails instead of skipping without one).
    #[test]
    fn the_kernels_need_as_many_storage_buffers_as_open_asks() {
        let Some((summary, adapter)) = enumerate().unwrap().into_iter().find(|(s, _)| s.name != "noop") else {
            assert_ne!(std::env::var("GSENC_REQUIRE_GPU").as_deref(), Ok("1"), "GSENC_REQUIRE_GPU=1 and wgpu sees no adapter");
            eprintln!("NOT RUN: wgpu sees no adapter");
            return;
        };
        let capped = |n: u32| wgpu::Limits { max_storage_buffers_per_shader_stage: n, ..adapter.limits() };
        let gpu = Gpu::open_with(summary.clone(), adapter.clone(), capped(STORAGE_BUFFERS)).unwrap();
        Kernels::new(&gpu).unwrap();
        let refused = Gpu::open_with(summary, adapter.clone(), capped(STORAGE_BUFFERS - 1)).err().expect("one binding short");
        assert!(refused.to_string().contains(&format!("bind {} storage buffers", STORAGE_BUFFERS - 1)), "{refused}");
        // A device with one fewer, opened past `open`'s check.
        let desc = wgpu::DeviceDescriptor { required_limits: capped(STORAGE_BUFFERS - 1), ..Default::default() };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc)).unwrap();
        let short = Gpu {
            device: ManuallyDrop::new(device),
            queue: ManuallyDrop::new(queue),
            adapter: gpu.adapter.clone(),
            limits: gpu.limits.clone(),
            failure: gpu.failure.clone(),
            sleepy_wait: gpu.sleepy_wait,
            uploads: Default::default(),
            process: gpu.process,
        };
        assert!(Kernels::new(&short).is_err(), "the kernels compiled with {} storage buffers a kernel", STORAGE_BUFFERS - 1);
    }
}
