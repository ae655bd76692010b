"""gsenc.Series: a time series warm-started step by step, the tool's
encode-series models byte for byte; restarts, refusals, and a step stopped
part way."""

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import gsenc
from conftest import QUICK, blobs

CLI_QUICK = ["--schedule", "short", "--iters", "40", "--points", "512", "--threads", "1", "--backend", "cpu"]


def moving(step, dims=(24, 20, 16)):
    """blobs() drifting one voxel along x per step, float32 [z][y][x]."""
    return np.roll(blobs(dims), step, axis=2).astype(np.float32)


def particle_steps(steps=3, n=2000):
    """Particles of a blob drifting along x, and growing: (positions, h, values) per step, float32."""
    rng = np.random.default_rng(5)
    pos0 = rng.normal(12.0, 3.0, (n, 3))
    h = rng.uniform(0.8, 1.6, n)
    out = []
    for t in range(steps):
        pos = pos0 + [0.4 * t, 0.0, 0.0]
        v = (1.0 + 0.1 * t) * np.exp(-((pos - [12.0 + 0.4 * t, 12.0, 12.0]) ** 2).sum(axis=1) / 20.0)
        out.append((pos.astype(np.float32), h.astype(np.float32), v.astype(np.float32)))
    return out


@pytest.mark.parametrize("validation", [(0, 50), (2048, 10)])
def test_a_series_is_the_tools_encode_series(tmp_path, cli, validation):
    steps = particle_steps()
    for name, col in (("p", 0), ("h", 1), ("v", 2)):
        np.concatenate([s[col].ravel() for s in steps]).tofile(tmp_path / f"{name}.raw")
    points, every = validation
    cli("encode-series", "--positions", tmp_path / "p.raw", "--smoothing-length", tmp_path / "h.raw", "--values", tmp_path / "v.raw",
        "--count", len(steps[0][2]), "--dims", "20,20,20", "--budget", 100, *CLI_QUICK, "--validation-points", points,
        "--validation-every", every, "--field", "rho", "--csv", tmp_path / "v.csv", "-o", tmp_path / "cli")
    csv = np.loadtxt(tmp_path / "v.csv", delimiter=",", skiprows=1, usecols=(1, 3, 4), ndmin=2)
    series = gsenc.Series(100, validation_points=points, validation_every=every, **QUICK)
    for t, (pos, h, v) in enumerate(steps):
        ours = series.encode_particles(pos, h, v, dims=(20, 20, 20), field="rho", step=t)
        assert ours.info["warm_started"] == (t > 0) and ours.info["step"] == t
        theirs = tmp_path / "cli" / f"rho_{t:06d}.gsm"
        ours.write(tmp_path / "py.gsm")
        assert (tmp_path / "py.gsm").read_bytes() == theirs.read_bytes(), f"step {t}"
        assert ours.psnr == pytest.approx(gsenc.read(theirs).psnr, abs=1e-9)
        # The validation scores, as the tool's CSV rows (4 decimals there).
        rows = csv[csv[:, 0] == t][:, 1:]
        # Scored on the series' points, or an `auto` warm step's own.
        assert len(rows) == len(ours.info["validation"]) and (len(rows) > 0) == (points > 0 or t > 0)
        np.testing.assert_allclose(np.array(ours.info["validation"]).reshape(-1, 2), rows, atol=6e-5)
    # The first step's range holds: the later, larger values are clamped.
    assert ours.info["value_max"] == pytest.approx(float(steps[0][2].max()), rel=1e-6)
    assert ours.info["clamped_values"] > 0


def test_a_warm_step_starts_from_the_previous_model():
    field = moving(0)
    series = gsenc.Series(150, warm="coarse", warm_iterations=10, **dict(QUICK, iterations=300))
    first = series.encode_grid(field, step=0)
    # The same data again, in 10 iterations: from the first model it keeps
    # (about) its PSNR; seeded afresh, 10 iterations reach far less.
    warm = series.encode_grid(field, step=1)
    cold = gsenc.encode_grid(field, 150, **dict(QUICK, iterations=10))
    assert warm.info["warm_started"] and warm.info["iterations"] == 10
    assert warm.psnr > first.psnr - 1.0, f"warm {warm.psnr:.2f} dB, first {first.psnr:.2f} dB"
    assert warm.psnr > cold.psnr + 5.0, f"warm {warm.psnr:.2f} dB, cold {cold.psnr:.2f} dB"
    # Off: every step on its own, as encode_grid with the first step's range.
    off = gsenc.Series(150, warm="off", **QUICK)
    off.encode_grid(moving(0), step=0)
    r = (float(moving(0).min()), float(moving(0).max()))
    alone = gsenc.encode_grid(moving(1), 150, range=r, step=1, **QUICK)
    np.testing.assert_array_equal(off.encode_grid(moving(1), step=1).params(), alone.params())


@pytest.mark.parametrize("payload", ["f32", "packed"])
def test_a_resumed_series_continues_as_unbroken(tmp_path, payload):
    options = dict(QUICK, payload=payload)
    unbroken = gsenc.Series(120, **options)
    models = [unbroken.encode_grid(moving(t), step=t, field="rho", time=0.5 * t) for t in range(3)]
    models[0].write(tmp_path / "rho_0.gsm")
    sources = [models[0]]  # the model an encode returned: its float32 parameters
    if payload == "f32":
        sources.append(gsenc.read(tmp_path / "rho_0.gsm"))  # a float32 file holds them too
    for source in sources:
        resumed = gsenc.Series(120, **options)
        resumed.resume(source)
        for t in (1, 2):
            again = resumed.encode_grid(moving(t), step=t, field="rho", time=0.5 * t)
            np.testing.assert_array_equal(again.params(), models[t].params())
            assert again.info["warm_started"] and again.info["time"] == 0.5 * t
    # Without the resume, step 1 would be a first step: another model.
    fresh = gsenc.Series(120, **options).encode_grid(moving(1), step=1, field="rho")
    assert not fresh.info["warm_started"]
    assert not np.array_equal(fresh.params(), models[1].params())


def test_refusals_leave_the_series_as_it_was():
    series = gsenc.Series(100, range=(0.0, 250.0), **QUICK)
    first = series.encode_grid(moving(0), step=3)
    with pytest.raises(ValueError, match="does not follow step 3"):
        series.encode_grid(moving(1), step=3)
    with pytest.raises(ValueError, match="share its lattice"):
        series.encode_grid(moving(1, dims=(24, 20, 12)), step=4)
    with pytest.raises(ValueError, match="share its lattice"):
        series.encode_grid(moving(1), step=4, origin=(1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="already has steps"):
        series.resume(first)
    with pytest.raises(ValueError):
        series.encode_grid(moving(1), step=4, field="a/b")
    with pytest.raises(ValueError, match="2-dimensional|3|dimension"):
        series.encode_grid(np.zeros((4, 4)), step=4)
    # After all that, step 4 follows step 3, as in a series without them.
    clean = gsenc.Series(100, range=(0.0, 250.0), **QUICK)
    clean.encode_grid(moving(0), step=3)
    np.testing.assert_array_equal(series.encode_grid(moving(1), step=4).params(), clean.encode_grid(moving(1), step=4).params())
    # A model of another rank or range is not continued.
    with pytest.raises(ValueError, match="rank 0's piece; this is rank 1"):
        gsenc.Series(100, range=(0.0, 250.0), rank=1, **QUICK).resume(first)
    with pytest.raises(ValueError, match="keeps its range"):
        gsenc.Series(100, range=(0.0, 300.0), **QUICK).resume(first)
    with pytest.raises(ValueError, match="keeps its range"):
        gsenc.Series(100, log10=True, **QUICK).resume(first)
    with pytest.raises(ValueError, match="warm start"):
        gsenc.Series(100, warm="lukewarm", **QUICK)
    with pytest.raises(ValueError, match="validation needs a positive interval"):
        gsenc.Series(100, validation_points=1024, validation_every=0, **QUICK)
    with pytest.raises(OverflowError):
        gsenc.Series(100, validation_points=-1, **QUICK)
    with pytest.raises(TypeError, match="budget"):
        gsenc.Series(**QUICK)


def test_a_step_stopped_part_way_is_encoded_again_whole():
    def stop(iteration, iterations, loss):
        if iteration >= 20:
            raise RuntimeError("stopped by the test")

    series = gsenc.Series(100, **QUICK)
    straight = gsenc.Series(100, **QUICK)
    for t in range(3):
        if t == 1:
            with pytest.raises(RuntimeError, match="stopped by the test"):
                series.encode_grid(moving(t), step=t, progress=stop)
        ours = series.encode_grid(moving(t), step=t)
        np.testing.assert_array_equal(ours.params(), straight.encode_grid(moving(t), step=t).params())


def test_steps_from_two_threads_take_turns():
    series = gsenc.Series(80, **QUICK)
    done, calls = {}, []

    def encode(field):
        for t in range(2):
            done[field, t] = series.encode_grid(moving(t), step=t, field=field, progress=lambda i, n, loss: calls.append(field))

    threads = [threading.Thread(target=encode, args=(f,)) for f in ("a", "b")]
    for th in threads:
        th.start()
    for th in threads:
        th.join(timeout=120)
    assert not any(th.is_alive() for th in threads), "a step waits for the other forever"
    # Each field's series is its own: as encoded alone.
    for field in ("a", "b"):
        alone = gsenc.Series(80, **QUICK)
        for t in range(2):
            np.testing.assert_array_equal(done[field, t].params(), alone.encode_grid(moving(t), step=t, field=field).params())
    assert set(calls) == {"a", "b"}


def test_a_one_thread_executor_is_a_background_queue():
    # The README's pattern for a Python solver that must not wait: each step
    # submitted with a copy of the solver's buffer, which the solver then
    # overwrites; the steps run in order on the executor's thread, with the
    # GIL released, and give the models of the same series run in line.
    series, inline = gsenc.Series(80, **QUICK), gsenc.Series(80, **QUICK)
    buffer = moving(0)
    with ThreadPoolExecutor(max_workers=1) as pool:
        futures = []
        for t in range(3):
            buffer[...] = moving(t)  # the solver's step t
            futures.append(pool.submit(series.encode_grid, buffer.copy(), step=t, field="rho"))
        buffer[...] = -1.0  # the solver goes on; the steps have their copies
        models = [f.result(timeout=120) for f in futures]
    for t, m in enumerate(models):
        np.testing.assert_array_equal(m.params(), inline.encode_grid(moving(t), step=t, field="rho").params())
        assert m.info["warm_started"] == (t > 0)
