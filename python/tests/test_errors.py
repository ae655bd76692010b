"""Every error path raises a Python exception with the library's message:
ValueError for bad arguments and data, OSError for files, gsenc.ModelError
for bad model files."""

import numpy as np
import pytest

import gsenc
from conftest import QUICK, blobs


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    path = tmp_path_factory.mktemp("errors") / "good.gsm"
    gsenc.encode_grid(blobs(), 40, **QUICK).write(path)
    return path


def test_files(tmp_path, good):
    with pytest.raises(FileNotFoundError, match="missing.gsm"):
        gsenc.read(tmp_path / "missing.gsm")
    (tmp_path / "foreign.gsm").write_bytes(b"not a model at all, just text")
    with pytest.raises(gsenc.ModelError, match="bad magic"):
        gsenc.read(tmp_path / "foreign.gsm")
    data = good.read_bytes()
    (tmp_path / "cut.gsm").write_bytes(data[: len(data) // 2])
    with pytest.raises(gsenc.ModelError, match="truncated"):
        gsenc.read(tmp_path / "cut.gsm")
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0x40
    (tmp_path / "flipped.gsm").write_bytes(bytes(flipped))
    with pytest.raises(gsenc.ModelError, match="checksum"):
        gsenc.read(tmp_path / "flipped.gsm")
    assert issubclass(gsenc.ModelError, ValueError)
    # Writing into a folder that does not exist fails and leaves nothing behind.
    with pytest.raises(OSError):
        gsenc.read(good).write(tmp_path / "no" / "such" / "dir" / "m.gsm")
    with pytest.raises(ValueError, match="payload"):
        gsenc.read(good).write(tmp_path / "m.gsm", payload="jpeg")
    assert not (tmp_path / "m.gsm").exists()
    # A step index naming a model that is not there.
    (tmp_path / "s.gsi").write_text('{"format": "gsenc-step-index"}')
    with pytest.raises(gsenc.ModelError):
        gsenc.read(tmp_path / "s.gsi")
    with pytest.raises(ValueError, match="HDF5 store"):
        gsenc.read(good, field="rho")
    with pytest.raises(OSError):
        gsenc.open_store(tmp_path / "missing.h5")


def test_decode_and_evaluate_arguments(good):
    m = gsenc.read(good)
    with pytest.raises(ValueError, match="lattice|positive"):
        m.decode(dims=(0, 4, 4))
    with pytest.raises(ValueError):
        m.decode(box=(0, 0, 0, 99, 4, 4))
    with pytest.raises(ValueError, match="backend"):
        m.decode(backend="tpu")
    with pytest.raises(ValueError, match="threads"):
        m.decode(threads=0)
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        m.evaluate(np.zeros((5, 2)))
    with pytest.raises(ValueError, match="not finite"):
        m.evaluate(np.array([[0.0, np.nan, 1.0]]))
    with pytest.raises(TypeError, match="numpy array"):
        m.evaluate([[0.0, 0.0, 0.0]])
    assert m.evaluate(np.zeros((0, 3))).shape == (0,)


def test_encode_arguments_and_data():
    field = blobs()
    with pytest.raises(ValueError, match="budget"):
        gsenc.encode_grid(field, 0, **QUICK)
    with pytest.raises(ValueError, match="schedule"):
        gsenc.encode_grid(field, 10, **{**QUICK, "schedule": "forever"})
    with pytest.raises(ValueError, match="2-dimensional"):
        gsenc.encode_grid(field[0], 10, **QUICK)
    with pytest.raises(ValueError, match="<U1"):
        gsenc.encode_grid(np.full((4, 4, 4), "a"), 10, **QUICK)
    with pytest.raises(TypeError, match="numpy array"):
        gsenc.encode_grid([[[1.0]]], 10, **QUICK)
    bad = field.copy()
    bad[3, 4, 5] = np.nan
    with pytest.raises(ValueError, match="finite|NaN"):
        gsenc.encode_grid(bad, 10, **QUICK)
    with pytest.raises(ValueError):
        gsenc.encode_grid(np.zeros((0, 4, 4)), 10, **QUICK)
    with pytest.raises(ValueError, match="range"):
        gsenc.encode_grid(field, 10, range=(5.0, 1.0), **QUICK)
    with pytest.raises(ValueError, match="field"):
        gsenc.encode_grid(field, 10, field="a/b", **QUICK)
    with pytest.raises(TypeError, match="progress"):
        gsenc.encode_grid(field, 10, progress="yes", **QUICK)
    pos = np.random.default_rng(1).uniform(0, 8, (50, 3))
    h, v = np.ones(50), np.ones(50)
    with pytest.raises(ValueError, match="dims"):
        gsenc.encode_particles(pos, h, v, budget=10, **QUICK)
    with pytest.raises(ValueError):
        gsenc.encode_particles(pos, h[:40], v, budget=10, dims=(8, 8, 8), **QUICK)
    with pytest.raises(ValueError, match="sizes"):
        gsenc.encode_cells(pos, v, budget=10, dims=(8, 8, 8), **QUICK)
    with pytest.raises(ValueError, match="not both"):
        gsenc.encode_cells(pos, v, volumes=h, budget=10, dims=(8, 8, 8), fit_dims=8, **QUICK)
    # The data's box (for fit_dims) is taken before the arrays are checked:
    # cells without sizes were read past their array there (a panic).
    for sizes, says in [(dict(volumes=np.ones(0)), "50 cell centres but 0 volumes"), (dict(sizes=np.ones((20, 3))), "but 20 edge-length")]:
        with pytest.raises(ValueError, match=says):
            gsenc.encode_cells(pos, v, **sizes, budget=10, fit_dims=8, **QUICK)
    bad = pos.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match="particle 7"):
        gsenc.encode_particles(bad, h, v, budget=10, fit_dims=8, **QUICK)


def test_copies_beyond_the_memory_are_refused(monkeypatch, good):
    """An array whose copy the process cannot take now raises ValueError
    before anything is allocated (a failed allocation would abort the
    interpreter), as does a decode onto a lattice beyond what a decode
    makes; with room again the same call works."""
    field = blobs()
    monkeypatch.setenv("GSENC_MEMORY_LIMIT", "1M")
    with pytest.raises(ValueError, match="the array's copy takes .* this process can take now"):
        gsenc.encode_grid(field, 40, **QUICK)
    monkeypatch.delenv("GSENC_MEMORY_LIMIT")
    assert len(gsenc.encode_grid(field, 40, **QUICK)) == 40
    with pytest.raises(ValueError, match="are too large"):
        gsenc.read(good).decode(dims=(5000, 5000, 5000))
