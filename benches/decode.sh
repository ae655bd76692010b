#!/usr/bin/env bash
# Decode throughput: voxels per second and peak memory of `gsenc decode`
# at several lattice resolutions, streaming to a .raw file.
#   bash benches/decode.sh [REPEATS]           # medians of REPEATS (3) a row
#   ROWS="rm128_32k@256 hydrogen_4k@256" bash benches/decode.sh 5
#   BASE_BIN=/path/to/other/gsenc bash benches/decode.sh
# With BASE_BIN, each run of a row runs that build and then this one, back
# to back, and their outputs must be the same bytes (checked); the table
# then sets the two builds' medians side by side.
# Uses the models benches/core.sh leaves in bench-out/ (rm128_32k_full,
# rm256_200k_full, hydrogen_4k_matched); a row whose model is missing is
# named and skipped. The 512^3 and 1024^3 rows run LARGE times (default
# once: 0.5 and 4.3 GB out;
# hydrogen's 1024^3 row, the decode of benches/gpu.sh, about 55 s on two
# cores with BACKEND=cpu).
# Env: BACKEND (default cpu: `auto` would take a GPU where there is one);
# ROWS selects rows by name; GSENC_BIN a build to time instead of this
# checkout's (benches/corpus.sh); OUT=null writes to standard output into
# /dev/null instead of a file, so that the disk's time is left out (the
# outputs are then not compared). With a build of the feature `gpu-noop`,
# BACKEND=gpu GSENC_ADAPTER=noop OUT=null times the host's share of a GPU
# decode (docs/BENCHMARKS.md "A decode written behind"). Each run to a
# file starts after a `sync`. One JSON line per run goes to
# bench-out/decode.jsonl.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
out=bench-out
mkdir -p "$out"
gsenc_bin
repeats=${1:-3}
log="$out/decode.jsonl"
rm -f "$log"
row() { # name model dims repeats
    local name=$1 model=$2 dims=$3 n=$4 i b exe
    want "$name" || return 0
    [ -f "$model" ] || { echo "skipping $name: $model is missing (run benches/core.sh)" >&2; return 0; }
    for i in $(seq 1 "$n"); do
        for b in "${builds[@]}"; do
            exe=$(build_bin "$b")
            if [ "${OUT:-file}" = null ]; then
                # The result goes to standard error when the data take standard output.
                "$exe" decode "$model" --dims "$dims" --backend "${BACKEND:-cpu}" -o - --json --quiet 2>&1 >/dev/null | tail -n 1
            else
                sync
                "$exe" decode "$model" --dims "$dims" --backend "${BACKEND:-cpu}" -o "$out/decode_$b.raw" --json --quiet
            fi | python3 -c "import json,sys; d=json.load(sys.stdin); d.update(row='$name', model='$model', build='$b', out='${OUT:-file}'); print(json.dumps(d))" >> "$log"
            echo "[$name] run $i/$n, $b build" >&2
        done
        if [ "${#builds[@]}" = 2 ] && [ "${OUT:-file}" != null ] && ! cmp -s "$out/decode_base.raw" "$out/decode_new.raw"; then
            echo "[$name] the two builds decoded different values" >&2
            exit 1
        fi
    done
    rm -f "$out"/decode_*.raw
}
row hydrogen_4k@256 "$out/hydrogen_4k_matched.gsm" 256 "$repeats"
large=${LARGE:-1}
row hydrogen_4k@512 "$out/hydrogen_4k_matched.gsm" 512 "$large"
row hydrogen_4k@1024 "$out/hydrogen_4k_matched.gsm" 1024 "$large"
row rm128_32k@128 "$out/rm128_32k_full.gsm" 128 "$repeats"
row rm128_32k@256 "$out/rm128_32k_full.gsm" 256 "$repeats"
row rm128_32k@512 "$out/rm128_32k_full.gsm" 512 "$large"
row rm128_32k@1024 "$out/rm128_32k_full.gsm" 1024 "$large"
row rm256_200k@256 "$out/rm256_200k_full.gsm" 256 "$repeats"
row rm256_200k@512 "$out/rm256_200k_full.gsm" 512 "$large"
python3 - "$log" <<'PY'
import json, statistics, sys
rows = {}
for line in open(sys.argv[1]):
    d = json.loads(line)
    rows.setdefault((d["row"], d["build"]), []).append(d)
print("| model @ lattice | build | runs | voxels | seconds (median) | voxels/s | peak RSS MB | output MB |")
print("|---|---|---|---|---|---|---|---|")
for (name, build), runs in rows.items():
    med = lambda k: statistics.median(r[k] for r in runs)
    each = ", ".join(f"{r['seconds']:.2f}" for r in runs)
    print(f"| {name} | {build} | {len(runs)} | {runs[0]['voxels']:,} | {med('seconds'):.2f} ({each}) | "
          f"{med('voxels_per_second')/1e6:.2f} M | {med('peak_rss_bytes')/1e6:.0f} | {runs[0]['voxels']*4/1e6:.0f} |")
PY
