"""Encodes from numpy: the same models as the command-line tool from the same
data, whatever the dtype and strides; progress, Ctrl-C and the GIL."""

import json
import threading
import time

import numpy as np
import pytest

import gsenc
from conftest import QUICK, blobs

CLI_QUICK = ["--schedule", "short", "--iters", "40", "--points", "512", "--threads", "1", "--backend", "cpu"]


def test_a_grid_encodes_to_the_tools_model(tmp_path, cli):
    field = blobs().astype(np.float32)
    field.tofile(tmp_path / "f.raw")
    cli("encode", "grid", "--input", tmp_path / "f.raw", "--dims", "24,20,16", "--dtype", "f32", "--budget", 150, *CLI_QUICK,
        "--payload", "packed", "-o", tmp_path / "cli.gsm")
    ours = gsenc.encode_grid(field, 150, payload="packed", **QUICK)
    theirs = gsenc.read(tmp_path / "cli.gsm")
    # The encoded model holds its parameters as the payload stores them.
    np.testing.assert_array_equal(ours.params(), theirs.params())
    np.testing.assert_array_equal(ours.decode(), theirs.decode())
    assert ours.psnr == pytest.approx(theirs.psnr, abs=1e-9) and ours.psnr > 20
    # Written, it is the tool's file byte for byte.
    ours.write(tmp_path / "py.gsm")
    assert (tmp_path / "py.gsm").read_bytes() == (tmp_path / "cli.gsm").read_bytes()


def test_a_target_psnr_chooses_the_tools_budget(tmp_path, cli):
    field = blobs().astype(np.float32)
    field.tofile(tmp_path / "f.raw")
    quick = dict(QUICK, iterations=300)
    out = json.loads(cli("encode", "grid", "--input", tmp_path / "f.raw", "--dims", "24,20,16", "--dtype", "f32", "--target-psnr", 38,
                         *CLI_QUICK[:2], "--iters", 300, *CLI_QUICK[4:], "-o", tmp_path / "cli.gsm", "--json"))
    ours = gsenc.encode_grid(field, target_psnr=38, **quick)
    theirs = gsenc.read(tmp_path / "cli.gsm")
    assert len(ours) == len(theirs) and ours.psnr == pytest.approx(theirs.psnr, abs=1e-9)
    assert abs(ours.psnr - 38) <= 1.0, f"{len(ours)} Gaussians, {ours.psnr:.2f} dB"
    # The search's report is the tool's (but for its times), and the model
    # keeps the slopes it went by.
    drop_times = lambda r: {k: v for k, v in r.items() if k != "seconds"} | {
        k: [{n: t[n] for n in ("budget", "psnr", "iterations")} for t in r[k]] for k in ("probes", "tries")}
    assert drop_times(ours.info["target"]) == drop_times(out["target"]) and ours.info["target"]["landed"]
    assert ours.info["target_curve"] == [out["target"]["db_per_budget_doubling"], out["target"]["db_per_iteration_doubling"]]
    assert theirs.info["target_curve"] == ours.info["target_curve"]
    # With a cap below what it needs, it stops there, and says so.
    capped = gsenc.encode_grid(field, 20, target_psnr=60, **quick)
    assert len(capped) <= 20 and capped.info["target"]["cap"] == 20 and not capped.info["target"]["landed"]
    assert gsenc.encode_grid(field, 20, **quick).info["target"] is None
    with pytest.raises(ValueError, match="target PSNR"):
        gsenc.encode_grid(field, target_psnr=-1, **quick)
    with pytest.raises(TypeError, match="budget"):
        gsenc.encode_grid(field, **quick)


def test_particles_and_cells_encode_to_the_tools_models(tmp_path, cli):
    rng = np.random.default_rng(3)
    n = 3000
    pos = rng.normal(12.0, 3.0, (n, 3)).astype(np.float32)
    h = rng.uniform(0.8, 1.6, n).astype(np.float32)
    v = np.exp(-((pos - 12.0) ** 2).sum(axis=1) / 20.0).astype(np.float32)
    mass = rng.uniform(0.5, 1.5, n).astype(np.float32)
    for name, a in dict(p=pos, h=h, v=v, m=mass).items():
        a.tofile(tmp_path / f"{name}.raw")
    cli("encode", "particles", "--positions", tmp_path / "p.raw", "--smoothing-length", tmp_path / "h.raw", "--values", tmp_path / "v.raw",
        "--mass", tmp_path / "m.raw", "--dims", "20,20,20", "--budget", 100, *CLI_QUICK, "-o", tmp_path / "p.gsm")
    ours = gsenc.encode_particles(pos, h, v, mass, budget=100, dims=(20, 20, 20), **QUICK)
    np.testing.assert_array_equal(ours.params(), gsenc.read(tmp_path / "p.gsm").params())

    centers = rng.uniform(0.0, 16.0, (800, 3)).astype(np.float32)
    sizes = np.full((800, 3), 2.0, dtype=np.float32)
    cv = (1.0 + np.sin(centers[:, 0] / 3.0)).astype(np.float32)
    for name, a in dict(c=centers, s=sizes, cv=cv).items():
        a.tofile(tmp_path / f"{name}.raw")
    cli("encode", "cells", "--centers", tmp_path / "c.raw", "--sizes", tmp_path / "s.raw", "--values", tmp_path / "cv.raw",
        "--fit-dims", "16", "--budget", 80, *CLI_QUICK, "-o", tmp_path / "c.gsm")
    ours = gsenc.encode_cells(centers, cv, sizes=sizes, budget=80, fit_dims=16, **QUICK)
    np.testing.assert_array_equal(ours.params(), gsenc.read(tmp_path / "c.gsm").params())


def test_every_dtype_and_any_strides_give_the_same_model():
    base = np.rint(blobs())  # whole numbers 0..200: exact in every dtype below but int8
    reference = gsenc.encode_grid(base.astype(np.float32), 60, **QUICK).params()
    for dtype in (np.uint8, np.uint16, np.int16, np.uint32, np.int32, np.uint64, np.int64, np.float32, np.float64):
        np.testing.assert_array_equal(gsenc.encode_grid(base.astype(dtype), 60, **QUICK).params(), reference, err_msg=str(dtype))
    half = np.floor(base / 2)  # 0..100 for int8
    np.testing.assert_array_equal(gsenc.encode_grid(half.astype(np.int8), 60, **QUICK).params(),
                                  gsenc.encode_grid(half.astype(np.float32), 60, **QUICK).params())
    # A strided view (every other voxel of a bigger array, x reversed), a
    # Fortran-ordered copy and a C copy all hold the same field.
    big = np.zeros((32, 42, 48))
    big[::2, 1:-1:2, ::2][:, :, :24] = base[:, :, ::-1]
    view = big[::2, 1:-1:2, ::2][:, :, :24][:, :, ::-1]
    assert not view.flags.c_contiguous and np.array_equal(view, base)
    np.testing.assert_array_equal(gsenc.encode_grid(view, 60, **QUICK).params(), reference)
    np.testing.assert_array_equal(gsenc.encode_grid(np.asfortranarray(base), 60, **QUICK).params(), reference)


def test_progress_is_reported_and_an_exception_from_it_stops_the_encode():
    seen = []
    gsenc.encode_grid(blobs(), 50, progress=lambda i, n, loss: seen.append((i, n, loss)), **QUICK)
    assert seen[-1][0] == seen[-1][1] == 40 and [s[0] for s in seen] == list(range(10, 41, 10))
    assert all(np.isfinite(s[2]) and s[2] > 0 for s in seen)

    class Stop(Exception):
        pass

    calls = []

    def stop(i, n, loss):
        calls.append(i)
        raise Stop("enough")

    with pytest.raises(Stop, match="enough"):
        gsenc.encode_grid(blobs(), 50, progress=stop, **{**QUICK, "iterations": 400})
    assert calls == [10], "the encode stopped at the first report"


def test_progress_true_draws_a_bar(capsys):
    """Without tqdm installed (this test environment has none), a text bar on stderr."""
    with pytest.raises(ImportError):
        import tqdm  # noqa: F401
    gsenc.encode_grid(blobs(), 50, progress=True, **QUICK)
    err = capsys.readouterr().err
    assert "40/40 it" in err and "loss" in err and err.endswith("\n")


def test_the_gil_is_released_while_encoding():
    """A Python thread runs on while another encodes: with the GIL held it
    would stop for the whole encode."""
    done = threading.Event()
    ticks = []

    def encode():
        gsenc.encode_grid(blobs(), 300, **{**QUICK, "iterations": 1500})
        done.set()

    worker = threading.Thread(target=encode)
    t0 = time.perf_counter()
    worker.start()
    time.sleep(0.05)  # the encode is under way
    while not done.is_set():
        ticks.append(time.perf_counter())
        time.sleep(0.01)
    worker.join()
    elapsed = time.perf_counter() - t0
    assert elapsed > 0.3, "the encode is long enough to tell"
    gaps = np.diff(ticks)
    assert len(ticks) > 10 and gaps.max() < 0.25, f"the main thread stalled for {gaps.max():.2f} s of {elapsed:.2f} s"


def test_a_written_model_reads_back_with_its_psnr_and_info(tmp_path):
    model = gsenc.encode_grid(blobs(), 80, field="rho", step=7, time=0.5, payload="8bit", **QUICK)
    assert model.info["payload"] == "8bit" and model.info["field"] == "rho"
    size = model.write(tmp_path / "m.gsm")
    back = gsenc.read(tmp_path / "m.gsm")
    assert back.info["bytes"] == size == (tmp_path / "m.gsm").stat().st_size
    assert back.info["step"] == 7 and back.info["time"] == 0.5 and back.psnr == pytest.approx(model.psnr)
    assert repr(back) == "<gsenc.Model 'rho' step 7: 80 primitives on [24, 20, 16]>"
