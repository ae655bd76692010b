#!/usr/bin/env bash
# Benchmarks of particle and cell input. Rerun with:
#   bash benches/inputs.sh [REPEATS] [ROWS...]
# REPEATS (default 3) runs of each row; ROWS selects rows by name (default all).
# Each row encodes the native samples against their deposit ("samples"), then
# the same deposit as a grid, voxel-seeded, at the same budget, schedule and
# iterations ("grid"), and scores both against the deposit.
# SUPPORT=none encodes the paper's models (no stored support; default stored).
# One JSON line per run goes to bench-out/inputs-SUPPORT.jsonl; a Markdown table of
# medians is printed at the end. The models of the last run stay in bench-out/
# for benches/bands.py, which tells where in the field the two differ.
set -euo pipefail
cd "$(dirname "$0")/.."
repeats=${1:-3}
shift || true
rows=("$@")
. benches/corpus.sh
corpus dm_halo_particles.positions.float32 dm_halo_particles.smoothing_length.float32 dm_halo_particles.mass.float32 dm_halo_particles.density.float32 enzo_amr_cells.centers.float32 enzo_amr_cells.sizes.float32 enzo_amr_cells.density.float32 dambreak3d_particles.positions.float32 dambreak3d_particles.smoothing_length.float32 dambreak3d_particles.mass.float32 dambreak3d_particles.speed.float32
out=bench-out
mkdir -p "$out"
cargo build --release --locked --bin gsenc >&2
bin=target/release/gsenc
schedule=${SCHEDULE:-matched}
support=${SUPPORT:-stored}
log="$out/inputs-$support.jsonl"
rm -f "$log"

halo=(particles --positions "$data/dm_halo_particles.positions.float32"
      --smoothing-length "$data/dm_halo_particles.smoothing_length.float32"
      --mass "$data/dm_halo_particles.mass.float32"
      --values "$data/dm_halo_particles.density.float32" --log10)
enzo=(cells --centers "$data/enzo_amr_cells.centers.float32" --sizes "$data/enzo_amr_cells.sizes.float32"
      --values "$data/enzo_amr_cells.density.float32" --log10)
# Step 10 of the 22 stored steps, and the last.
dam10=(particles --positions "$data/dambreak3d_particles.positions.float32"
     --smoothing-length "$data/dambreak3d_particles.smoothing_length.float32"
     --mass "$data/dambreak3d_particles.mass.float32"
     --values "$data/dambreak3d_particles.speed.float32" --count 42042 --row 10)
dam=(particles --positions "$data/dambreak3d_particles.positions.float32"
     --smoothing-length "$data/dambreak3d_particles.smoothing_length.float32"
     --mass "$data/dambreak3d_particles.mass.float32"
     --values "$data/dambreak3d_particles.speed.float32" --count 42042 --row 21)

want() { [ ${#rows[@]} -eq 0 ] || [[ " ${rows[*]} " == *" $1 "* ]]; }

tag() { python3 -c "import json,sys; d=json.load(sys.stdin); d.update(row='$1', seeding='$2'); print(json.dumps(d))"; }

run() { # name dims budget input...   (dims: N for N^3, or fitN for --fit-dims N)
    local name=$1 dims=$2 budget=$3; shift 3
    want "$name" || return 0
    local kind=$1; shift
    local place=(--dims "$dims")
    [[ "$dims" == fit* ]] && place=(--fit-dims "${dims#fit}")
    "$bin" deposit "$kind" "$@" "${place[@]}" --normalized -o "$out/$name.deposit.raw" --json --quiet \
        | tag "$name" deposit >> "$log"
    local grid_dims
    grid_dims=$(tail -n 1 "$log" | python3 -c "import json,sys; print(','.join(map(str, json.load(sys.stdin)['dims'])))")
    # The grid encode runs the samples encode's iterations (particles: 4000 in full).
    local iters
    case "$schedule" in
        full) if [ "$kind" = particles ]; then iters=4000; else iters=3000; fi ;;
        matched) iters=1500 ;;
        short) iters=500 ;;
    esac
    for i in $(seq 1 "$repeats"); do
        echo "[$name] run $i/$repeats" >&2
        "$bin" encode "$kind" "$@" "${place[@]}" --budget "$budget" --schedule "$schedule" --support "$support" \
            -o "$out/$name.gsm" --json --quiet | tag "$name" samples >> "$log"
        "$bin" encode grid --input "$out/$name.deposit.raw" --dims "$grid_dims" --dtype f32 --range 0,1 \
            --budget "$budget" --schedule "$schedule" --iters "$iters" --support "$support" \
            -o "$out/$name.grid.gsm" --json --quiet | tag "$name" grid >> "$log"
    done
}

run halo128_50k 128 50000 "${halo[@]}"
run halo128_200k 128 200000 "${halo[@]}"
run halo256_50k 256 50000 "${halo[@]}"
run halo256_200k 256 200000 "${halo[@]}"
run enzo128_20k 128 20000 "${enzo[@]}"
run dambreak10_128_10k 128 10000 "${dam10[@]}"
run dambreak128_10k 128 10000 "${dam[@]}"
# The same on a lattice fitted to the water's box (128 x 38 x 22).
run dambreak_fit128_10k fit128 10000 "${dam[@]}"

python3 - "$log" <<'PY'
import json, statistics, sys
rows, deposits = {}, {}
for line in open(sys.argv[1]):
    d = json.loads(line)
    if d["seeding"] == "deposit":
        deposits[d["row"]] = d
    else:
        rows.setdefault(d["row"], {}).setdefault(d["seeding"], []).append(d)
print("| row | seeding | runs | voxel PSNR dB (median; min-max) | occupied PSNR dB | bytes | deposit s | deposit peak MB | loop s (median) | total s |")
print("|---|---|---|---|---|---|---|---|---|---|")
for name, kinds in rows.items():
    dep = deposits[name]
    for kind, runs in kinds.items():
        med = lambda k: statistics.median(r[k] for r in runs)
        lo, hi = min(r["voxel_psnr"] for r in runs), max(r["voxel_psnr"] for r in runs)
        spread = f" ({lo:.2f}-{hi:.2f})" if len(runs) > 1 else ""
        occ = [r["occupied_psnr"] for r in runs if r.get("occupied_psnr") is not None]
        occ = f"{statistics.median(occ):.2f}" if occ else "-"
        print(f"| {name} | {kind} | {len(runs)} | {med('voxel_psnr'):.2f}{spread} | {occ} | {runs[0]['bytes']} | "
              f"{dep['deposit_seconds']:.2f} | {dep['deposit_peak_bytes']/1e6:.0f} | {med('seconds'):.1f} | {med('total_seconds'):.1f} |")
print()
print("| row | samples - grid PSNR dB | samples / grid loop time |")
print("|---|---|---|")
for name, kinds in rows.items():
    if "samples" in kinds and "grid" in kinds:
        m = lambda kind, k: statistics.median(r[k] for r in kinds[kind])
        print(f"| {name} | {m('samples','voxel_psnr') - m('grid','voxel_psnr'):+.2f} | {m('samples','seconds') / m('grid','seconds'):.2f} |")
PY
