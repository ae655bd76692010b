"""Reads a gsenc HDF5 store with h5py alone, following docs/FORMAT.md, and
checks every entry against the float32 model file `gsenc store extract`
writes for it, and a model's support against the data it was encoded from:
the store is readable without gsenc.

    python3 tests/store_h5py.py GSENC_BINARY
Builds its own store from random models written by `gsenc store add`.
"""
import os
import struct
import subprocess
import sys
import tempfile
import zlib

import h5py
import numpy as np

gsenc = sys.argv[1]


def read_store_entry(g):
    """Parameters (12 x N) of one entry, from the layout in docs/FORMAT.md."""
    if g.attrs["payload"] == "f32":
        return g["params"][()].astype(np.float64)
    c, k = g["centres"], g["codes"]
    if c.dtype == np.float16:
        mu = c[()].astype(np.float64)
    else:
        lo, hi = c.attrs["lo"].astype(np.float32), c.attrs["hi"].astype(np.float32)
        mu = lo[:, None] + (hi - lo)[:, None] * (c[()].astype(np.float32) / np.float32(65535))
    lo, hi = k.attrs["lo"].astype(np.float32), k.attrs["hi"].astype(np.float32)
    rest = lo[:, None] + (hi - lo)[:, None] * (k[()].astype(np.float32) / np.float32(255))
    return np.vstack([mu, rest]).astype(np.float64)


def read_gsm_f32(path):
    """Parameters (12 x N) of a float32 .gsm file (docs/FORMAT.md)."""
    b = open(path, "rb").read()
    assert b[:8] == b"GSENCMDL"
    header_len = struct.unpack_from("<I", b, 12)[0]
    payload, count = struct.unpack_from("<IQ", b, 16)
    assert payload == 0
    body = np.frombuffer(b, dtype="<f4", count=12 * count, offset=16 + header_len)
    return body.reshape(count, 12).T.astype(np.float64)


def write_gsm_f32(path, params, field, step, rank, curve=None, fell_back=None, warm=None):
    """A float32 model file with the given parameters, without a support:
    version 1.1; with why it `fell_back` (text) and an `auto` `warm` start
    ((code, moved)) 1.4; with a target PSNR's `curve` (two slopes) 1.5, no
    fall-back and no warm start (0xff, 0 moved)."""
    h = struct.pack("<IQ3I3dd2dI", 0, params.shape[0], 32, 32, 32, 0, 0, 0, 1.0, 0.0, 1.0, 0)
    h += struct.pack("<QIIQQ", step, 10, 100, 1, 2)
    for s in ("short", field):
        h += struct.pack("<H", len(s)) + s.encode()
    h += struct.pack("<dId", 0.5 * step, rank, float("nan"))
    minor = 1
    if curve is not None:
        h += struct.pack("<IHBI2d", 0, 0, 0xFF, 0, *curve)
        minor = 5
    elif warm is not None:
        text = fell_back.encode()
        h += struct.pack("<IH", 0, len(text)) + text + struct.pack("<BI", *warm)
        minor = 4
    b = b"GSENCMDL" + struct.pack("<HHI", 1, minor, len(h)) + h + params.astype("<f4").tobytes()
    b += struct.pack("<I", zlib.crc32(b))
    open(path, "wb").write(b)


WARM_CODES = {"kept": 0, "repaired": 1, "fresh": 2}


def entry_crc(g):
    """An f32 entry's checksum, following docs/FORMAT.md "The entry
    checksum": the model file's first header fields (payload code, count,
    frame, range, step, schedule, seeds, field, time, rank, encode PSNR),
    then why it fell back, a warm start (or 0xff), a target PSNR's curve
    (where there is one), the support's bits and outside (where there is
    one), and the parameters primitive by primitive, float32."""
    a = g.attrs
    assert a["payload"] == "f32" and a["transform"] == "linear"
    h = struct.pack("<IQ", 0, int(a["count"])) + struct.pack("<3I", *(int(d) for d in a["dims"]))
    h += struct.pack("<3d", *a["bmin"]) + struct.pack("<dddI", a["gamma"], a["vmin"], a["vmax"], 0)
    h += struct.pack("<QIIQQ", int(a["step"]), int(a["iterations"]), int(a["points"]), int(a["seed_init"]), int(a["seed_sample"]))
    for name in ("schedule", "field"):
        text = a[name].encode()
        h += struct.pack("<H", len(text)) + text
    h += struct.pack("<dId", a["time"], int(a["rank"]), a["encode_psnr"])
    fell_back = a["fell_back"].encode() if "fell_back" in a else b""
    h += struct.pack("<Q", len(fell_back)) + fell_back
    if "warm_start" in a:
        h += struct.pack("<BI", WARM_CODES[a["warm_start"]], int(a["warm_moved"]))
    else:
        h += b"\xff"
    if "target_curve" in a:
        h += struct.pack("<2d", *a["target_curve"])
    if "support" in g:
        outside = g["support"].attrs["outside"] if "outside" in g["support"].attrs else (0.0, 0.0)
        h += g["support"][()].tobytes() + struct.pack("<2f", *outside)
    return zlib.crc32(h + np.ascontiguousarray(g["params"][()].T).astype("<f4").tobytes())


def checksum_checked(g, name):
    """1 when `entry_crc(g)` differs from the entry's stored sum, printed."""
    ours, stored = entry_crc(g), int(g.attrs["crc32"])
    print(f"h5py {name} checksum: {ours:08x} computed, {stored:08x} stored", "ok" if ours == stored else "FAILED")
    return int(ours != stored)


def main():
    rng = np.random.default_rng(7)
    failures = 0
    with tempfile.TemporaryDirectory() as d:
        store = os.path.join(d, "s.h5")
        for i, payload in enumerate(["f32", "8bit", "8bit-u16", "f32"]):
            n = 500 + 13 * i
            p = np.column_stack([rng.uniform(0, 31, (n, 3)), rng.uniform(-2, 1, (n, 3)), rng.uniform(-3, 3, (n, 6))])
            m = os.path.join(d, f"m{i}.gsm")
            # The first float32 entry's model holds a target PSNR's curve;
            # the second fell back to the CPU and is an `auto` warm step.
            extra = {0: dict(curve=(1.75, 0.625)), 3: dict(fell_back="GPU 'x': device lost", warm=(1, 37))}.get(i, {})
            write_gsm_f32(m, p, "rho", 10 + i, i, **extra)
            subprocess.run([gsenc, "store", "add", store, m, "--payload", payload], check=True, capture_output=True)
        with h5py.File(store, "r") as f:
            assert f.attrs["gsenc_store"] == "1.5"
            entries = [(field, step, rank) for field in f for step in f[field] for rank in f[field][step]]
            assert len(entries) == 4, entries
            for field, step, rank in entries:
                g = f[field][step][rank]
                mine = read_store_entry(g)
                out = os.path.join(d, "x.gsm")
                subprocess.run([gsenc, "store", "extract", store, f"{field}/{step}/{rank}", "-o", out,
                                "--payload", "f32"], check=True, capture_output=True)
                theirs = read_gsm_f32(out)
                err = np.max(np.abs(mine - theirs) / np.maximum(np.abs(theirs), 1.0))
                ok = mine.shape == (12, g.attrs["count"]) and err <= 1e-6
                failures += not ok
                print(f"h5py {field}/{step}/{rank} {g.attrs['payload']}: max relative difference {err:.2e}",
                      "ok" if ok else "FAILED")
                if g.attrs["payload"] == "f32":
                    if step == "10":
                        assert list(g.attrs["target_curve"]) == [1.75, 0.625]
                    else:
                        assert (g.attrs["warm_start"], g.attrs["warm_moved"]) == ("repaired", 37)
                        assert g.attrs["fell_back"] == "GPU 'x': device lost"
                    failures += checksum_checked(g, f"{field}/{step}/{rank}")
        failures += check_support(d)
    print(f"h5py: {8 - failures} passed, {failures} failed")
    sys.exit(1 if failures else 0)


def check_support(d):
    """A grid with an empty region, encoded by gsenc and stored: the entry's
    `support` dataset, unpacked by numpy, is where the normalised data
    exceed 0.005. Returns the number of failures."""
    dims = (12, 10, 8)
    z, y, x = np.meshgrid(*[np.arange(n) for n in reversed(dims)], indexing="ij")
    data = np.where(x < 7, 1.0 + np.sin(x + 2 * y) ** 2 + z, 0.0).astype("<f4")
    raw, model, store = (os.path.join(d, n) for n in ("g.f32", "g.gsm", "support.h5"))
    data.tofile(raw)
    subprocess.run([gsenc, "encode", "grid", "--input", raw, "--dims", ",".join(map(str, dims)), "--dtype", "f32",
                    "--budget", "40", "--iters", "10", "--points", "256", "-o", model, "--quiet"], check=True, capture_output=True)
    subprocess.run([gsenc, "store", "add", store, model], check=True, capture_output=True)
    with h5py.File(store, "r") as f:
        g = f["scalar"]["0"]["rank_0"]
        bits = np.unpackbits(g["support"][()], bitorder="little")[: data.size]
        summed = checksum_checked(g, "support entry")
    want = ((data - data.min()) / (data.max() - data.min()) > 0.005).ravel()
    ok = bits.shape == want.shape and np.array_equal(bits.astype(bool), want) and 0 < want.sum() < want.size
    print(f"h5py support: {int(bits.sum())} of {bits.size} voxels", "ok" if ok else "FAILED")
    return (0 if ok else 1) + summed


main()
