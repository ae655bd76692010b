#!/usr/bin/env python3
"""The GPU backend's host phases per iteration, from an encode's JSON lines.

Usage: python3 benches/host_phases.py FILE.jsonl
Each line is one `gsenc encode --json` run with a `row` name (and, from
benches/gpu.sh, a `which`); lines without `gpu_host_seconds` (CPU rows,
failed runs) are skipped. Prints a Markdown table: per row, the median over
its runs of each phase's seconds divided by the run's iterations, in ms
(mod.rs `GpuBackend::host`: the phases of every point call of the encode, so
relocation and validation passes are in them too).
"""
import json
import statistics
import sys

PHASES = ["arrange", "write", "record", "submit", "wait", "read"]

runs = {}
for line in open(sys.argv[1]):
    d = json.loads(line)
    if not d.get("gpu_host_seconds"):
        continue
    key = d["row"] + (f" ({d['which']})" if "which" in d else "")
    runs.setdefault(key, []).append(d)
if not runs:
    sys.exit(f"{sys.argv[1]}: no run has gpu_host_seconds")
print("| row | " + " | ".join(PHASES) + " | all |")
print("|---|" + "---|" * (len(PHASES) + 1))
for key, rs in runs.items():
    ms = lambda f: statistics.median(1e3 * f(d) / d["iterations"] for d in rs)
    phase = lambda d, p: d["gpu_host_seconds"].get(p, {}).get("seconds", 0.0)
    cells = [f"{ms(lambda d: phase(d, p)):.3f}" for p in PHASES]
    total = ms(lambda d: sum(phase(d, p) for p in PHASES))
    print(f"| {key} | " + " | ".join(cells) + f" | {total:.3f} |")
