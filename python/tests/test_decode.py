"""Models read and decoded from Python give what the command-line tool gives,
bit for bit: model files of every payload, a step index of two pieces, and a
store written by the C API; and in a worker that multiprocessing forked,
what its parent gets."""

import json
import multiprocessing

import numpy as np
import pytest

import gsenc
from conftest import QUICK, blobs, read_raw, write_step_index


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("decode") / "blobs.gsm"
    gsenc.encode_grid(blobs(), 150, **QUICK).write(path)
    return path


@pytest.mark.parametrize("payload", ["f32", "8bit", "8bit-u16", "packed"])
def test_a_decode_is_the_tools_bit_for_bit(tmp_path, model_file, cli, payload):
    path = tmp_path / f"m_{payload}.gsm"
    gsenc.read(model_file).write(path, payload=payload)
    model = gsenc.read(path)
    assert model.info["payload"] == payload
    cases = [
        ({}, [], model.dims),
        (dict(dims=(30, 25, 21)), ["--dims", "30,25,21"], (30, 25, 21)),
        (dict(box=(3, 2, 1, 20, 17, 9)), ["--box", "3,2,1,20,17,9"], (17, 15, 8)),
        (dict(normalized=True), ["--normalized"], model.dims),
    ]
    for kwargs, args, dims in cases:
        out = tmp_path / "out.raw"
        cli("decode", path, "-o", out, "--backend", "cpu", *args)
        ours = model.decode(backend="cpu", **kwargs)
        assert ours.shape == (dims[2], dims[1], dims[0]) and ours.dtype == np.float32
        np.testing.assert_array_equal(ours, read_raw(out, dims), err_msg=f"{payload} {kwargs}")


def test_info_is_the_tools(model_file, cli):
    theirs = json.loads(cli("info", model_file, "--json"))
    assert gsenc.read(model_file).info == theirs


def test_evaluate_matches_the_decode_at_voxel_centres(model_file):
    model = gsenc.read(model_file)
    grid = model.decode(backend="cpu")
    (ox, oy, oz), (sx, sy, sz) = model.geometry()
    nx, ny, nz = model.dims
    Z, Y, X = np.meshgrid(oz + sz * np.arange(nz), oy + sy * np.arange(ny), ox + sx * np.arange(nx), indexing="ij")
    points = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    values = model.evaluate(points)
    # Another summation order than the lattice's: equal to float rounding.
    np.testing.assert_allclose(values, grid.ravel(), rtol=1e-5, atol=1e-4)
    assert np.abs(values).max() > 50, "the field is not empty"
    # Normalised values are the same map of the decode.
    np.testing.assert_allclose(model.evaluate(points[:100], normalized=True), model.decode(normalized=True).ravel()[:100], rtol=1e-5, atol=1e-6)


def test_a_points_value_is_the_same_bits_whatever_is_asked_beside_it(model_file):
    model = gsenc.read(model_file)
    rng = np.random.default_rng(4)
    (ox, oy, oz), (sx, sy, sz) = model.geometry()
    nx, ny, nz = model.dims
    lo, hi = np.array([ox, oy, oz]) - [sx, sy, sz], np.array([ox + nx * sx, oy + ny * sy, oz + nz * sz])
    points = lo + (hi - lo) * rng.random((5000, 3))
    values = model.evaluate(points, threads=2)
    assert np.abs(values).max() > 50, "the field is not empty"
    np.testing.assert_array_equal(model.evaluate(points[::-1], threads=1)[::-1], values)
    for i in range(0, len(points), 397):
        np.testing.assert_array_equal(model.evaluate(points[i : i + 1]), values[i : i + 1], err_msg=f"point {i} alone")


def _in_a_forked_worker(path):
    """A decode, an evaluation and an encode, none naming a thread count."""
    model = gsenc.read(path)
    points = np.array([[8.0, 9.0, 7.0], [1.5, 2.5, 3.5]])
    encoded = gsenc.encode_grid(blobs(), 40, **dict(QUICK, threads=None))
    return model.decode(backend="cpu"), model.evaluate(points), encoded.params()


def test_a_forked_worker_decodes_and_encodes_as_its_parent(model_file):
    """multiprocessing forks its workers (Linux's default before Python
    3.14), and a worker has only the thread that forked: a decode there ran
    on the pool the parent's decode had started, which had no threads in
    the worker, and waited for ever. The worker starts its own now."""
    model = gsenc.read(model_file)
    points = np.array([[8.0, 9.0, 7.0], [1.5, 2.5, 3.5]])
    # In the parent first, on the default pool (no thread count), which the
    # fork then copies without its threads.
    decoded, evaluated = model.decode(backend="cpu"), model.evaluate(points)
    encoded = gsenc.encode_grid(blobs(), 40, **dict(QUICK, threads=None)).params()
    with multiprocessing.get_context("fork").Pool(2) as pool:
        outs = pool.map_async(_in_a_forked_worker, [str(model_file)] * 2).get(timeout=120)
    for d, e, p in outs:
        np.testing.assert_array_equal(d, decoded)
        np.testing.assert_array_equal(e, evaluated)
        np.testing.assert_array_equal(p, encoded)


def test_primitives_are_the_models_parameters(model_file):
    model = gsenc.read(model_file)
    p, flat = model.primitives, model.params()
    assert p.dtype == gsenc.PRIMITIVE_DTYPE and p.shape == (len(model),) == (150,)
    np.testing.assert_array_equal(p["mu"], flat[:, 0:3])
    np.testing.assert_array_equal(p["quat"], flat[:, 6:10])
    np.testing.assert_array_equal(p["beta"], flat[:, 11])
    # Centres in the index frame: inside the reference lattice, give or take its border.
    assert (p["mu"] > -2).all() and (p["mu"] < np.array(model.dims) + 1).all()


def test_a_step_index_decodes_as_the_tools_blend(tmp_path, cli):
    """Two pieces of a 32 x 16 x 16 field, overlapping by 8 voxels (a halo of
    4), each encoded on its own box and named by a step index."""
    field = blobs((32, 16, 16))
    encode = lambda part, origin, rank: gsenc.encode_grid(part, 80, origin=origin, range=(0.0, 220.0), field="rho", step=4, rank=rank, **QUICK)
    write_step_index(tmp_path, field, encode)
    step = gsenc.read(tmp_path / "rho_000004.gsi")
    assert step.info["pieces"] == 2 and step.dims == (32, 16, 16) and len(step) == 160
    for kwargs, args in [({}, []), (dict(additive=True), ["--additive"]), (dict(dims=(40, 20, 20)), ["--dims", "40,20,20"])]:
        cli("decode", tmp_path / "rho_000004.gsi", "-o", tmp_path / "out.raw", "--backend", "cpu", *args)
        dims = kwargs.get("dims", (32, 16, 16))
        np.testing.assert_array_equal(step.decode(backend="cpu", **kwargs), read_raw(tmp_path / "out.raw", dims), err_msg=str(kwargs))
    # The blend is not the additive decode (the pieces' tails differ across the halo).
    blended, additive = step.decode(), step.decode(additive=True)
    assert not np.array_equal(blended, additive)
    # Evaluated at the voxel centres, the step gives its decode, blended or additive.
    Z, Y, X = np.meshgrid(np.arange(16.0), np.arange(16.0), np.arange(32.0), indexing="ij")
    centres = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    np.testing.assert_allclose(step.evaluate(centres), blended.ravel(), rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(step.evaluate(centres, additive=True), additive.ravel(), rtol=1e-5, atol=1e-4)
    # Writing is per model: a step of several refuses, clearly.
    with pytest.raises(ValueError, match="step of 2 pieces"):
        step.write(tmp_path / "x.gsm")


def test_a_step_of_a_store_with_its_index_is_the_blended_global_field(tmp_path, cli):
    """An MPI run's folder added to a store (its models and step index):
    the step read without a rank is its global field, as from the .gsi."""
    field = blobs((32, 16, 16))
    encode = lambda part, origin, rank: gsenc.encode_grid(part, 80, origin=origin, range=(0.0, 220.0), field="rho", step=4, rank=rank, **QUICK)
    run = tmp_path / "run"
    run.mkdir()
    write_step_index(run, field, encode)
    cli("store", "add", tmp_path / "models.h5", run / "rho_000004.gsm", run / "rho_000004_r1.gsm")
    cli("store", "add", tmp_path / "run.h5", run)
    from_index = gsenc.read(run / "rho_000004.gsi")
    for step in (gsenc.read(tmp_path / "run.h5", field="rho", step=4), gsenc.open_store(tmp_path / "run.h5").read("rho", 4)):
        assert step.info["pieces"] == 2 and step.dims == (32, 16, 16)
        np.testing.assert_array_equal(step.decode(backend="cpu"), from_index.decode(backend="cpu"))
        np.testing.assert_array_equal(step.decode(backend="cpu", additive=True), from_index.decode(backend="cpu", additive=True))
    # Every entry and the step index check out (gsenc store verify's verdicts).
    checked = gsenc.open_store(tmp_path / "run.h5").verify()
    assert [c["item"] for c in checked] == ["/rho/4/rank_0", "/rho/4/rank_1", "/rho/4/index"]
    assert all(c["ok"] and c["checksum"] and "error" not in c for c in checked), checked
    # A rank is still one piece; without an index the step asks for one.
    assert gsenc.read(tmp_path / "run.h5", field="rho", step=4, rank=1).info["rank"] == 1
    with pytest.raises(ValueError, match="no step index to blend them"):
        gsenc.read(tmp_path / "models.h5", field="rho", step=4)


def test_a_store_written_by_the_c_api_reads_as_the_tool_extracts_it(tmp_path, cli, mock_solver):
    import subprocess

    store = tmp_path / "run.h5"
    done = subprocess.run([mock_solver, store, "2", "120", "30", "20", "off"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    s = gsenc.open_store(store)
    assert s.fields() == ["amr", "grid", "tracers"] and s.steps("grid") == [0, 1] and s.ranks("grid", 1) == [0]
    assert len(s) == 6 and all(e["primitives"] == 120 and "error" not in e for e in s.entries)
    for field in s.fields():
        model = s.read(field, 1)
        assert model.info["field"] == field and model.info["step"] == 1 and model.psnr > 10
        cli("store", "extract", store, f"{field}/1/0", "-o", tmp_path / f"{field}.gsm")
        cli("decode", tmp_path / f"{field}.gsm", "-o", tmp_path / "out.raw", "--backend", "cpu")
        np.testing.assert_array_equal(model.decode(backend="cpu"), read_raw(tmp_path / "out.raw", model.dims), err_msg=field)
        # gsenc.read of the store names the same entry.
        np.testing.assert_array_equal(gsenc.read(store, field=field, step=1).params(), model.params())
    with pytest.raises(ValueError, match="6 entries"):
        gsenc.read(store)
    with pytest.raises(ValueError, match="no entry"):
        s.read("grid", 7)
