#!/usr/bin/env bash
# The host's share of a GPU encode, on any machine: the GPU rows' training
# loops run on wgpu's no-op device (cargo feature `gpu-noop`,
# GSENC_ADAPTER=noop), which runs no kernel and returns at once, so the
# loop's time is what the host does for it: drawing the next batch, sorting
# it into bricks, recording and submitting the step, reading results back.
# The models are not fitted (the kernels never ran); only times count.
# What the no-op device cannot show is the driver's own share (NVIDIA's
# Vulkan driver recording and submitting): on the H200 the `submit` phase
# took 0.40 ms an iteration where this script measures 0.07-0.10 ms here.
# Rerun with:
#   bash benches/gpu_host.sh                       # medians of 3 runs a row
#   REPEAT=5 ROWS="rm128_32k_matched" bash benches/gpu_host.sh
#   GSENC_BIN=/path/to/other/gsenc bash benches/gpu_host.sh   # another build (with gpu-noop)
# Env: REPEAT (default 3) runs a row; ROWS selects rows by name; ITERS caps
# every row's iterations (default 3000; the 200K row 300); THREADS the
# encode's threads (default: every core, as benches/gpu.sh runs the GPU rows).
# Prints a Markdown table: per iteration, the loop and its phases
# (refine.rs `LoopPhases`; `draw` runs beside `submit` and `wait` on
# another pool thread), medians of the runs; each run's JSON line goes to
# bench-out/gpu_host.jsonl.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
out=bench-out
mkdir -p "$out"
# A target folder of its own: the feature changes wgpu's build.
CARGO_TARGET_DIR=target/noop gsenc_bin -p gsenc-cli --features gsenc/gpu-noop
log="$out/gpu_host.jsonl"
rm -f "$log"
threads=()
[ -n "${THREADS:-}" ] && threads=(--threads "$THREADS")
row() { # name iterations args...
    local name=$1 iters=$2 i; shift 2
    want "$name" || return 0
    for i in $(seq "${REPEAT:-3}"); do
        echo "[$name] run $i, $iters iterations" >&2
        GSENC_ADAPTER=noop "$bin" encode "$@" --iters "$iters" --backend gpu "${threads[@]}" -o "$out/gpu_host.gsm" --json --quiet \
            | python3 -c "import json,sys; d=json.load(sys.stdin); d['row']='$name'; print(json.dumps(d))" >> "$log"
    done
}
row rm128_32k_matched "${ITERS:-3000}" "${rm128[@]}" --range 0,255 --budget 32000 --schedule matched
row rm128_32k_full "${ITERS:-3000}" "${rm128[@]}" --range 0,255 --budget 32000 --schedule full
row hydrogen_4k_matched "${ITERS:-3000}" "${hyd[@]}" --budget 4096 --schedule matched
row rm256_200k_full "${ITERS:-300}" "${rm256[@]}" --range 0,255 --budget 200000 --schedule full
rm -f "$out/gpu_host.gsm"

python3 - "$log" <<'PY'
import json, statistics, sys
rows = {}
for line in open(sys.argv[1]):
    d = json.loads(line)
    if not d["backend"].startswith("wgpu:noop"):
        sys.exit(f"{d['row']} ran on {d['backend']}, not wgpu's no-op device")
    rows.setdefault(d["row"], []).append(d)
print("| row (no-op device) | runs | points | loop ms / iteration | draw | submit | wait |")
print("|---|---|---|---|---|---|---|")
for name, runs in rows.items():
    ms = lambda f: statistics.median(1e3 * f(d) / d["iterations"] for d in runs)
    phase = lambda k: f"{ms(lambda d: d['loop_phases'][k]):.3f}"
    print(f"| {name} | {len(runs)} | {runs[0]['points']} | {ms(lambda d: d['seconds']):.3f} | {phase('draw')} | {phase('submit')} | {phase('wait')} |")
PY
echo
echo "The GPU backend's own phases, ms an iteration (benches/host_phases.py):"
echo
python3 benches/host_phases.py "$log"
