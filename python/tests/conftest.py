"""Shared fixtures of the Python package's tests (run by tests/python.sh).

GSENC_BIN names the command-line tool the decodes are compared with, and
GSENC_MOCK_SOLVER the C mock solver (built against libgsenc with HDF5) that
writes a store through the C API. Both are required: a test never skips.
"""

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
