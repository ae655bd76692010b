"""Fixtures of the plugins' tests (run by tests/plugins.sh, headless).

GSENC_BIN names the command-line tool (built with HDF5), GSENC_PLUGIN_DIR
the installed lib/ folder holding libgsenc_adios2_operator.so and
libgsenc.so.0, GSENC_LIBRARY the latter (the reader's ctypes path), and
GSENC_PARAVIEW_DIR the installed reader's folder. All but the last are
required: a test never skips.
"""

import importlib.util
import os
import sys

import numpy as np
import pytest

# The Python package's test fixtures (gsenc_bin: GSENC_BIN; cli: runs the
# tool), shared rather than written again.
_root = os.path.join(os.path.dirname(__file__), "..", "..")
_spec = importlib.util.spec_from_file_location("gsenc_python_tests", os.path.join(_root, "python", "tests", "conftest.py"))
_shared = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_shared)
gsenc_bin, cli, write_step_index = _shared.gsenc_bin, _shared.cli, _shared.write_step_index

# The reader as installed (tests/plugins.sh), else the checkout's.
sys.path.insert(0, os.environ.get("GSENC_PARAVIEW_DIR") or os.path.join(os.path.dirname(__file__), "..", "paraview"))


@pytest.fixture(scope="session")
def plugin_dir():
    return _shared._required("GSENC_PLUGIN_DIR")


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
