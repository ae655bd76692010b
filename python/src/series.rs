//! `gsenc.Series`: a time series encoded step by step, each step of a
//! field warm-started from its previous one: the library's series encoder
//! (as `gsenc encode-series`, the C API's encoders and MPI run it) over the
//! inputs and options of `encode.rs`, on one backend opened for the whole
//! series. Synchronous: a step returns its model (the C API's encoders are
//! the background queue).

use crate::encode::{detached, finished, options, Options};
use crate::errors::IntoPy;
use crate::inputs::Arrays;
use crate::model::{backend_choice, Model};
use gsenc::backend::Backend;
use gsenc::threads::with_threads;
use gsenc::encode::{Cancel, WarmStart};
use gsenc::format::Payload;
use gsenc::series::{SeriesConfig, SeriesEncoder};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::{Mutex, MutexGuard};

/// A series encoder and the backend its steps run on.
#[pyclass(module = "gsenc", frozen)]
pub struct Series {
    /// Held for a step, and taken only with the GIL released: a second
    /// thread's step waits for the first, whose progress needs the GIL.
    state: Mutex<State>,
    /// The configuration's: cleared at the start of each step, set by
    /// Ctrl-C or an exception from `progress`.
    cancel: Cancel,
    payload: Payload,
    threads: Option<usize>,
}

struct State {
    encoder: SeriesEncoder,
    backend: Box<dyn Backend>,
}

impl Series {
    fn state(&self) -> MutexGuard<'_, State> {
        // A step that panicked left the encoder as it was before the step.
        self.state.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Encodes `arrays` as `field`'s step `step` and returns its model as stored.
    fn step(&self, py: Python<'_>, arrays: Arrays, field: String, step: u64, time: Option<f64>, progress: Option<Py<PyAny>>) -> PyResult<Model> {
        gsenc::format::check_field_name(&field).py_err()?;
        let result = detached(py, &self.cancel, progress, |report| {
            let state = &mut *self.state();
            self.cancel.set(false);
            let (encoder, backend) = (&mut state.encoder, state.backend.as_mut());
            with_threads(self.threads, || arrays.with_input(|input| encoder.encode_step(&field, step, time, input, backend, report)))?
        })?;
        let (prepared, warm_started) = (&result.prepared, result.encoded.warm_started);
        let (clamped, outside) = (prepared.clamped_values, prepared.outside_items());
        // [iteration, PSNR] pairs, the rows of `encode-series --csv`.
        let validation = serde_json::json!(result.encoded.output.validation);
        let mut model = finished(result.encoded, self.payload)?;
        model.info.insert("warm_started".into(), serde_json::json!(warm_started));
        model.info.insert("validation".into(), validation);
        model.info.insert("clamped_values".into(), serde_json::json!(clamped));
        model.info.insert("outside_items".into(), serde_json::json!(outside));
        Ok(model)
    }
}

#[pymethods]
impl Series {
    /// A series of the encode options `options` (those of `encode_grid`
    /// but the labels of a step), warm-starting each field's later steps
    /// as `warm` says ("auto", "off", "coarse", "dense"), in
    /// `warm_iterations` iterations when given, scoring each step on
    /// `validation_points` fixed points every `validation_every`
    /// iterations (0 points: none, as the C API's encoders).
    #[new]
    #[pyo3(signature = (options, warm, warm_iterations=None, validation_points=0, validation_every=50))]
    fn new(
        py: Python<'_>,
        options: &Bound<'_, PyDict>,
        warm: &str,
        warm_iterations: Option<usize>,
        validation_points: usize,
        validation_every: usize,
    ) -> PyResult<Series> {
        let Options { request, range, threads, backend } = self::options(options)?;
        let warm = WarmStart::from_name(warm).py_err()?;
        let cancel = Cancel::default();
        let mut encode = request.config;
        encode.cancel = Some(cancel.clone());
        let mut cfg = SeriesConfig::new(encode, warm, range.into());
        (cfg.validation_points, cfg.validation_every) = (validation_points, validation_every);
        cfg.warm_iterations = warm_iterations;
        cfg.payload = request.payload;
        cfg.rank = request.labels.rank;
        cfg.store_support = request.store_support;
        let encoder = SeriesEncoder::new(cfg).py_err()?;
        let choice = backend_choice(&backend)?;
        let backend = py.detach(|| choice.open()).py_err()?;
        Ok(Series { state: Mutex::new(State { encoder, backend }), cancel, payload: request.payload, threads })
    }

    /// Encodes a 3D array `[z][y][x]` as `field`'s step `step`.
    #[pyo3(signature = (array, origin, spacing, field, step, time=None, progress=None))]
    #[allow(clippy::too_many_arguments)] // Python's keyword arguments
    fn encode_grid(
        &self,
        py: Python<'_>,
        array: &Bound<'_, PyAny>,
        origin: [f64; 3],
        spacing: f64,
        field: String,
        step: u64,
        time: Option<f64>,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<Model> {
        self.step(py, Arrays::grid(array, origin, spacing)?, field, step, time, progress)
    }

    /// Encodes SPH particles as `field`'s step `step`.
    #[pyo3(signature = (positions, smoothing_length, values, mass, place, field, step, time=None, progress=None))]
    #[allow(clippy::too_many_arguments)]
    fn encode_particles(
        &self,
        py: Python<'_>,
        positions: &Bound<'_, PyAny>,
        smoothing_length: &Bound<'_, PyAny>,
        values: &Bound<'_, PyAny>,
        mass: Option<&Bound<'_, PyAny>>,
        place: &Bound<'_, PyDict>,
        field: String,
        step: u64,
        time: Option<f64>,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<Model> {
        self.step(py, Arrays::particles(positions, smoothing_length, values, mass, place)?, field, step, time, progress)
    }

    /// Encodes hexahedral cells as `field`'s step `step`.
    #[pyo3(signature = (centers, values, sizes, volumes, place, field, step, time=None, progress=None))]
    #[allow(clippy::too_many_arguments)]
    fn encode_cells(
        &self,
        py: Python<'_>,
        centers: &Bound<'_, PyAny>,
        values: &Bound<'_, PyAny>,
        sizes: Option<&Bound<'_, PyAny>>,
        volumes: Option<&Bound<'_, PyAny>>,
        place: &Bound<'_, PyDict>,
        field: String,
        step: u64,
        time: Option<f64>,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<Model> {
        self.step(py, Arrays::cells(centers, values, sizes, volumes, place)?, field, step, time, progress)
    }

    /// Continues `model`'s field from it (its last stored step, after a
    /// restart). An encoded model continues from its float32 parameters,
    /// as the series that made it would; a read one from those it stores.
    fn resume(&self, py: Python<'_>, model: &Model) -> PyResult<()> {
        let model = match &model.unquantized {
            Some(m) => m.clone(),
            None => model.one("resume")?.clone(),
        };
        py.detach(|| self.state().encoder.resume(model)).py_err()
    }
}
