#!/usr/bin/env bash
# A target PSNR through a time series: the dam break's speed with the
# settings of benches/series.sh (particles deposited on 128^3 over the
# series' whole box, range 0..4 m/s), `encode-series --target-psnr T` with
# the `matched` schedule and the default `auto` warm start, steps A..B; then
# the same series stopped after step M and restarted from its stored model
# (`--resume-from`), whose steps M+1..B must be the unbroken run's files
# byte for byte (the model keeps the slopes the first step measured).
#   bash benches/target_series.sh [TARGETS] [STEPS] [M]
#   (default "50 55", 1..22 (steps 1 to 21), 11)
#   python3 benches/target_series_report.py   # the Markdown tables
# Outputs bench-out/target_series/T/ (the unbroken run's models and JSON
# lines) and T.resumed/ (the restart's). About 15 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus dambreak3d_particles.positions.float32 dambreak3d_particles.smoothing_length.float32 dambreak3d_particles.mass.float32 dambreak3d_particles.speed.float32
targets=(${1:-50 55})
steps=${2:-1..22}
stop=${3:-11}
out=bench-out/target_series
mkdir -p "$out"
gsenc_bin
dam=(--positions "$data/dambreak3d_particles.positions.float32"
     --smoothing-length "$data/dambreak3d_particles.smoothing_length.float32"
     --mass "$data/dambreak3d_particles.mass.float32"
     --values "$data/dambreak3d_particles.speed.float32" --count 42042
     --dims 128 --bounds 0.021,-0.481,0.0107,3.22,0.481,0.55
     --range 0,4 --field speed --schedule matched --json --quiet)
last=${steps##*..}
for t in "${targets[@]}"; do
    rm -rf "$out/$t" "$out/$t.resumed"
    "$bin" encode-series "${dam[@]}" --target-psnr "$t" --steps "$steps" -o "$out/$t" > "$out/$t.jsonl"
    from=$(printf '%s/%s/speed_%06d.gsm' "$out" "$t" "$stop")
    "$bin" encode-series "${dam[@]}" --target-psnr "$t" --steps "$((stop + 1))..$last" --resume-from "$from" \
        -o "$out/$t.resumed" > "$out/$t.resumed.jsonl"
    same=0 differ=0
    for f in "$out/$t.resumed"/speed_*.gsm; do
        if cmp -s "$f" "$out/$t/$(basename "$f")"; then same=$((same + 1)); else differ=$((differ + 1)); fi
    done
    echo "{\"target\": $t, \"resumed_after\": $stop, \"same_files\": $same, \"different_files\": $differ}" > "$out/$t.restart.json"
    echo "[target_series] $t dB: restarted after step $stop, $same files the same, $differ different" >&2
done
python3 benches/target_series_report.py "$out" "${targets[@]}"
