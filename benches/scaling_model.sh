#!/usr/bin/env bash
# The thread-scaling model of the CPU backend, on any machine: encodes
# benches/core.sh's scaling rows on one thread with a build that records
# every task's time (feature task-profile, src/profile.rs), then schedules
# those tasks on 1, 2, 4, 8 and 16 workers (benches/scaling_model.py) and
# prints, per row, where an iteration's time goes and the predicted speed-up.
# Rerun with:
#   bash benches/scaling_model.sh [ROWS...]   (default: rm128_32k_matched hydrogen_4k_matched rm128_32k_full)
# The profiled binary is built in the usual target folder (only gsenc and
# the tool recompile), kept as bench-out/scaling_model/gsenc, and the
# ordinary binary is linked again afterwards; GSENC_PROFILED_BIN names one
# built elsewhere (benches/lent/prepare.sh), and nothing is built. `full`
# runs 1,000 iterations (its passes are the same in every iteration). A prediction, not a
# measurement: on a 16-core machine, set it beside `bash benches/scaling.sh`.
set -euo pipefail
cd "$(dirname "$0")/.."
rows=("$@")
[ ${#rows[@]} -gt 0 ] || rows=(rm128_32k_matched hydrogen_4k_matched rm128_32k_full)
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
out=bench-out/scaling_model
mkdir -p "$out"
. benches/profiled.sh
bin=$(profiled_bin "$out")
profiles=()
for r in "${rows[@]}"; do
    scaling_row_args "$r" || exit 2
    # `full` runs 1,000 iterations: its passes are the same in every one.
    [ "$r" != rm128_32k_full ] || args+=(--iters 1000)
    echo "[$r] one thread, task profile" >&2
    GSENC_TASK_PROFILE="$out/$r.tsv" "$bin" encode grid "${args[@]}" --backend cpu --threads 1 -o "$out/$r.gsm" --quiet > /dev/null
    profiles+=("$out/$r.tsv")
done
python3 benches/scaling_model.py "${profiles[@]}"
