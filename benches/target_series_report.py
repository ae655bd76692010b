"""The tables of docs/BENCHMARKS.md "A target PSNR through a time series"
from benches/target_series.sh's outputs:

    python3 benches/target_series_report.py [OUT] [TARGETS...]
    (default bench-out/target_series, 50 55)

One table per target: each step's start, budget, the tries of its search
(budget: PSNR, the chosen one last or marked), whether it landed, the PSNR
as stored, the iterations of the chosen model and the step's seconds; then
a summary line, with the restart's comparison."""
import json
import os
import sys

LANDS_BELOW, LANDS_ABOVE = 0.5, 1.0


def rows(path):
    """The per-step JSON lines of an encode-series run (not its summary)."""
    with open(path) as f:
        lines = [json.loads(l) for l in f if l.strip()]
    return [l for l in lines if "step" in l and "start" in l]


def report(out, target):
    steps = rows(os.path.join(out, f"{target}.jsonl"))
    print(f"**{target} dB**\n")
    print("| step | start | primitives | tries (budget: dB) | lands | voxel PSNR dB | iterations | step s |")
    print("|---|---|---|---|---|---|---|---|")
    landed = grew = 0
    budgets = []
    for r in steps:
        t = r["target"]
        tries = " → ".join(f"{x['budget']}: {x['psnr']:.2f}" for x in t["tries"])
        if len(t["tries"]) > 1 and t["chosen"] != len(t["tries"]) - 1:
            tries += f" (kept {t['tries'][t['chosen']]['budget']})"
        start = r["start"] if r["taken"] is None else f"{r['start']}/{r['taken']}"
        if t["probes"]:
            start += f", {len(t['probes'])} probes"
        landed += t["landed"]
        grew += bool(budgets) and r["primitives"] > budgets[-1]
        budgets.append(r["primitives"])
        print(f"| {r['step']} | {start} | {r['primitives']} | {tries} | {'yes' if t['landed'] else 'no'} | "
              f"{r['voxel_psnr']:.2f} | {r['iterations']} | {r['step_seconds']:.1f} |")
    psnrs = [r["voxel_psnr"] for r in steps]
    curve = steps[0]["target"]
    print(f"\n{landed} of {len(steps)} steps land in [{target - LANDS_BELOW}, {target + LANDS_ABOVE}] dB; PSNR "
          f"{min(psnrs):.2f} to {max(psnrs):.2f} dB; the budget grew at {grew} steps, {budgets[0]} to {budgets[-1]} "
          f"primitives; the first step's slopes {curve['db_per_budget_doubling']:.2f} dB per budget doubling, "
          f"{curve['db_per_iteration_doubling']:.2f} per iteration doubling; "
          f"{sum(r['step_seconds'] for r in steps):.0f} s in all.")
    restart = os.path.join(out, f"{target}.restart.json")
    if os.path.exists(restart):
        r = json.load(open(restart))
        print(f"Restarted after step {r['resumed_after']}: {r['same_files']} models the unbroken run's byte for byte, "
              f"{r['different_files']} different.")
    print()


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "bench-out/target_series"
    targets = [float(t) if "." in t else int(t) for t in sys.argv[2:]] or [50, 55]
    for t in targets:
        report(out, t)


if __name__ == "__main__":
    main()
