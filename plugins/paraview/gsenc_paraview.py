"""gsenc models in ParaView: a reader for ``.gsm`` model files, ``.gsi`` step
indexes (every rank's model of a step, blended into one global field) and
HDF5 stores (a time series: one time step per stored step, at the
simulation time its models carry, else at its step number).

Load it in ParaView with Tools > Manage Plugins > Load New (or put its folder
on ``PV_PLUGIN_PATH``); then File > Open a model. The model is decoded on
ParaView's side onto a lattice of ``Dims`` cells over the model's box (0, 0,
0, the default: the model's own reference lattice) and comes out as
``vtkImageData`` with the world origin and spacing (points at the cells'
centres) and the field's values, named after the field, in data units.

Decoding goes through the ``gsenc`` Python package when it is importable,
otherwise through the C ABI (``libgsenc.so``, found by ``GSENC_LIBRARY``, then
the system's library path) by ctypes; the C ABI reads ``.gsm`` files only.
``GSENC_PARAVIEW_BACKEND=python|ctypes`` forces one. The same class runs
headless with the plain ``vtk`` wheel (no ParaView): ParaView's decorators
are then no-ops.
"""

import ctypes
import ctypes.util
import math
import os

import numpy as np
from vtkmodules.util import numpy_support
from vtkmodules.util.vtkAlgorithm import VTKPythonAlgorithmBase
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline

try:
    from paraview.util.vtkAlgorithm import smdomain, smhint, smproperty, smproxy
except ImportError:  # plain VTK: ParaView's proxy decorators do nothing

    class _NoOp:
        def __getattr__(self, _name):
            return lambda *args, **kwargs: (lambda f: f)

    smdomain = smhint = smproperty = smproxy = _NoOp()

# What File > Open offers this reader for (ParaView takes them space-separated).
EXTENSIONS = "gsm gsi h5 hdf5"


def _is_store(path):
    return os.path.splitext(path)[1].lower() in (".h5", ".hdf5")


class _PythonBackend:
    """Decodes through the gsenc Python package."""

    def __init__(self):
        import gsenc

        self.gsenc = gsenc
        self.listed = None  # (path, the store's listing) of the last steps()

    def steps(self, path, field):
        """(field, [steps], [times]) of a store; (field, None, None) for a
        single model. A step's time is the simulation time its models
        carry, else its step number (as in the XDMF of `gsenc
        decode-series`); where those times do not rise with the steps, the step
        numbers are the times."""
        if not _is_store(path):
            return field, None, None
        store = self.gsenc.open_store(path)
        self.listed = (path, store)
        fields = store.fields()
        if not fields:
            raise ValueError(f"{path}: the store holds no model")
        field = field or fields[0]
        if field not in fields:
            raise ValueError(f"{path}: no field '{field}' (fields: {', '.join(fields)})")
        steps = store.steps(field)
        carried = {}
        for e in store.entries:
            if e["field"] == field and e.get("time") is not None and math.isfinite(e["time"]):
                carried.setdefault(e["step"], float(e["time"]))
        times = [carried.get(s, float(s)) for s in steps]
        if any(later <= earlier for earlier, later in zip(times, times[1:])):
            times = [float(s) for s in steps]
        return field, steps, times

    def decode(self, path, field, step, rank, dims):
        """(values [z][y][x] float32, origin, spacing, name)."""
        if _is_store(path):
            # Each time step reads its entry alone, from the listing made
            # when the steps were listed.
            listed = self.listed[1] if self.listed and self.listed[0] == path else self.gsenc.open_store(path)
            model = listed.read(field, step, None if rank < 0 else rank)
        else:
            model = self.gsenc.read(path)
        dims = tuple(dims) if all(d > 0 for d in dims) else None
        values = model.decode(dims=dims)
        centre, spacing = model.geometry(dims)
        name = field or model.info.get("field") or "scalar"
        return values, centre, spacing, name


class _GsencModelInfo(ctypes.Structure):
    """gsenc_model_info of include/gsenc.h."""

    _fields_ = [
        ("struct_size", ctypes.c_size_t),
        ("count", ctypes.c_uint64),
        ("dims", ctypes.c_uint64 * 3),
        ("origin", ctypes.c_double * 3),
        ("spacing", ctypes.c_double),
        ("step", ctypes.c_uint64),
        ("time", ctypes.c_double),
        ("rank", ctypes.c_uint32),
        ("iterations", ctypes.c_uint32),
        ("warm_started", ctypes.c_int32),
        ("encode_psnr", ctypes.c_double),
        ("fell_back", ctypes.c_int32),
        ("warm_taken", ctypes.c_int32),
        ("warm_moved", ctypes.c_uint32),
    ]


class _CtypesBackend:
    """Decodes ``.gsm`` files through the C ABI."""

    def __init__(self):
        path = os.environ.get("GSENC_LIBRARY") or ctypes.util.find_library("gsenc")
        if not path:
            raise OSError("libgsenc not found: set GSENC_LIBRARY to its path, or install the gsenc Python package")
        lib = ctypes.CDLL(path)
        lib.gsenc_model_read.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_void_p)]
        lib.gsenc_model_info_get.argtypes = [ctypes.c_void_p, ctypes.POINTER(_GsencModelInfo)]
        lib.gsenc_model_decode.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint64), ctypes.c_void_p, ctypes.c_uint64]
        lib.gsenc_model_field.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_size_t, ctypes.POINTER(ctypes.c_size_t)]
        lib.gsenc_model_destroy.argtypes = [ctypes.c_void_p]
        lib.gsenc_model_destroy.restype = None
        lib.gsenc_last_error.argtypes = [ctypes.c_char_p, ctypes.c_size_t]
        lib.gsenc_last_error.restype = ctypes.c_size_t
        self.lib = lib

    def _check(self, status):
        if status != 0:
            n = self.lib.gsenc_last_error(None, 0)
            buf = ctypes.create_string_buffer(n + 1)
            self.lib.gsenc_last_error(buf, n + 1)
            raise ValueError(f"gsenc: {buf.value.decode(errors='replace')}")

    def steps(self, path, field):
        if _is_store(path) or path.lower().endswith(".gsi"):
            raise ValueError(f"{path}: the C ABI reads .gsm files only; install the gsenc Python package for step indexes and stores")
        return field, None, None

    def decode(self, path, field, step, rank, dims):
        self.steps(path, field)
        model = ctypes.c_void_p()
        self._check(self.lib.gsenc_model_read(os.fsencode(path), ctypes.byref(model)))
        try:
            info = _GsencModelInfo(struct_size=ctypes.sizeof(_GsencModelInfo))
            self._check(self.lib.gsenc_model_info_get(model, ctypes.byref(info)))
            own = [int(d) for d in info.dims]
            lattice = [int(d) for d in dims] if all(d > 0 for d in dims) else own
            n = ctypes.c_size_t()
            self._check(self.lib.gsenc_model_field(model, None, 0, ctypes.byref(n)))
            name = ctypes.create_string_buffer(n.value + 1)
            self._check(self.lib.gsenc_model_field(model, name, n.value + 1, ctypes.byref(n)))
            values = np.empty(lattice[::-1], dtype=np.float32)
            c_dims = (ctypes.c_uint64 * 3)(*lattice)
            self._check(self.lib.gsenc_model_decode(model, c_dims, values.ctypes.data, values.size))
            # The model's box: its own lattice's cells; the lattice's cells divide it.
            spacing = tuple(info.spacing * own[a] / lattice[a] for a in range(3))
            centre = tuple(info.origin[a] + 0.5 * spacing[a] for a in range(3))
        finally:
            self.lib.gsenc_model_destroy(model)
        return values, centre, spacing, name.value.decode() or "scalar"


def _backend():
    choice = os.environ.get("GSENC_PARAVIEW_BACKEND", "")
    if choice == "ctypes":
        return _CtypesBackend()
    if choice == "python":
        return _PythonBackend()
    if choice:
        raise ValueError(f"GSENC_PARAVIEW_BACKEND={choice}: python or ctypes")
    try:
        return _PythonBackend()
    except ImportError:
        return _CtypesBackend()


@smproxy.reader(name="gsencReader", label="gsenc model", extensions=EXTENSIONS, file_description="gsenc models")
class GsencReader(VTKPythonAlgorithmBase):
    """A gsenc model, step index or store, decoded to vtkImageData."""

    def __init__(self):
        VTKPythonAlgorithmBase.__init__(self, nInputPorts=0, nOutputPorts=1, outputType="vtkImageData")
        self._path = None
        self._field = ""
        self._dims = (0, 0, 0)
        self._rank = -1
        self._backend = None
        self._steps = None  # a store's steps of the field, and their times
        self._times = None

    def _be(self):
        if self._backend is None:
            self._backend = _backend()
        return self._backend

    @smproperty.stringvector(name="FileName")
    @smdomain.filelist()
    @smhint.filechooser(extensions=EXTENSIONS, file_description="gsenc models")
    def SetFileName(self, path):
        if path != self._path:
            self._path = path
            self._steps = None
            self.Modified()

    @smproperty.stringvector(name="Field", default_values="")
    def SetField(self, field):
        """A store's field (default: its first)."""
        if field != self._field:
            self._field = field
            self._steps = None
            self.Modified()

    @smproperty.intvector(name="Dims", default_values=[0, 0, 0])
    def SetDims(self, x, y, z):
        """Cells of the decoded lattice over the model's box; 0, 0, 0: the model's own."""
        dims = (int(x), int(y), int(z))
        if any(d < 0 for d in dims) or (any(d > 0 for d in dims) and not all(d > 0 for d in dims)):
            raise ValueError(f"Dims {dims}: three positive numbers, or 0, 0, 0 for the model's own lattice")
        if dims != self._dims:
            self._dims = dims
            self.Modified()

    @smproperty.intvector(name="Rank", default_values=[-1])
    def SetRank(self, rank):
        """A store's rank (default -1: the only one, or every rank of a
        step blended into its global field where the store holds the step's
        index)."""
        if int(rank) != self._rank:
            self._rank = int(rank)
            self.Modified()

    def _time_steps(self):
        """The times of a store's steps ([] for a single model)."""
        if self._steps is None:
            if not self._path:
                raise ValueError("no FileName")
            field, steps, times = self._be().steps(self._path, self._field)
            self._field = field
            self._steps = [] if steps is None else list(steps)
            self._times = [] if times is None else list(times)
        return self._times

    @smproperty.doublevector(name="TimestepValues", information_only="1", si_class="vtkSITimeStepsProperty")
    def GetTimestepValues(self):
        if not self._path:
            return None  # ParaView asks before the file is set
        return self._time_steps() or None

    def RequestInformation(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        sddp = vtkStreamingDemandDrivenPipeline
        info.Remove(sddp.TIME_STEPS())
        info.Remove(sddp.TIME_RANGE())
        times = self._time_steps()
        for t in times:
            info.Append(sddp.TIME_STEPS(), t)
        if times:
            info.Set(sddp.TIME_RANGE(), [times[0], times[-1]], 2)
        return 1

    def RequestData(self, request, inInfo, outInfo):
        info = outInfo.GetInformationObject(0)
        sddp = vtkStreamingDemandDrivenPipeline
        times = self._time_steps()
        step = time = None
        if times:
            t = info.Get(sddp.UPDATE_TIME_STEP()) if info.Has(sddp.UPDATE_TIME_STEP()) else times[0]
            # The stored step at or before the time asked for (the first
            # before them all); the tolerance is relative to the times.
            eps = 1e-9 * max(1.0, abs(t))
            i = max([i for i, s in enumerate(times) if s <= t + eps] or [0])
            step, time = self._steps[i], times[i]
        values, centre, spacing, name = self._be().decode(self._path, self._field, step, self._rank, self._dims)
        out = vtkImageData.GetData(outInfo, 0)
        nz, ny, nx = values.shape
        out.SetDimensions(nx, ny, nz)
        out.SetOrigin(*centre)
        out.SetSpacing(*spacing)
        array = numpy_support.numpy_to_vtk(np.ascontiguousarray(values).ravel(), deep=True)
        array.SetName(name)
        out.GetPointData().SetScalars(array)
        if time is not None:
            out.GetInformation().Set(out.DATA_TIME_STEP(), time)
        return 1
