#!/usr/bin/env bash
# Benchmark of time-series warm starts on dambreak3d_particles (and, with
# SERIES=static, on a field that does not move: see below):
# speed deposited on a 128^3 reference over the series' whole box (the
# manifest's bounds: the fluid moves across the tank, so the first step's box
# would drop most later particles), 50,000 primitives, steps 1..21 (step 0 is
# the dam at rest: speed 0 everywhere), range 0..4 m/s fixed for the series. Three series: every step independent (3000 iterations), and
# warm-started coarse (1000, no relocation) and dense (1500, relocation on),
# whose first step is the independent one; auto (the library's default:
# the previous model kept, repaired or replaced by a fresh seeding, whichever
# validates best, stopping when the validation PSNR stops rising, at most
# 3000 iterations); and paper, the paper's protocol: each step warm-started
# (dense) from the previous step's *independent* model (run after off).
# Validation PSNR every 50
# iterations goes to bench-out/series_<mode>.csv; `benches/series_report.py`
# turns the CSVs into the table of docs/BENCHMARKS.md.
#   bash benches/series.sh [POINTS] [STEPS] [MODES]
#   (points per iteration, default 4096; steps A..B, default 1..22; modes,
#   default "off auto dense coarse paper")
# SERIES=static: dm_halo_particles' one snapshot repeated as steps 0..5
# (its files concatenated five times into bench-out/static/), log10 density,
# the same budget and iterations; outputs bench-out/static_<mode>.*.
# BUDGET=N encodes N primitives instead of 50,000 (outputs
# bench-out/<series|static>N_<mode>.*).
# A run of steps A..B with A > 1 continues an earlier one: each warm series
# resumes from its stored step A-1 (`--resume-from`, bitwise the unbroken
# series), and the new steps replace steps >= A in the CSV and JSON lines.
set -euo pipefail
cd "$(dirname "$0")/.."
points=${1:-4096}
steps=${2:-1..22}
modes=${3:-off auto dense coarse paper}
. benches/corpus.sh
out=bench-out
mkdir -p "$out"
gsenc_bin
if [ "${SERIES:-dambreak}" = static ]; then
    corpus dm_halo_particles.positions.float32 dm_halo_particles.smoothing_length.float32 dm_halo_particles.mass.float32 dm_halo_particles.density.float32
    mkdir -p "$out/static"
    for f in positions smoothing_length mass density; do
        src="$data/dm_halo_particles.$f.float32"
        cat "$src" "$src" "$src" "$src" "$src" > "$out/static/halo.$f.float32"
    done
    steps=${2:-0..5}
    name=static field=density
    dam=(--positions "$out/static/halo.positions.float32" --smoothing-length "$out/static/halo.smoothing_length.float32"
         --mass "$out/static/halo.mass.float32" --values "$out/static/halo.density.float32" --log10 --count 174312
         --dims 128 --field density)
else
    corpus dambreak3d_particles.positions.float32 dambreak3d_particles.smoothing_length.float32 dambreak3d_particles.mass.float32 dambreak3d_particles.speed.float32
    name=series field=speed
    dam=(--positions "$data/dambreak3d_particles.positions.float32"
         --smoothing-length "$data/dambreak3d_particles.smoothing_length.float32"
         --mass "$data/dambreak3d_particles.mass.float32"
         --values "$data/dambreak3d_particles.speed.float32" --count 42042
         --dims 128 --bounds 0.021,-0.481,0.0107,3.22,0.481,0.55
         --range 0,4 --field speed)
fi
budget=${BUDGET:-50000}
[ "$budget" = 50000 ] || name="$name$budget"
train=(--budget "$budget" --schedule full --iters 3000 --points "$points" --no-relocation --validation-every 50 --json --quiet)
first=${steps%%..*}
last=${steps##*..}
for mode in $modes; do
    if [ "$mode" = paper ]; then
        # Each step from the previous step's independent model, one call a step.
        rm -rf "$out/${name}_paper" "$out/${name}_paper.csv" "$out/${name}_paper.jsonl"
        for ((s = first + 1; s < last; s++)); do
            indep=$(printf '%s/%s_off/%s_%06d.gsm' "$out" "$name" "$field" $((s - 1)))
            [ -f "$indep" ] || { echo "[series] paper: $indep is missing (run the off mode first)" >&2; exit 1; }
            "$bin" encode-series "${dam[@]}" --steps "$s..$((s + 1))" "${train[@]}" --warm dense --resume-from "$indep" \
                -o "$out/${name}_paper" --csv "$out/${name}_paper.step.csv" >> "$out/${name}_paper.jsonl"
            if [ -f "$out/${name}_paper.csv" ]; then tail -n +2 "$out/${name}_paper.step.csv" >> "$out/${name}_paper.csv"
            else cp "$out/${name}_paper.step.csv" "$out/${name}_paper.csv"; fi
        done
        rm -f "$out/${name}_paper.step.csv"
        echo "[series] paper done" >&2
        continue
    fi
    prev=$(printf '%s/%s_%s/%s_%06d.gsm' "$out" "$name" "$mode" "$field" $((first - 1)))
    resume=() part=""
    if [[ $steps == *..* && $first -gt 1 && -f $prev ]]; then
        [[ $mode == off ]] || resume=(--resume-from "$prev")
        part=".from$first"
    else
        rm -rf "$out/${name}_$mode"
    fi
    "$bin" encode-series "${dam[@]}" --steps "$steps" "${train[@]}" --warm "$mode" "${resume[@]}" \
        -o "$out/${name}_$mode" --csv "$out/${name}_$mode$part.csv" > "$out/${name}_$mode$part.jsonl"
    if [[ -n $part ]]; then
        python3 - "$out/${name}_$mode" "$part" "$first" <<'PY'
import json, sys
base, part, first = sys.argv[1], sys.argv[2], int(sys.argv[3])
def merge(ext, keep):
    try:
        old = open(f"{base}.{ext}").read().splitlines()
    except FileNotFoundError:
        old = []
    new = open(f"{base}{part}.{ext}").read().splitlines()
    lines = [l for l in old if keep(l)] + [l for l in new if not l.startswith("field,") or not old]
    open(f"{base}.{ext}", "w").write("\n".join(lines) + "\n")
merge("csv", lambda l: l.startswith("field,") or int(l.split(",")[1]) < first)
merge("jsonl", lambda l: json.loads(l).get("step", first) < first)
PY
    fi
    echo "[series] $mode done" >&2
done
python3 benches/series_report.py "$out" "$name"
