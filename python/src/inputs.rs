//! A call's numpy arrays as the library's encode inputs: copied out of
//! numpy while the GIL is held (any dtype, any strides), then lent to the
//! pipeline as an [`Input`] once the GIL is released. `gsenc.encode_*` and
//! `gsenc.Series.encode_*` take the same arrays through these.

use crate::args::named;
use crate::arrays::{grid_values, triples, values, values_f64};
use crate::errors::IntoPy;
use gsenc::field::{Bounds, Grid, IndexFrame};
use gsenc::input::cells::{CellSize, Cells};
use gsenc::input::particles::Particles;
use gsenc::input::{Input, Placement};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The data of one field of one step, owned.
pub enum Arrays {
    Grid { grid: Grid, frame: IndexFrame },
    Particles { positions: Vec<[f64; 3]>, smoothing_length: Vec<f64>, values: Vec<f32>, mass: Vec<f32>, placement: Placement },
    Cells { centres: Vec<[f64; 3]>, edges: Vec<[f64; 3]>, volumes: Vec<f64>, values: Vec<f32>, placement: Placement },
}

impl Arrays {
    /// A 3D array `[z][y][x]` whose voxel (0, 0, 0) is centred at `origin`,
    /// voxels `spacing` apart.
    pub fn grid(array: &Bound<'_, PyAny>, origin: [f64; 3], spacing: f64) -> PyResult<Arrays> {
        let (dims, values) = grid_values(array, "array")?;
        let grid = Grid::new(dims, values).py_err()?;
        let frame = IndexFrame::for_grid(dims, origin, spacing).py_err()?;
        Ok(Arrays::Grid { grid, frame })
    }

    /// SPH particles (mass 1 where none is given), deposited as `place` says.
    pub fn particles(
        positions: &Bound<'_, PyAny>,
        smoothing_length: &Bound<'_, PyAny>,
        values: &Bound<'_, PyAny>,
        mass: Option<&Bound<'_, PyAny>>,
        place: &Bound<'_, PyDict>,
    ) -> PyResult<Arrays> {
        let positions = triples(positions, "positions")?;
        let smoothing_length = values_f64(smoothing_length, "smoothing_length")?;
        let values = self::values(values, "values")?;
        let mass = match mass {
            Some(m) => self::values(m, "mass")?,
            None => vec![1.0; positions.len()],
        };
        let particles = Particles { positions: &positions, smoothing_length: &smoothing_length, mass: &mass, values: &values };
        // Checked before their box is taken (for fit_dims).
        particles.validate().py_err()?;
        let placement = placement(place, || particles.bounds())?;
        Ok(Arrays::Particles { positions, smoothing_length, values, mass, placement })
    }

    /// Hexahedral cells with their edge lengths (`sizes`) or their volumes.
    pub fn cells(
        centers: &Bound<'_, PyAny>,
        values: &Bound<'_, PyAny>,
        sizes: Option<&Bound<'_, PyAny>>,
        volumes: Option<&Bound<'_, PyAny>>,
        place: &Bound<'_, PyDict>,
    ) -> PyResult<Arrays> {
        let centres = triples(centers, "centers")?;
        let values = self::values(values, "values")?;
        let (edges, volumes) = match (sizes, volumes) {
            (Some(s), None) => (triples(s, "sizes")?, vec![]),
            (None, Some(v)) => (vec![], values_f64(v, "volumes")?),
            _ => return Err(PyValueError::new_err("give sizes (an (n, 3) array of cell edges) or volumes, one of them")),
        };
        let placement = {
            // Sized as given (an empty array of volumes is not edges), and
            // checked before their box is taken (for fit_dims); once checked,
            // the array given is the one that is not empty, as `cells` reads it.
            let size = if sizes.is_some() { CellSize::Edges(&edges) } else { CellSize::Volumes(&volumes) };
            let cells = Cells { centres: &centres, size, values: &values };
            cells.validate().py_err()?;
            placement(place, || cells.bounds())?
        };
        Ok(Arrays::Cells { centres, edges, volumes, values, placement })
    }

    /// Calls `f` with the arrays as the pipeline's input.
    pub fn with_input<R>(&self, f: impl FnOnce(Input<'_>) -> R) -> R {
        match self {
            Arrays::Grid { grid, frame } => f(Input::Grid { values: grid, frame: *frame }),
            Arrays::Particles { positions, smoothing_length, values, mass, placement } => {
                let particles = Particles { positions, smoothing_length, mass, values };
                f(Input::Particles { particles: &particles, placement: *placement })
            }
            Arrays::Cells { centres, edges, volumes, values, placement } => {
                let cells = cells(centres, edges, volumes, values);
                f(Input::Cells { cells: &cells, placement: *placement })
            }
        }
    }
}

/// Cells sized by their edges, or (none given) by their volumes.
fn cells<'a>(centres: &'a [[f64; 3]], edges: &'a [[f64; 3]], volumes: &'a [f64], values: &'a [f32]) -> Cells<'a> {
    let size = if volumes.is_empty() { CellSize::Edges(edges) } else { CellSize::Volumes(volumes) };
    Cells { centres, size, values }
}

/// Where particles or cells are deposited: `dims`, or `fit_dims` voxels
/// along the longest axis of `bounds` (default the data's).
fn placement(place: &Bound<'_, PyDict>, data_bounds: impl FnOnce() -> Bounds) -> PyResult<Placement> {
    let dims: Option<[usize; 3]> = place.get_item("dims")?.map(|v| named(&v, "dims")).transpose()?.flatten();
    let fit: Option<usize> = place.get_item("fit_dims")?.map(|v| named(&v, "fit_dims")).transpose()?.flatten();
    let bounds: Option<[[f64; 3]; 2]> = place.get_item("bounds")?.map(|v| named(&v, "bounds")).transpose()?.flatten();
    Placement::resolve(dims, fit, bounds.map(|[min, max]| Bounds { min, max }), data_bounds).py_err()
}
