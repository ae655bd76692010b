#!/usr/bin/env bash
# What the packed payload's precision search costs an encode
# (src/encode/precision.rs): `decode_seconds` of `gsenc encode --payload
# packed` holds the search (its sample scorings) and the whole-lattice
# decodes that check it; `seconds` is the training loop alone.
#   bash benches/precision.sh                 # medians of 3 runs a row
#   REPEAT=5 ROWS="hydrogen_4k_tuned" bash benches/precision.sh
#   BASE_BIN=/path/to/other/gsenc bash benches/precision.sh
# With BASE_BIN, each run of a row runs that build and then this one, back
# to back, and their models must be the same bytes (checked); the table
# then sets the two builds' medians side by side.
# Env: REPEAT (default 3) runs a row; ROWS selects rows by name; GSENC_BIN a
# build to time instead of this checkout's (benches/corpus.sh).
# Each run's JSON line goes to bench-out/precision.jsonl.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
out=bench-out
mkdir -p "$out"
gsenc_bin
log="$out/precision.jsonl"
rm -f "$log"
row() { # name args...
    local name=$1 i b exe; shift
    want "$name" || return 0
    for i in $(seq "${REPEAT:-3}"); do
        for b in "${builds[@]}"; do
            exe=$(build_bin "$b")
            echo "[$name] run $i, $b build" >&2
            "$exe" encode "$@" --backend cpu --payload packed -o "$out/precision_$b.gsm" --json --quiet \
                | python3 -c "import json, sys; d = json.load(sys.stdin); d.update(row='$name', build='$b'); print(json.dumps(d))" >> "$log"
        done
        if [ "${#builds[@]}" = 2 ] && ! cmp -s "$out/precision_base.gsm" "$out/precision_new.gsm"; then
            echo "[$name] the two builds wrote different models" >&2
            exit 1
        fi
    done
}
row hydrogen_4k_tuned "${hyd[@]}" --budget 4096 --schedule tuned
# Trained for 300 iterations only, its first choice loses more than 0.1 dB
# on the whole lattice, so the search runs again with the next allowance.
row hydrogen_4k_tuned_300it "${hyd[@]}" --budget 4096 --schedule tuned --iters 300
row rm128_32k_matched "${rm128[@]}" --range 0,255 --budget 32000 --schedule matched

python3 - "$log" <<'EOF'
import json, statistics, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
print("| row | build | runs | search and checks s (decode_seconds) | loop s | bytes | precision |")
print("|---|---|---|---|---|---|---|")
for row in dict.fromkeys(r["row"] for r in runs):
    for build in dict.fromkeys(r["build"] for r in runs if r["row"] == row):
        rs = [r for r in runs if r["row"] == row and r["build"] == build]
        med = lambda k: statistics.median(r[k] for r in rs)
        each = ", ".join(f"{r['decode_seconds']:.2f}" for r in rs)
        print(f"| {row} | {build} | {len(rs)} | {med('decode_seconds'):.2f} ({each}) | {med('seconds'):.2f} | {rs[0]['bytes']} | {json.dumps(rs[0]['precision'])} |")
EOF
