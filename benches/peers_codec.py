"""The voxel codecs gsenc is compared with (benches/peers.sh): zfp (zfpy) in
fixed-rate mode and SZ3 (pysz) with an absolute error bound searched to a
byte target, both on the same normalised float32 grid gsenc is scored on.

Every codec call runs in a process of its own (this script calling itself):
pysz aborts on some large error bounds and zfp on rates below its 3D
minimum, and an abort must cost one point of the curve, not the run.

    python3 peers_codec.py grid-ref RAW DTYPE X,Y,Z DOWNSAMPLE OUT  # normalised reference
    python3 peers_codec.py score REF DECODED X,Y,Z                    # PSNR of a decode
    python3 peers_codec.py zfp REF X,Y,Z BYTES                        # one JSON line
    python3 peers_codec.py sz REF X,Y,Z BYTES                         # one JSON line

PSNR is 10 log10(1 / MSE) on values normalised to [0, 1], as gsenc's.
"""
import json
import math
import subprocess
import sys

import numpy as np


def load(path, dims):
    x, y, z = dims
    return np.fromfile(path, dtype="<f4").reshape(z, y, x)


def psnr(a, b):
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(1 / mse)


def grid_ref(raw, dtype, dims, factor, out):
    """The mean-downsampled grid normalised by its own min and max, as
    `gsenc encode grid --downsample` prepares it."""
    x, y, z = dims
    a = np.fromfile(raw, dtype={"u8": "u1", "u16": "<u2", "f32": "<f4", "f64": "<f8"}[dtype]).reshape(z, y, x).astype(np.float64)
    f = factor
    if f > 1:
        a = a[: z // f * f, : y // f * f, : x // f * f]
        a = a.reshape(z // f, f, y // f, f, x // f, f).mean(axis=(1, 3, 5))
    lo, hi = a.min(), a.max()
    ((a - lo) / (hi - lo)).astype("<f4").tofile(out)
    print(",".join(map(str, a.shape[::-1])))


def one(args):
    """A child process: one codec call; prints its bytes and PSNR."""
    codec, ref, dims, setting = args[0], args[1], [int(v) for v in args[2].split(",")], float(args[3])
    a = load(ref, dims)
    if codec == "zfp-one":
        import zfpy
        packed = zfpy.compress_numpy(a, rate=setting)
        back = zfpy.decompress_numpy(packed)
        size = len(packed)
    else:
        from pysz import sz, szConfig, szErrorBoundMode
        cfg = szConfig(a.shape)
        cfg.errorBoundMode = szErrorBoundMode.ABS
        cfg.absErrorBound = setting
        packed, _ = sz.compress(a, cfg)
        back, _ = sz.decompress(packed, np.float32, a.shape)
        size = int(packed.nbytes)
    print(json.dumps({"bytes": size, "psnr": psnr(a, back)}))


def child(codec, ref, dims, setting):
    r = subprocess.run([sys.executable, __file__, codec, ref, dims, repr(setting)], capture_output=True, text=True, timeout=600)
    if r.returncode != 0:
        return None
    return json.loads(r.stdout)


def zfp(ref, dims, target):
    voxels = math.prod(int(v) for v in dims.split(","))
    rate = target * 8 / voxels
    got = child("zfp-one", ref, dims, rate)
    if got is None:
        return {"codec": "zfp", "target_bytes": target, "rate": rate, "cannot_reach": f"zfp aborted at {rate:.3f} bits a value (below its fixed-rate minimum)"}
    return {"codec": "zfp", "target_bytes": target, "rate": rate, **got}


def sz(ref, dims, target):
    """The best PSNR of an SZ3 stream within `target` bytes. SZ3's size is
    not monotone in the error bound (near the sizes gsenc reaches it
    switches predictors, and a bound 5 % larger can give a larger stream),
    so the bound is swept: 8 steps a decade from 1e-6 to 0.5 of the range,
    then 48 a decade from half a decade below the finest bound that fits to
    a quarter above it. The best stream that fits wins."""
    def sweep(lo, hi, per_decade):
        n = int(round(per_decade * math.log10(hi / lo)))
        return [(eb, child("sz-one", ref, dims, eb)) for eb in (lo * 10 ** (k / per_decade) for k in range(n + 1))]

    fits = lambda r: r is not None and r["bytes"] <= target
    coarse = sweep(1e-6, 0.5, 8)
    found = [(eb, r) for eb, r in coarse if fits(r)]
    if not found:
        widest = coarse[-1][1]
        why = "SZ3 aborted" if widest is None else f"{widest['bytes']} bytes at an error bound of half the range"
        return {"codec": "sz3", "target_bytes": target, "cannot_reach": why}
    first = found[0][0]
    found += [(eb, r) for eb, r in sweep(first / 10 ** 0.5, min(first * 10 ** 0.25, 0.5), 48) if fits(r)]
    eb, best = max(found, key=lambda f: f[1]["psnr"])
    return {"codec": "sz3", "target_bytes": target, **best, "error_bound": eb}


def main():
    cmd, args = sys.argv[1], sys.argv[2:]
    if cmd == "grid-ref":
        grid_ref(args[0], args[1], [int(v) for v in args[2].split(",")], int(args[3]), args[4])
    elif cmd == "score":
        dims = [int(v) for v in args[2].split(",")]
        print(psnr(load(args[0], dims), load(args[1], dims)))
    elif cmd in ("zfp-one", "sz-one"):
        one([cmd] + args)
    elif cmd == "zfp":
        print(json.dumps(zfp(args[0], args[1], int(args[2]))))
    elif cmd == "sz":
        print(json.dumps(sz(args[0], args[1], int(args[2]))))
    else:
        sys.exit(f"unknown command {cmd}")


if __name__ == "__main__":
    main()
