#!/usr/bin/env bash
# Quality per byte against the voxel codecs users compare with: zfp (fixed
# rate) and SZ3 (absolute error bound searched to the same bytes), on every
# grid dataset of the corpus and on the deposits of its particle and cell
# datasets (the codecs get the deposited grid, gsenc the native samples).
# Rerun with:
#   bash benches/peers.sh [DATASETS...]      # default: all; then
#   python3 benches/peers_report.py          # table, crossovers, plot
# DATASETS: rm128 rm128full rm256 hydrogen halo enzo dambreak payloads.
# gsenc stores its models with the packed payload (schedule SCHEDULE,
# default tuned; matched for the paper's; rm128full: the `full` schedule,
# whatever SCHEDULE) and is scored on its
# decode of the reference lattice, normalised, against the same normalised
# float32 array the codecs get; ratios are against that array's float32
# bytes. `payloads` measures the packed payload against float32 and 8-bit
# on RM 128^3 at 32K and hydrogen at 4,096 (issue 19's targets), with
# SCHEDULE too. BUDGETS (e.g. "8000 32000") replaces every dataset's list
# of budgets, for a schedule too long to run at them all (tuned-full).
# zfpy and pysz are installed into bench-out/peers-venv (PyPI); every codec
# call runs in a process of its own (benches/peers_codec.py). One JSON line
# per point goes to bench-out/peers/peers.jsonl (rows of the datasets and
# schedule run are replaced). Takes about 45 minutes for everything on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32 dm_halo_particles.positions.float32 dm_halo_particles.smoothing_length.float32 dm_halo_particles.mass.float32 dm_halo_particles.density.float32 enzo_amr_cells.centers.float32 enzo_amr_cells.sizes.float32 enzo_amr_cells.density.float32 dambreak3d_particles.positions.float32 dambreak3d_particles.smoothing_length.float32 dambreak3d_particles.mass.float32 dambreak3d_particles.speed.float32
datasets=("$@")
[ ${#datasets[@]} -gt 0 ] || datasets=(payloads rm128 rm128full hydrogen enzo dambreak halo rm256)
out=bench-out/peers
mkdir -p "$out"
cargo build --release --locked --bin gsenc >&2
# A copy, so that a rebuild during the run changes nothing.
cp target/release/gsenc "$out/gsenc"
bin=$out/gsenc
venv=bench-out/peers-venv
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import zfpy, pysz, numpy, matplotlib" 2>/dev/null; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install -q "zfpy==1.0.1.post0" "pysz==1.1.0" numpy matplotlib
fi
py=$venv/bin/python
cp benches/peers_codec.py "$out/peers_codec.py"
codec() { "$py" "$out/peers_codec.py" "$@"; }
log=$out/peers.jsonl
touch "$log"
schedule=${SCHEDULE:-tuned}

# tag JSON-FIELDS: adds the fields (a JSON object) to the JSON line on stdin.
tag() { python3 -c "import json,sys; d=json.load(sys.stdin); d.update(json.loads(sys.argv[1])); print(json.dumps(d))" "$1"; }

# point DATASET REF DIMS BUDGET SCHEDULE ENCODE-ARGS...: gsenc at BUDGET, then
# zfp and SZ3 at the bytes gsenc took.
point() {
    local ds=$1 ref=$2 dims=$3 budget=$4 sched=$5; shift 5
    local model="$out/${ds}_${budget}_$sched.gsm" dec="$out/decoded.raw"
    echo "[$ds] $budget primitives, $sched" >&2
    local enc
    enc=$("$bin" encode "$@" --budget "$budget" --schedule "$sched" --payload packed -o "$model" --json --quiet)
    "$bin" decode "$model" --normalized -o "$dec" --quiet
    local psnr
    psnr=$(codec score "$ref" "$dec" "$dims")
    local voxels
    voxels=$(python3 -c "import math; print(math.prod(int(v) for v in '$dims'.split(',')))")
    local bytes
    bytes=$(echo "$enc" | python3 -c "import json,sys; print(json.load(sys.stdin)['bytes'])")
    echo "$enc" | tag "{\"dataset\": \"$ds\", \"codec\": \"gsenc\", \"schedule\": \"$sched\", \"budget\": $budget, \"psnr\": $psnr, \"voxels\": $voxels}" >> "$log"
    local c
    for c in zfp sz; do
        codec "$c" "$ref" "$dims" "$bytes" | tag "{\"dataset\": \"$ds\", \"schedule\": \"$sched\", \"budget\": $budget, \"voxels\": $voxels}" >> "$log"
    done
}

# deposit NAME DIMS-ARGS INPUT...: the normalised deposit the codecs get; prints its dims.
deposit() {
    local ref=$1; shift
    "$bin" deposit "$@" --normalized -o "$ref" --json --quiet | python3 -c "import json,sys; print(','.join(map(str, json.load(sys.stdin)['dims'])))"
}

budgets() { # the budgets to run: BUDGETS when set, else the dataset's list ($@)
    echo "${BUDGETS:-$*}"
}

forget() { # drops the rows of dataset $1 encoded with schedule $2 from the log
    python3 -c "
import json,sys
keep = lambda d: d.get('dataset') != '$1' or d.get('schedule', '$2') != '$2'
rows = [l for l in open('$log') if l.strip() and keep(json.loads(l))]
open('$log', 'w').writelines(rows)"
}

rm_raw=$data/richtmyer_meshkov_t20.uint8
# payload MODEL-NAME BUDGET ENCODE-ARGS...: one float32 encode, stored as
# float32, 8-bit and 8bit-u16 (converted) and packed (the same encode with
# its precision measured: the same parameters, so the same float32 PSNR).
payload() {
    local name=$1 budget=$2; shift 2
    local f32="$out/payload_${name}_${schedule}_f32.gsm"
    echo "[payloads] $name float32" >&2
    "$bin" encode "$@" --budget "$budget" --schedule "$schedule" -o "$f32" --json --quiet \
        | tag "{\"dataset\": \"payloads\", \"schedule\": \"$schedule\", \"model\": \"$name\", \"payload\": \"f32\"}" >> "$log"
    local p
    for p in 8bit 8bit-u16; do
        local m="$out/payload_${name}_${schedule}_$p.gsm"
        "$bin" convert "$f32" --payload "$p" -o "$m" --json > /dev/null
        "$bin" eval "$m" "${@:2}" --json | tag "{\"dataset\": \"payloads\", \"schedule\": \"$schedule\", \"model\": \"$name\", \"payload\": \"$p\", \"bytes\": $(stat -c %s "$m"), \"payload_bytes_per_primitive\": $("$bin" info "$m" --json | python3 -c "import json,sys; print(json.load(sys.stdin)['payload_bytes_per_primitive'])")}" >> "$log"
    done
    echo "[payloads] $name packed" >&2
    "$bin" encode "$@" --budget "$budget" --schedule "$schedule" --payload packed -o "$out/payload_${name}_${schedule}_packed.gsm" --json --quiet \
        | tag "{\"dataset\": \"payloads\", \"schedule\": \"$schedule\", \"model\": \"$name\", \"payload\": \"packed\"}" >> "$log"
}

for ds in "${datasets[@]}"; do
    case "$ds" in
        rm128full) forget "$ds" full ;;
        *) forget "$ds" "$schedule" ;;
    esac
    case "$ds" in
        payloads)
            payload rm128_32k 32000 "${rm128[@]}"
            payload hydrogen_4096 4096 "${hyd[@]}" ;;
        rm128|rm128full)
            ref=$out/rm128.ref
            dims=$(codec grid-ref "$rm_raw" u8 256,256,256 2 "$ref")
            if [ "$ds" = rm128 ]; then
                for n in $(budgets 2000 4000 8000 16000 32000 64000); do point rm128 "$ref" "$dims" $n "$schedule" "${rm128[@]}"; done
            else
                for n in 8000 32000; do point rm128full "$ref" "$dims" $n full "${rm128[@]}"; done
            fi ;;
        rm256)
            ref=$out/rm256.ref
            dims=$(codec grid-ref "$rm_raw" u8 256,256,256 1 "$ref")
            for n in $(budgets 30000 60000 120000 240000); do point rm256 "$ref" "$dims" $n "$schedule" "${rm256[@]}"; done ;;
        hydrogen)
            ref=$out/hydrogen.ref
            dims=$(codec grid-ref "$data/hydrogen_atom.float32" f32 64,64,64 1 "$ref")
            for n in $(budgets 512 1024 2048 4096 8192); do point hydrogen "$ref" "$dims" $n "$schedule" "${hyd[@]}"; done ;;
        halo)
            ref=$out/halo.ref
            dims=$(deposit "$ref" "${halo[@]}")
            for n in $(budgets 5000 10000 20000 50000); do point halo "$ref" "$dims" $n "$schedule" "${halo[@]}"; done ;;
        enzo)
            ref=$out/enzo.ref
            dims=$(deposit "$ref" "${enzo[@]}")
            for n in $(budgets 2500 5000 10000 20000 40000); do point enzo "$ref" "$dims" $n "$schedule" "${enzo[@]}"; done ;;
        dambreak)
            ref=$out/dambreak.ref
            dims=$(deposit "$ref" "${dam[@]}")
            for n in $(budgets 250 500 1000 2000 4000); do point dambreak "$ref" "$dims" $n "$schedule" "${dam[@]}"; done ;;
        *) echo "unknown dataset $ds (rm128 rm128full rm256 hydrogen halo enzo dambreak payloads)" >&2; exit 2 ;;
    esac
done
echo "peers: rows in $log; python3 benches/peers_report.py" >&2
