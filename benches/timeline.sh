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
. benches/profiled.sh
bin=$(profiled_bin "$out")
files=()
for r in "${rows[@]}"; do
    scaling_row_args "$r" || exit 2
    for t in $threads; do
        echo "[$r] $t threads, $iters iterations, timeline" >&2
        GSENC_TASK_TIMELINE="$out/$r-t$t.tsv" "$bin" encode grid "${args[@]}" --iters "$iters" --backend cpu --threads "$t" -o "$out/$r.gsm" --quiet > /dev/null
        files+=("$out/$r-t$t.tsv")
    done
done
python3 benches/timeline.py "${files[@]}"
