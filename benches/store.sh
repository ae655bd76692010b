#!/usr/bin/env bash
# Benchmark of the HDF5 store: each model is appended to a fresh
# store with each payload (`gsenc store add`), and the store is decoded to
# HDF5 + XDMF (`gsenc decode-series`).
#   bash benches/store.sh [REPEATS]
# Needs the cargo feature hdf5 (apt libhdf5-dev) and the models the other
# benchmarks leave in bench-out/ (see the header of benches/export.sh).
# One JSON line per (model, payload) goes to bench-out/store.jsonl; a Markdown
# table is printed at the end. Times are medians of REPEATS (default 3).
set -euo pipefail
cd "$(dirname "$0")/.."
repeats=${1:-3}
out=bench-out
cargo build --release --locked --features hdf5 --bin gsenc >&2
bin=target/release/gsenc
rm -f "$out/store.jsonl"

median() { python3 -c "import statistics, sys; print(statistics.median(float(x) for x in sys.argv[1:]))" "$@"; }
seconds() { local t0 t1; t0=$(date +%s.%N); "$@" > /dev/null; t1=$(date +%s.%N); python3 -c "print($t1 - $t0)"; }

row() { # name model
    local name=$1 model=$2
    if [ ! -f "$model" ]; then
        echo "skipping $name: $model is missing" >&2
        return 0
    fi
    for payload in f32 8bit 8bit-u16; do
        local store="$out/$name.$payload.h5" add=() series=()
        for i in $(seq 1 "$repeats"); do
            rm -f "$store"
            add+=("$(seconds "$bin" store add "$store" "$model" --payload "$payload")")
            series+=("$(seconds "$bin" decode-series "$store" -o "$out/$name.series.h5" --quiet)")
        done
        "$bin" convert "$model" --payload "$payload" -o "$out/$name.store-cmp.gsm" --json > "$out/convert.json"
        "$bin" info "$store" --json | python3 -c "
import json, os, sys
d = json.load(sys.stdin); e = d['entries'][0]; c = json.load(open('$out/convert.json'))
n = e['primitives']; voxels = e['dims'][0] * e['dims'][1] * e['dims'][2]
print(json.dumps(dict(row='$name', payload='$payload', primitives=n, store_bytes=d['bytes'],
      dataset_bytes_per_primitive=e['stored_bytes'] / n, gsm_bytes_per_primitive=c['bytes_per_primitive'],
      add_seconds=$(median "${add[@]}"), decode_series_seconds=$(median "${series[@]}"),
      decode_series_voxels_per_second=voxels / $(median "${series[@]}"))))" >> "$out/store.jsonl"
        echo "[$name] $payload done" >&2
    done
    rm -f "$out/$name.store-cmp.gsm" "$out/$name.series.h5" "$out/$name.series.xmf"
}

row rm128_32k "$out/rm128_32k_full.gsm"
row rm256_200k "$out/rm256_200k_full.gsm"
row halo256_200k "$out/halo256_200k.gsm"

python3 - "$out/store.jsonl" <<'PY'
import json, sys
print("| model | primitives | payload | store bytes/primitive (datasets) | .gsm bytes/primitive | store add s | decode-series s | voxels/s |")
print("|---|---|---|---|---|---|---|---|")
for line in open(sys.argv[1]):
    d = json.loads(line)
    print(f"| {d['row']} | {d['primitives']:,} | {d['payload']} | {d['dataset_bytes_per_primitive']:.2f} | "
          f"{d['gsm_bytes_per_primitive']:.2f} | {d['add_seconds']:.2f} | {d['decode_series_seconds']:.1f} | "
          f"{d['decode_series_voxels_per_second'] / 1e6:.2f} M |")
PY
