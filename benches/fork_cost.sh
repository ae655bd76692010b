#!/usr/bin/env bash
# What a pass of parallel tasks costs beyond its work on p threads: rayon's
# pool, as the CPU backend uses it, against a team of threads that spin
# between passes (examples/fork_cost.rs: 7 passes of 64 equal tasks an
# iteration, the work's time on one thread alone as the reference). The
# answer to whether the CPU backend's passes would scale further with
# threads that do not fall asleep between them (docs/BENCHMARKS.md "Where
# an iteration loses time on p threads"). Rerun with:
#   bash benches/fork_cost.sh [THREADS...]   (default: 2, 4, 8 and 16, up to the cores here)
# PASS_US (default "250 1000 4000") sets a pass's work in microseconds on
# one thread. GSENC_FORK_COST_BIN names a binary built elsewhere (the lent
# kit), and nothing is built. Writes bench-out/fork_cost.jsonl and prints a
# Markdown table.
set -euo pipefail
cd "$(dirname "$0")/.."
threads=("$@")
if [ ${#threads[@]} -eq 0 ]; then
    for t in 2 4 8 16; do [ "$t" -le "$(nproc)" ] && threads+=("$t"); done
    [ ${#threads[@]} -gt 0 ] || threads=(1)
fi
bin=${GSENC_FORK_COST_BIN:-}
if [ -z "$bin" ]; then
    cargo build --release --locked --example fork_cost >&2
    bin=${CARGO_TARGET_DIR:-target}/release/examples/fork_cost
fi
mkdir -p bench-out
# shellcheck disable=SC2086 # PASS_US is a list
"$bin" "${threads[@]}" --pass-us ${PASS_US:-250 1000 4000} > bench-out/fork_cost.jsonl
python3 - bench-out/fork_cost.jsonl <<'PY'
import json, sys
rows = {}
for line in open(sys.argv[1]):
    d = json.loads(line)
    rows.setdefault((d["threads"], d["pass_work_us"]), {})[d["scheduler"]] = d
print("| threads | a pass's work on one thread, µs | rayon: beyond the work, µs a pass (speed-up) | spinning team: the same |")
print("|---|---|---|---|")
for (p, us), r in sorted(rows.items()):
    cell = lambda d: f'{d["beyond_work_per_pass_us"]:.1f} ({d["speedup"]:.2f}×)'
    print(f"| {p} | {us:g} | {cell(r['rayon'])} | {cell(r['spinning team'])} |")
PY
