//! `gsenc.encode_grid`, `encode_particles` and `encode_cells`: numpy
//! arrays into the library's inputs (`inputs.rs`), then its one encode
//! pipeline (as the command line and the C API run it), with the GIL
//! released. Keyword options arrive as a dict from `gsenc/__init__.py`,
//! which spells them out and documents them. `series.rs` runs a time
//! series' steps through the same options, GIL release and models.

use crate::args::named;
use crate::errors::IntoPy;
use crate::inputs::Arrays;
use crate::model::{backend_choice, in_memory, Model};
use gsenc::encode::pipeline::{self, Labels, Request, Start};
use gsenc::threads::with_threads;
use gsenc::encode::{Cancel, EncodeConfig, Progress, Schedule, TargetPsnr};
use gsenc::format::Payload;
use gsenc::input::RangeSpec;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Options every encode takes (their defaults are `gsenc/__init__.py`'s).
pub struct Options {
    pub request: Request<'static>,
    pub range: RangeSpec,
    pub threads: Option<usize>,
    pub backend: String,
}

const OPTIONS: [&str; 18] = [
    "budget", "target_psnr", "schedule", "range", "log10", "payload", "field", "step", "time", "rank", "iterations", "points", "seed", "sample_seed", "relocation", "support", "threads", "backend",
];

pub fn options(o: &Bound<'_, PyDict>) -> PyResult<Options> {
    for key in o.keys() {
        let key: String = key.extract()?;
        if !OPTIONS.contains(&key.as_str()) {
            return Err(PyTypeError::new_err(format!("unknown encode option '{key}'")));
        }
    }
    fn get<'py, T: pyo3::conversion::FromPyObjectOwned<'py>>(o: &Bound<'py, PyDict>, key: &str) -> PyResult<Option<T>> {
        match o.get_item(key)? {
            Some(v) if !v.is_none() => named(&v, key).map(Some),
            _ => Ok(None),
        }
    }
    let budget: Option<usize> = get(o, "budget")?;
    let target = get::<f64>(o, "target_psnr")?.map(TargetPsnr::new).transpose().py_err()?;
    if budget.is_none() && target.is_none() {
        return Err(PyTypeError::new_err("give a budget, or a target_psnr"));
    }
    let schedule = Schedule::from_name(&get::<String>(o, "schedule")?.unwrap_or_else(|| "matched".into())).py_err()?;
    let mut config = EncodeConfig::new(budget.unwrap_or(0), schedule);
    config.target = target;
    config.iterations = get(o, "iterations")?;
    config.points = get(o, "points")?;
    config.seed_init = get(o, "seed")?.unwrap_or(0);
    config.seed_sample = get(o, "sample_seed")?.unwrap_or(1);
    config.relocation = get(o, "relocation")?.unwrap_or(true);
    let range = RangeSpec::of(get::<[f64; 2]>(o, "range")?, get(o, "log10")?.unwrap_or(false)).py_err()?;
    let payload = Payload::from_name(&get::<String>(o, "payload")?.unwrap_or_else(|| "f32".into())).py_err()?;
    let labels = Labels { field: get(o, "field")?.unwrap_or_else(|| "scalar".into()), step: get(o, "step")?.unwrap_or(0), time: get(o, "time")?, rank: get(o, "rank")?.unwrap_or(0) };
    gsenc::format::check_field_name(&labels.field).py_err()?;
    let request = Request { config, start: Start::Seeded, payload, store_support: get(o, "support")?.unwrap_or(true), labels, validation: None };
    Ok(Options { request, range, threads: get(o, "threads")?, backend: get(o, "backend")?.unwrap_or_else(|| "auto".into()) })
}

/// Runs `encode` without the GIL, reporting its progress to `progress(iteration,
/// iterations, loss)` every 10 iterations (and at the last). Ctrl-C, or an
/// exception from `progress`, sets `cancel` (the encode stops between
/// iterations) and is raised.
pub fn detached<T: Send>(
    py: Python<'_>,
    cancel: &Cancel,
    progress: Option<Py<PyAny>>,
    encode: impl FnOnce(&mut (dyn FnMut(&Progress) + Send)) -> gsenc::Result<T> + Send,
) -> PyResult<T> {
    let mut raised: Option<PyErr> = None;
    let result = py.detach(|| {
        let mut report = |p: &Progress| {
            if !p.iteration.is_multiple_of(10) && p.iteration != p.iterations {
                return;
            }
            Python::attach(|py| {
                let outcome = py.check_signals().and_then(|_| match &progress {
                    Some(f) => f.call1(py, (p.iteration, p.iterations, p.loss)).map(drop),
                    None => Ok(()),
                });
                if let Err(e) = outcome {
                    raised.get_or_insert(e);
                    cancel.set(true);
                }
            })
        };
        encode(&mut report)
    });
    match raised {
        Some(e) => Err(e),
        None => result.py_err(),
    }
}

/// The encoded model as its payload stores it (what its PSNR scores, and
/// what a reader of the written file gets), so that it decodes as the file
/// will; `write` stores the float32 model it came from, as the tool would.
pub fn finished(mut encoded: pipeline::Encoded, payload: Payload) -> PyResult<Model> {
    let unquantized = encoded.model.clone();
    encoded.model.params = payload.round_trip(&encoded.model).py_err()?;
    let mut model = in_memory(encoded.model, payload, Some(encoded.psnr), "gsenc model (encoded, not yet written)");
    model.unquantized = Some(unquantized);
    model.info.insert("float32_psnr".into(), serde_json::json!(encoded.float32_psnr));
    model.info.insert("target".into(), gsenc::encode::target::report_json(encoded.target.as_ref()));
    Ok(model)
}

/// Runs the pipeline on `arrays` (see [`detached`]).
fn run(py: Python<'_>, arrays: Arrays, mut o: Options, progress: Option<Py<PyAny>>) -> PyResult<Model> {
    let choice = backend_choice(&o.backend)?;
    let cancel = Cancel::default();
    o.request.config.cancel = Some(cancel.clone());
    let (request, range, threads) = (&o.request, &o.range, o.threads);
    let encoded = detached(py, &cancel, progress, |report| {
        let mut backend = choice.open()?;
        let (_, encoded) = with_threads(threads, || arrays.with_input(|input| pipeline::encode(&input, range, request, backend.as_mut(), report)))??;
        Ok(encoded)
    })?;
    finished(encoded, o.request.payload)
}

/// Encodes a 3D array `[z][y][x]` (see `gsenc.encode_grid`).
#[pyfunction]
#[pyo3(signature = (array, origin, spacing, options, progress=None))]
pub fn encode_grid(py: Python<'_>, array: &Bound<'_, PyAny>, origin: [f64; 3], spacing: f64, options: &Bound<'_, PyDict>, progress: Option<Py<PyAny>>) -> PyResult<Model> {
    let o = self::options(options)?;
    run(py, Arrays::grid(array, origin, spacing)?, o, progress)
}

/// Encodes SPH particles against their deposit (see `gsenc.encode_particles`).
#[pyfunction]
#[pyo3(signature = (positions, smoothing_length, values, mass, place, options, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn encode_particles(
    py: Python<'_>,
    positions: &Bound<'_, PyAny>,
    smoothing_length: &Bound<'_, PyAny>,
    values: &Bound<'_, PyAny>,
    mass: Option<&Bound<'_, PyAny>>,
    place: &Bound<'_, PyDict>,
    options: &Bound<'_, PyDict>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Model> {
    let o = self::options(options)?;
    run(py, Arrays::particles(positions, smoothing_length, values, mass, place)?, o, progress)
}

/// Encodes hexahedral cells against their deposit (see `gsenc.encode_cells`).
#[pyfunction]
#[pyo3(signature = (centers, values, sizes, volumes, place, options, progress=None))]
#[allow(clippy::too_many_arguments)]
pub fn encode_cells(
    py: Python<'_>,
    centers: &Bound<'_, PyAny>,
    values: &Bound<'_, PyAny>,
    sizes: Option<&Bound<'_, PyAny>>,
    volumes: Option<&Bound<'_, PyAny>>,
    place: &Bound<'_, PyDict>,
    options: &Bound<'_, PyDict>,
    progress: Option<Py<PyAny>>,
) -> PyResult<Model> {
    let o = self::options(options)?;
    run(py, Arrays::cells(centers, values, sizes, volumes, place)?, o, progress)
}
