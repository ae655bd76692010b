#!/usr/bin/env bash
# Benchmark of time-series warm starts on dambreak3d_particles:
# speed deposited on a 128^3 reference over the series' whole box (the
# manifest's bounds: the fluid moves across the tank, so the first step's box
# would drop most later particles), 50,000 primitives, steps 1..21 (step 0 is
# the dam at rest: speed 0 everywhere), range 0..4 m/s fixed for the series. Three series: every step independent (3000 iterations), and
# warm-started coarse (1000, no relocation) and dense (1500, relocation on),
# whose first step is the independent one. Validation PSNR every 50
# iterations goes to bench-out/series_<mode>.csv; `benches/series_report.py`
# turns the CSVs into the table of docs/BENCHMARKS.md.
#   bash benches/series.sh [POINTS] [STEPS] [MODES]
#   (points per iteration, default 4096; steps A..B, default 1..22; modes,
#   default "off dense coarse")
# A run of steps A..B with A > 1 continues an earlier one: each warm series
# resumes from its stored step A-1 (`--resume-from`, bitwise the unbroken
# series), and the new steps replace steps >= A in the CSV and JSON lines.
set -euo pipefail
cd "$(dirname "$0")/.."
points=${1:-4096}
steps=${2:-1..22}
modes=${3:-off dense coarse}
. benches/corpus.sh
corpus dambreak3d_particles.positions.float32 dambreak3d_particles.smoothing_length.float32 dambreak3d_particles.mass.float32 dambreak3d_particles.speed.float32
out=bench-out
mkdir -p "$out"
cargo build --release --locked --bin gsenc >&2
bin=${GSENC_BIN:-target/release/gsenc}
dam=(--positions "$data/dambreak3d_particles.positions.float32"
     --smoothing-length "$data/dambreak3d_particles.smoothing_length.float32"
     --mass "$data/dambreak3d_particles.mass.float32"
     --values "$data/dambreak3d_particles.speed.float32" --count 42042
     --dims 128 --bounds 0.021,-0.481,0.0107,3.22,0.481,0.55
     --range 0,4 --steps "$steps" --field speed)
first=${steps%%..*}
for mode in $modes; do
    prev=$(printf '%s/series_%s/speed_%06d.gsm' "$out" "$mode" $((first - 1)))
    resume=() part=""
    if [[ $steps == *..* && $first -gt 1 && -f $prev ]]; then
        [[ $mode == off ]] || resume=(--resume-from "$prev")
        part=".from$first"
    else
        rm -rf "$out/series_$mode"
    fi
    "$bin" encode-series "${dam[@]}" --budget 50000 --schedule full --iters 3000 --points "$points" --no-relocation \
        --warm "$mode" "${resume[@]}" --validation-every 50 -o "$out/series_$mode" --csv "$out/series_$mode$part.csv" \
        --json --quiet > "$out/series_$mode$part.jsonl"
    if [[ -n $part ]]; then
        python3 - "$out/series_$mode" "$part" "$first" <<'PY'
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
python3 benches/series_report.py "$out"
