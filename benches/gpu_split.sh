#!/usr/bin/env bash
# How the GPU backend's point passes are cut into workgroups, swept on a
# GPU: each row encoded with every split of its list (GSENC_GPU_SPLIT =
# points a forward workgroup, backward workgroups a brick, primitives a bin
# workgroup, threads a primitive's reduction, chunks a coarse cell's list
# at the brick level; the first is the default, whose team follows the
# primitive count, kernels::reduce_team_for, and whose chunks the lists'
# size, kernels::brick_chunks_for), a short run each, and a table of the
# kernels' device time per iteration, the binning's first level (and the
# decode's, in the PSNR check) and its brick level apart.
# Hydrogen and RM 128^3, whose point passes weigh most, sweep the reduction
# teams and the first two (SPLITS); RM 256^3 at 200K, whose binning weighs
# most, the third and the fifth (BIN_SPLITS). Every split must give the model
# of the first, byte for byte (the script fails otherwise): only the time
# may differ. Rerun with:
#   bash benches/gpu_split.sh                                   # a machine with a GPU
#   GSENC_ADAPTER=llvmpipe ITERS=10 bash benches/gpu_split.sh   # lavapipe: the check only
# Env: ITERS caps every row (default: hydrogen 300, RM 128^3 150, RM 256^3
# 40 iterations); ROWS selects rows by name; SPLITS, BIN_SPLITS the
# splits (space-separated); STOP_AFTER
# (seconds) skips the runs that would start later; GSENC_BIN a prebuilt
# gsenc (nothing is built). Prints one JSON line per run to
# bench-out/gpu-split.jsonl and the table to bench-out/gpu-split.md.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
out=bench-out/gpu-split
mkdir -p "$out"
rm -f "$out"/*.gsm
gsenc_bin
log=bench-out/gpu-split.jsonl
: > "$log"
work_splits=(${SPLITS:-8,8,4096 8,8,4096,1 8,8,4096,8 8,8,4096,32 4,8,4096 16,8,4096 32,8,4096 8,4,4096 8,16,4096})
bin_splits=(${BIN_SPLITS:-8,8,4096 8,8,1024 8,8,4096,1,8 8,8,4096,1,128})
rm_args=(--input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8 --range 0,255)
h_args=(--input "$data/hydrogen_atom.float32" --dims 64,64,64 --dtype f32)
status=0

row() { # name iterations splits-array-name args...
    local name=$1 iters=${ITERS:-$2}
    local -n splits=$3
    shift 3
    want "$name" || return 0
    local split first=
    for split in "${splits[@]}"; do
        if [ -n "${STOP_AFTER:-}" ] && [ "$SECONDS" -ge "$STOP_AFTER" ]; then
            echo "[$name] $split skipped: STOP_AFTER=$STOP_AFTER s passed" >&2
            continue
        fi
        echo "[$name] GSENC_GPU_SPLIT=$split" >&2
        local model="$out/${name}_${split//,/_}.gsm" result
        if result=$(GSENC_GPU_SPLIT=$split "$bin" encode grid "$@" --iters "$iters" --backend gpu -o "$model" --json --quiet); then
            local same=True
            if [ -z "$first" ]; then
                first=$model
            elif ! cmp -s "$first" "$model"; then
                same=False status=1
                echo "[$name] GSENC_GPU_SPLIT=$split gave another model than ${splits[0]}" >&2
            fi
            echo "$result" | python3 -c "import json,sys; d=json.load(sys.stdin); d.update(row='$name', split='$split', same_model=$same); print(json.dumps(d))" >> "$log"
        else
            echo "{\"row\": \"$name\", \"split\": \"$split\", \"failed\": true}" >> "$log"
            status=1
        fi
    done
}

# RM 256^3 first: since 2026-12-05 its binning is made from bit rows and
# unmeasured on a GPU, and a lent run gives this script a minute.
row rm256_200k_full 40 bin_splits "${rm_args[@]}" --budget 200000 --schedule full
row hydrogen_4k_matched 300 work_splits "${h_args[@]}" --budget 4096 --schedule matched
row rm128_32k_full 150 work_splits "${rm_args[@]}" --downsample 2 --budget 32000 --schedule full

python3 - "$log" <<'PY' | tee bench-out/gpu-split.md
import json, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
# Device time: every kernel of the run (seeding's and the PSNR's too),
# per loop iteration; the kernels' columns likewise.
print("| row | split (piece, slices, chunk, team, brick chunks) | iterations | loop ms / it | device ms / it | bin: coarse level and the PSNR decode | bin: bricks | forward | backward | reduce | same model |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for d in runs:
    if d.get("failed"):
        print(f"| {d['row']} | {d['split']} | failed | | | | | | | | |")
        continue
    it = d["iterations"]
    k = d.get("kernel_seconds") or {}
    ms = lambda *names: f"{sum(k.get(n, {}).get('seconds', 0) for n in names) * 1e3 / it:.3f}" if k else ""
    device = f"{sum(v.get('seconds', 0) for v in k.values()) * 1e3 / it:.3f}" if k else ""
    print(f"| {d['row']} | {d['split']} | {it} | {d['seconds'] * 1e3 / it:.3f} | {device} | {ms('bin count', 'bin fill', 'bin cells count', 'bin cells total', 'bin cells fill')} | {ms('bin bricks count', 'bin bricks total', 'bin bricks fill')} | {ms('forward')} | {ms('backward')} | {ms('reduce', 'reduce adam')} | {d['same_model']} |")
PY
exit $status
