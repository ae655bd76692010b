#!/usr/bin/env bash
# Benchmark of the model payloads: each model is rewritten as
# float32, 8-bit with float16 centres and 8-bit with uint16 centres
# (`gsenc convert`), then scored against its reference (`gsenc eval`).
#   bash benches/export.sh [REPEATS]
# It reuses the models the other benchmarks leave in bench-out/; make them first:
#   bash benches/core.sh 1 rm128_32k_full rm256_200k_full
#   bash benches/inputs.sh 1 halo128_50k halo256_200k
# One JSON line per (model, payload) goes to bench-out/export.jsonl; a Markdown
# table is printed at the end. Convert times are medians of REPEATS (default 3).
set -euo pipefail
cd "$(dirname "$0")/.."
repeats=${1:-3}
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8
out=bench-out
cargo build --release --locked --bin gsenc >&2
bin=target/release/gsenc
rm -f "$out/export.jsonl"

rm_ref=(--input "$data/richtmyer_meshkov_t20.uint8" --dims 256,256,256 --dtype u8)
row() { # name model eval-args...
    local name=$1 model=$2; shift 2
    if [ ! -f "$model" ]; then
        echo "skipping $name: $model is missing (see the header of this script)" >&2
        return 0
    fi
    for payload in f32 8bit 8bit-u16; do
        local file="$out/$name.$payload.gsm" times=()
        for i in $(seq 1 "$repeats"); do
            local t0 t1
            t0=$(date +%s.%N)
            "$bin" convert "$model" --payload "$payload" -o "$file" --json > "$out/convert.json"
            t1=$(date +%s.%N)
            times+=("$(python3 -c "print($t1 - $t0)")")
        done
        "$bin" eval "$file" "$@" --json --quiet | python3 -c "
import json, statistics, sys
d = json.load(sys.stdin); c = json.load(open('$out/convert.json'))
d.update(row='$name', payload='$payload', primitives=c['primitives'], bytes=c['bytes'],
         bytes_per_primitive=c['bytes_per_primitive'], convert_seconds=statistics.median([${times[*]/%/,}]))
print(json.dumps(d))" >> "$out/export.jsonl"
        echo "[$name] $payload done" >&2
    done
}

row rm128_32k "$out/rm128_32k_full.gsm" "${rm_ref[@]}" --downsample 2
row rm256_200k "$out/rm256_200k_full.gsm" "${rm_ref[@]}"
row halo128_50k "$out/halo128_50k.gsm" --input "$out/halo128_50k.deposit.raw" --dims 128,128,128 --dtype f32 --normalized
row halo256_200k "$out/halo256_200k.gsm" --input "$out/halo256_200k.deposit.raw" --dims 256,256,256 --dtype f32 --normalized

python3 - "$out/export.jsonl" <<'PY'
import json, sys
rows = {}
for line in open(sys.argv[1]):
    d = json.loads(line)
    rows.setdefault(d["row"], {})[d["payload"]] = d
print("| model | primitives | payload | bytes | bytes/primitive | voxel PSNR dB | change dB | size ratio | convert s |")
print("|---|---|---|---|---|---|---|---|---|")
for name, p in rows.items():
    base = p["f32"]
    for kind, d in p.items():
        print(f"| {name} | {d['primitives']} | {kind} | {d['bytes']} | {d['bytes_per_primitive']:.2f} | "
              f"{d['voxel_psnr']:.3f} | {d['voxel_psnr'] - base['voxel_psnr']:+.3f} | "
              f"{base['bytes'] / d['bytes']:.2f} | {d['convert_seconds']:.2f} |")
PY
