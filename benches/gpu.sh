#!/usr/bin/env bash
# The GPU backend's benchmark rows and the same rows on the CPU backend (all
# cores) for the ratio: one prepared script for a lent GPU machine, under
# 8 minutes there. Rerun with:
#   bash benches/gpu.sh                                    # a machine with a GPU
#   GSENC_ADAPTER=llvmpipe ITERS=100 bash benches/gpu.sh   # lavapipe: correctness only
# Env: ITERS caps every row's iterations (default: the schedule's);
# CPU_ITERS caps the CPU rows (default 200: the ratio is per iteration, so
# the CPU rows need not run the whole schedule); ROWS selects rows by name;
# ROW_LIMIT (default 150 s) stops any one run, recorded as timed out, so the
# script ends in time; INSITU=0 skips the in-situ run (benches/insitu.sh,
# one run of 8 steps, on the GPU backend); OUT (the device machine's output
# folder) also receives the results.
# Prints one JSON line per run to bench-out/gpu.jsonl, the adapters to
# bench-out/gpu-devices.json, and a Markdown table of the rows.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
out=bench-out
mkdir -p "$out"
cargo build --release --locked --bin gsenc >&2
bin=target/release/gsenc
log="$out/gpu.jsonl"
rm -f "$log"
"$bin" devices --json > "$out/gpu-devices.json"
cat "$out/gpu-devices.json" >&2
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv > "$out/gpu-nvidia-smi.csv" || true
lscpu | grep -E "Model name|^CPU\(s\)" > "$out/gpu-cpu.txt" || true

rm_args=(--input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8 --range 0,255)
h_args=(--input "$data/hydrogen_atom.float32" --dims 64,64,64 --dtype f32)
want() { [ -z "${ROWS:-}" ] || [[ " $ROWS " == *" $1 "* ]]; }

run() { # name backend iteration-cap args...
    local name=$1 backend=$2 cap=$3; shift 3
    want "$name" || return 0
    local iters=()
    [ -n "$cap" ] && iters=(--iters "$cap")
    echo "[$name] $backend ${iters[*]}" >&2
    local result
    if result=$(timeout "${ROW_LIMIT:-150}" "$bin" encode grid "$@" "${iters[@]}" --backend "$backend" -o "$out/gpu_${name}_$backend.gsm" --json --quiet); then
        echo "$result" | python3 -c "import json,sys; d=json.load(sys.stdin); d['row']='$name'; d['which']='$backend'; print(json.dumps(d))" >> "$log"
    else
        echo "{\"row\": \"$name\", \"which\": \"$backend\", \"failed_or_timed_out\": true}" >> "$log"
    fi
}

row() { # name args...: the row on the GPU, then on the CPU
    local name=$1; shift
    run "$name" gpu "${ITERS:-}" "$@"
    run "$name" cpu "${CPU_ITERS:-200}" "$@"
}

row rm128_32k_matched "${rm_args[@]}" --downsample 2 --budget 32000 --schedule matched
row rm128_32k_full "${rm_args[@]}" --downsample 2 --budget 32000 --schedule full
row hydrogen_4k_matched "${h_args[@]}" --budget 4096 --schedule matched
row rm256_200k_full "${rm_args[@]}" --budget 200000 --schedule full

# The decode of 1024^3 (4 GiB of float32, streamed to disk and deleted).
if want decode_1024; then
    "$bin" encode grid "${h_args[@]}" --budget 4096 --schedule short --iters 100 --backend cpu -o "$out/gpu_decode_model.gsm" --quiet
    for backend in gpu cpu; do
        echo "[decode_1024] $backend" >&2
        "$bin" decode "$out/gpu_decode_model.gsm" --dims 1024,1024,1024 --backend "$backend" -o "$out/gpu_decode.raw" --json \
            | python3 -c "import json,sys; d=json.load(sys.stdin); d['row']='decode_1024'; d['which']='$backend'; print(json.dumps(d))" >> "$log"
        rm -f "$out/gpu_decode.raw"
    done
fi

# Push latency and the solver's slowdown with the encoder on the GPU.
if [ "${INSITU:-1}" = 1 ] && want insitu; then
    GSENC_BACKEND=gpu timeout 240 bash benches/insitu.sh 1 8 600 > "$out/gpu-insitu.md" || echo "insitu: failed or timed out" >> "$out/gpu-insitu.md"
    cat "$out/gpu-insitu.md" >&2
fi

python3 - "$log" <<'PY' | tee "$out/gpu-table.md"
import json, sys
rows = {}
for line in open(sys.argv[1]):
    d = json.loads(line)
    if d.get("failed_or_timed_out"):
        print(f"<!-- {d['row']} on {d['which']}: failed or timed out -->")
        continue
    rows.setdefault(d["row"], {})[d["which"]] = d
print("| row | backend | iterations | voxel PSNR dB | loop s | s / iteration | GPU speed-up per iteration | PSNR gap dB |")
print("|---|---|---|---|---|---|---|---|")
for name, by in rows.items():
    if name == "decode_1024":
        g, c = by.get("gpu"), by.get("cpu")
        for w, d in by.items():
            print(f"| {name} | {d.get('backend', w)} | | | {d['seconds']:.2f} | | {c['seconds'] / g['seconds']:.1f}x |  |" if w == "gpu" and c else f"| {name} | {w} | | | {d['seconds']:.2f} | | | |")
        continue
    per = {w: d["seconds"] / d["iterations"] for w, d in by.items()}
    for w, d in by.items():
        ratio = f"{per['cpu'] / per['gpu']:.1f}x" if w == "gpu" and "cpu" in per else ""
        gap = ""
        if w == "gpu" and "cpu" in by and by["cpu"]["iterations"] == d["iterations"]:
            gap = f"{d['voxel_psnr'] - by['cpu']['voxel_psnr']:+.3f}"
        print(f"| {name} | {d['backend']} | {d['iterations']} | {d['voxel_psnr']:.2f} | {d['seconds']:.2f} | {per[w]*1e3:.2f} ms | {ratio} | {gap} |")
PY
if [ -n "${OUT:-}" ]; then
    cp "$out"/gpu.jsonl "$out"/gpu-*.json "$out"/gpu-table.md "$out"/gpu-insitu.md "$OUT"/ 2>/dev/null || true
    cp "$out"/gpu-nvidia-smi.csv "$out"/gpu-cpu.txt "$OUT"/ 2>/dev/null || true
fi
