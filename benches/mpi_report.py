"""Medians of benches/mpi.sh runs: one row per form, step and rank count."""
import json
import statistics
import sys
from collections import defaultdict

rows = defaultdict(list)
for line in open(sys.argv[1]):
    if line.startswith("{"):
        d = json.loads(line)
        rows[(d["form"], d["step"], d["ranks"])].append(d)
single = {(f, s): statistics.median(r["global_psnr"] for r in v) for (f, s, n), v in rows.items() if n == 1}
print("| form | step | ranks | Gaussians/rank | blended PSNR | vs 1 rank | additive PSNR | s/step | push ms (rank 0) | peak MB | index+decode s | runs |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for (f, s, n), v in sorted(rows.items(), key=lambda kv: (["grid", "particles", "cells"].index(kv[0][0]), kv[0][2], kv[0][1])):
    med = lambda k: statistics.median(r[k] for r in v)
    psnr = med("global_psnr")
    print(f"| {f} | {s} | {n} | {v[0]['budget_per_rank']} | {psnr:.2f} | {psnr - single[(f, s)]:+.2f} | {med('additive_psnr'):.2f} | "
          f"{med('seconds_per_step'):.1f} | {1000 * med('push_seconds_rank0'):.0f} | {med('peak_rss_mb_max_rank'):.0f} | {med('decode_seconds'):.2f} | {len(v)} |")
