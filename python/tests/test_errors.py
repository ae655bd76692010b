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


def test_numbers_of_the_wrong_kind_are_refused_by_name(good):
    """A lattice, a box or a count given as a fraction, a string or a
    negative number is refused, naming the argument: in the message for
    the encode options, a deposit's placement (they travel to the native
    side in a dict) and a decode's box, in the exception's note (pyo3's)
    for the native methods' other arguments. dims=(8.9, 8, 8) was truncated to 8 without a word, and a
    string for dims or origin raised int()'s or float()'s error, unnamed."""
    field = blobs()
    pos = np.random.default_rng(1).uniform(0, 8, (50, 3))
    h, v = np.ones(50), np.random.default_rng(2).uniform(1, 2, 50)
    for place, error, says in [
        (dict(dims=(8.9, 8, 8)), TypeError, "dims: 'float'"),
        (dict(dims="abc"), TypeError, "dims: 'str'"),
        (dict(dims=8), TypeError, "dims: 'int'"),
        (dict(dims=(8, 8)), ValueError, "dims: expected a sequence of length 3"),
        (dict(dims=(-8, 8, 8)), OverflowError, "dims: can't convert negative"),
        (dict(fit_dims=-4), OverflowError, "fit_dims: can't convert negative"),
        (dict(fit_dims=2**70), OverflowError, "fit_dims: int too big"),
        (dict(fit_dims=8, bounds=3), TypeError, "bounds: 'int'"),
        (dict(fit_dims=8, bounds=((0, 0, 0),)), ValueError, "bounds: expected a sequence of length 2"),
        (dict(fit_dims=8, bounds=((0, 0, 0), (1, "x", 1))), TypeError, "bounds: must be real number"),
    ]:
        with pytest.raises(error, match=says):
            gsenc.encode_particles(pos, h, v, budget=10, **place, **QUICK)
    for option, error, says in [
        (dict(budget=-3), OverflowError, "budget: can't convert negative"),
        (dict(budget=10, step=-1), OverflowError, "step: can't convert negative"),
        (dict(budget=10, rank=2**40), OverflowError, "rank: "),
        (dict(budget="ten"), TypeError, "budget: 'str'"),
        (dict(budget=10, range=(0.0,)), ValueError, "range: expected a sequence of length 2"),
    ]:
        with pytest.raises(error, match=says):
            gsenc.encode_grid(field, **option, **QUICK)

    def noted(call, error, name):
        with pytest.raises(error) as raised:
            call()
        assert f"while processing '{name}'" in getattr(raised.value, "__notes__", []), raised.value

    noted(lambda: gsenc.encode_grid(field, 10, origin="abc", **QUICK), TypeError, "origin")
    noted(lambda: gsenc.encode_grid(field, 10, spacing="one", **QUICK), TypeError, "spacing")
    noted(lambda: gsenc.Series(10, **QUICK).encode_grid(field, step=-1), OverflowError, "step")
    m = gsenc.read(good)
    noted(lambda: m.decode(dims=(-1, 4, 4)), OverflowError, "dims")
    with pytest.raises(OverflowError, match="box: int too big"):
        m.decode(box=(0, 0, 0, 2**70, 1, 1))
    noted(lambda: m.geometry(dims=(4.5, 4, 4)), TypeError, "dims")
    noted(lambda: gsenc.read(good, step=-1), OverflowError, "step")
    # What a numpy user passes is taken as the tuples are: the same models.
    a = gsenc.encode_particles(pos, h, v, budget=10, dims=np.array([8, 8, 8]), **QUICK)
    b = gsenc.encode_particles(pos, h, v, budget=10, dims=(8, 8, 8), **QUICK)
    np.testing.assert_array_equal(a.params(), b.params())
    a = gsenc.encode_particles(pos, h, v, budget=10, fit_dims=np.int64(8), bounds=np.array([[0.0, 0, 0], [8, 8, 8]]), **QUICK)
    b = gsenc.encode_particles(pos, h, v, budget=10, fit_dims=8, bounds=[(0, 0, 0), (8.0, 8.0, 8.0)], **QUICK)
    np.testing.assert_array_equal(a.params(), b.params())
    a = gsenc.encode_grid(field, 10, origin=np.array([1.0, 2.0, 3.0]), spacing=np.float32(0.5), **QUICK)
    b = gsenc.encode_grid(field, 10, origin=(1, 2, 3), spacing=0.5, **QUICK)
    np.testing.assert_array_equal(a.params(), b.params())
    assert a.geometry() == b.geometry() == ((1.0, 2.0, 3.0), (0.5, 0.5, 0.5))


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
