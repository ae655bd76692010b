#!/usr/bin/env bash
# Decode throughput: voxels per second and peak memory of
# `gsenc decode` at several lattice resolutions, streaming to a .raw file.
#   bash benches/decode.sh [REPEATS]
# Uses the models benches/core.sh leaves in bench-out/ (rm128_32k_full,
# rm256_200k_full). One JSON line per run goes to bench-out/decode.jsonl; a
# Markdown table of medians is printed. The 1024^3 row runs once (4 GiB out).
set -euo pipefail
cd "$(dirname "$0")/.."
repeats=${1:-3}
out=bench-out
cargo build --release --locked --bin gsenc >&2
bin=target/release/gsenc
rm -f "$out/decode.jsonl"
row() { # name model dims repeats
    local name=$1 model=$2 dims=$3 n=$4
    [ -f "$model" ] || { echo "skipping $name: $model is missing (run benches/core.sh)" >&2; return 0; }
    for i in $(seq 1 "$n"); do
        "$bin" decode "$model" --dims "$dims" -o "$out/decode.raw" --json --quiet \
            | python3 -c "import json,sys; d=json.load(sys.stdin); d.update(row='$name', model='$model'); print(json.dumps(d))" >> "$out/decode.jsonl"
        echo "[$name] run $i/$n" >&2
    done
    rm -f "$out/decode.raw"
}
row rm128_32k@128 "$out/rm128_32k_full.gsm" 128 "$repeats"
row rm128_32k@256 "$out/rm128_32k_full.gsm" 256 "$repeats"
row rm128_32k@512 "$out/rm128_32k_full.gsm" 512 1
row rm128_32k@1024 "$out/rm128_32k_full.gsm" 1024 1
row rm256_200k@256 "$out/rm256_200k_full.gsm" 256 "$repeats"
row rm256_200k@512 "$out/rm256_200k_full.gsm" 512 1
python3 - "$out/decode.jsonl" <<'PY'
import json, statistics, sys
rows = {}
for line in open(sys.argv[1]):
    d = json.loads(line)
    rows.setdefault(d["row"], []).append(d)
print("| model @ lattice | runs | voxels | seconds (median) | voxels/s | peak RSS MB | output MB |")
print("|---|---|---|---|---|---|---|")
for name, runs in rows.items():
    med = lambda k: statistics.median(r[k] for r in runs)
    print(f"| {name} | {len(runs)} | {runs[0]['voxels']:,} | {med('seconds'):.2f} | {med('voxels_per_second')/1e6:.2f} M | "
          f"{med('peak_rss_bytes')/1e6:.0f} | {runs[0]['voxels']*4/1e6:.0f} |")
PY
