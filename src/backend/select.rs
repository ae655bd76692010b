//! Choosing a backend: `auto`, `cpu` or `gpu`, overridden by `GSENC_BACKEND`.
//!
//! - `cpu`: the CPU backend.
//! - `gpu`: the GPU backend on hardware adapter `gpu_index` (default 0), or
//!   on the adapter `GSENC_ADAPTER` names (the only way to a software
//!   adapter such as llvmpipe); failing to open it is an error.
//! - `auto`: a hardware GPU when there is one, the CPU otherwise; never a
//!   software adapter. When the GPU cannot be opened, or fails during a
//!   call, the work goes on on the CPU and a warning says so
//!   ([`Fallback::fell_back`]).

use super::cpu::CpuBackend;
use super::{Backend, Lattice, PointBatch, PointLoss, Resident};
use crate::error::{by_name, Error, Result};
use crate::math::kernel::Primitive;
use crate::math::loss::LossWeights;

/// Which backend evaluates an encode or a decode.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BackendKind {
    #[default]
    Auto,
    Cpu,
    Gpu,
}

impl BackendKind {
    pub const ALL: [BackendKind; 3] = [BackendKind::Auto, BackendKind::Cpu, BackendKind::Gpu];

    pub fn from_name(s: &str) -> Result<BackendKind> {
        by_name(&BackendKind::ALL, BackendKind::name, s, "backend")
    }

    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Auto => "auto",
            BackendKind::Cpu => "cpu",
            BackendKind::Gpu => "gpu",
        }
    }

    /// The kind `GSENC_BACKEND` names when it is set (and not empty), else `self`.
    pub fn or_env(self) -> Result<BackendKind> {
        match std::env::var("GSENC_BACKEND") {
            Ok(s) if !s.trim().is_empty() => BackendKind::from_name(s.trim()).map_err(|e| e.in_context("GSENC_BACKEND")),
            _ => Ok(self),
        }
    }
}

/// One adapter as `gsenc devices` lists it.
#[derive(Clone, Debug, PartialEq)]
pub struct AdapterSummary {
    /// Its index among the hardware adapters (what `gpu_index` selects), or
    /// `None` for a software adapter.
    pub index: Option<usize>,
    pub name: String,
    /// "Vulkan", "Metal", "Dx12".
    pub api: String,
    /// "DiscreteGpu", "IntegratedGpu", "VirtualGpu", "Cpu", "Other".
    pub device_type: String,
    pub driver: String,
}

impl AdapterSummary {
    pub fn software(&self) -> bool {
        self.index.is_none()
    }
}

/// The adapters the GPU backend sees (none when gsenc is built without it).
pub fn adapters() -> Vec<AdapterSummary> {
    #[cfg(feature = "gpu")]
    return super::gpu::device::adapters();
    #[cfg(not(feature = "gpu"))]
    return vec![];
}

/// Whether this gsenc has the GPU backend (cargo feature `gpu`).
pub const HAS_GPU_BACKEND: bool = cfg!(feature = "gpu");

/// What to open: the kind, the hardware GPU's index, and the edge of the
/// training bricks (both backends' default when `None`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BackendChoice {
    pub kind: BackendKind,
    pub gpu_index: Option<usize>,
    pub brick: Option<f32>,
}

impl BackendChoice {
    pub fn cpu() -> BackendChoice {
        BackendChoice { kind: BackendKind::Cpu, ..BackendChoice::default() }
    }

    /// The choice for the rank `node_rank` of a node: unless an index was
    /// given, the GPU `node_rank` modulo the node's hardware GPUs, so that
    /// the ranks of a node share its GPUs evenly.
    pub fn for_node_rank(self, node_rank: usize) -> BackendChoice {
        if self.gpu_index.is_some() || self.kind.or_env().ok() == Some(BackendKind::Cpu) {
            return self;
        }
        match hardware_gpus() {
            0 => self,
            n => BackendChoice { gpu_index: Some(node_rank % n), ..self },
        }
    }

    /// Opens the backend, `GSENC_BACKEND` overriding the kind; a
    /// `GSENC_SIMD` that names no build is refused here too.
    pub fn open(self) -> Result<Box<dyn Backend>> {
        crate::math::simd::check_env()?;
        match self.kind.or_env()? {
            BackendKind::Cpu => Ok(Box::new(cpu_backend(self.brick))),
            BackendKind::Gpu => gpu_backend(self.gpu_index, adapter_from_env(), self.brick),
            BackendKind::Auto => Ok(Box::new(Fallback::open(self))),
        }
    }
}

fn cpu_backend(brick: Option<f32>) -> CpuBackend {
    let mut b = CpuBackend::new();
    if let Some(e) = brick {
        b.brick = e;
    }
    b
}

/// The GPU backend on the adapter named like `name`, else on hardware
/// adapter `index`.
#[cfg(feature = "gpu")]
fn gpu_backend(index: Option<usize>, name: Option<String>, brick: Option<f32>) -> Result<Box<dyn Backend>> {
    use super::gpu::{device::DeviceRequest, GpuBackend};
    let mut b = GpuBackend::new(&DeviceRequest { index, name })?;
    if let Some(e) = brick {
        b.brick = e;
    }
    Ok(Box::new(b))
}

#[cfg(not(feature = "gpu"))]
fn gpu_backend(_: Option<usize>, _: Option<String>, _: Option<f32>) -> Result<Box<dyn Backend>> {
    Err(Error::Device("this gsenc was built without the GPU backend (cargo feature gpu)".into()))
}

/// The adapter `GSENC_ADAPTER` names, when it is set and not empty.
fn adapter_from_env() -> Option<String> {
    std::env::var("GSENC_ADAPTER").ok().filter(|s| !s.trim().is_empty())
}

/// `auto`: a hardware GPU when one opens, the CPU otherwise and from the
/// first GPU failure on.
pub struct Fallback {
    gpu: Option<Box<dyn Backend>>,
    cpu: CpuBackend,
    /// Kernel evaluations of the GPU before it failed.
    earlier: u64,
    /// Why the work runs on the CPU, once it does after a GPU was tried.
    pub fell_back: Option<String>,
}

impl Fallback {
    pub fn open(choice: BackendChoice) -> Fallback {
        let mut f = Fallback::cpu_only(choice.brick);
        if hardware_gpus() > 0 {
            // `auto` never takes a software adapter, whatever GSENC_ADAPTER says.
            match gpu_backend(Some(choice.gpu_index.unwrap_or(0)), None, choice.brick) {
                Ok(g) => f.gpu = Some(g),
                Err(e) => f.fail(&e),
            }
        }
        f
    }

    /// `gpu` first, the CPU from its first device error on.
    pub fn with_gpu(gpu: Box<dyn Backend>, brick: Option<f32>) -> Fallback {
        Fallback { gpu: Some(gpu), ..Fallback::cpu_only(brick) }
    }

    fn cpu_only(brick: Option<f32>) -> Fallback {
        Fallback { gpu: None, cpu: cpu_backend(brick), earlier: 0, fell_back: None }
    }

    /// Runs `call` on the GPU while there is one, and on the CPU from its
    /// first device error on.
    fn run<R>(&mut self, mut call: impl FnMut(&mut dyn Backend) -> Result<R>) -> Result<R> {
        if let Some(g) = self.gpu.as_mut() {
            match call(g.as_mut()) {
                Err(e @ Error::Device(_)) => self.fail(&e),
                other => return other,
            }
        }
        call(&mut self.cpu)
    }

    fn fail(&mut self, e: &Error) {
        tracing::warn!(error = %e, "the GPU backend failed; continuing on the CPU");
        self.earlier += self.gpu.take().map_or(0, |g| g.kernel_evaluations());
        self.fell_back = Some(e.to_string());
    }
}

fn hardware_gpus() -> usize {
    adapters().iter().filter(|a| !a.software()).count()
}

impl Backend for Fallback {
    fn name(&self) -> String {
        match &self.gpu {
            Some(g) => g.name(),
            None => self.cpu.name(),
        }
    }

    fn kernel_evaluations(&self) -> u64 {
        self.earlier + self.cpu.kernel_evaluations() + self.gpu.as_ref().map_or(0, |g| g.kernel_evaluations())
    }

    fn fell_back(&self) -> Option<String> {
        self.fell_back.clone()
    }

    fn on_device(&self) -> bool {
        self.gpu.as_ref().is_some_and(|g| g.on_device())
    }

    fn kernel_seconds(&self) -> Vec<(String, u64, f64)> {
        self.gpu.as_ref().map_or(vec![], |g| g.kernel_seconds())
    }

    fn host_seconds(&self) -> Vec<(String, u64, f64)> {
        self.gpu.as_ref().map_or(vec![], |g| g.host_seconds())
    }

    fn brick_edge(&self) -> Option<f32> {
        match &self.gpu {
            Some(g) => g.brick_edge(),
            None => self.cpu.brick_edge(),
        }
    }

    fn resident(&mut self) -> Option<&mut dyn Resident> {
        self.gpu.as_mut().and_then(|g| g.resident())
    }

    fn abandon_device(&mut self, error: &Error) -> bool {
        if self.gpu.is_none() || !matches!(error, Error::Device(_)) {
            return false;
        }
        self.fail(error);
        true
    }

    fn evaluate_points(&mut self, params: &[Primitive], pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]) -> Result<()> {
        self.run(|b| b.evaluate_points(params, pos, rho, n))
    }

    /// On the CPU whatever the choice (the trait's default for devices).
    fn evaluate_each(&mut self, params: &[Primitive], pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]) -> Result<()> {
        self.cpu.evaluate_each(params, pos, rho, n)
    }

    fn point_loss_grad(&mut self, params: &[Primitive], batch: &PointBatch, weights: &LossWeights, grad: &mut [Primitive]) -> Result<PointLoss> {
        self.run(|b| b.point_loss_grad(params, batch, weights, grad))
    }

    fn decode_lattice(&mut self, params: &[Primitive], lattice: &Lattice, out: &mut [f32]) -> Result<()> {
        self.run(|b| b.decode_lattice(params, lattice, out))
    }
}
