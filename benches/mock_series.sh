#!/usr/bin/env bash
# Warm starts in the library's own in-situ path: the C mock solver of
# examples_c/mock_solver.c at the package test's settings (tests/package.sh:
# 20 steps, 1,000 Gaussians, 300 iterations for step 0, 150 per warm step),
# once with each warm start of MODES, and once with every step a fresh
# encode given the warm steps' 150 iterations ("fresh150"). Prints, per step
# and field, the PSNR each run's models scored at encode time, and per warm
# mode how many warm steps end at least as high as the fresh encode of that
# step (within 0.3 dB) and the trend of the grid's PSNR over the warm steps.
#   bash benches/mock_series.sh [STEPS [MODES]]   (defaults 20, "auto dense")
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:-20} modes=${2:-auto dense}
out=bench-out/mock_series
mkdir -p "$out"
cargo build --release --locked -p gsenc-capi >&2
cc -std=c99 -O2 -Iinclude -Iexamples_c examples_c/mock_solver.c target/release/libgsenc.a -lpthread -ldl -lm -o "$out/mock_solver"
run() { # NAME ITERATIONS WARM_ITERATIONS WARM
    rm -rf "$out/$1" && mkdir -p "$out/$1"
    "$out/mock_solver" "$out/$1" "$steps" 1000 "$2" "$3" "$4" > "$out/$1.txt"
    echo "[mock_series] $1 done" >&2
}
run fresh150 150 150 off
for m in $modes; do run "$m" 300 150 "$m"; done
python3 - "$out" "$steps" $modes <<'PY'
import re, sys
out, steps, modes = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
def load(name):
    rows = {}
    for line in open(f"{out}/{name}.txt"):
        m = re.match(r"step\s+(\d+)", line)
        if m:
            rows[int(m.group(1))] = {f: float(v) for f, v in re.findall(r"(\w+) (-?[\d.]+|inf) dB", line)}
    return rows
fresh = load("fresh150")
fields = sorted(next(iter(fresh.values())))
print("| step | " + " | ".join(f"{f} {r}" for f in fields for r in ["fresh150"] + modes) + " |")
print("|---|" + "---|" * (len(fields) * (1 + len(modes))))
runs = {m: load(m) for m in modes}
for s in sorted(fresh):
    print(f"| {s} | " + " | ".join(f"{(runs[r] if r in runs else fresh)[s][f]:.2f}" for f in fields for r in ["fresh150"] + modes) + " |")
print()
for m in modes:
    for f in fields:
        warm = [s for s in sorted(fresh) if s > 0]
        ok = sum(runs[m][s][f] >= fresh[s][f] - 0.3 for s in warm)
        worst = min(runs[m][s][f] - fresh[s][f] for s in warm)
        half = len(warm) // 2
        first, last = warm[:half], warm[half:]
        trend = sum(runs[m][s][f] for s in last) / len(last) - sum(runs[m][s][f] for s in first) / len(first)
        print(f"- {m} {f}: {ok} of {len(warm)} warm steps at least the fresh 150-iteration encode (within 0.3 dB), "
              f"worst {worst:+.2f} dB; mean of the second half minus the first {trend:+.2f} dB "
              f"(fresh: {sum(fresh[s][f] for s in last) / len(last) - sum(fresh[s][f] for s in first) / len(first):+.2f} dB)")
PY
