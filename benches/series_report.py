"""Table of the series benchmark (benches/series.sh): per step, the final
validation PSNR of the independent encode and of each warm start, and the
first iteration at which each warm start reaches the independent final PSNR.
    python3 benches/series_report.py bench-out
"""
import csv
import json
import sys

out = sys.argv[1]


def load(mode):
    """Per step, [(iteration, validation PSNR, start)], from the run's CSV, or
    (a run stopped before its CSV was written) the final PSNR of each step
    from its JSON lines."""
    runs = {}
    try:
        rows = list(csv.DictReader(open(f"{out}/series_{mode}.csv")))
    except FileNotFoundError:
        try:
            lines = [json.loads(l) for l in open(f"{out}/series_{mode}.jsonl") if '"step"' in l]
        except FileNotFoundError:
            return {}
        # Leave a final-only CSV behind so that `gsenc plot-series` can draw it.
        with open(f"{out}/series_{mode}.csv", "w") as f:
            f.write("field,step,start,iteration,validation_psnr\n")
            for d in lines:
                f.write(f"speed,{d['step']},{d['start']},{d['iterations']},{d['validation_psnr']:.4f}\n")
        return {d["step"]: [(d["iterations"], d["validation_psnr"], d["start"])] for d in lines}
    for r in rows:
        runs.setdefault(int(r["step"]), []).append((int(r["iteration"]), float(r["validation_psnr"]), r["start"]))
    return runs


indep = load("off")
warm = {m: load(m) for m in ("coarse", "dense")}
print("| step | independent final dB (3000 its) | coarse final dB | coarse reaches it at | dense final dB | dense reaches it at |")
print("|---|---|---|---|---|---|")
reached = {m: [0, 0] for m in warm}
for step in sorted(indep):
    target = indep[step][-1][1]
    cells = [str(step), f"{target:.2f}"]
    for m, runs in warm.items():
        log = runs.get(step)
        if not log:
            cells += ["-", "-"]
            continue
        if log[0][2] == "independent":
            cells += [f"{log[-1][1]:.2f}", "(first step: independent)"]
            continue
        hit = next((it for it, p, _ in log if p >= target), None)
        total = log[-1][0]
        reached[m][1] += 1
        if hit is not None and hit <= 1500:
            reached[m][0] += 1
        cells += [f"{log[-1][1]:.2f}", f"{hit} of {total}" if hit is not None else f"not in {total}"]
    print("| " + " | ".join(cells) + " |")
for m, (ok, n) in reached.items():
    if n:
        print(f"\n{m}: reaches the independent final PSNR within 1500 iterations (50 % of 3000) on {ok} of {n} warm steps")
