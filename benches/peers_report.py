"""Tables and the plot of benches/peers.sh: PSNR against compression ratio for
gsenc (packed payload), SZ3 and zfp on each dataset, the ratio where gsenc
and SZ3 cross, and the payload comparison.

    bench-out/peers-venv/bin/python benches/peers_report.py [LOG] [PNG]

LOG defaults to bench-out/peers/peers.jsonl, PNG to docs/peers.png (drawn
when matplotlib imports: peers.sh installs it in its venv). Prints Markdown.
"""
import json
import math
import sys
from collections import defaultdict

log = sys.argv[1] if len(sys.argv) > 1 else "bench-out/peers/peers.jsonl"
png = sys.argv[2] if len(sys.argv) > 2 else "docs/peers.png"
rows = [json.loads(line) for line in open(log) if line.strip()]

ORDER = ["rm128", "rm128full", "rm256", "hydrogen", "enzo", "dambreak", "halo"]
NAMES = {
    "rm128": "Richtmyer-Meshkov 128³",
    "rm128full": "Richtmyer-Meshkov 128³",
    "rm256": "Richtmyer-Meshkov 256³",
    "hydrogen": "hydrogen atom 64³",
    "enzo": "Enzo AMR cells, deposit 128³, log10",
    "dambreak": "dam break particles (step 21), deposit 128 (fit)",
    "halo": "dark-matter halo particles, deposit 128³, log10",
}


def title(key):
    ds, schedule = key
    return f"{NAMES.get(ds, ds)} (`{schedule}`)"


def order(keys):
    rank = {s: i for i, s in enumerate(["tuned", "tuned-full", "full", "matched"])}
    return sorted(keys, key=lambda k: (ORDER.index(k[0]) if k[0] in ORDER else len(ORDER), k[0], rank.get(k[1], 9), k[1]))


def fmt(v, digits=1):
    return "—" if v is None else f"{v:.{digits}f}"


def payloads():
    got = [r for r in rows if r.get("dataset") == "payloads"]
    if not got:
        return
    print("### Payloads (one encode stored four ways)\n")
    print("| model | schedule | payload | bytes a primitive (payload) | file bytes | voxel PSNR dB | change vs f32 dB | precision (bits: centre per class, scale, rotation, value, weight) |")
    print("|---|---|---|---|---|---|---|---|")
    by_model = defaultdict(dict)
    for r in got:
        by_model[(r["model"], r.get("schedule", "matched"))][r["payload"]] = r
    for (model, schedule), ps in by_model.items():
        f32 = ps.get("f32", {}).get("voxel_psnr")
        for name in ["f32", "8bit", "8bit-u16", "packed"]:
            r = ps.get(name)
            if r is None:
                continue
            per = r.get("payload_bytes_per_primitive") or r["payload_bytes"] / r["primitives"]
            p = r.get("precision")
            # The centre lattices, one per centre class, read as 4/4/2/0.
            group = lambda v: "/".join(map(str, v)) if isinstance(v, list) else str(v)
            bits = ", ".join(group(p[k]) for k in ["centre", "scale", "rotation", "value", "weight"]) if p else ""
            change = r["voxel_psnr"] - f32 if f32 is not None and name != "f32" else None
            print(f"| {model} | {schedule} | {name} | {per:.2f} | {r['bytes']} | {r['voxel_psnr']:.2f} | {fmt(change, 3)} | {bits} |")
    print()


def curves():
    data = defaultdict(lambda: defaultdict(dict))  # (dataset, schedule) -> budget -> codec -> row
    for r in rows:
        ds = r.get("dataset")
        if ds in (None, "payloads"):
            continue
        data[(ds, r["schedule"])][r["budget"]][r["codec"]] = r
    summary = []
    for ds in order(data):
        print(f"### {title(ds)}\n")
        print("| primitives | ratio | gsenc bytes | gsenc PSNR dB | float32 PSNR dB | SZ3 PSNR dB | zfp PSNR dB | gsenc − SZ3 | gsenc − zfp | encode s |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        points = []
        for budget in sorted(b for b in data[ds] if b != "_points"):
            c = data[ds][budget]
            g = c.get("gsenc")
            if g is None:
                continue
            ratio = g["voxels"] * 4 / g["bytes"]

            def peer(name):
                r = c.get(name)
                if r is None or "cannot_reach" in r:
                    return None
                return r["psnr"]

            s, z = peer("sz3"), peer("zfp")
            points.append((ratio, g["psnr"], s, z))
            d_s = None if s is None else g["psnr"] - s
            d_z = None if z is None else g["psnr"] - z
            sz_note = "" if s is not None else " (SZ3: cannot reach)"
            zfp_note = "" if z is not None else " (zfp: cannot reach)"
            print(f"| {budget} | {ratio:.0f}x | {g['bytes']} | {g['psnr']:.2f} | {fmt(g.get('float32_psnr'), 2)} | {fmt(s, 2)}{sz_note} | {fmt(z, 2)}{zfp_note} | {fmt(d_s, 2)} | {fmt(d_z, 2)} | {g['total_seconds']:.1f} |")
        print()
        summary.append((ds, crossover(points)))
        data[ds]["_points"] = points
    print("Crossover against SZ3 (gsenc's PSNR minus SZ3's at equal bytes changes sign):\n")
    for ds, text in summary:
        print(f"- {title(ds)}: {text}")
    print()
    return data


def crossover(points):
    """Every ratio where gsenc's PSNR minus SZ3's changes sign (interpolated
    in log ratio), or which side gsenc stays on."""
    pts = sorted((r, g - s) for r, g, s, _ in points if s is not None)
    if not pts:
        return "SZ3 reaches none of gsenc's sizes"
    span = f"measured {pts[0][0]:.0f}x to {pts[-1][0]:.0f}x"
    crossings = []
    for (r0, d0), (r1, d1) in zip(pts, pts[1:]):
        if (d0 < 0) != (d1 < 0):
            t = d0 / (d0 - d1)
            r = math.exp(math.log(r0) + t * (math.log(r1) - math.log(r0)))
            crossings.append(f"{'ahead' if d1 >= 0 else 'behind'} from about {r:.0f}x")
    if crossings:
        return f"gsenc {'behind' if pts[0][1] < 0 else 'ahead'} at {pts[0][0]:.0f}x, " + ", ".join(crossings) + f" ({span})"
    side = "ahead" if pts[0][1] >= 0 else "behind"
    closest = max(d for _, d in pts) if side == "behind" else min(d for _, d in pts)
    return f"gsenc {side} over the whole range ({span}; closest {closest:+.1f} dB)"


def plot(data):
    """One panel a dataset: gsenc's curve for each schedule run, and SZ3's
    and zfp's points at every size gsenc took (all schedules together)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(f"(matplotlib is missing: no plot written to {png})")
        return
    panel = lambda ds: "rm128" if ds == "rm128full" else ds
    sets = []
    for key in order(data):
        if panel(key[0]) not in sets:
            sets.append(panel(key[0]))
    cols = 3
    rows_n = math.ceil(len(sets) / cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(5 * cols, 3.8 * rows_n), squeeze=False)
    for ax, name in zip(axes.flat, sets):
        keys = [k for k in order(data) if panel(k[0]) == name]
        peers = {"SZ3": [], "zfp": []}
        for k in keys:
            pts = data[k]["_points"]
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=f"gsenc {k[1]} (packed)")
            peers["SZ3"] += [(p[0], p[2]) for p in pts if p[2] is not None]
            peers["zfp"] += [(p[0], p[3]) for p in pts if p[3] is not None]
        for label, style in [("SZ3", "s--"), ("zfp", "^:")]:
            xy = sorted(peers[label])
            if xy:
                ax.plot([x for x, _ in xy], [y for _, y in xy], style, color="gray" if label == "zfp" else "black", label=label)
        ax.set_xscale("log")
        ax.set_title(NAMES.get(name, name), fontsize=9)
        ax.set_xlabel("compression ratio (float32 bytes / stored bytes)")
        ax.set_ylabel("PSNR (dB)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(sets):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    print(f"Plot: {png}")


payloads()
plot(curves())
