#!/usr/bin/env bash
# What the machine itself allows p threads, apart from the thread pool: p
# one-thread CPU encodes of the same row run at once, copy i pinned to the
# i-th CPU this process may use. Each copy does one thread's whole work, so
# nothing is shared but the machine: caches, memory bandwidth, the clock a
# loaded socket keeps, and a core's hyperthread sibling where the VM shows
# one as a core. If p copies each take f times as long as one alone, then p
# threads of one encode can reach at most p / f times one thread's speed
# (issue 21's 12x at 16 threads needs f <= 1.33); what the pool loses comes
# on top (benches/timeline.sh, benches/fork_cost.sh).
#   bash benches/rate.sh [ROWS...]   (default: rm128_32k_matched hydrogen_4k_matched rm128_32k_full)
# COPIES (default "1 2 4 8 16", capped at the CPUs there are, and the CPU
# count added) sets the p's; ITERS sets every row's iterations (default 100
# for RM `matched`, 300 for hydrogen, 50 for RM `full`: 2-3 s a copy on the
# H200 machine's cores); GSENC_BIN names a prebuilt gsenc. Every copy of a
# row must write the same model bytes (checked: the same seeds under load).
# Writes bench-out/rate.jsonl and prints a Markdown table. SCALING names
# the same machine's benches/scaling.sh runs (bench-out/scaling.jsonl), so
# that the table sets the speed-up p threads measured beside the ceiling.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus richtmyer_meshkov_t20.uint8 hydrogen_atom.float32
gsenc_bin
rows=("$@")
[ ${#rows[@]} -gt 0 ] || rows=(rm128_32k_matched hydrogen_4k_matched rm128_32k_full)
out=bench-out/rate
rm -rf "$out"
mkdir -p "$out"
: > bench-out/rate.jsonl
read -r -a cpus <<< "$(python3 -c 'import os; print(*sorted(os.sched_getaffinity(0)))')"
copies=$(python3 -c '
import sys
n, asked = int(sys.argv[1]), [int(c) for c in sys.argv[2].split()]
print(*sorted({c for c in asked if c <= n} | {n}))' "${#cpus[@]}" "${COPIES:-1 2 4 8 16}")

args() { # ROW: its encode arguments (corpus.sh's, as benches/core.sh's rows) and default iterations
    local rm=("${rm128[@]}" --range 0,255 --budget 32000)
    case $1 in
        rm128_32k_matched) row_args=("${rm[@]}" --schedule matched); row_iters=100 ;;
        rm128_32k_full) row_args=("${rm[@]}" --schedule full); row_iters=50 ;;
        hydrogen_4k_matched) row_args=("${hyd[@]}" --budget 4096 --schedule matched); row_iters=300 ;;
        *) echo "rate.sh: no row named $1" >&2; exit 2 ;;
    esac
}

for row in "${rows[@]}"; do
    args "$row"
    for p in $copies; do
      # The copy alone is the reference of every ratio: ALONE runs of it (default 3).
      for round in $(seq 1 $([ "$p" -eq 1 ] && echo "${ALONE:-3}" || echo 1)); do
        echo "[$row] $p copies" >&2
        pids=()
        for i in $(seq 0 $((p - 1))); do
            taskset -c "${cpus[$i]}" "$bin" encode "${row_args[@]}" --iters "${ITERS:-$row_iters}" --threads 1 --backend cpu \
                -o "$out/$row-$p-$i.gsm" --json --quiet > "$out/$row-$p-$i.json" &
            pids+=($!)
        done
        for pid in "${pids[@]}"; do wait "$pid"; done
        [ "$p" -gt 1 ] || cp "$out/$row-1-0.gsm" "$out/$row-alone.gsm"
        for i in $(seq 0 $((p - 1))); do
            cmp -s "$out/$row-alone.gsm" "$out/$row-$p-$i.gsm" || { echo "$row: copy $i of $p wrote another model than the copy alone" >&2; exit 1; }
            python3 -c "
import json, sys
d = json.load(open(sys.argv[1]))
if d['backend'] != 'cpu':
    sys.exit(f\"{sys.argv[2]}: encoded by {d['backend']}, not the CPU backend\")
print(json.dumps({'row': sys.argv[2], 'copies': int(sys.argv[3]), 'cpu': int(sys.argv[4]), 'seconds': d['seconds'],
                  'iterations': d['iterations'], 'simd': d.get('simd')}))" \
                "$out/$row-$p-$i.json" "$row" "$p" "${cpus[$i]}" >> bench-out/rate.jsonl
        done
      done
    done
done

python3 - bench-out/rate.jsonl "${SCALING:-}" <<'PY'
import json, statistics, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
scaling = {}
if sys.argv[2]:
    for l in open(sys.argv[2]):
        d = json.loads(l)
        scaling[(d["row"], d["threads"])] = d["seconds"] / d["iterations"]
print("| row | copies | loop s a copy: median (min-max) | each copy's slowdown f | ceiling p / f | p threads measured (benches/scaling.sh) |")
print("|---|---|---|---|---|---|")
for row in dict.fromkeys(r["row"] for r in runs):
    alone = None
    for p in sorted({r["copies"] for r in runs if r["row"] == row}):
        s = [r["seconds"] for r in runs if r["row"] == row and r["copies"] == p]
        med = statistics.median(s)
        alone = alone or med
        f = med / alone
        one, many = scaling.get((row, 1)), scaling.get((row, p))
        measured = f"{one / many:.2f}x, {one / many / (p / f) * 100:.0f} % of the ceiling" if one and many else ""
        print(f"| {row} | {p} | {med:.3f} ({min(s):.3f}-{max(s):.3f}) | {f:.2f} | {p / f:.1f}x | {measured} |")
simd = {r["simd"] for r in runs}
print(f"\nThe CPU backend's build: {', '.join(sorted(map(str, simd)))}; iterations a copy: "
      + ", ".join(f"{row} {next(r['iterations'] for r in runs if r['row'] == row)}" for row in dict.fromkeys(r["row"] for r in runs)))
PY
