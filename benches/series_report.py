"""Tables of the series benchmark (benches/series.sh): per step, the final
validation PSNR of the independent encode and of each warm-started series,
the iterations each ran and the first at which it came within 0.3 dB of the
independent final; then per series the targets of docs/BENCHMARKS.md.
    python3 benches/series_report.py bench-out [series|static]
"""
import csv
import json
import sys

out = sys.argv[1]
name = sys.argv[2] if len(sys.argv) > 2 else "series"
TOLERANCE = 0.3


def load(mode):
    """Per step: [(iteration, validation PSNR)] from the run's CSV, and the
    run's JSON line (start, iterations, taken, moved, loop seconds)."""
    logs, lines = {}, {}
    try:
        for l in open(f"{out}/{name}_{mode}.jsonl"):
            d = json.loads(l)
            if "step" in d:
                lines[d["step"]] = d
    except FileNotFoundError:
        pass
    try:
        for r in csv.DictReader(open(f"{out}/{name}_{mode}.csv")):
            logs.setdefault(int(r["step"]), []).append((int(r["iteration"]), float(r["validation_psnr"])))
    except FileNotFoundError:
        # A run stopped before its CSV was written: the finals of its lines.
        logs = {s: [(d["iterations"], d["validation_psnr"])] for s, d in lines.items()}
    return logs, lines


indep, indep_lines = load("off")
modes = [m for m in ("auto", "paper", "dense", "coarse") if load(m)[0]]
runs = {m: load(m) for m in modes}
head = ["step", "independent final dB (3000 its)"]
for m in modes:
    head += [f"{m} final dB", f"{m} its", f"{m} within {TOLERANCE} dB at"]
    if m == "auto":
        head += ["auto start (moved)"]
print("| " + " | ".join(head) + " |")
print("|" + "---|" * len(head))
summary = {m: {"n": 0, "ok": 0, "its": 0, "worst": float("inf"), "loop": 0.0, "indep_loop": 0.0, "reached_half": 0} for m in modes}
for step in sorted(indep):
    target = indep[step][-1][1]
    cells = [str(step), f"{target:.2f}"]
    for m in modes:
        logs, lines = runs[m]
        log, line = logs.get(step), lines.get(step, {})
        if not log:
            cells += ["-", "-", "-"] + (["-"] if m == "auto" else [])
            continue
        final, its = log[-1][1], line.get("iterations", log[-1][0])
        if line.get("start", "") == "independent":
            cells += [f"{final:.2f}", str(its), "(first step: independent)"] + (["-"] if m == "auto" else [])
            continue
        hit = next((it for it, p in log if p >= target - TOLERANCE), None)
        s = summary[m]
        s["n"] += 1
        s["its"] += its
        s["ok"] += final >= target - TOLERANCE
        s["reached_half"] += hit is not None and hit <= 1500
        s["worst"] = min(s["worst"], final - target)
        s["loop"] += line.get("loop_seconds", 0.0)
        s["indep_loop"] += indep_lines.get(step, {}).get("loop_seconds", 0.0)
        cells += [f"{final:.2f}", str(its), str(hit) if hit is not None else "not reached"]
        if m == "auto":
            cells += [f"{line.get('taken')} ({line.get('moved')})"]
    print("| " + " | ".join(cells) + " |")
print()
for m, s in summary.items():
    if not s["n"]:
        continue
    print(
        f"- {m}: ends within {TOLERANCE} dB of the independent final (or above it) on {s['ok']} of {s['n']} warm steps; "
        f"gets there within 1500 iterations on {s['reached_half']}; worst {s['worst']:+.2f} dB; "
        f"mean iterations {s['its'] / s['n']:.0f} ({100 * s['its'] / s['n'] / 3000:.0f} % of 3000); "
        f"loop time of the warm steps {s['loop']:.0f} s vs {s['indep_loop']:.0f} s independent "
        f"({100 * s['loop'] / max(s['indep_loop'], 1e-9):.0f} %)"
    )
