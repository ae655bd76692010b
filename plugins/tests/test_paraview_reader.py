"""The ParaView reader (plugins/paraview/gsenc_paraview.py), run headless
with the vtk wheel: a .gsm, a .gsi and a store, checked against `gsenc
decode` of the same models read back by VTK's own .vti reader."""

import gsenc
import numpy as np
import pytest
from conftest import blobs, write_step_index
from vtkmodules.util import numpy_support
from vtkmodules.vtkIOXML import vtkXMLImageDataReader

import gsenc_paraview

QUICK = dict(schedule="short", iterations=60, points=1024, threads=1, backend="cpu")


def reader_output(path, dims=None, time=None, backend=None, monkeypatch=None, field=None):
    if backend:
        monkeypatch.setenv("GSENC_PARAVIEW_BACKEND", backend)
    r = gsenc_paraview.GsencReader()
    r.SetFileName(str(path))
    if field:
        r.SetField(field)
    if dims:
        r.SetDims(*dims)
    if time is None:
        r.Update()
    else:
        r.UpdateTimeStep(float(time))
    return r, r.GetOutputDataObject(0)


def tool_decode(cli, tmp_path, path, dims=None):
    out = tmp_path / "tool.vti"
    cli("decode", path, "-o", out, *(["--dims", ",".join(map(str, dims))] if dims else []))
    vti = vtkXMLImageDataReader()
    vti.SetFileName(str(out))
    vti.Update()
    return vti.GetOutput()


def same_image(ours, tool, name):
    assert ours.GetDimensions() == tool.GetDimensions()
    np.testing.assert_allclose(ours.GetOrigin(), tool.GetOrigin(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(ours.GetSpacing(), tool.GetSpacing(), rtol=0, atol=1e-12)
    a, b = ours.GetPointData().GetScalars(), tool.GetPointData().GetScalars()
    assert a.GetName() == name == b.GetName()
    values, expected = numpy_support.vtk_to_numpy(a), numpy_support.vtk_to_numpy(b)
    assert np.abs(expected).max() > 1.0, "the field is not empty"
    np.testing.assert_array_equal(values, expected)


@pytest.fixture(scope="module")
def gsm(tmp_path_factory):
    """A model with a world origin and spacing of its own."""
    d = tmp_path_factory.mktemp("gsm")
    model = gsenc.encode_grid(blobs((24, 20, 16)), 120, origin=(-3.0, 10.0, 0.5), spacing=0.25, field="rho", **QUICK)
    model.write(d / "rho.gsm")
    return d / "rho.gsm"


@pytest.mark.parametrize("backend", ["python", "ctypes"])
def test_a_model_file_at_its_own_lattice_and_at_any_dims(gsm, cli, tmp_path, monkeypatch, backend):
    for dims in (None, (30, 10, 16)):
        _, ours = reader_output(gsm, dims=dims, backend=backend, monkeypatch=monkeypatch)
        same_image(ours, tool_decode(cli, tmp_path, gsm, dims), "rho")
    # World placement: voxel (0, 0, 0)'s centre where the grid had it, a quarter-unit lattice.
    _, ours = reader_output(gsm, backend=backend, monkeypatch=monkeypatch)
    assert ours.GetDimensions() == (24, 20, 16) and ours.GetSpacing() == (0.25, 0.25, 0.25)
    np.testing.assert_allclose(ours.GetOrigin(), (-3.0, 10.0, 0.5), rtol=0, atol=1e-12)


def test_a_step_index_is_the_blended_global_field(tmp_path, cli):
    encode = lambda part, origin, rank: gsenc.encode_grid(part, 80, origin=origin, range=(0.0, 8.0), field="rho", step=4, rank=rank, **QUICK)
    write_step_index(tmp_path, blobs((32, 16, 16)), encode, vrange=(0.0, 8.0))
    _, ours = reader_output(tmp_path / "rho_000004.gsi")
    same_image(ours, tool_decode(cli, tmp_path, tmp_path / "rho_000004.gsi"), "rho")


def test_a_store_of_an_mpi_run_is_its_global_field(tmp_path, cli):
    """A run's folder (each rank's model and the step index) added to a
    store: the reader's step is the blended global field, as of the .gsi."""
    encode = lambda part, origin, rank: gsenc.encode_grid(part, 80, origin=origin, range=(0.0, 8.0), field="rho", step=4, rank=rank, **QUICK)
    run = tmp_path / "run"
    run.mkdir()
    write_step_index(run, blobs((32, 16, 16)), encode, vrange=(0.0, 8.0))
    cli("store", "add", tmp_path / "run.h5", run)
    r, ours = reader_output(tmp_path / "run.h5")
    assert r.GetTimestepValues() == [4.0]
    same_image(ours, tool_decode(cli, tmp_path, run / "rho_000004.gsi"), "rho")


def test_a_store_is_a_time_series(tmp_path, cli):
    for step, shift in ((3, 0.0), (7, 4.0)):
        model = gsenc.encode_grid(blobs((20, 16, 12), shift=shift), 90, range=(0.0, 8.0), field="rho", step=step, **QUICK)
        model.write(tmp_path / f"rho_{step}.gsm")
    gsenc.encode_grid(blobs((20, 16, 12)), 60, field="temp", step=5, **QUICK).write(tmp_path / "temp_5.gsm")
    cli("store", "add", tmp_path / "run.h5", tmp_path / "rho_3.gsm", tmp_path / "rho_7.gsm", tmp_path / "temp_5.gsm")
    r, first = reader_output(tmp_path / "run.h5")
    assert r.GetTimestepValues() == [3.0, 7.0], "the first field's steps"
    same_image(first, tool_decode(cli, tmp_path, tmp_path / "rho_3.gsm"), "rho")
    for time, step in ((7.0, 7), (5.5, 3), (100.0, 7)):
        _, ours = reader_output(tmp_path / "run.h5", time=time)
        same_image(ours, tool_decode(cli, tmp_path, tmp_path / f"rho_{step}.gsm"), "rho")
    r, other = reader_output(tmp_path / "run.h5", field="temp")
    assert r.GetTimestepValues() == [5.0]
    same_image(other, tool_decode(cli, tmp_path, tmp_path / "temp_5.gsm"), "temp")


def test_a_stores_times_are_the_simulation_times_its_models_carry(tmp_path, cli):
    """ParaView lines the reader up with the simulation's own output by
    time: a step's time is its models' simulation time (its step number
    where none is carried, as in `gsenc decode-series`'s XDMF)."""
    def store(name, times):
        paths = []
        for (step, time), shift in zip(times, (0.0, 3.0, 6.0)):
            model = gsenc.encode_grid(blobs((20, 16, 12), shift=shift), 60, range=(0.0, 8.0), field="rho", step=step, time=time, **QUICK)
            paths.append(tmp_path / f"{name}_{step}.gsm")
            model.write(paths[-1])
        cli("store", "add", tmp_path / f"{name}.h5", *paths)
        return tmp_path / f"{name}.h5"

    timed = store("timed", [(10, 0.125), (20, 0.25), (30, None)])
    entries = gsenc.open_store(timed).entries
    assert [e["time"] for e in entries] == [0.125, 0.25, None]
    r, first = reader_output(timed)
    assert r.GetTimestepValues() == [0.125, 0.25, 30.0]
    assert first.GetInformation().Get(first.DATA_TIME_STEP()) == 0.125
    for time, step, shown in ((0.25, 20, 0.25), (0.2, 10, 0.125), (29.0, 20, 0.25), (30.0, 30, 30.0), (0.0, 10, 0.125)):
        _, ours = reader_output(timed, time=time)
        same_image(ours, tool_decode(cli, tmp_path, tmp_path / f"timed_{step}.gsm"), "rho")
        assert ours.GetInformation().Get(ours.DATA_TIME_STEP()) == shown, (time, step)
    # Times that do not rise with the steps: the step numbers instead.
    r, _ = reader_output(store("restarted", [(1, 5.0), (2, 0.5), (3, 1.0)]))
    assert r.GetTimestepValues() == [1.0, 2.0, 3.0]


def test_bad_input_is_a_clear_error(tmp_path, gsm, monkeypatch):
    with pytest.raises(ValueError, match="Dims"):
        gsenc_paraview.GsencReader().SetDims(10, 0, 4)
    monkeypatch.setenv("GSENC_PARAVIEW_BACKEND", "ctypes")
    r = gsenc_paraview.GsencReader()
    r.SetFileName(str(tmp_path / "x.gsi"))
    with pytest.raises(ValueError, match="gsm files only"):
        r._time_steps()
    r = gsenc_paraview.GsencReader()
    (tmp_path / "junk.gsm").write_bytes(b"not a model")
    r.SetFileName(str(tmp_path / "junk.gsm"))
    with pytest.raises(ValueError, match="not a gsenc model"):
        r._be().decode(str(tmp_path / "junk.gsm"), "", None, -1, (0, 0, 0))
