//! Owned input: a step's arrays copied out of the caller's memory.

use crate::error::{Error, Result};
use crate::field::{check_finite_serial as check_finite, Grid, IndexFrame};
use crate::input::cells::{CellSize, Cells};
use crate::input::particles::Particles;
use crate::input::prepare::{Input, Placement};

/// One field of one step, owned: what the background queue holds after a
/// push has copied the caller's arrays, and what MPI routes between ranks.
pub enum StepData {
    /// A grid over `frame`, in data units.
    Grid { grid: Grid, frame: IndexFrame },
    /// SPH particles, deposited on `placement`.
    Particles { positions: Vec<[f64; 3]>, smoothing_length: Vec<f64>, mass: Vec<f32>, values: Vec<f32>, placement: Placement },
    /// Cells as centres with edge lengths (`volumes` empty) or with volumes
    /// (`edges` empty), deposited on `placement`.
    Cells { centres: Vec<[f64; 3]>, edges: Vec<[f64; 3]>, volumes: Vec<f64>, values: Vec<f32>, placement: Placement },
}

impl StepData {
    /// The memory the copy holds.
    pub fn bytes(&self) -> usize {
        match self {
            StepData::Grid { grid, .. } => grid.values.len() * 4,
            StepData::Particles { positions, values, .. } => positions.len() * 24 + values.len() * (8 + 4 + 4),
            StepData::Cells { centres, edges, volumes, values, .. } => {
                centres.len() * 24 + edges.len() * 24 + volumes.len() * 8 + values.len() * 4
            }
        }
    }

    /// Refuses non-finite values now, so the failing push is the one that
    /// passed them rather than a later encode. Runs on the calling thread
    /// only (no rayon pool).
    pub fn check_finite(&self) -> Result<()> {
        match self {
            StepData::Grid { grid, .. } => check_finite(&grid.values),
            StepData::Particles { positions, smoothing_length, mass, values, .. } => {
                check_finite(values)?;
                check_finite(mass)?;
                if positions.iter().flatten().chain(smoothing_length).any(|v| !v.is_finite()) {
                    return Err(Error::data("a particle position or smoothing length is not finite"));
                }
                Ok(())
            }
            StepData::Cells { centres, edges, volumes, values, .. } => {
                check_finite(values)?;
                if centres.iter().chain(edges).flatten().chain(volumes).any(|v| !v.is_finite()) {
                    return Err(Error::data("a cell centre, edge length or volume is not finite"));
                }
                Ok(())
            }
        }
    }

    /// [`Self::check_finite`], and every particle or cell as the encode
    /// will check it ([`Particles::validate_each`],
    /// [`Cells::validate_each`]: positive smoothing lengths and sizes,
    /// masses not negative), on the calling thread alone: a push refuses a
    /// bad item at once rather than its encode later, and a rank of a
    /// decomposed field, whose items go to the pieces they reach, before a
    /// bad one fails an encode elsewhere or goes nowhere. None at all is no
    /// fault here (a rank of a decomposed field may hold none).
    pub fn check_each(&self) -> Result<()> {
        self.check_finite()?;
        self.with_input(|input| match input {
            Input::Particles { particles, .. } => particles.validate_each(true),
            Input::Cells { cells, .. } => cells.validate_each(true),
            _ => Ok(()),
        })
    }

    /// Runs `f` on this data as an [`Input`].
    pub fn with_input<R>(&self, f: impl FnOnce(Input) -> R) -> R {
        match self {
            StepData::Grid { grid, frame } => f(Input::Grid { values: grid, frame: *frame }),
            StepData::Particles { positions, smoothing_length, mass, values, placement } => {
                let particles = Particles { positions, smoothing_length, mass, values };
                f(Input::Particles { particles: &particles, placement: *placement })
            }
            StepData::Cells { centres, edges, volumes, values, placement } => {
                let size = if volumes.is_empty() { CellSize::Edges(edges) } else { CellSize::Volumes(volumes) };
                let cells = Cells { centres, size, values };
                f(Input::Cells { cells: &cells, placement: *placement })
            }
        }
    }
}

