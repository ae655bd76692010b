#!/usr/bin/env bash
# In-situ benchmark with the C mock solver of benches/insitu.c on a
# 128^3 float grid, one core for the solver and one for the encoder (its
# pool has 1 thread): push latency, solver step time with and without
# encoding every step, and encode throughput (the solver doing no work, so
# the encoder sets the pace). Prints a table of medians over RUNS runs.
#   bash benches/insitu.sh [RUNS [STEPS [SWEEPS [BUDGET [ITERATIONS [WARM_ITERATIONS]]]]]]
#   (defaults 3 runs, 12 steps, 1800 Jacobi sweeps a step (about 4 s here),
#   4000 Gaussians, 200 iterations for step 0, 60 for warm steps)
# INSITU_BIN names a prebuilt mock solver (the cc line below, run elsewhere)
# for a machine without a Rust toolchain. INSITU_CPUS runs the whole process
# on those CPUs (taskset), as an MPI rank bound to them runs: INSITU_CPUS=0
# puts the solver and the encoder on one core, where the encoder's priority
# (GSENC_ENCODER_PRIORITY=normal|low|idle, read by the library) decides
# who waits; GSENC_ENCODER_CPUS places the encoder's threads within them.
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-3} steps=${2:-12} sweeps=${3:-1800} budget=${4:-4000} iters=${5:-200} warm=${6:-60}
out=bench-out/insitu
mkdir -p "$out"
if [ -n "${INSITU_BIN:-}" ]; then
    cp "$INSITU_BIN" "$out/insitu"
else
    cargo build --release --locked -p gsenc-capi >&2
    cc -std=c99 -O2 -Iinclude -Iexamples_c benches/insitu.c target/release/libgsenc.a -lpthread -ldl -lm -o "$out/insitu"
fi
: > "$out/runs.jsonl"
run=()
[ -z "${INSITU_CPUS:-}" ] || run=(taskset -c "$INSITU_CPUS")
for r in $(seq "$runs"); do
    for mode in 0 1; do
        rm -rf "$out/models" && mkdir -p "$out/models"
        "${run[@]}" "$out/insitu" "$out/models" "$steps" "$mode" "$sweeps" "$budget" "$iters" "$warm" 1 | tee -a "$out/runs.jsonl" >&2
    done
    rm -rf "$out/models" && mkdir -p "$out/models"
    "${run[@]}" "$out/insitu" "$out/models" "$steps" 1 0 "$budget" "$iters" "$warm" 1 | sed 's/^{/{"encoder_bound":1,/' | tee -a "$out/runs.jsonl" >&2
done
python3 - "$out/runs.jsonl" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
plain = [r for r in rows if r["encode"] == 0]
insitu = [r for r in rows if r["encode"] == 1 and "encoder_bound" not in r]
bound = [r for r in rows if "encoder_bound" in r]
med = lambda rs, k: statistics.median(r[k] for r in rs)
base, with_enc = med(plain, "step_mean_s"), med(insitu, "step_mean_s")
print(f"| quantity | median of {len(plain)} runs |")
print("|---|---|")
print(f"| solver step, no encoding | {base:.3f} s |")
print(f"| solver step, encoding every step (compute + push) | {with_enc:.3f} s ({100 * (with_enc / base - 1):+.1f} %) |")
print(f"| push latency, median of steps | {med(insitu, 'push_median_ms'):.2f} ms |")
print(f"| push latency, max of steps | {med(insitu, 'push_max_ms'):.2f} ms (worst run {max(r['push_max_ms'] for r in insitu):.2f} ms) |")
print(f"| push latency, max of steps after the first | {med(insitu, 'push_max_after_first_ms'):.2f} ms (worst run {max(r['push_max_after_first_ms'] for r in insitu):.2f} ms) |")
print(f"| final wait after the last step | {med(insitu, 'final_wait_s'):.2f} s |")
print(f"| encode throughput, encoder-bound | {med(bound, 'encode_steps_per_s'):.3f} steps/s ({med(bound, 'encode_steps_per_s') * 128**3 / 1e6:.2f} Mvoxel/s) |")
print(f"| push latency, encoder-bound (queue growing) | median {med(bound, 'push_median_ms'):.2f} ms, max {med(bound, 'push_max_ms'):.2f} ms |")
print(f"| last step's PSNR | {med(insitu, 'last_psnr'):.2f} dB |")
PY
