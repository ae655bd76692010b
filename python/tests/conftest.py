"""Shared fixtures of the Python package's tests (run by tests/python.sh).

GSENC_BIN names the command-line tool the decodes are compared with, and
GSENC_MOCK_SOLVER the C mock solver (built against libgsenc with HDF5) that
writes a store through the C API. Both are required: a test never skips.
"""

import json
import os
import subprocess

import numpy as np
import pytest


def _required(name):
    path = os.environ.get(name)
    if not path or not os.path.exists(path):
        raise RuntimeError(f"{name} must name an existing file (tests/python.sh sets it)")
    return path


@pytest.fixture(scope="session")
def gsenc_bin():
    return _required("GSENC_BIN")


@pytest.fixture(scope="session")
def mock_solver():
    return _required("GSENC_MOCK_SOLVER")


@pytest.fixture(scope="session")
def cli(gsenc_bin):
    """Runs the tool; fails the test with its stderr when it fails."""

    def run(*args):
        done = subprocess.run([gsenc_bin, *map(str, args)], capture_output=True, text=True)
        assert done.returncode == 0, f"gsenc {' '.join(map(str, args))}: {done.stderr}"
        return done.stdout

    return run


def blobs(dims=(24, 20, 16)):
    """Two Gaussian blobs on a lattice of dims (x, y, z): float64 [z][y][x], values 0..~200."""
    x, y, z = (np.arange(n, dtype=np.float64) for n in dims)
    Z, Y, X = np.meshgrid(z, y, x, indexing="ij")
    a = np.exp(-((X - 8) ** 2 + (Y - 9) ** 2 + (Z - 7) ** 2) / 18.0)
    b = np.exp(-((X - 17) ** 2 + (Y - 12) ** 2 + (Z - 9) ** 2) / 8.0)
    return 200.0 * (a + 0.7 * b)


#: A short encode: enough to test plumbing and parity in about a second.
QUICK = dict(schedule="short", iterations=40, points=512, threads=1, backend="cpu")


def read_raw(path, dims):
    """A raw float32 file the tool wrote, as [z][y][x]."""
    return np.fromfile(path, dtype="<f4").reshape(dims[2], dims[1], dims[0])


def write_step_index(folder, field, encode, halo=4, vrange=(0.0, 220.0)):
    """Two pieces of ``field`` ([z][y][x], 32 wide in x), overlapping by
    ``2 * halo`` voxels in x, each encoded on its own box by ``encode(part,
    origin, rank)`` and written as rho_000004.gsm and rho_000004_r1.gsm,
    named by a step index rho_000004.gsi in ``folder``; returns its path."""
    nz, ny, nx = field.shape
    lo, hi = [(0, 0, 0), (nx // 2 - halo, 0, 0)], [(nx // 2 + halo, ny, nz), (nx, ny, nz)]
    pieces = []
    for rank in (0, 1):
        part = field[:, :, lo[rank][0]:hi[rank][0]]
        name = "rho_000004.gsm" if rank == 0 else "rho_000004_r1.gsm"
        encode(part, (lo[rank][0], 0, 0), rank).write(folder / name)
        pieces.append(dict(rank=rank, model=name, lo=list(lo[rank]), hi=list(hi[rank]),
                           world_min=[lo[rank][a] - 0.5 for a in range(3)], world_max=[hi[rank][a] - 0.5 for a in range(3)]))
    index = dict(format="gsenc-step-index", version=1, field="rho", step=4, time=None, ranks=2, halo=halo,
                 range=dict(vmin=vrange[0], vmax=vrange[1], transform="linear"), dims=[nx, ny, nz], bmin=[-0.5, -0.5, -0.5],
                 gamma=1.0, pieces=pieces)
    path = folder / "rho_000004.gsi"
    path.write_text(json.dumps(index))
    return path
