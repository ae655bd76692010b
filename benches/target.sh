#!/usr/bin/env bash
# A quality instead of a budget: `gsenc encode --target-psnr` on RM 128^3,
# hydrogen, the dark-matter halo (particles, log10, 128^3) and the Enzo
# cells (log10, 128^3) at 35, 40 and 45 dB; right after each, a
# fixed-budget encode of the budget it chose, for the time and the PSNR of
# the same size without the search. Rerun with:
#   bash benches/target.sh [DATASETS...]   # default: rm128 hydrogen halo enzo
#   python3 benches/target_report.py       # the Markdown table
# SCHEDULE (default matched) and TARGETS (default "35 40 45") select the
# rest. One JSON line per encode goes to bench-out/target/target.jsonl
# (rows of earlier runs are kept: remove it to start again).
# About 25 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32 dm_halo_particles.positions.float32 dm_halo_particles.smoothing_length.float32 dm_halo_particles.mass.float32 dm_halo_particles.density.float32 enzo_amr_cells.centers.float32 enzo_amr_cells.sizes.float32 enzo_amr_cells.density.float32
datasets=("$@")
[ ${#datasets[@]} -gt 0 ] || datasets=(rm128 hydrogen halo enzo)
schedule=${SCHEDULE:-matched}
targets=(${TARGETS:-35 40 45})
out=bench-out/target
mkdir -p "$out"
# GSENC_BIN: a gsenc built elsewhere (default: this checkout's, built here).
gsenc_bin
log=$out/target.jsonl

tag() { python3 -c "import json,sys; d=json.load(sys.stdin); d.update(json.loads(sys.argv[1])); print(json.dumps(d))" "$1"; }

for ds in "${datasets[@]}"; do
    case "$ds" in
        rm128) args=("${rm128[@]}") ;;
        hydrogen) args=("${hyd[@]}") ;;
        halo) args=("${halo[@]}") ;;
        enzo) args=("${enzo[@]}") ;;
        *) echo "unknown dataset $ds (rm128 hydrogen halo enzo)" >&2; exit 2 ;;
    esac
    for t in "${targets[@]}"; do
        echo "[$ds] target $t dB" >&2
        line=$("$bin" encode "${args[@]}" --schedule "$schedule" --target-psnr "$t" -o "$out/${ds}_$t.gsm" --json --quiet)
        echo "$line" | tag "{\"dataset\": \"$ds\", \"schedule\": \"$schedule\", \"run\": \"target\", \"target_psnr\": $t}" >> "$log"
        n=$(echo "$line" | python3 -c "import json,sys; print(json.load(sys.stdin)['primitives'])")
        echo "[$ds] fixed budget $n" >&2
        "$bin" encode "${args[@]}" --schedule "$schedule" --budget "$n" -o "$out/${ds}_${t}_fixed.gsm" --json --quiet \
            | tag "{\"dataset\": \"$ds\", \"schedule\": \"$schedule\", \"run\": \"fixed\", \"target_psnr\": $t}" >> "$log"
    done
done
python3 benches/target_report.py "$log"
