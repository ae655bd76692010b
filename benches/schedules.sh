#!/usr/bin/env bash
# What gsenc's schedules cost beside the paper's at the same iterations and
# points: `tuned` against `matched` and `tuned-full` against `full`, on the
# corpus datasets, REPEATS times each, the two schedules of a pair run back
# to back (this VM's speed drifts). Rerun with:
#   bash benches/schedules.sh [REPEATS]
# Prints one JSON line per run to bench-out/schedules.jsonl and a Markdown
# table of medians (encode seconds, voxel PSNR) with the ratio of each pair.
set -euo pipefail
cd "$(dirname "$0")/.."
repeats=${1:-3}
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32 dm_halo_particles.positions.float32 dm_halo_particles.smoothing_length.float32 dm_halo_particles.mass.float32 dm_halo_particles.density.float32
out=bench-out
mkdir -p "$out"
cargo build --release --locked --bin gsenc >&2
bin=target/release/gsenc
log=$out/schedules.jsonl
rm -f "$log"

# pair ROW BUDGET PAPER GSENC ENCODE-ARGS...: the two schedules, alternating.
pair() {
    local row=$1 budget=$2 paper=$3 ours=$4; shift 4
    local i s
    for i in $(seq 1 "$repeats"); do
        for s in "$paper" "$ours"; do
            echo "[$row] $s run $i/$repeats" >&2
            "$bin" encode "$@" --budget "$budget" --schedule "$s" -o "$out/schedules_${row}_$s.gsm" --json --quiet \
                | python3 -c "import json,sys; d=json.load(sys.stdin); d.update(row='$row', schedule='$s'); print(json.dumps(d))" >> "$log"
        done
    done
}

pair rm128_8k 8000 matched tuned "${rm128[@]}"
pair hydrogen_4k 4096 matched tuned "${hyd[@]}"
pair halo_10k 10000 matched tuned "${halo[@]}"
pair rm128_12k 12000 full tuned-full "${rm128[@]}"

python3 - "$log" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
print("| row | schedule | encode s (median) | voxel PSNR dB | time vs the paper's schedule |")
print("|---|---|---|---|---|")
for row in dict.fromkeys(r["row"] for r in rows):
    got = {}
    for s in dict.fromkeys(r["schedule"] for r in rows if r["row"] == row):
        rs = [r for r in rows if r["row"] == row and r["schedule"] == s]
        got[s] = (statistics.median(r["total_seconds"] for r in rs), rs[0]["voxel_psnr"])
    paper = next(iter(got.values()))[0]
    for s, (t, p) in got.items():
        print(f"| {row} | {s} | {t:.2f} | {p:.2f} | {t / paper:.2f}x |")
PY
