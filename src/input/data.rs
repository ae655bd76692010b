//! Owned input: a step's arrays copied out of the caller's memory.

use crate::error::Result;
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

    /// What a push refuses at once, so that the failing push is the one
    /// that passed it rather than a later encode: non-finite values, and
    /// every particle or cell as the encode will check it
    /// ([`Particles::validate_each`], [`Cells::validate_each`]: finite
    /// positions, positive finite smoothing lengths and sizes, masses
    /// finite and not negative). On the calling thread alone (no rayon
    /// pool). A rank of a decomposed field sends its items to the pieces
    /// they reach: a bad one would fail an encode elsewhere or go nowhere.
    /// None at all is no fault here (a rank of a decomposed field may hold
    /// none).
    pub fn check_each(&self) -> Result<()> {
        match self {
            StepData::Grid { grid, .. } => check_finite(&grid.values),
            StepData::Particles { values, .. } | StepData::Cells { values, .. } => {
                check_finite(values)?;
                self.with_input(|input| match input {
                    Input::Particles { particles, .. } => particles.validate_each(true),
                    Input::Cells { cells, .. } => cells.validate_each(true),
                    _ => Ok(()),
                })
            }
        }
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

