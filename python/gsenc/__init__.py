"""gsenc: 3D scalar fields as a fixed budget of anisotropic Gaussians.

Read models written by a simulation (``.gsm`` files, a step's ``.gsi``
index, entries of an HDF5 store), decode them at any resolution into numpy
arrays, evaluate them anywhere, and encode numpy arrays, SPH particles or
hexahedral cells into new models. A thin layer over the Rust library gsenc:
the same readers, decoder and encode pipeline as the ``gsenc`` command-line
tool and the C API, so a decode here is bit for bit the tool's.

A time series goes through :class:`Series`: each step of a field starts
from its previous step's model.

Arrays are C order ``[z][y][x]`` (x varies fastest), as the tool writes
them. Errors raise ``ValueError`` (bad arguments or data), ``OSError``
(files), :class:`ModelError` (a ``ValueError``: a corrupted, foreign or
newer model file) or ``KeyboardInterrupt`` (Ctrl-C during an encode).
"""

from __future__ import annotations

import sys

import numpy as np

from . import _gsenc
from ._gsenc import HAS_HDF5, Model, ModelError, __version__

#: An HDF5 store as :func:`open_store` lists it (None without HDF5).
Store = getattr(_gsenc, "Store", None)

__all__ = [
    "HAS_HDF5",
    "Model",
    "ModelError",
    "PRIMITIVE_DTYPE",
    "Series",
    "Store",
    "__version__",
    "encode_cells",
    "encode_grid",
    "encode_particles",
    "open_store",
    "read",
]

#: One primitive of :attr:`Model.primitives`: centre in the model's index
#: frame (voxel units of its reference lattice), log scales, rotation
#: quaternion (w, x, y, z), ``alpha`` (the value's logit) and ``beta`` (the
#: weight's log).
PRIMITIVE_DTYPE = np.dtype(
    [("mu", "<f4", (3,)), ("log_scale", "<f4", (3,)), ("quat", "<f4", (4,)), ("alpha", "<f4"), ("beta", "<f4")]
)


def read(path, field=None, step=None, rank=None) -> Model:
    """Reads a model file (``.gsm``), a step index (``.gsi``: every rank's
    model of one step, decoded as one global field blended across the
    halos), or an entry of an HDF5 store (``field``, ``step``, ``rank``; any
    may be left out where the store holds one choice; without ``rank``, a
    step of several ranks whose step index the store holds is its global
    field, as from the ``.gsi``)."""
    return _gsenc.read(str(path), field, step, rank)


def open_store(path):
    """Lists an HDF5 store: ``.entries`` (dicts of field, step, rank,
    payload, primitives, bytes, time: the simulation time or None),
    ``.fields()``, ``.steps(field)``, ``.ranks(field, step)`` and
    ``.read(field, step, rank)``."""
    if not HAS_HDF5:
        raise ValueError("this gsenc was built without HDF5")
    return _gsenc.open_store(str(path))


class _Bar:
    """A text progress bar on stderr, for when tqdm is not installed."""

    def __init__(self):
        self.last = -1

    def __call__(self, iteration, iterations, loss):
        done = int(40 * iteration / max(iterations, 1))
        if done != self.last or iteration == iterations:
            self.last = done
            end = "\n" if iteration == iterations else ""
            sys.stderr.write(f"\r[{'=' * done}{' ' * (40 - done)}] {iteration}/{iterations} it  loss {loss:.3e}{end}")
            sys.stderr.flush()

    def close(self):
        pass


class _Tqdm:
    def __init__(self, tqdm):
        self.tqdm, self.bar = tqdm, None

    def __call__(self, iteration, iterations, loss):
        if self.bar is None:
            self.bar = self.tqdm(total=iterations, unit="it")
        self.bar.update(iteration - self.bar.n)
        self.bar.set_postfix(loss=f"{loss:.3e}", refresh=False)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _progress(progress):
    """``progress``: None/False (silent), True (tqdm when installed, else a
    text bar) or a callable ``f(iteration, iterations, loss)``."""
    if progress is None or progress is False:
        return None
    if progress is True:
        try:
            from tqdm.auto import tqdm
        except ImportError:
            return _Bar()
        return _Tqdm(tqdm)
    if callable(progress):
        return progress
    raise TypeError("progress: True, False or a callable f(iteration, iterations, loss)")


def _run(call, progress):
    report = _progress(progress)
    try:
        return call(report)
    finally:
        if report is not None and hasattr(report, "close"):
            report.close()


def _options(budget, target_psnr, schedule, range, log10, payload, field, step, time, rank, iterations, points, seed,
             sample_seed, relocation, support, threads, backend):
    return dict(budget=budget, target_psnr=target_psnr, schedule=schedule, range=range, log10=log10, payload=payload, field=field, step=step,
                time=time, rank=rank, iterations=iterations, points=points, seed=seed, sample_seed=sample_seed,
                relocation=relocation, support=support, threads=threads, backend=backend)


def encode_grid(array, budget=None, *, target_psnr=None, schedule="matched", range=None, log10=False, origin=(0.0, 0.0, 0.0), spacing=1.0,
                payload="f32", field="scalar", step=0, time=None, rank=0, iterations=None, points=None, seed=0, sample_seed=1,
                relocation=True, support=True, threads=None, backend="auto", progress=None) -> Model:
    """Encodes a 3D array ``[z][y][x]`` into ``budget`` Gaussians, or into
    as many as reach ``target_psnr`` (dB, the voxel PSNR as stored; then
    ``budget`` is the most it may choose, default one per 32 voxels that
    hold data; docs/METHOD.md "A quality instead of a budget"), the search
    reported in ``model.info["target"]`` as the tool's encode prints it
    (whether it landed, the cap, every probe and try, the slopes).

    ``array``: any of uint8/int8/uint16/int16/uint32/int32/uint64/int64/
    float32/float64, any strides (read in place). ``schedule``: "short",
    "matched" (the paper's), "full", "tuned" or "tuned-full". ``range``: (lo, hi) in data
    units, default the data's own; ``log10`` encodes log10 of the values.
    ``origin`` is the world position of voxel (0, 0, 0)'s centre and
    ``spacing`` the voxel size. ``payload`` ("f32", "8bit", "8bit-u16",
    "packed") is what the model will be written with: its PSNR is measured
    as stored. ``support`` stores where the data are (decodes to 0 elsewhere).
    ``field``, ``step``, ``time`` and ``rank`` label the model (a domain's
    piece: its MPI rank, as a step index names it).
    ``progress``: True for a bar, or ``f(iteration, iterations, loss)``.
    Returns the model; ``model.psnr`` is its voxel PSNR against the array.
    The GIL is released while it runs; Ctrl-C stops it."""
    o = _options(budget, target_psnr, schedule, range, log10, payload, field, step, time, rank, iterations, points, seed,
                 sample_seed, relocation, support, threads, backend)
    return _run(lambda report: _gsenc.encode_grid(array, origin, spacing, o, report), progress)


def _place(dims, fit_dims, bounds):
    # Passed as given: the native side converts them, refusing a fraction
    # of a voxel and naming the argument it cannot take.
    return dict(dims=dims, fit_dims=fit_dims, bounds=bounds)


def encode_particles(positions, smoothing_length, values, mass=None, *, budget=None, target_psnr=None, dims=None, fit_dims=None, bounds=None,
                     schedule="matched", range=None, log10=False, payload="f32", field="scalar", step=0, time=None,
                     rank=0, iterations=None, points=None, seed=0, sample_seed=1, relocation=True, support=True, threads=None,
                     backend="auto", progress=None) -> Model:
    """Encodes SPH particles (``positions`` (n, 3), ``smoothing_length`` (n,),
    ``values`` (n,), ``mass`` (n,) default 1) against their deposit on a
    lattice of ``dims`` (x, y, z), or of ``fit_dims`` voxels along the longest
    axis of ``bounds`` ((min x, y, z), (max x, y, z); default the particles').
    Other options as :func:`encode_grid`."""
    o = _options(budget, target_psnr, schedule, range, log10, payload, field, step, time, rank, iterations, points, seed,
                 sample_seed, relocation, support, threads, backend)
    place = _place(dims, fit_dims, bounds)
    return _run(lambda report: _gsenc.encode_particles(positions, smoothing_length, values, mass, place, o, report),
                progress)


def encode_cells(centers, values, sizes=None, volumes=None, *, budget=None, target_psnr=None, dims=None, fit_dims=None, bounds=None,
                 schedule="matched", range=None, log10=False, payload="f32", field="scalar", step=0, time=None,
                 rank=0, iterations=None, points=None, seed=0, sample_seed=1, relocation=True, support=True, threads=None,
                 backend="auto", progress=None) -> Model:
    """Encodes hexahedral (AMR) cells (``centers`` (n, 3), ``values`` (n,),
    and either ``sizes`` (n, 3) edge lengths or ``volumes`` (n,)) against
    their volume-weighted deposit; placement as :func:`encode_particles`,
    other options as :func:`encode_grid`."""
    o = _options(budget, target_psnr, schedule, range, log10, payload, field, step, time, rank, iterations, points, seed,
                 sample_seed, relocation, support, threads, backend)
    place = _place(dims, fit_dims, bounds)
    return _run(lambda report: _gsenc.encode_cells(centers, values, sizes, volumes, place, o, report), progress)


class Series:
    """A time series encoded step by step: each field's first step as
    :func:`encode_grid` would (the same options), each later step
    warm-started from the field's previous model on the first step's lattice
    and value range (docs/METHOD.md "Warm start"), as ``gsenc
    encode-series`` and the C API's encoders do. Fields are independent
    series; a field's steps must increase and share its lattice (particles
    and cells of later steps are deposited in the first step's box).

    ``warm``: "auto" (the previous model, repaired where it misses, or a
    fresh seeding, whichever validates best), "off" (each step on its own),
    "coarse" (1000 iterations, no relocation) or "dense" (1500, relocation
    on); ``warm_iterations`` caps a warm step's iterations.
    ``validation_points`` (default 0, as the C API's encoders) fixed points
    of the first step's lattice score every step each ``validation_every``
    iterations, as ``gsenc encode-series`` does (its default 65536 and 50:
    the same options give its models byte for byte); an ``auto`` warm step
    decides by them, or by 16,384 points of its own. ``range``: (lo,
    hi) for every step, default the first step's own (later steps clamp
    values outside it: a model's ``info["clamped_values"]`` counts them).
    ``rank`` labels the models. One backend is opened for the whole series.

    A step returns its model as :func:`encode_grid` does (``info`` adds
    ``warm_started``, ``clamped_values``, ``outside_items``: particles or
    cells outside the first step's box, and ``validation``: [iteration,
    PSNR] pairs of the validation scores, the rows of ``encode-series
    --csv``). Steps run one at a time; a
    step that fails (bad data, Ctrl-C) leaves the series as it was."""

    def __init__(self, budget=None, *, target_psnr=None, warm="auto", warm_iterations=None, validation_points=0, validation_every=50,
                 schedule="matched", range=None, log10=False, payload="f32", rank=0, iterations=None, points=None, seed=0, sample_seed=1,
                 relocation=True, support=True, threads=None, backend="auto"):
        o = _options(budget, target_psnr, schedule, range, log10, payload, None, None, None, rank, iterations, points, seed,
                     sample_seed, relocation, support, threads, backend)
        self._series = _gsenc.Series(o, warm, warm_iterations, validation_points, validation_every)

    def encode_grid(self, array, *, step, field="scalar", time=None, origin=(0.0, 0.0, 0.0), spacing=1.0, progress=None) -> Model:
        """Encodes a 3D array ``[z][y][x]`` as ``field``'s step ``step``
        (simulation time ``time``); ``array``, ``origin``, ``spacing`` and
        ``progress`` as :func:`encode_grid`."""
        return _run(lambda report: self._series.encode_grid(array, origin, spacing, field, step, time, report), progress)

    def encode_particles(self, positions, smoothing_length, values, mass=None, *, step, field="scalar", time=None, dims=None,
                         fit_dims=None, bounds=None, progress=None) -> Model:
        """Encodes SPH particles as ``field``'s step ``step``; arguments as
        :func:`encode_particles` (a later step's ``bounds`` are the first
        step's, whatever is given)."""
        place = _place(dims, fit_dims, bounds)
        return _run(lambda report: self._series.encode_particles(positions, smoothing_length, values, mass, place, field, step, time,
                                                                 report), progress)

    def encode_cells(self, centers, values, sizes=None, volumes=None, *, step, field="scalar", time=None, dims=None, fit_dims=None,
                     bounds=None, progress=None) -> Model:
        """Encodes hexahedral cells as ``field``'s step ``step``; arguments
        as :func:`encode_cells`."""
        place = _place(dims, fit_dims, bounds)
        return _run(lambda report: self._series.encode_cells(centers, values, sizes, volumes, place, field, step, time, report),
                    progress)

    def resume(self, model):
        """Continues the series of ``model``'s field from it, the last step
        stored before a run stopped: the field's next step (which must come
        after it) starts from it, on its lattice and value range, as if the
        series had not stopped. Before the field's first step only; the
        model must be of this series' rank and range (a given ``range``,
        or ``log10``). A model read from a float32 file, or returned by an
        encode, continues bit for bit; one read from a rounded payload
        starts from the parameters it stores."""
        self._series.resume(model)
