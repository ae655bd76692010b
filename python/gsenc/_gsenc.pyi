"""Types of the native module `gsenc._gsenc` (use it through `gsenc`)."""

from os import PathLike
from typing import Any, Callable, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str
HAS_HDF5: bool

_Path = Union[str, "PathLike[str]"]
_Dims = Tuple[int, int, int]
_Box = Tuple[int, int, int, int, int, int]
_Progress = Optional[Callable[[int, int, float], Any]]

class ModelError(ValueError):
    """A model file, store entry or step index that is corrupted, foreign or written by a newer gsenc."""

class Model:
    """A model, or a step's global field (several pieces blended across their halos)."""

    def decode(
        self,
        dims: Optional[_Dims] = None,
        box: Optional[_Box] = None,
        normalized: bool = False,
        additive: bool = False,
        threads: Optional[int] = None,
        backend: str = "auto",
    ) -> npt.NDArray[np.float32]:
        """float32 [z][y][x] on a lattice of dims (x, y, z) over the model's box, or its part box; data units unless normalized."""
    def evaluate(self, points: npt.ArrayLike, normalized: bool = False, additive: bool = False, threads: Optional[int] = None) -> npt.NDArray[np.float32]:
        """The value at world points ((n, 3): x, y, z); a step's pieces blended unless additive. A point's value is the same bits whatever is asked beside it."""
    def write(self, path: _Path, payload: Optional[str] = None) -> int:
        """Writes the model ("f32", "8bit", "8bit-u16" or "packed"); returns the bytes written."""
    def geometry(self, dims: Optional[_Dims] = None) -> Tuple[Tuple[float, float, float], Tuple[float, float, float]]:
        """World position of voxel (0, 0, 0)'s centre and the voxel size on a lattice of dims."""
    def params(self) -> npt.NDArray[np.float32]:
        """(n, 12) float32: mu (3), log scales (3), quaternion (4), alpha, beta."""
    @property
    def primitives(self) -> np.ndarray:
        """The primitives as a structured array of gsenc.PRIMITIVE_DTYPE."""
    @property
    def info(self) -> dict[str, Any]:
        """Every header field."""
    @property
    def psnr(self) -> Optional[float]:
        """Voxel PSNR (dB) of the model as stored against its reference, when known."""
    @property
    def dims(self) -> _Dims:
        """The reference lattice's dims (x, y, z)."""
    def __len__(self) -> int: ...

class Store:
    """An HDF5 store of models, as listed when opened."""

    @property
    def entries(self) -> list[dict[str, Any]]:
        """Every entry: field, step, rank, payload, primitives, bytes and time
        (the simulation time, None when the model carries none), or error
        (why it cannot be read, such as an append cut short)."""
    @property
    def path(self) -> str: ...
    def fields(self) -> list[str]: ...
    def steps(self, field: str) -> list[int]: ...
    def ranks(self, field: str, step: int) -> list[int]: ...
    def read(self, field: Optional[str] = None, step: Optional[int] = None, rank: Optional[int] = None) -> Model: ...
    def verify(self) -> list[dict[str, Any]]:
        """Reads and checks every entry and step index: dicts of item, ok, and
        checksum (False for an entry written before store layout 1.4) or error."""
    def __len__(self) -> int: ...

def read(path: _Path, field: Optional[str] = None, step: Optional[int] = None, rank: Optional[int] = None) -> Model: ...
def open_store(path: _Path) -> Store: ...
def encode_grid(array: np.ndarray, origin: Tuple[float, float, float], spacing: float, options: dict[str, Any], progress: _Progress = None) -> Model: ...
def encode_particles(
    positions: np.ndarray, smoothing_length: np.ndarray, values: np.ndarray, mass: Optional[np.ndarray], place: dict[str, Any], options: dict[str, Any], progress: _Progress = None
) -> Model: ...
def encode_cells(
    centers: np.ndarray, values: np.ndarray, sizes: Optional[np.ndarray], volumes: Optional[np.ndarray], place: dict[str, Any], options: dict[str, Any], progress: _Progress = None
) -> Model: ...

class Series:
    """A time series' encoder (use it through gsenc.Series)."""

    def __init__(
        self, options: dict[str, Any], warm: str, warm_iterations: Optional[int] = None, validation_points: int = 0, validation_every: int = 50
    ) -> None: ...
    def encode_grid(
        self, array: np.ndarray, origin: Tuple[float, float, float], spacing: float, field: str, step: int, time: Optional[float] = None, progress: _Progress = None
    ) -> Model: ...
    def encode_particles(
        self,
        positions: np.ndarray,
        smoothing_length: np.ndarray,
        values: np.ndarray,
        mass: Optional[np.ndarray],
        place: dict[str, Any],
        field: str,
        step: int,
        time: Optional[float] = None,
        progress: _Progress = None,
    ) -> Model: ...
    def encode_cells(
        self,
        centers: np.ndarray,
        values: np.ndarray,
        sizes: Optional[np.ndarray],
        volumes: Optional[np.ndarray],
        place: dict[str, Any],
        field: str,
        step: int,
        time: Optional[float] = None,
        progress: _Progress = None,
    ) -> Model: ...
    def resume(self, model: Model) -> None: ...
