#!/usr/bin/env bash
# The CPU backend's roofline on one core: the core's multiply-add and exp
# throughput, the lane code's ceiling from cache, and what the encodes of
# benches/core.sh reach per core (their kernel evaluations a second at one
# thread). Rerun with:
#   bash benches/roofline.sh [SECONDS]
# Prints JSON lines to bench-out/roofline.jsonl. x86-64 with AVX-512VL and FMA.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-3}
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
out=bench-out
mkdir -p "$out"
cargo build --release --locked --bin gsenc --example roofline >&2
target/release/examples/roofline "$seconds" | tee "$out/roofline.jsonl"
enc() { # name args...: one thread, kernel evaluations a second
    local name=$1; shift
    target/release/gsenc encode grid "$@" --threads 1 -o "$out/roofline_$name.gsm" --json --quiet \
        | python3 -c "import json,sys; d=json.load(sys.stdin); print(json.dumps({'row': '$name', 'threads': 1, 'seconds': d['seconds'], 'kernel_evals_per_second': d['kernel_evals_per_second']}))" \
        | tee -a "$out/roofline.jsonl"
}
enc hydrogen_4k_matched --input "$data/hydrogen_atom.float32" --dims 64,64,64 --dtype f32 --budget 4096 --schedule matched
enc rm128_32k_matched --input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8 --range 0,255 --downsample 2 --budget 32000 --schedule matched
