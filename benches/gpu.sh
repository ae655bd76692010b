#!/usr/bin/env bash
# The GPU backend's benchmark rows and the same rows on the CPU backend (all
# cores) for the ratio: one prepared script for a lent GPU machine, under
# 8 minutes there. Rerun with:
#   bash benches/gpu.sh                                    # a machine with a GPU
#   GSENC_ADAPTER=llvmpipe ITERS=100 bash benches/gpu.sh   # lavapipe: correctness only
# Env: ITERS caps every row's iterations (default: the schedule's);
# CPU_ITERS caps the CPU rows (default 200: the ratio is per iteration, so
# the CPU rows need not run the whole schedule; CPU_ITERS= runs the whole
# schedule, which the PSNR gap needs); ROWS selects rows by name, WHICH
# the backends (default "gpu gpuw gpub gpu4 cpu"; gpuw is the GPU with a
# step's uploads written buffer by buffer, GSENC_GPU_UPLOAD=writes, run
# beside each gpu run, for what the mapped staging buffer saves; gpub the
# GPU with BATCH (default 4) training steps to a submission,
# GSENC_GPU_BATCH, run beside each gpu run, for what the driver's cost per
# submission takes from a step; gpu1 (not
# run by default: measured 2026-12-04) the GPU with one training step in
# flight rather than two, GSENC_GPU_DEPTH=1; gpunt (not run by default:
# 0.92-1.11x, noise, on 2026-12-04) the GPU without timestamp queries,
# GSENC_GPU_TIMING=0, once a row, for what timing every pass costs; gpu4
# the GPU with a host pool of 4 threads, --threads 4, once a row, for
# whether waking every core costs the host's draw); REPEAT
# (default 1) runs each GPU row that many times (the table takes medians)
# while the script is younger than DEADLINE seconds (default 300);
# ROW_LIMIT (default 150 s; 240 s for the in-situ run) stops any one run,
# recorded as timed out, and
# STOP_AFTER (seconds, default none) skips every run that would start later,
# so the script ends in time; DECODE_WHICH (default "gpu cpu"; empty: no
# decode) the decode's
# backends (the CPU's decode of 1024^3 took over 110 s on the H200's 16
# cores); INSITU=0 skips the in-situ run (benches/insitu.sh,
# one run of 8 steps, on the GPU backend); OUT (the device machine's output
# folder) receives every result as soon as it exists. On a machine without a
# Rust toolchain, GSENC_BIN names a prebuilt gsenc and INSITU_BIN a prebuilt
# benches/insitu.c (both built elsewhere with --release), and nothing is built.
# Prints one JSON line per run to bench-out/gpu.jsonl, the adapters to
# bench-out/gpu-devices.json, a Markdown table of the rows (and, as
# comments, each row's ratio of uploads through the staging buffer to
# writes buffer by buffer, of steps batched to one a submission, and of
# two steps in flight to one when gpu1 ran), and a table of
# where each GPU row's loop went per iteration (draw, submit, wait, device).
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
out=bench-out
mkdir -p "$out"
gsenc_bin
log="$out/gpu.jsonl"
rm -f "$log"
keep() { [ -z "${OUT:-}" ] || cp "$@" "$OUT"/ 2>/dev/null || true; }
"$bin" devices --json > "$out/gpu-devices.json"
cat "$out/gpu-devices.json" >&2
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv > "$out/gpu-nvidia-smi.csv" || true
lscpu | grep -E "Model name|^CPU\(s\)|Thread\(s\) per core|Core\(s\) per socket|Socket\(s\)" > "$out/gpu-cpu.txt" || true
keep "$out/gpu-devices.json" "$out/gpu-nvidia-smi.csv" "$out/gpu-cpu.txt"

rm_args=(--input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8 --range 0,255)
h_args=(--input "$data/hydrogen_atom.float32" --dims 64,64,64 --dtype f32)
late() { # true (and says so) when STOP_AFTER has passed
    [ -n "${STOP_AFTER:-}" ] && [ "$SECONDS" -ge "$STOP_AFTER" ] && echo "[$1] skipped: STOP_AFTER=$STOP_AFTER s passed" >&2
}

run() { # name backend iteration-cap args...
    local name=$1 backend=$2 cap=$3; shift 3
    want "$name" || return 0
    [[ " ${WHICH:-gpu gpuw gpub gpu4 cpu} " == *" $backend "* ]] || return 0
    late "$name" && return 0
    local iters=()
    [ -n "$cap" ] && iters=(--iters "$cap")
    echo "[$name] $backend ${iters[*]}" >&2
    local result
    # `gpu1`: the GPU with one training step in flight instead of two.
    local depth=2 as=$backend timing=1 upload= batch=1 threads=()
    [ "$backend" = gpu1 ] && depth=1 as=gpu
    [ "$backend" = gpunt ] && timing=0 as=gpu
    [ "$backend" = gpuw ] && upload=writes as=gpu
    [ "$backend" = gpub ] && batch=${BATCH:-4} as=gpu
    [ "$backend" = gpu4 ] && threads=(--threads 4) as=gpu
    if result=$(GSENC_GPU_DEPTH=$depth GSENC_GPU_TIMING=$timing GSENC_GPU_UPLOAD=$upload GSENC_GPU_BATCH=$batch timeout "${ROW_LIMIT:-150}" "$bin" encode grid "$@" "${iters[@]}" "${threads[@]}" --backend "$as" -o "$out/gpu_${name}_$backend.gsm" --json --quiet); then
        echo "$result" | python3 -c "import json,sys; d=json.load(sys.stdin); d['row']='$name'; d['which']='$backend'; print(json.dumps(d))" >> "$log"
    else
        echo "{\"row\": \"$name\", \"which\": \"$backend\", \"failed_or_timed_out\": true}" >> "$log"
    fi
    keep "$log"
}

row() { # name args...: the row on the GPU, then on the CPU
    local name=$1; shift
    local i
    for i in $(seq "${REPEAT:-1}"); do
        [ "$i" = 1 ] || [ "$SECONDS" -lt "${DEADLINE:-300}" ] || break
        run "$name" gpu "${ITERS:-}" "$@"
        run "$name" gpuw "${ITERS:-}" "$@"
        run "$name" gpub "${ITERS:-}" "$@"
        run "$name" gpu1 "${ITERS:-}" "$@"
    done
    run "$name" gpunt "${ITERS:-}" "$@"
    run "$name" gpu4 "${ITERS:-}" "$@"
    run "$name" cpu "${CPU_ITERS-200}" "$@"
}

row rm128_32k_matched "${rm_args[@]}" --downsample 2 --budget 32000 --schedule matched
row rm128_32k_full "${rm_args[@]}" --downsample 2 --budget 32000 --schedule full
row hydrogen_4k_matched "${h_args[@]}" --budget 4096 --schedule matched
row rm256_200k_full "${rm_args[@]}" --budget 200000 --schedule full

# The decode of 1024^3 (4 GiB of float32, streamed to disk and deleted).
if want decode_1024 && [ -n "${DECODE_WHICH-gpu cpu}" ]; then
    "$bin" encode grid "${h_args[@]}" --budget 4096 --schedule short --iters 100 --backend cpu -o "$out/gpu_decode_model.gsm" --quiet
    for backend in ${DECODE_WHICH-gpu cpu}; do
        late decode_1024 && break
        echo "[decode_1024] $backend" >&2
        if result=$(timeout "${ROW_LIMIT:-150}" "$bin" decode "$out/gpu_decode_model.gsm" --dims 1024,1024,1024 --backend "$backend" -o "$out/gpu_decode.raw" --json); then
            echo "$result" | python3 -c "import json,sys; d=json.load(sys.stdin); d['row']='decode_1024'; d['which']='$backend'; print(json.dumps(d))" >> "$log"
        else
            echo "{\"row\": \"decode_1024\", \"which\": \"$backend\", \"failed_or_timed_out\": true}" >> "$log"
        fi
        rm -f "$out/gpu_decode.raw"
        keep "$log"
    done
fi

# Push latency and the solver's slowdown with the encoder on the GPU.
if [ "${INSITU:-1}" = 1 ] && want insitu && ! late insitu; then
    GSENC_BACKEND=gpu timeout "${ROW_LIMIT:-240}" bash benches/insitu.sh 1 8 600 > "$out/gpu-insitu.md" || echo "insitu: failed or timed out" >> "$out/gpu-insitu.md"
    cat "$out/gpu-insitu.md" >&2
    keep "$out/gpu-insitu.md"
    [ -z "${OUT:-}" ] || cp bench-out/insitu/runs.jsonl "$OUT/gpu-insitu-runs.jsonl" 2>/dev/null || true
fi

python3 - "$log" <<'PY' | tee "$out/gpu-table.md"
import json, statistics, sys
rows = {}
for line in open(sys.argv[1]):
    d = json.loads(line)
    if d.get("failed_or_timed_out"):
        print(f"<!-- {d['row']} on {d['which']}: failed or timed out -->")
        continue
    rows.setdefault(d["row"], {}).setdefault(d["which"], []).append(d)
# Repeated runs: the median time; the PSNR of the first (runs on one
# adapter are bitwise equal, so any run's PSNR is the same).
sec = lambda runs: statistics.median(d["seconds"] for d in runs)
print("| row | backend | runs | iterations | voxel PSNR dB | loop s (median) | s / iteration | GPU speed-up per iteration | PSNR gap dB |")
print("|---|---|---|---|---|---|---|---|---|")
for name, by in rows.items():
    if name == "decode_1024":
        for w, runs in by.items():
            ratio = f"{sec(by['cpu']) / sec(runs):.1f}x" if w == "gpu" and "cpu" in by else ""
            print(f"| {name} | {runs[0].get('backend', w)} | {len(runs)} | | | {sec(runs):.2f} | | {ratio} | |")
        continue
    per = {w: sec(runs) / runs[0]["iterations"] for w, runs in by.items()}
    for w, runs in by.items():
        d = runs[0]
        gpu = w.startswith("gpu")
        ratio = f"{per['cpu'] / per[w]:.1f}x" if gpu and "cpu" in per else ""
        gap = ""
        if gpu and "cpu" in by and by["cpu"][0]["iterations"] == d["iterations"]:
            gap = f"{d['voxel_psnr'] - by['cpu'][0]['voxel_psnr']:+.3f}"
        print(f"| {name} | {d['backend']} ({w}) | {len(runs)} | {d['iterations']} | {d['voxel_psnr']:.2f} | {sec(runs):.2f} | {per[w]*1e3:.2f} ms | {ratio} | {gap} |")
    # Each variant beside the gpu runs: its comment's words around the
    # ratio, and whether the ratio is the variant's time over gpu's (else
    # gpu's over the variant's).
    for w, before, after, over_gpu in (
        ("gpu1", "two steps in flight", "x one", True),
        ("gpuw", "a step's uploads through its staging buffer", "x faster than buffer by buffer", True),
        ("gpub", "steps batched to a submission", "x faster than one a submission", False),
        ("gpu4", "a host pool of every core", "x faster than of 4 threads", True),
        ("gpunt", "timing every pass costs", "x an iteration without", False),
    ):
        if "gpu" in by and w in by:
            same = by["gpu"][0]["voxel_psnr"] == by[w][0]["voxel_psnr"]
            ratio = per[w] / per["gpu"] if over_gpu else per["gpu"] / per[w]
            print(f"<!-- {name}: {before} {ratio:.2f}{after}; same model: {same} -->")
# Where a GPU row's loop went, per iteration (medians over the runs): the
# host's phases (refine.rs `LoopPhases`; drawing runs beside submit and
# wait when the pool has a second thread) and the kernels' device time.
print()
print("| row | loop ms / it | draw | submit | wait | device (every kernel of the run) |")
print("|---|---|---|---|---|---|")
for (name, w), runs in [((n, w), by.get(w, [])) for n, by in rows.items() for w in ("gpu", "gpuw", "gpub", "gpu1", "gpunt", "gpu4")]:
    if name == "decode_1024" or not runs or "loop_phases" not in runs[0]:
        continue
    it = runs[0]["iterations"]
    ms = lambda f: statistics.median(f(d) for d in runs) * 1e3 / it
    phase = lambda k: f"{ms(lambda d: d['loop_phases'][k]):.3f}"
    device = ms(lambda d: sum(v.get("seconds", 0) for v in (d.get("kernel_seconds") or {}).values()))
    print(f"| {name} ({w}) | {ms(lambda d: d['seconds']):.3f} | {phase('draw')} | {phase('submit')} | {phase('wait')} | {device:.3f} |")
PY
# The GPU backend's share of `submit` and `wait`, by phase (none without GPU rows).
{ echo; python3 benches/host_phases.py "$log" || true; } | tee -a "$out/gpu-table.md"
keep "$out/gpu-table.md"
