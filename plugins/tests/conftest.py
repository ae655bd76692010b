"""Fixtures of the plugins' tests (run by tests/plugins.sh, headless).

GSENC_BIN names the command-line tool (built with HDF5), GSENC_PLUGIN_DIR
the installed lib/ folder holding libgsenc_adios2_operator.so and
libgsenc.so.0, GSENC_LIBRARY the latter (the reader's ctypes path), and
GSENC_PARAVIEW_DIR the installed reader's folder. All but the last are
required: a test never skips.
"""

import os
import subprocess
import sys

import numpy as np
import pytest

# The reader as installed (tests/plugins.sh), else the checkout's.
sys.path.insert(0, os.environ.get("GSENC_PARAVIEW_DIR") or os.path.join(os.path.dirname(__file__), "..", "paraview"))


def _required(name):
    path = os.environ.get(name)
    if not path or not os.path.exists(path):
        raise RuntimeError(f"{name} must name an existing path (tests/plugins.sh sets it)")
    return path


@pytest.fixture(scope="session")
def gsenc_bin():
    return _required("GSENC_BIN")


@pytest.fixture(scope="session")
def plugin_dir():
    return _required("GSENC_PLUGIN_DIR")


@pytest.fixture(scope="session")
def cli(gsenc_bin):
    """Runs the tool; fails the test with its stderr when it fails."""

    def run(*args):
        done = subprocess.run([gsenc_bin, *map(str, args)], capture_output=True, text=True)
        assert done.returncode == 0, f"gsenc {' '.join(map(str, args))}: {done.stderr}"
        return done.stdout

    return run


def blobs(dims, shift=0.0):
    """Two Gaussian blobs on a lattice of dims (x, y, z): float64 [z][y][x], values 1..~7."""
    x, y, z = (np.arange(n, dtype=np.float64) for n in dims)
    Z, Y, X = np.meshgrid(z, y, x, indexing="ij")
    a = np.exp(-((X - 0.4 * dims[0] - shift) ** 2 + (Y - 0.5 * dims[1]) ** 2 + (Z - 0.55 * dims[2]) ** 2) / 40.0)
    b = np.exp(-((X - 0.7 * dims[0]) ** 2 + (Y - 0.3 * dims[1]) ** 2 + (Z - 0.35 * dims[2]) ** 2) / 18.0)
    return 1.0 + 5.0 * a + 2.0 * b


def psnr(decoded, reference):
    """Voxel PSNR (dB) on the reference's own value range, as gsenc measures it."""
    span = reference.max() - reference.min()
    mse = np.mean(((decoded - reference) / span) ** 2)
    return 10 * np.log10(1.0 / mse)
