//! `gsenc.Model`: a model read from a file, a step index or a store entry,
//! or made by an encode; decoded, evaluated and written through the
//! library, as the command line does.

use crate::args::named;
use crate::arrays::{grid_array, triples, vector};
use crate::errors::IntoPy;
use gsenc::backend::select::{BackendChoice, BackendKind};
use gsenc::domain::global::GlobalField;
use gsenc::threads::with_threads;
use gsenc::field::IndexBox;
use gsenc::format::info::{meta_info, model_info};
use gsenc::format::{write_model_as, Payload};
use gsenc::io::{read_field, read_model_file, write_atomic};
use numpy::{PyArray1, PyArray2, PyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use serde_json::{json, Map, Value};
use std::path::PathBuf;

/// A model, or a step's global field (several pieces, blended).
#[pyclass(module = "gsenc", frozen)]
pub struct Model {
    pub field: GlobalField,
    /// What `info` returns.
    pub info: Map<String, Value>,
    /// The payload it was read with or encoded for: `write`'s default.
    pub payload: Payload,
    /// The encode's PSNR as stored, or the file's record of it.
    pub psnr: Option<f64>,
    /// An encode's model before its payload's quantisation (`field` holds
    /// it as stored): what `write` stores, as the tool would.
    pub unquantized: Option<gsenc::model::Model>,
}

impl Model {
    /// The model of one piece, or a clear error for a step of several.
    pub fn one(&self, what: &str) -> PyResult<&gsenc::model::Model> {
        match self.field.pieces() {
            [one] => Ok(one),
            pieces => Err(PyValueError::new_err(format!("{what} takes one model; this is a step of {} pieces (read each piece's .gsm)", pieces.len()))),
        }
    }
}

pub fn backend_choice(backend: &str) -> PyResult<BackendChoice> {
    Ok(BackendChoice { kind: BackendKind::from_name(backend).py_err()?, gpu_index: None, brick: None })
}

/// Reads a model file (`.gsm`), a step index (`.gsi`: every rank's model
/// of a step, decoded as one global field, blended across the halos), or
/// an entry of an HDF5 store (`field`, `step`, `rank`: each may be left out
/// when the store holds one choice; without `rank`, a step of several
/// ranks with its step index in the store is its global field).
#[pyfunction]
#[pyo3(signature = (path, field=None, step=None, rank=None))]
pub fn read(py: Python<'_>, path: PathBuf, field: Option<String>, step: Option<u64>, rank: Option<u32>) -> PyResult<Model> {
    if gsenc::io::is_hdf5_file(&path) {
        #[cfg(feature = "hdf5")]
        return crate::store::read_entry(py, &path, field, step, rank);
        #[cfg(not(feature = "hdf5"))]
        return Err(PyValueError::new_err(format!("{}: an HDF5 store; this gsenc was built without HDF5", path.display())));
    }
    if field.is_some() || step.is_some() || rank.is_some() {
        return Err(PyValueError::new_err("field, step and rank choose an entry of an HDF5 store; a model file or step index holds one"));
    }
    py.detach(|| -> gsenc::Result<Model> {
        if path.extension().is_some_and(|e| e == "gsi") {
            return of_step(read_field(std::slice::from_ref(&path))?);
        }
        let file = read_model_file(&path)?;
        let bytes = std::fs::metadata(&path).map_err(|e| gsenc::Error::io(&path, e))?.len();
        let info = match model_info(&file, bytes) {
            Value::Object(m) => m,
            _ => Map::new(),
        };
        let psnr = file.model.meta.encode_psnr;
        Ok(Model { payload: file.payload, psnr, field: GlobalField::of_model(file.model), info, unquantized: None })
    })
    .py_err()
}

/// A decomposed step's global field (from a `.gsi`, or a store's index).
pub fn of_step(field: GlobalField) -> gsenc::Result<Model> {
    let Some(index) = field.index.as_ref() else { return Err(gsenc::Error::format("not a step index")) };
    let mut info = gsenc::format::info::meta_info(field.merged());
    info.insert("format".into(), json!(format!("gsenc step index {}", index.version)));
    info.insert("pieces".into(), json!(field.pieces().len()));
    info.insert("halo".into(), json!(index.halo));
    info.insert("primitives".into(), json!(field.merged().len()));
    info.insert("encode_psnr".into(), Value::Null);
    Ok(Model { field, info, payload: Payload::Float32, psnr: None, unquantized: None })
}

/// A model in memory: its info from its metadata.
pub fn in_memory(model: gsenc::model::Model, payload: Payload, psnr: Option<f64>, format: &str) -> Model {
    let mut info = Map::new();
    info.insert("format".into(), json!(format));
    info.insert("payload".into(), json!(payload.name()));
    info.insert("primitives".into(), json!(model.len()));
    info.extend(meta_info(&model));
    Model { field: GlobalField::of_model(model), info, payload, psnr, unquantized: None }
}

#[pymethods]
impl Model {
    /// Decodes onto a lattice of `dims` (x, y, z; default the model's own)
    /// covering the model's box, or the part `box` (x0, y0, z0, x1, y1, z1:
    /// half-open voxel ranges of that lattice). Returns float32 `[z][y][x]`
    /// in data units (or normalised to [0, 1]): what `gsenc decode` writes.
    #[pyo3(signature = (dims=None, r#box=None, normalized=false, additive=false, threads=None, backend="auto"))]
    #[allow(clippy::too_many_arguments)] // Python's keyword arguments
    fn decode<'py>(
        &self,
        py: Python<'py>,
        dims: Option<[usize; 3]>,
        // Taken as it comes: pyo3 would note a failed conversion as of
        // 'r#box'; `named` names it as Python spells it.
        r#box: Option<Bound<'py, PyAny>>,
        normalized: bool,
        additive: bool,
        threads: Option<usize>,
        backend: &str,
    ) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let choice = backend_choice(backend)?;
        let dims = dims.unwrap_or(self.field.merged().meta.frame.dims);
        let region: Option<[usize; 6]> = r#box.map(|b| named(&b, "box")).transpose()?.flatten();
        let region = match region {
            Some([x0, y0, z0, x1, y1, z1]) => IndexBox { lo: [x0, y0, z0], hi: [x1, y1, z1] },
            None => IndexBox::whole(dims),
        };
        let range = self.field.merged().meta.range;
        let values = py
            .detach(|| -> gsenc::Result<Vec<f32>> {
                let mut backend = choice.open()?;
                with_threads(threads, || {
                    let mut values = self.field.decode(backend.as_mut(), dims, region, additive)?;
                    if !normalized {
                        range.denormalize_all(&mut values);
                    }
                    Ok(values)
                })?
            })
            .py_err()?;
        grid_array(py, region.dims(), values)
    }

    /// The decoded value at world points (an (n, 3) array of x, y, z), in
    /// data units (or normalised): what a decode gives at a voxel centre (a
    /// step's pieces blended as its decode blends them, unless `additive`).
    #[pyo3(signature = (points, normalized=false, additive=false, threads=None))]
    fn evaluate<'py>(&self, py: Python<'py>, points: &Bound<'py, PyAny>, normalized: bool, additive: bool, threads: Option<usize>) -> PyResult<Bound<'py, PyArray1<f32>>> {
        let points = triples(points, "points")?;
        let range = self.field.merged().meta.range;
        let values = py
            .detach(|| -> gsenc::Result<Vec<f32>> {
                let mut cpu = gsenc::backend::cpu::CpuBackend::new();
                with_threads(threads, || {
                    let mut values = self.field.evaluate(&mut cpu, &points, additive)?;
                    if !normalized {
                        range.denormalize_all(&mut values);
                    }
                    Ok(values)
                })?
            })
            .py_err()?;
        Ok(vector(py, values))
    }

    /// Writes the model to `path` (through a temporary file and a rename)
    /// with `payload` ("f32", "8bit", "8bit-u16" or "packed"; default the
    /// one it was read with or encoded for). Returns the bytes written.
    #[pyo3(signature = (path, payload=None))]
    fn write(&self, py: Python<'_>, path: PathBuf, payload: Option<&str>) -> PyResult<usize> {
        let model = self.unquantized.as_ref().map_or_else(|| self.one("write"), Ok)?;
        let payload = match payload {
            Some(name) => Payload::from_name(name).py_err()?,
            None => self.payload,
        };
        py.detach(|| -> gsenc::Result<usize> {
            let bytes = write_model_as(model, payload)?;
            write_atomic(&path, &bytes)?;
            Ok(bytes.len())
        })
        .py_err()
    }

    /// Every header field (a step index: its merged metadata, its pieces and halo).
    #[getter]
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let json = py.import("json")?;
        json.call_method1("loads", (Value::Object(self.info.clone()).to_string(),))?.cast_into::<PyDict>().map_err(Into::into)
    }

    /// Voxel PSNR (dB) of the model as stored against its reference, when known.
    #[getter]
    fn psnr(&self) -> Option<f64> {
        self.psnr
    }

    /// The reference lattice's dims (x, y, z).
    #[getter]
    fn dims(&self) -> (usize, usize, usize) {
        let [x, y, z] = self.field.merged().meta.frame.dims;
        (x, y, z)
    }

    /// World position of voxel (0, 0, 0)'s centre and the voxel size, on a
    /// lattice of `dims` (default the model's own) over the model's box.
    #[pyo3(signature = (dims=None))]
    fn geometry(&self, dims: Option<[usize; 3]>) -> ((f64, f64, f64), (f64, f64, f64)) {
        let f = &self.field.merged().meta.frame;
        let dims = dims.unwrap_or(f.dims);
        let s = [0, 1, 2].map(|i| f.dims[i] as f64 / dims[i].max(1) as f64 / f.gamma);
        let o = [0, 1, 2].map(|i| f.bmin[i] + 0.5 * s[i]);
        ((o[0], o[1], o[2]), (s[0], s[1], s[2]))
    }

    /// The primitives, one row of 12 float32 each: centre (3, index frame),
    /// log scales (3), rotation quaternion (4), alpha, beta.
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let p = &self.field.merged().params;
        let flat: Vec<f32> = p.iter().flatten().copied().collect();
        let a = numpy::ndarray::Array2::from_shape_vec((p.len(), 12), flat).map_err(|e| PyValueError::new_err(e.to_string()))?;
        Ok(numpy::IntoPyArray::into_pyarray(a, py))
    }

    /// The primitives as a structured array of `gsenc.PRIMITIVE_DTYPE`
    /// (fields mu, log_scale, quat, alpha, beta).
    #[getter]
    fn primitives<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let dtype = py.import("gsenc")?.getattr("PRIMITIVE_DTYPE")?;
        self.params(py)?.call_method1("view", (dtype,))?.call_method1("reshape", (self.field.merged().len(),))
    }

    fn __len__(&self) -> usize {
        self.field.merged().len()
    }

    fn __repr__(&self) -> String {
        let m = &self.field.merged().meta;
        let pieces = match self.field.pieces().len() {
            1 => String::new(),
            n => format!(", {n} pieces"),
        };
        format!("<gsenc.Model '{}' step {}: {} primitives on {:?}{pieces}>", m.field, m.step, self.field.merged().len(), m.frame.dims)
    }
}
