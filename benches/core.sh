#!/usr/bin/env bash
# Benchmarks of the encoder core on the CPU backend (named, so that a
# machine with a GPU, where auto would take it, times the CPU too; the GPU's
# rows are benches/gpu.sh's). Rerun with:
#   bash benches/core.sh [REPEATS] [ROWS...]
# REPEATS (default 3) runs of each row; the 256^3 row runs once unless
# REPEATS_LARGE is set. ROWS selects rows by name (default: all). THREADS
# sets the encoder's thread count (default: every core), for scaling runs:
#   THREADS=1 bash benches/core.sh 3 rm128_32k_matched hydrogen_4k_matched
# ITERS caps the timing rows' iterations (a scaling run on a lent machine's
# clock: the time an iteration takes is what compares). GSENC_BIN names a
# gsenc built elsewhere, for a machine without a Rust toolchain (nothing is
# built then).
# Prints one JSON line per run to bench-out/core.jsonl and a Markdown table
# of medians at the end. Every row's model stays in bench-out/ (ROW.gsm; the
# fidelity rows ROW_sSEED.gsm), so two builds can be compared byte for byte.
set -euo pipefail
cd "$(dirname "$0")/.."
repeats=${1:-3}
shift || true
rows=("$@")
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
out=bench-out
mkdir -p "$out"
gsenc_bin
rm -f "$out/core.jsonl"

rm_args=(--input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8 --range 0,255)
h_args=(--input "$data/hydrogen_atom.float32" --dims 64,64,64 --dtype f32)

want() { [ ${#rows[@]} -eq 0 ] || [[ " ${rows[*]} " == *" $1 "* ]]; }

run() { # name repeats args...  (the model file is ROW${tag}.gsm)
    local name=$1 n=$2; shift 2
    want "$name" || return 0
    local cap=()  # the fidelity rows (a tag) set their own iterations
    [ -z "${ITERS:-}" ] || [ -n "${tag:-}" ] || cap=(--iters "$ITERS")
    for i in $(seq 1 "$n"); do
        echo "[$name] run $i/$n" >&2
        "$bin" encode grid "$@" --backend cpu ${THREADS:+--threads "$THREADS"} "${cap[@]}" -o "$out/$name${tag:-}.gsm" --json --quiet \
            | python3 -c "import json,sys; d=json.load(sys.stdin); d['row']='$name'; print(json.dumps(d))" >> "$out/core.jsonl"
    done
}

run rm128_32k_matched "$repeats" "${rm_args[@]}" --downsample 2 --budget 32000 --schedule matched
run rm128_32k_full "$repeats" "${rm_args[@]}" --downsample 2 --budget 32000 --schedule full
run hydrogen_4k_matched "$repeats" "${h_args[@]}" --budget 4096 --schedule matched
run rm256_200k_full "${REPEATS_LARGE:-1}" "${rm_args[@]}" --budget 200000 --schedule full
# Fidelity check: 300 x 3072 at 4,096 primitives, eight seed
# pairs each, values normalised by the data's own range (the reference run's
# protocol: RM 64^3 with value/255 instead lands about 1.3 dB higher).
rm_data_range=(--input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8)
for s in 0 1 2 3 4 5 6 7; do
    tag=_s$s
    run fidelity_hydrogen_4k_300it 1 "${h_args[@]}" --budget 4096 --iters 300 --points 3072 --seed "$s" --sample-seed $((s + 1))
    run fidelity_rm64_4k_300it 1 "${rm_data_range[@]}" --downsample 4 --budget 4096 --iters 300 --points 3072 --seed "$s" --sample-seed $((s + 1))
done
tag=

python3 - "$out/core.jsonl" <<'PY'
import json, statistics, sys
rows = {}
for line in open(sys.argv[1]):
    d = json.loads(line)
    rows.setdefault(d["row"], []).append(d)
print("| row | runs | voxel PSNR dB (median; min-max) | sampled PSNR dB | bytes | loop s (median) | total s | kernel evals/s |")
print("|---|---|---|---|---|---|---|---|")
for name, runs in rows.items():
    med = lambda k: statistics.median(r[k] for r in runs)
    lo, hi = min(r['voxel_psnr'] for r in runs), max(r['voxel_psnr'] for r in runs)
    spread = f" ({lo:.2f}-{hi:.2f})" if len(runs) > 1 else ""
    print(f"| {name} | {len(runs)} | {med('voxel_psnr'):.2f}{spread} | {med('sampled_psnr'):.2f} | {runs[0]['bytes']} | "
          f"{med('seconds'):.2f} | {med('total_seconds'):.2f} | {med('kernel_evals_per_second')/1e6:.0f} M |")
PY
