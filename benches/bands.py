#!/usr/bin/env python3
"""Where in the field two models of one deposit differ (the
samples-vs-grid question of docs/BENCHMARKS.md). Run after benches/inputs.sh:

    python3 benches/bands.py ROW [ROW...]

For each row it decodes bench-out/ROW.gsm (sample-seeded) and
bench-out/ROW.grid.gsm (voxel-seeded) to the deposit's lattice, normalised,
and prints the PSNR of each against bench-out/ROW.deposit.raw in bands of the
reference value: below the median, 50-90 %, 90-99 % and the top 1 % of voxels.
Standard library only; about 15 s per 256^3 row.
"""
import array, math, os, random, subprocess, sys, tempfile

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
BIN = os.path.join(ROOT, "target", "release", "gsenc")
OUT = os.path.join(ROOT, "bench-out")
BANDS = [("below median", 0.5), ("50-90 %", 0.9), ("90-99 %", 0.99), ("top 1 %", 1.0)]


def load(path):
    a = array.array("f")
    with open(path, "rb") as f:
        a.frombytes(f.read())
    return a


def decode(model, tmp):
    path = os.path.join(tmp, os.path.basename(model) + ".raw")
    subprocess.run([BIN, "decode", model, "--normalized", "-o", path, "--quiet"], check=True,
                   stdout=subprocess.DEVNULL)
    return load(path)


def main(rows):
    print("| row | band of reference values | voxels | samples PSNR dB | grid PSNR dB |")
    print("|---|---|---|---|---|")
    for row in rows:
        ref = load(os.path.join(OUT, row + ".deposit.raw"))
        with tempfile.TemporaryDirectory() as tmp:
            s = decode(os.path.join(OUT, row + ".gsm"), tmp)
            g = decode(os.path.join(OUT, row + ".grid.gsm"), tmp)
        if not (len(ref) == len(s) == len(g)):
            sys.exit(f"{row}: decoded sizes differ from the deposit")
        rng = random.Random(1)
        sub = sorted(rng.sample(list(ref), min(len(ref), 200_000)))
        cuts = [sub[int(q * len(sub)) - 1] if q < 1 else math.inf for _, q in BANDS]
        acc = [[0.0, 0.0, 0] for _ in BANDS]
        for r, a, b in zip(ref, s, g):
            i = 0
            while r > cuts[i]:
                i += 1
            e = acc[i]
            e[0] += (a - r) ** 2
            e[1] += (b - r) ** 2
            e[2] += 1
        for (name, _), (se_s, se_g, n) in zip(BANDS, acc):
            if n:
                p = lambda se: 10 * math.log10(n / max(se, 1e-20))
                print(f"| {row} | {name} | {n} | {p(se_s):.2f} | {p(se_g):.2f} |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
