"""The table of benches/target.sh: per dataset and target, the budget the
search chose, the PSNR it reached, whether it landed, the search's time
against a fixed-budget encode of that budget, and that encode's PSNR."""
import json
import sys

log = sys.argv[1] if len(sys.argv) > 1 else "bench-out/target/target.jsonl"
rows = [json.loads(l) for l in open(log) if l.strip()]
fixed = {(r["dataset"], r["schedule"], r["target_psnr"]): r for r in rows if r["run"] == "fixed"}
print("| dataset | schedule | target dB | primitives chosen (cap) | PSNR dB | lands | tries (probes) | search s | fixed-budget s | ratio | fixed-budget PSNR dB |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for r in rows:
    if r["run"] != "target":
        continue
    t = r["target"]
    f = fixed.get((r["dataset"], r["schedule"], r["target_psnr"]))
    fs = f["total_seconds"] if f else float("nan")
    tries = " → ".join(f"{x['budget']}: {x['psnr']:.2f}" for x in t["tries"])
    print(f"| {r['dataset']} | {r['schedule']} | {r['target_psnr']:g} | {r['primitives']} ({t['cap']}) | {r['voxel_psnr']:.2f} | "
          f"{'yes' if t['landed'] else 'no'} | {tries} ({len(t['probes'])}) | {r['total_seconds']:.1f} | {fs:.1f} | "
          f"{r['total_seconds'] / fs:.2f} | {f['voxel_psnr'] if f else float('nan'):.2f} |")
