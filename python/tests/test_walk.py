"""Seeded random walks over the Python package, as a careless user might call
it: encodes of grids, particles and cells (alone and in a Series), decodes,
evaluations, writes and reads, with arguments drawn from what is valid and
what is not (arrays empty, of the wrong shape or dtype, strided, with NaN
or infinities, or not arrays at all; constant, a single spike, values near
1e30, 1e-30 and the ends of float32; grids of one voxel or one row;
budgets of zero, negative, past 2^63 or not numbers; unknown names; dims
and boxes of zero or too large; paths that do not exist or are folders;
cut, damaged and foreign files; steps out of order; progress callbacks
that raise or are not callable).

Nothing is expected of a call but what the package promises of every call:
it returns, or raises one of its exceptions (ValueError, gsenc.ModelError,
TypeError, OverflowError, OSError; RuntimeError only for a GPU asked for
where there is none; backend="gpu" runs on Mesa's software adapter,
which the walk names in GSENC_ADAPTER) with a message, never a panic
(pyo3_runtime.PanicException) nor a crash of the interpreter; what it
returns is what it says (a model of at most its budget that decodes to
finite values, a decode of the shape asked, finite values at finite
points, a file that reads back as the model written); and a failed write
leaves the file that was there byte for byte.

GSENC_PY_WALKS sets the number of walks (default 40 of 25 calls, a few
seconds), GSENC_PY_WALK_SEED the first seed; a failure names its seed and
the call. GSENC_PY_WALK_TRACE prints every call's outcome (pytest -s).
"""

import math
import os

import numpy as np
import pytest

import gsenc
from conftest import blobs

WALKS = int(os.environ.get("GSENC_PY_WALKS", "40"))
FIRST = int(os.environ.get("GSENC_PY_WALK_SEED", "1"))
TRACE = bool(os.environ.get("GSENC_PY_WALK_TRACE"))
CALLS = 25

#: The package's own exceptions: a call may raise these, with a message.
ANSWERS = (ValueError, TypeError, OverflowError, OSError)


class Walk:
    def __init__(self, seed, tmp):
        self.rng = np.random.default_rng(seed)
        self.tmp = tmp
        self.models = []
        self.series = None
        self.step = 0
        self.files = {}

    def chance(self, p):
        return self.rng.random() < p

    def pick(self, items):
        return items[int(self.rng.integers(len(items)))]

    def value(self, usual, odd):
        """Mostly `usual`, sometimes one of `odd`."""
        return usual if self.chance(0.8) else self.pick(odd)

    def array(self, shape, low=0.5, high=10.0):
        """An array of `shape` in [low, high), or (now and then) not quite."""
        good = self.rng.uniform(low, high, shape)
        if self.chance(0.75):
            return good
        kind = int(self.rng.integers(15))
        if kind == 0:
            return np.zeros((0,) + tuple(shape[1:]))
        if kind == 1:
            return good.reshape(-1)
        if kind == 2:
            return good[..., None]
        if kind == 3:
            return good.astype(self.pick([np.float32, np.float16, np.int16, np.uint8, np.bool_, np.complex64]))
        if kind == 4:
            return np.repeat(good, 2, axis=0)[::2]  # strided, same shape
        if kind == 5:
            bad = good.copy()
            bad.flat[int(self.rng.integers(bad.size))] = self.pick([np.nan, np.inf, -np.inf])
            return bad
        if kind == 6:
            return good.tolist()
        if kind == 7:
            return self.pick([None, "values", 3.5])
        if kind == 8:
            return good.astype(object)
        if kind == 9:
            return good[: max(1, shape[0] // 2)]
        if kind == 10:
            return -good
        if kind == 11:
            return np.asfortranarray(good)
        if kind == 12:
            return np.full(shape, 3.0)
        if kind == 13:
            return good * self.pick([1e30, 1e-30, 1e-310, 3e38])
        spike = np.zeros(shape)
        spike.flat[int(self.rng.integers(spike.size))] = 1.0
        return spike

    def options(self):
        """Encode options: a short encode, or one with an odd value."""
        o = dict(schedule="short", iterations=8, points=256, threads=1, backend="cpu")
        for key, odd in [
            ("schedule", ["bogus", "matched", ""]),
            ("iterations", [0, 1, -1, 2**70, "8"]),
            ("points", [0, 1, -5, 2**40]),
            ("threads", [0, -1, 3, 2**40]),
            ("backend", ["bogus", "auto", "gpu"]),
        ]:
            if self.chance(0.05):
                o[key] = self.pick(odd)
        for key, odd in [
            ("range", [(1.0, 0.0), (math.nan, 1.0), (0.0, 20.0), (5.0,)]),
            ("log10", [True]),
            ("payload", ["8bit", "8bit-u16", "packed", "zip"]),
            ("field", ["rho", "", "a/b", "x" * 300]),
            ("step", [3, -1, 2**64]),
            ("time", [0.5, math.nan, math.inf]),
            ("rank", [1, -1, 2**33]),
            ("seed", [7, -7, 2**64]),
            ("relocation", [False]),
            ("support", [False]),
            ("target_psnr", [30.0, 0.0, math.nan, 1000.0]),
            ("progress", [True, "yes", self.raising, lambda i, n, loss: None]),
        ]:
            if self.chance(0.05):
                o[key] = self.pick(odd)
        return o

    @staticmethod
    def raising(i, n, loss):
        raise ValueError("stopped by the walk's progress callback")

    def budget(self):
        return self.value(6, [0, -1, 1, 2**63, 2**70, 1.5, "6", None])

    def place(self):
        """dims or fit_dims, and now and then bounds."""
        p = {}
        if self.chance(0.5):
            p["dims"] = self.value((8, 7, 6), [(0, 1, 1), (8, 7), (2**33, 1, 1), (-1, 2, 3), (100000, 100000, 100000)])
        else:
            p["fit_dims"] = self.value(8, [0, 1, -3, 10**6])
        if self.chance(0.15):
            p["bounds"] = self.pick([((0, 0, 0), (4, 4, 4)), ((4, 4, 4), (0, 0, 0)), ((0, 0, 0), (0, 0, 0)), ((math.nan, 0, 0), (1, 1, 1))])
        return p

    def path(self, name):
        """A file to write: mostly a new one, sometimes where none can be."""
        return self.value(self.tmp / name, [self.tmp / "missing" / name, self.tmp, self.tmp / "there.gsm"])

    def readable(self):
        good = self.files.get("good")
        return self.value(good or self.tmp / "missing.gsm", [self.tmp / "missing.gsm", self.tmp, *self.files.values()])


# The calls: each makes one call of the package with arguments drawn by the
# walk, and checks what the call returned.


def check_model(m, budget=None):
    assert isinstance(m, gsenc.Model)
    assert len(m) >= 1 and (budget is None or not isinstance(budget, int) or len(m) <= budget)
    d = m.decode(dims=(5, 4, 3), threads=1, backend="cpu")
    assert d.shape == (3, 4, 5) and d.dtype == np.float32 and np.isfinite(d).all()


def encode_grid(w):
    shape = w.value((6, 7, 8), [(1, 1, 1), (1, 7, 1), (2, 2, 2), (40, 1, 1)])
    a = w.array(shape) if w.chance(0.9) else blobs((9, 8, 7))
    b, o = w.budget(), w.options()
    m = gsenc.encode_grid(a, b, **o)
    check_model(m, None if "target_psnr" in o else b)
    w.models.append(m)


def encode_particles(w):
    n = 40
    pos, h, v = w.array((n, 3), 0.0, 6.0), w.array((n,), 0.5, 1.5), w.array((n,))
    mass = w.array((n,)) if w.chance(0.3) else None
    m = gsenc.encode_particles(pos, h, v, mass, budget=w.budget(), **w.place(), **w.options())
    check_model(m)
    w.models.append(m)


def encode_cells(w):
    n = 27
    centres = w.array((n, 3), 0.0, 6.0)
    sizes = {}
    k = int(w.rng.integers(10))
    if k < 5:
        sizes["volumes"] = w.array((n,), 0.2, 1.0)
    elif k < 9:
        sizes["sizes"] = w.array((n, 3), 0.3, 1.0)
    elif w.chance(0.5):
        sizes = dict(volumes=w.array((n,), 0.2, 1.0), sizes=w.array((n, 3), 0.3, 1.0))
    m = gsenc.encode_cells(centres, w.array((n,)), **sizes, budget=w.budget(), **w.place(), **w.options())
    check_model(m)
    w.models.append(m)


def decode(w):
    m = w.pick(w.models)
    kw = {}
    if w.chance(0.6):
        kw["dims"] = w.value((5, 6, 7), [(0, 1, 1), (5, 6), (2**33, 1, 1), (100000, 100000, 100000), (-1, 2, 2), "5,6,7"])
    if w.chance(0.2):
        kw["box"] = w.value((0, 0, 0, 2, 2, 2), [(2, 2, 2, 0, 0, 0), (0, 0, 0, 100, 100, 100), (0, 0, 0), (-1, 0, 0, 1, 1, 1)])
    for key, values in [("normalized", [True]), ("additive", [True]), ("threads", [0, 2, -1]), ("backend", ["bogus", "gpu"])]:
        if w.chance(0.1):
            kw[key] = w.pick(values)
    d = m.decode(**kw)
    dims = kw.get("dims", m.dims)
    box = kw.get("box", (0, 0, 0, *dims))
    want = tuple(box[3 + a] - box[a] for a in (2, 1, 0))
    assert d.shape == want and d.dtype == np.float32 and np.isfinite(d).all(), (d.shape, want)


def evaluate(w):
    m = w.pick(w.models)
    n = int(w.rng.integers(0, 20))
    pts = w.value(w.rng.uniform(-2, 10, (n, 3)), [w.rng.uniform(0, 1, (n, 2)), [[1, 2, 3]], np.full((2, 3), np.nan), "points", np.zeros(3)])
    kw = {k: v for k, v in [("normalized", True), ("additive", True), ("threads", w.pick([0, 2]))] if w.chance(0.1)}
    v = m.evaluate(pts, **kw)
    p = np.asarray(pts, dtype=np.float64)
    assert v.shape == (p.shape[0],) and v.dtype == np.float32
    assert np.isfinite(v[np.isfinite(p).all(axis=1)]).all()


def write(w):
    m = w.pick(w.models)
    there = w.tmp / "there.gsm"
    before = there.read_bytes()
    to = w.path("w.gsm")
    payload = w.value(None, ["f32", "8bit", "8bit-u16", "packed", "zip", ""])
    try:
        n = m.write(to, payload) if payload is not None else m.write(to)
    except ANSWERS:
        assert there.read_bytes() == before, "a failed write changed the file that was there"
        raise
    assert n == os.path.getsize(to)
    back = gsenc.read(to)
    assert len(back) == len(m) and back.dims == m.dims
    # Written with its own payload, a model reads back as it is held (an
    # encode's model is held as its payload stores it; written as float32,
    # it is its parameters before that payload's rounding).
    if payload in (None, m.info["payload"]):
        assert back.info["payload"] == m.info["payload"]
        assert np.array_equal(back.params(), m.params())
    w.files["written"] = to


def read(w):
    m = gsenc.read(w.readable())
    check_model(m)
    w.models.append(m)


def look(w):
    m = w.pick(w.models)
    dims = w.value(None, [(4, 4, 4), (0, 1, 1), (2**40, 1, 1)])
    origin, voxel = m.geometry(dims) if dims is not None else m.geometry()
    assert all(map(math.isfinite, (*origin, *voxel)))
    p = m.params()
    assert p.shape == (len(m), 12) and np.isfinite(p).all()
    assert len(m.primitives) == len(m)
    assert m.info["primitives"] == len(m)


def series(w):
    if w.series is None or w.chance(0.1):
        o = w.options()
        for key in ["field", "step", "time", "progress"]:
            o.pop(key, None)
        extra = {k: v for k, v in [("warm", w.pick(["auto", "off", "coarse", "dense", "bogus"])), ("validation_points", w.pick([0, 64, -1])), ("validation_every", w.pick([4, 0]))] if w.chance(0.3)}
        w.series = gsenc.Series(w.budget(), **extra, **o)
        w.step = 0
    step = w.value(w.step, [w.step - 1, 0, -1, 2**64])
    field = w.value("rho", ["", "other"])
    kind = int(w.rng.integers(3))
    if kind == 0:
        m = w.series.encode_grid(w.array((6, 7, 8)), step=step, field=field)
    elif kind == 1:
        n = 40
        m = w.series.encode_particles(w.array((n, 3), 0.0, 6.0), w.array((n,), 0.5, 1.5), w.array((n,)), step=step, field=field, **w.place())
    else:
        n = 27
        m = w.series.encode_cells(w.array((n, 3), 0.0, 6.0), w.array((n,)), volumes=w.array((n,), 0.2, 1.0), step=step, field=field, **w.place())
    check_model(m)
    w.models.append(m)
    w.step = max(w.step, step + 1) if isinstance(step, int) and step < 2**63 else w.step


def resume(w):
    if w.series is None:
        w.series = gsenc.Series(6, schedule="short", iterations=8, points=256, threads=1, backend="cpu")
    w.series.resume(w.pick(w.models))


CALLS_BY_WEIGHT = [encode_grid] * 3 + [encode_particles, encode_cells] * 2 + [decode] * 3 + [evaluate] * 2 + [write, read, look] * 2 + [series] * 3 + [resume]


def test_random_calls_keep_the_packages_promises(tmp_path, monkeypatch):
    # backend="gpu" runs on Mesa's software adapter where it is installed
    # (CI's), and is a RuntimeError naming the adapter where none is.
    monkeypatch.setenv("GSENC_ADAPTER", "llvmpipe")
    good = gsenc.encode_grid(blobs((9, 8, 7)), 8, schedule="short", iterations=8, points=256, threads=1, backend="cpu")
    good.write(tmp_path / "good.gsm")
    data = (tmp_path / "good.gsm").read_bytes()
    (tmp_path / "cut.gsm").write_bytes(data[: len(data) // 2])
    damaged = bytearray(data)
    damaged[len(data) // 3] ^= 0x10
    (tmp_path / "damaged.gsm").write_bytes(bytes(damaged))
    (tmp_path / "empty.gsm").write_bytes(b"")
    (tmp_path / "foreign.gsm").write_bytes(b"not a model at all")
    raised = 0
    for seed in range(FIRST, FIRST + WALKS):
        w = Walk(seed, tmp_path)
        w.models.append(good)
        w.files = {name: tmp_path / f"{name}.gsm" for name in ["good", "cut", "damaged", "empty", "foreign"]}
        (tmp_path / "there.gsm").write_bytes(data)
        for call in range(CALLS):
            f = w.pick(CALLS_BY_WEIGHT)
            label = f"walk {seed} call {call}: {f.__name__}"
            try:
                f(w)
                if TRACE:
                    print(f"{label}: ok")
            except ANSWERS as e:
                assert str(e).strip(), f"{label}: {type(e).__name__} without a message"
                raised += 1
                if TRACE:
                    print(f"{label}: {type(e).__name__}: {e}")
            except RuntimeError as e:
                assert "GPU" in str(e) or "adapter" in str(e), f"{label}: RuntimeError {e}"
                raised += 1
            except AssertionError as e:
                raise AssertionError(f"{label}: {e}") from e
            except BaseException as e:  # a panic is a BaseException
                pytest.fail(f"{label}: {type(e).__module__}.{type(e).__name__}: {e}")
    # The walks reached what they are for: many calls failed, and many did not.
    total = WALKS * CALLS
    assert total // 10 < raised < total - total // 10, f"{raised} of {total} raised"
