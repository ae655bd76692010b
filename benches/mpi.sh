#!/usr/bin/env bash
# Per-rank encoding of a decomposed domain on 1, 2 and 4 ranks (mpirun,
# oversubscribed beyond the cores): the mock solver's grid, particles and cells,
# the same total budget split over the ranks. One JSON line per form, step and
# rank count: global PSNR, time per step (slowest rank, push to wait),
# peak memory of the largest rank, step-index read + global decode time.
# Usage: bash benches/mpi.sh [RUNS [OUT_DIR]]   (default 3 runs, bench-out/mpi);
# then python3 benches/mpi_report.py OUT_DIR/runs.jsonl prints the medians.
set -euo pipefail
cd "$(dirname "$0")/.."
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
runs="${1:-3}"
out="${2:-bench-out/mpi}"
rm -rf "$out"
mkdir -p "$out"
cargo build --release --locked --features mpi --example mpi_mock_solver
args=(--grid 64 --particles 40000 --budget 1200 --iterations 400 --steps 2 --halo 4)
for run in $(seq "$runs"); do
    for n in 1 2 4; do
        extra=(--write-baseline)
        [ "$n" -gt 1 ] && extra=(--baseline "$out/m1/baseline.json" --tolerance-db 100)
        mpirun --oversubscribe -n "$n" target/release/examples/mpi_mock_solver --out "$out/m$n" "${extra[@]}" "${args[@]}" \
            | sed "s/^{/{\"run\":$run,/" | tee -a "$out/runs.jsonl"
    done
done
python3 benches/mpi_report.py "$out/runs.jsonl"
