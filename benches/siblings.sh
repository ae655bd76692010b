#!/usr/bin/env bash
# Which CPUs share a core with CPU 0, measured rather than read from lscpu
# (a VM may show hyperthread siblings as cores of their own): a one-thread
# CPU encode (hydrogen 4,096, ITERS iterations, default 100) pinned to CPU 0
# alone, then beside the same encode pinned to each other CPU in turn. Two
# threads of this FMA-bound loop on one core's hyperthreads each run about
# 1.6-2x slower; on separate cores 1.1-1.25x (shared caches and memory, on
# the 2-core VM), so a pair above 1.45x is flagged. Each pair runs twice and the
# run whose slower encode was faster is kept. Whether the 16 vCPUs of a lent
# machine are 16 cores or 8 decides what 16 threads can reach (issue 21's
# 12x) and whether an in-situ encoder's thread shares the solver's core.
#   bash benches/siblings.sh          (GSENC_BIN: a prebuilt gsenc)
# Prints a Markdown table: each CPU's pair time against CPU 0 alone. About
# 2 s a CPU on the H200 machine's cores.
set -euo pipefail
cd "$(dirname "$0")/.."
. benches/corpus.sh
corpus hydrogen_atom.float32
gsenc_bin
out=bench-out/siblings
mkdir -p "$out"
encode() { # CPU OUTPUT: the loop seconds of one pinned encode, into OUTPUT
    taskset -c "$1" "$bin" encode grid --input "$data/hydrogen_atom.float32" --dims 64,64,64 --dtype f32 --budget 4096 \
        --schedule matched --iters "${ITERS:-100}" --threads 1 --backend cpu -o "$out/cpu$1.gsm" --json --quiet \
        | python3 -c 'import json, sys; print(json.load(sys.stdin)["seconds"])' > "$2"
}
cpus=$(nproc)
for r in 1 2 3; do encode 0 "$out/alone$r"; done
alone=$(python3 -c 'import statistics, sys; print(statistics.median(float(open(f).read()) for f in sys.argv[1:]))' "$out"/alone?)
echo "| CPU beside CPU 0 | CPU 0's time / alone | that CPU's time / alone | |"
echo "|---|---|---|---|"
for k in $(seq 1 $((cpus - 1))); do
    for r in 1 2; do  # twice: a sibling slows both runs, noise one
        encode 0 "$out/pair0_$r" & a=$!
        encode "$k" "$out/pairk_$r" & b=$!
        wait "$a" "$b"
    done
    python3 - "$alone" "$k" "$out" <<'PY'
import sys
alone, k, out = float(sys.argv[1]), sys.argv[2], sys.argv[3]
runs = [[float(open(f"{out}/pair{w}_{r}").read()) / alone for w in ("0", "k")] for r in (1, 2)]
p0, pk = min(runs, key=max)
print(f"| {k} | {p0:.2f} | {pk:.2f} | {'shares a core with CPU 0' if max(p0, pk) > 1.45 else ''} |")
PY
done
echo
echo "CPU 0 alone: $alone s (median of 3, ${ITERS:-100} iterations)"
