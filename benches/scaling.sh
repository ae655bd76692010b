#!/usr/bin/env bash
# Thread scaling of the CPU backend: benches/core.sh's rows, one run each,
# at 1, 2, 4, 8 and 16 threads (or THREAD_COUNTS), then the speed-up of each
# against one thread. Rerun with:
#   bash benches/scaling.sh [ROWS...]     (default: rm128_32k_matched hydrogen_4k_matched rm128_32k_full)
# Writes bench-out/scaling.jsonl and prints a Markdown table. About 4
# minutes on a 16-core machine. The models of every thread count must be
# the same bytes: the script checks that and fails if they are not.
# ITERS (caps each row's iterations) and GSENC_BIN (a prebuilt gsenc) pass
# through to benches/core.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
rows=("$@")
[ ${#rows[@]} -gt 0 ] || rows=(rm128_32k_matched hydrogen_4k_matched rm128_32k_full)
counts=${THREAD_COUNTS:-"1 2 4 8 16"}
out=bench-out
rm -rf "$out/scaling"  # the models of this run's first thread count, compared with the others'
mkdir -p "$out/scaling"
: > "$out/scaling.jsonl"
for t in $counts; do
    THREADS=$t bash benches/core.sh 1 "${rows[@]}" > /dev/null
    python3 -c "
import json, sys
for line in open('$out/core.jsonl'):
    d = json.loads(line); d['threads'] = $t; print(json.dumps(d))
    if d['backend'] != 'cpu':
        sys.exit(f\"{d['row']}: encoded by {d['backend']}, not the CPU backend\")" >> "$out/scaling.jsonl"
    for r in "${rows[@]}"; do
        if [ -f "$out/scaling/$r.gsm" ]; then
            cmp -s "$out/$r.gsm" "$out/scaling/$r.gsm" || { echo "$r: the model at $t threads differs from the one at the first thread count" >&2; exit 1; }
        else
            cp "$out/$r.gsm" "$out/scaling/$r.gsm"
        fi
    done
done
python3 - "$out/scaling.jsonl" <<'PY'
import json, sys
runs = [json.loads(l) for l in open(sys.argv[1])]
rows = sorted({r["row"] for r in runs}, key=[r["row"] for r in runs].index)
counts = sorted({r["threads"] for r in runs})
print("| row | " + " | ".join(f"{t} thr" for t in counts) + " |")
print("|---|" + "---|" * len(counts))
for name in rows:
    s = {r["threads"]: r["seconds"] for r in runs if r["row"] == name}
    base = s[counts[0]]
    print(f"| {name} | " + " | ".join(f"{s[t]:.2f} s ({base / s[t]:.2f}x)" for t in counts) + " |")
PY
