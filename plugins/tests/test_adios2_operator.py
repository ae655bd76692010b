"""The ADIOS2 operator (plugins/adios2), chosen in adios2.xml alone: a BP5
file written through it and read back by ADIOS2's Python API."""

import os
import subprocess
import sys
import textwrap

import adios2
import gsenc
import numpy as np
import pytest
from adios2 import bindings
from conftest import blobs, psnr

DIMS = (40, 32, 24)  # x, y, z: the variable's shape is (24, 32, 40)
NAMES = ("rho", "line", "tiny", "holed")
BUDGET = 600


def xml(path, params):
    """An adios2.xml whose variables rho, line, tiny and holed go through gsenc."""
    keys = "".join(f'<parameter key="{k}" value="{v}"/>' for k, v in params.items())
    op = f'<operation type="plugin"><parameter key="PluginName" value="gsenc"/><parameter key="PluginLibrary" value="gsenc_adios2_operator"/>{keys}</operation>'
    variables = "".join(f'<variable name="{v}">{op}</variable>' for v in ("rho", "line", "tiny", "holed"))
    path.write_text(f'<?xml version="1.0"?><adios-config><io name="output"><engine type="BP5"/>{variables}</io></adios-config>')
    return str(path)


def write(path, config, steps):
    """What a simulation writes: its code knows nothing of gsenc."""
    ad = adios2.Adios(config) if config else adios2.Adios()
    io = ad.declare_io("output")
    variables = [io.define_variable(name, a, list(a.shape), [0] * a.ndim, list(a.shape)) for name, a in zip(NAMES, steps[0])]
    w = io.open(str(path), bindings.Mode.Write)
    for arrays in steps:
        w.begin_step()
        for v, a in zip(variables, arrays):
            w.put(v, a)
        w.end_step()
    w.close()


def read(path):
    """Every step's variables, through ADIOS2 (and the operator)."""
    ad = adios2.Adios()
    io = ad.declare_io("input")
    r = io.open(str(path), bindings.Mode.Read)
    out = []
    while r.begin_step() == bindings.StepStatus.OK:
        got = []
        for name, dtype in zip(NAMES, (np.float64, np.float64, np.float32, np.float64)):
            v = io.inquire_variable(name)
            a = np.zeros(v.shape(), dtype=dtype)
            r.get(v, a, bindings.Mode.Sync)
            got.append(a)
        r.end_step()
        out.append(got)
    r.close()
    return out


def size(path):
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(path) for f in files)


@pytest.fixture(scope="module")
def steps():
    """Two steps: a moving blob field (float64), a 1D line, a tiny 3D block,
    and a 3D field with a hole (a NaN)."""
    out = []
    for s in (0.0, 2.0):
        holed = blobs(DIMS, shift=-s)
        holed[3, 4, 5] = np.nan
        out.append((blobs(DIMS, shift=s), np.linspace(0.0, 1.0, 500) + s, np.arange(27, dtype=np.float32).reshape(3, 3, 3) * (1 + s), holed))
    return out


@pytest.fixture(scope="module")
def written(tmp_path_factory, steps, plugin_dir):
    d = tmp_path_factory.mktemp("adios2")
    os.environ["ADIOS2_PLUGIN_PATH"] = plugin_dir
    config = xml(d / "adios2.xml", dict(budget=BUDGET, schedule="short", threads=1, backend="cpu"))
    write(d / "gsenc.bp", config, steps)
    write(d / "raw.bp", None, steps)
    return d


def test_a_3d_block_reads_back_within_the_models_psnr(written, steps):
    back = read(written / "gsenc.bp")
    assert len(back) == 2
    for (rho, *_), (got, *_) in zip(steps, back):
        assert got.shape == rho.shape and got.dtype == np.float64
        # The model the operator stored is the one the Python package encodes
        # from the same block and settings (same pipeline, same seeds).
        model = gsenc.encode_grid(rho, BUDGET, schedule="short", payload="packed", threads=1)
        reached = psnr(got, rho)
        assert abs(reached - model.psnr) < 0.01, f"read back at {reached:.3f} dB, the model scores {model.psnr:.3f} dB"
        assert reached > 35.0
        # And its decode is what came back.
        np.testing.assert_allclose(got, model.decode().astype(np.float64), rtol=0, atol=0)


def test_other_shapes_tiny_blocks_and_refused_data_are_stored_raw(written, steps):
    for (_, line, tiny, holed), (_, got_line, got_tiny, got_holed) in zip(steps, read(written / "gsenc.bp")):
        np.testing.assert_array_equal(got_line, line)
        np.testing.assert_array_equal(got_tiny, tiny)
        np.testing.assert_array_equal(got_holed, holed)  # NaN where the NaN was


def test_the_file_is_smaller_than_the_raw_one(written):
    ours, raw = size(written / "gsenc.bp"), size(written / "raw.bp")
    # rho: two steps of 30,720 float64 values (491,520 bytes); the line,
    # tiny and holed blocks are raw in both files (499,736 bytes).
    rho, others = 491_520, 499_736
    assert raw > rho + others, f"{raw} bytes raw"
    assert ours - others < rho / 10, f"{ours} bytes through gsenc (rho {ours - others}), {raw} raw"


def test_reading_without_the_plugin_fails_with_adios2s_error(written):
    script = textwrap.dedent(f"""
        import adios2, numpy as np
        from adios2 import bindings
        io = adios2.Adios().declare_io("in")
        r = io.open({str(written / "gsenc.bp")!r}, bindings.Mode.Read)
        r.begin_step()
        v = io.inquire_variable("rho")
        a = np.zeros(v.shape())
        r.get(v, a, bindings.Mode.Sync)
    """)
    env = {k: v for k, v in os.environ.items() if k != "ADIOS2_PLUGIN_PATH"}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert done.returncode != 0
    assert "ADIOS2 EXCEPTION" in done.stderr and "plugin" in done.stderr, done.stderr


def test_a_bad_parameter_is_an_error_at_the_first_put(tmp_path, steps, plugin_dir):
    os.environ["ADIOS2_PLUGIN_PATH"] = plugin_dir
    for params, says in [(dict(budget="many"), "budget 'many'"), (dict(schedule="slow"), "schedule 'slow'"), (dict(colour="red"), "unknown parameter 'colour'"),
                         (dict(backend="tpu"), "backend 'tpu'"),
                         (dict(target_psnr="200"), "target_psnr '200'")]:
        with pytest.raises(Exception, match=says):
            write(tmp_path / "bad.bp", xml(tmp_path / "bad.xml", params), steps[:1])


def test_a_target_quality_instead_of_a_budget(tmp_path, steps, plugin_dir):
    os.environ["ADIOS2_PLUGIN_PATH"] = plugin_dir
    write(tmp_path / "t.bp", xml(tmp_path / "t.xml", dict(target_psnr=50, schedule="short", threads=1)), steps[:1])
    (got, *_), = read(tmp_path / "t.bp")
    assert abs(psnr(got, steps[0][0]) - 50.0) <= 1.0


# Reads step 0 of a BP file with bytes of data.0 changed, one change at a
# time, each restored before the next: a line per change, "same" (every
# value as read from the sound file), "error <message>" or "wrong".
DAMAGED_READER = textwrap.dedent("""
    import sys, numpy as np, adios2
    from adios2 import bindings
    path, sound = sys.argv[1], np.load(sys.argv[2])
    changes = [tuple(map(int, c.split(":"))) for c in sys.argv[3].split(",")]
    def step0():
        io = adios2.Adios().declare_io("in")
        r = io.open(path, bindings.Mode.Read)
        r.begin_step()
        got = []
        for name in sound.files:
            v = io.inquire_variable(name)
            a = np.zeros(v.shape(), dtype=sound[name].dtype)
            r.get(v, a, bindings.Mode.Sync)
            got.append(a)
        r.close()
        return got
    with open(path + "/data.0", "r+b") as f:
        for at, value in changes:
            f.seek(at); was = f.read(1); f.seek(at); f.write(bytes([value])); f.flush()
            try:
                got = step0()
                same = all(np.array_equal(a, sound[n], equal_nan=True) for a, n in zip(got, sound.files))
                print("same" if same else "wrong", flush=True)
            except Exception as e:
                print("error", str(e).replace(chr(10), " "), flush=True)
            f.seek(at); f.write(was); f.flush()
""")


def test_a_damaged_block_is_an_error_not_a_crash(written, tmp_path):
    """ADIOS2 does not tell the operator how large the buffer it decodes
    into is: the block's own header says it. One byte changed in a block's
    header (or in its model) must give an error naming the operator, or
    the sound values where the byte is one the operator does not need (the
    reserved bytes, the budget); before the header was checked against the
    model's lattice, a changed count made the reader write past ADIOS2's
    buffer (SIGSEGV)."""
    bp = tmp_path / "damaged.bp"
    import shutil
    shutil.copytree(written / "gsenc.bp", bp)
    (sound,) = [read(bp)[0]]
    np.savez(tmp_path / "sound.npz", **dict(zip(NAMES, sound)))
    data = (bp / "data.0").read_bytes()
    starts = [i for i in range(len(data)) if data[i:i + 4] == b"GSA2"]
    assert len(starts) == 2 * len(NAMES), starts  # a block per variable and step
    changes, models = [], 0
    for at in starts[:len(NAMES)]:  # step 0's blocks
        ndims = data[at + 7]
        header = 16 + 8 * ndims + 16
        body = int.from_bytes(data[at + header - 8:at + header], "little")
        models += data[at + 5] == 1
        # Every header byte; every 61st byte of a model (a raw block's
        # values are the values).
        where = list(range(at, at + header)) + (list(range(at + header, at + header + body, 61)) if data[at + 5] == 1 else [])
        for w in where:
            for v in sorted({data[w] ^ 0x01, data[w] ^ 0x80, 0x00, 0xFF} - {data[w]}):
                changes.append((w, v))
    assert models == 1  # rho is a model; the line, the tiny block and the holed field are raw
    done = subprocess.run([sys.executable, "-c", DAMAGED_READER, str(bp), str(tmp_path / "sound.npz"), ",".join(f"{a}:{v}" for a, v in changes)],
                          capture_output=True, text=True)
    lines = done.stdout.splitlines()
    assert done.returncode == 0, f"the reader died ({done.returncode}) at change {len(lines)} of {len(changes)}, byte {changes[len(lines)][0] - starts[0]} from the first block: {done.stderr[-2000:]}"
    assert len(lines) == len(changes)
    same = set()
    for (w, v), line in zip(changes, lines):
        block = max(s for s in starts if s <= w)
        offset = w - block
        assert line == "same" or (line.startswith("error") and "gsenc ADIOS2 operator" in line), f"byte {offset} of the block at {block} set to {v}: {line}"
        if line == "same":
            same.add(offset)
        # A 3D block's count (bytes 16 to 39) changed is always an error.
        assert not (data[block + 7] == 3 and 16 <= offset < 40 and line == "same"), f"byte {offset} of the block at {block} set to {v}"
    assert {12, 13, 14, 15} <= same, same  # reserved
