"""Types of the package `gsenc` (see gsenc/__init__.py for the full documentation)."""

from os import PathLike
from typing import Any, Callable, Optional, Sequence, Tuple, Union

import numpy as np

from ._gsenc import HAS_HDF5 as HAS_HDF5, Model as Model, ModelError as ModelError, Store as Store, __version__ as __version__

_Path = Union[str, "PathLike[str]"]
_Vec3 = Tuple[float, float, float]
_Progress = Union[None, bool, Callable[[int, int, float], Any]]

PRIMITIVE_DTYPE: np.dtype

def read(path: _Path, field: Optional[str] = None, step: Optional[int] = None, rank: Optional[int] = None) -> Model: ...
def open_store(path: _Path) -> Store: ...
def encode_grid(
    array: np.ndarray,
    budget: Optional[int] = None,
    *,
    target_psnr: Optional[float] = None,
    schedule: str = "matched",
    range: Optional[Tuple[float, float]] = None,
    log10: bool = False,
    origin: _Vec3 = (0.0, 0.0, 0.0),
    spacing: float = 1.0,
    payload: str = "f32",
    field: str = "scalar",
    step: int = 0,
    time: Optional[float] = None,
    rank: int = 0,
    iterations: Optional[int] = None,
    points: Optional[int] = None,
    seed: int = 0,
    sample_seed: int = 1,
    relocation: bool = True,
    support: bool = True,
    threads: Optional[int] = None,
    backend: str = "auto",
    progress: _Progress = None,
) -> Model: ...
def encode_particles(
    positions: np.ndarray,
    smoothing_length: np.ndarray,
    values: np.ndarray,
    mass: Optional[np.ndarray] = None,
    *,
    budget: Optional[int] = None,
    target_psnr: Optional[float] = None,
    dims: Optional[Tuple[int, int, int]] = None,
    fit_dims: Optional[int] = None,
    bounds: Optional[Tuple[_Vec3, _Vec3]] = None,
    schedule: str = "matched",
    range: Optional[Tuple[float, float]] = None,
    log10: bool = False,
    payload: str = "f32",
    field: str = "scalar",
    step: int = 0,
    time: Optional[float] = None,
    rank: int = 0,
    iterations: Optional[int] = None,
    points: Optional[int] = None,
    seed: int = 0,
    sample_seed: int = 1,
    relocation: bool = True,
    support: bool = True,
    threads: Optional[int] = None,
    backend: str = "auto",
    progress: _Progress = None,
) -> Model: ...
def encode_cells(
    centers: np.ndarray,
    values: np.ndarray,
    sizes: Optional[np.ndarray] = None,
    volumes: Optional[np.ndarray] = None,
    *,
    budget: Optional[int] = None,
    target_psnr: Optional[float] = None,
    dims: Optional[Tuple[int, int, int]] = None,
    fit_dims: Optional[int] = None,
    bounds: Optional[Tuple[_Vec3, _Vec3]] = None,
    schedule: str = "matched",
    range: Optional[Tuple[float, float]] = None,
    log10: bool = False,
    payload: str = "f32",
    field: str = "scalar",
    step: int = 0,
    time: Optional[float] = None,
    rank: int = 0,
    iterations: Optional[int] = None,
    points: Optional[int] = None,
    seed: int = 0,
    sample_seed: int = 1,
    relocation: bool = True,
    support: bool = True,
    threads: Optional[int] = None,
    backend: str = "auto",
    progress: _Progress = None,
) -> Model: ...

class Series:
    def __init__(
        self,
        budget: Optional[int] = None,
        *,
        target_psnr: Optional[float] = None,
        warm: str = "auto",
        warm_iterations: Optional[int] = None,
        validation_points: int = 0,
        validation_every: int = 50,
        schedule: str = "matched",
        range: Optional[Tuple[float, float]] = None,
        log10: bool = False,
        payload: str = "f32",
        rank: int = 0,
        iterations: Optional[int] = None,
        points: Optional[int] = None,
        seed: int = 0,
        sample_seed: int = 1,
        relocation: bool = True,
        support: bool = True,
        threads: Optional[int] = None,
        backend: str = "auto",
    ) -> None: ...
    def encode_grid(
        self,
        array: np.ndarray,
        *,
        step: int,
        field: str = "scalar",
        time: Optional[float] = None,
        origin: _Vec3 = (0.0, 0.0, 0.0),
        spacing: float = 1.0,
        progress: _Progress = None,
    ) -> Model: ...
    def encode_particles(
        self,
        positions: np.ndarray,
        smoothing_length: np.ndarray,
        values: np.ndarray,
        mass: Optional[np.ndarray] = None,
        *,
        step: int,
        field: str = "scalar",
        time: Optional[float] = None,
        dims: Optional[Tuple[int, int, int]] = None,
        fit_dims: Optional[int] = None,
        bounds: Optional[Tuple[_Vec3, _Vec3]] = None,
        progress: _Progress = None,
    ) -> Model: ...
    def encode_cells(
        self,
        centers: np.ndarray,
        values: np.ndarray,
        sizes: Optional[np.ndarray] = None,
        volumes: Optional[np.ndarray] = None,
        *,
        step: int,
        field: str = "scalar",
        time: Optional[float] = None,
        dims: Optional[Tuple[int, int, int]] = None,
        fit_dims: Optional[int] = None,
        bounds: Optional[Tuple[_Vec3, _Vec3]] = None,
        progress: _Progress = None,
    ) -> Model: ...
    def resume(self, model: Model) -> None: ...
