//! Choosing a backend and falling back from a failing GPU: no device needed
//! (a stand-in backend fails the way a lost device does).

mod common;
use common::*;
use gsenc::backend::cpu::CpuBackend;
use gsenc::backend::select::{BackendChoice, BackendKind, Fallback};
use gsenc::backend::{Backend, Lattice, PointBatch, PointLoss, Resident};
use gsenc::encode::pipeline::{self, Request};
use gsenc::encode::{encode, EncodeConfig, Schedule};
use gsenc::field::{IndexFrame, Transform};
use gsenc::format::{read_model_file, write_model};
use gsenc::input::{Input, RangeSpec};
use gsenc::input::Target;
use gsenc::math::kernel::Primitive;
use gsenc::math::loss::{regularizers, LossWeights, RegTerms};
use gsenc::math::optim::Adam;
use gsenc::{Error, Result};

/// The CPU backend under another name, failing with `error` from its
/// `fail_at`-th call on; with `resident`, it keeps its own copies of the
/// parameters and moments as a device would, and trains them with the
/// host's own code (so the models must equal the host loop's bit for bit).
struct Failing {
    inner: CpuBackend,
    calls: usize,
    fail_at: usize,
    error: fn() -> Error,
    resident: bool,
    held: Option<(Vec<Primitive>, Adam)>,
    /// What the last `submit` computed, until `finish` returns it.
    submitted: Option<Option<(PointLoss, RegTerms)>>,
    steps: usize,
}

fn failing(fail_at: usize, error: fn() -> Error, resident: bool) -> Failing {
    Failing { inner: CpuBackend::new(), calls: 0, fail_at, error, resident, held: None, submitted: None, steps: 0 }
}

impl Resident for Failing {
    fn load(&mut self, params: &[Primitive], adam: &Adam) -> Result<()> {
        self.tick()?;
        self.held = Some((params.to_vec(), adam.clone()));
        Ok(())
    }
    fn submit(&mut self, batch: &PointBatch, weights: &LossWeights, lr: f32, report: bool) -> Result<()> {
        self.tick()?;
        assert!(self.submitted.is_none(), "submit twice without finish");
        self.steps += 1;
        let (params, adam) = self.held.as_mut().expect("loaded");
        let mut grad = vec![[0.0; 12]; params.len()];
        let pl = self.inner.point_loss_grad(params, batch, weights, &mut grad)?;
        let reg = regularizers(params, weights, &mut grad);
        adam.step(params, &grad, lr);
        self.submitted = Some(report.then_some((pl, reg)));
        Ok(())
    }
    fn finish(&mut self) -> Result<Option<(PointLoss, RegTerms)>> {
        self.tick()?;
        Ok(self.submitted.take().expect("finish after submit"))
    }
    fn store(&mut self, params: &mut [Primitive], adam: &mut Adam) -> Result<()> {
        self.tick()?;
        let (p, a) = self.held.as_ref().expect("loaded");
        params.copy_from_slice(p);
        *adam = a.clone();
        Ok(())
    }
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
    fn resident(&mut self) -> Option<&mut dyn Resident> {
        if self.resident {
            Some(self)
        } else {
            None
        }
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
    let mut auto = Fallback::with_gpu(Box::new(failing(25, lost, false)), None);
    assert_eq!(auto.name(), "stand-in gpu");
    let out = encode(&t, &cfg, None, &mut auto, &mut |_| {}).unwrap();
    assert_eq!(out.backend, "cpu");
    // The device's own message, said once.
    assert_eq!(out.fell_back.as_deref(), Some("GPU: device lost (test)"));
    // The stand-in computes what the CPU does, so the model is the same.
    assert_eq!(out.params, reference.params);
    // The model file says so too (format 1.3), and a model whose encode ran
    // where it was meant to stays a 1.2 file.
    let frame = IndexFrame::for_grid(field.dims, [0.0; 3], 1.0).unwrap();
    let input = Input::Grid { values: &field, frame };
    let range = RangeSpec::FromData(Transform::Linear);
    let mut auto = Fallback::with_gpu(Box::new(failing(25, lost, false)), None);
    let (_, enc) = pipeline::encode(&input, &range, &Request::new(cfg.clone()), &mut auto, &mut |_| {}).unwrap();
    let file = read_model_file(&write_model(&enc.model).unwrap()).unwrap();
    assert_eq!(file.version, (1, 3));
    assert!(file.model.meta.fell_back.as_deref().is_some_and(|m| m.contains("device lost")), "{:?}", file.model.meta.fell_back);
    let (_, enc) = pipeline::encode(&input, &range, &Request::new(cfg.clone()), &mut CpuBackend::new(), &mut |_| {}).unwrap();
    let file = read_model_file(&write_model(&enc.model).unwrap()).unwrap();
    assert_eq!((file.version, file.model.meta.fell_back), ((1, 2), None));
    // And a backend that works keeps the work and reports no fall-back.
    let fine = || Error::Device("never".into());
    let mut auto = Fallback::with_gpu(Box::new(failing(usize::MAX, fine, false)), None);
    let out = encode(&t, &cfg, None, &mut auto, &mut |_| {}).unwrap();
    assert_eq!((out.backend.as_str(), out.fell_back), ("stand-in gpu", None));
}

#[test]
fn errors_other_than_the_device_are_not_hidden_by_a_fall_back() {
    let (field, cfg) = setup();
    let t = Target { reference: &field, samples: &field };
    let bad = || Error::data("not a device problem");
    let mut auto = Fallback::with_gpu(Box::new(failing(3, bad, false)), None);
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

/// The loop of a resident backend (parameters and moments held on the
/// "device", loaded, stepped and stored around relocation and validation)
/// gives the host loop's model bit for bit, when the steps compute the same.
#[test]
fn the_resident_loop_is_the_host_loop() {
    let (field, mut cfg) = setup();
    cfg.iterations = Some(90); // relocation at 31, 49 and 67
    let t = Target { reference: &field, samples: &field };
    let validation = gsenc::encode::Validation::from_reference(&field, 500, 9, 20).unwrap();
    let host = gsenc::encode::encode_validated(&t, &cfg, None, Some(&validation), &mut CpuBackend::new(), &mut |_| {}).unwrap();
    let mut held = failing(usize::MAX, || Error::Device("never".into()), true);
    let mut losses = vec![];
    let out = gsenc::encode::encode_validated(&t, &cfg, None, Some(&validation), &mut held, &mut |p| losses.push(p.loss)).unwrap();
    assert_eq!(held.steps, 90, "every iteration ran as a resident step");
    assert_eq!(out.params, host.params);
    assert_eq!(out.validation, host.validation);
    assert_eq!(out.last_loss.total, host.last_loss.total);
    assert_eq!(out.relocations.len(), 3);
    assert!(losses.iter().all(|l| l.is_finite() && *l > 0.0));
}

/// A device lost in the middle of a resident encode: `auto` starts the
/// encode again on the CPU, and the model is the CPU's.
#[test]
fn a_device_lost_in_a_resident_encode_starts_it_again_on_the_cpu() {
    let (field, cfg) = setup();
    let t = Target { reference: &field, samples: &field };
    let reference = encode(&t, &cfg, None, &mut CpuBackend::new(), &mut |_| {}).unwrap();
    let mut auto = Fallback::with_gpu(Box::new(failing(40, || Error::Device("device lost (test)".into()), true)), None);
    let out = encode(&t, &cfg, None, &mut auto, &mut |_| {}).unwrap();
    assert_eq!(out.backend, "cpu");
    assert_eq!(out.fell_back.as_deref(), Some("GPU: device lost (test)"));
    assert_eq!(out.params, reference.params);
    // Without a fall-back (an explicit GPU), the error is the answer.
    let mut gpu = failing(40, || Error::Device("device lost (test)".into()), true);
    let e = encode(&t, &cfg, None, &mut gpu, &mut |_| {}).err().expect("the device error reaches the caller");
    assert!(matches!(e, Error::Device(_)), "{e}");
}

/// The CPU backend reads a batch's sort into bricks made ahead, and only
/// one of its own edge (`common::check_sorted_ahead`).
#[test]
fn a_batch_sorted_ahead_gives_the_gradient_of_one_sorted_in_the_call() {
    let mut rng = gsenc::math::rng::Rng::new(31);
    let params = random_model(&mut rng, 400, 48.0);
    let plain = random_batch(&mut rng, 5000, 48.0);
    check_sorted_ahead(&mut CpuBackend::new(), &params, &plain);
}
