#!/usr/bin/env bash
# Where an iteration of the CPU backend loses time on p threads: encodes
# benches/core.sh's scaling rows with a build that records when and on which
# thread each task ran (feature task-profile, GSENC_TASK_TIMELINE,
# src/profile.rs), at each thread count, and prints per pass the time lost
# to the pool joining late, to a last task running alone, and between
# passes (benches/timeline.py). What the scaling model (scaling_model.sh)
# cannot see, measured. Rerun with:
#   bash benches/timeline.sh [ROWS...]   (default: rm128_32k_matched hydrogen_4k_matched)
# THREADS (default "1 <all cores>"), ITERS (default 300) a row. The profiled
# binary is built as scaling_model.sh builds it; GSENC_PROFILED_BIN names
# one built elsewhere (benches/lent/prepare.sh), and nothing is built.
set -euo pipefail
cd "$(dirname "$0")/.."
rows=("$@")
[ ${#rows[@]} -gt 0 ] || rows=(rm128_32k_matched hydrogen_4k_matched)
threads=${THREADS:-"1 $(nproc)"}
iters=${ITERS:-300}
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
out=bench-out/timeline
mkdir -p "$out"
if [ -n "${GSENC_PROFILED_BIN:-}" ]; then
    bin=$GSENC_PROFILED_BIN
else
    cargo build --release --locked --bin gsenc --features gsenc/task-profile >&2
    cp "${CARGO_TARGET_DIR:-target}/release/gsenc" "$out/gsenc"
    cargo build --release --locked --bin gsenc >&2
    bin=$out/gsenc
fi
rm_args=(--input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8 --range 0,255 --downsample 2 --budget 32000)
h_args=(--input "$data/hydrogen_atom.float32" --dims 64,64,64 --dtype f32 --budget 4096)
files=()
for r in "${rows[@]}"; do
    case $r in
        rm128_32k_matched) args=("${rm_args[@]}" --schedule matched) ;;
        rm128_32k_full) args=("${rm_args[@]}" --schedule full) ;;
        hydrogen_4k_matched) args=("${h_args[@]}" --schedule matched) ;;
        *) echo "unknown row $r" >&2; exit 2 ;;
    esac
    for t in $threads; do
        echo "[$r] $t threads, $iters iterations, timeline" >&2
        GSENC_TASK_TIMELINE="$out/$r-t$t.tsv" "$bin" encode grid "${args[@]}" --iters "$iters" --backend cpu --threads "$t" -o "$out/$r.gsm" --quiet > /dev/null
        files+=("$out/$r-t$t.tsv")
    done
done
python3 benches/timeline.py "${files[@]}"
