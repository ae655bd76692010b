//! Choosing a backend and falling back from a failing GPU: no device needed
//! (a stand-in backend fails the way a lost device does).

mod common;
use common::*;
use gsenc::backend::cpu::CpuBackend;
use gsenc::backend::select::{BackendChoice, BackendKind, Fallback};
use gsenc::backend::{Backend, Lattice, PointBatch, PointLoss};
use gsenc::encode::{encode, EncodeConfig, Schedule};
use gsenc::input::Target;
use gsenc::math::kernel::Primitive;
use gsenc::math::loss::LossWeights;
use gsenc::{Error, Result};

/// The CPU backend under another name, failing with `error` from its
/// `fail_at`-th call on.
struct Failing {
    inner: CpuBackend,
    calls: usize,
    fail_at: usize,
    error: fn() -> Error,
}

impl Failing {
    fn tick(&mut self) -> Result<()> {
        self.calls += 1;
        if self.calls >= self.fail_at {
            return Err((self.error)());
        }
        Ok(())
    }
}

impl Backend for Failing {
    fn name(&self) -> String {
        "stand-in gpu".into()
    }
    fn kernel_evaluations(&self) -> u64 {
        self.inner.kernel_evaluations()
    }
    fn evaluate_points(&mut self, params: &[Primitive], pos: &[[f32; 3]], rho: &mut [f32], n: &mut [f32]) -> Result<()> {
        self.tick()?;
        self.inner.evaluate_points(params, pos, rho, n)
    }
    fn point_loss_grad(&mut self, params: &[Primitive], batch: &PointBatch, weights: &LossWeights, grad: &mut [Primitive]) -> Result<PointLoss> {
        self.tick()?;
        self.inner.point_loss_grad(params, batch, weights, grad)
    }
    fn decode_lattice(&mut self, params: &[Primitive], lattice: &Lattice, out: &mut [f32]) -> Result<()> {
        self.tick()?;
        self.inner.decode_lattice(params, lattice, out)
    }
}

fn setup() -> (gsenc::field::Grid, EncodeConfig) {
    let field = blobs([20, 20, 20], 3, 3);
    let mut cfg = EncodeConfig::new(120, Schedule::Short);
    cfg.iterations = Some(60);
    cfg.points = Some(2048);
    (field, cfg)
}

#[test]
fn a_device_lost_mid_encode_finishes_on_the_cpu_and_says_so() {
    let (field, cfg) = setup();
    let t = Target { reference: &field, samples: &field };
    let reference = encode(&t, &cfg, None, &mut CpuBackend::new(), &mut |_| {}).unwrap();
    let lost = || Error::Device("device lost (test)".into());
    let mut auto = Fallback::with_gpu(Box::new(Failing { inner: CpuBackend::new(), calls: 0, fail_at: 25, error: lost }), None);
    assert_eq!(auto.name(), "stand-in gpu");
    let out = encode(&t, &cfg, None, &mut auto, &mut |_| {}).unwrap();
    assert_eq!(out.backend, "cpu");
    assert!(out.fell_back.as_deref().is_some_and(|m| m.contains("device lost")), "{:?}", out.fell_back);
    // The stand-in computes what the CPU does, so the model is the same.
    assert_eq!(out.params, reference.params);
    // And a backend that works keeps the work and reports no fall-back.
    let fine = || Error::Device("never".into());
    let mut auto = Fallback::with_gpu(Box::new(Failing { inner: CpuBackend::new(), calls: 0, fail_at: usize::MAX, error: fine }), None);
    let out = encode(&t, &cfg, None, &mut auto, &mut |_| {}).unwrap();
    assert_eq!((out.backend.as_str(), out.fell_back), ("stand-in gpu", None));
}

#[test]
fn errors_other_than_the_device_are_not_hidden_by_a_fall_back() {
    let (field, cfg) = setup();
    let t = Target { reference: &field, samples: &field };
    let bad = || Error::data("not a device problem");
    let mut auto = Fallback::with_gpu(Box::new(Failing { inner: CpuBackend::new(), calls: 0, fail_at: 3, error: bad }), None);
    let e = encode(&t, &cfg, None, &mut auto, &mut |_| {}).err().expect("the error must reach the caller");
    assert!(matches!(e, Error::InvalidData(_)), "{e}");
    assert!(auto.fell_back.is_none());
}

#[test]
fn backend_names() {
    for k in BackendKind::ALL {
        assert_eq!(BackendKind::from_name(k.name()).unwrap(), k);
    }
    let e = BackendKind::from_name("cuda").unwrap_err();
    assert!(e.to_string().contains("auto, cpu, gpu"), "{e}");
    // The CPU opens everywhere and is what it says.
    assert_eq!(BackendChoice::cpu().open().unwrap().name(), "cpu");
}
