#!/usr/bin/env python3
"""Where an iteration loses time on p threads, from an encode's timeline
(`src/profile.rs`, feature `task-profile`, `GSENC_TASK_TIMELINE`):

    python3 benches/timeline.py TIMELINE...
    python3 benches/timeline.py --check     (the script's own test)

Per pass of the iteration (the main path's passes that most iterations
run; what runs beside them, the next batch's draw, is left out), the
medians over the iterations of:
- wall: from the pass's first task's start to its last task's end;
- work / p: the tasks' summed time, and the time the pool spent beside it
  within the pass (drawing the next batch), over the p threads that the
  pool has: what the pass would take if no thread ever waited;
- join: how long after the pass's first task each other thread started its
  first task (the mean over those threads; a thread that took no task
  counts the whole wall), the pool waking and stealing;
- tail: how long the pass's last task ran alone at its end (after every
  other thread's last task of the pass had ended);
- lost: wall - work / p (for tasks; a serial section and a pass timed
  whole show their wall only).
Then the gaps between consecutive passes (the serial sections, and the
wait for the pool between one pass's end and the next one's start: a
thread that ran out of work falls asleep within tens of microseconds, and
waking it takes longer on a virtual machine), each and in all, and the
iteration's whole time. On 1 thread, lost
is the cost of timing itself; on p threads, lost and the gaps are what the
thread-scaling model (`benches/scaling_model.py`) cannot see.
"""
import statistics
import sys

BESIDE = "beside: "
SERIAL = "(serial) "
WHOLE = "(timed whole) "


def read(path):
    """The iterations of a timeline, each a list of (pass, thread, start,
    end), and the pool's size from its first line (None in a timeline
    written before it had one); a serial section's pass gets `SERIAL`
    before it, a pass timed whole `WHOLE` (after `BESIDE`, when it has
    that)."""
    its, cur, threads = [], [], None
    with open(path) as f:
        for line in f:
            if line.startswith("#threads\t"):
                threads = int(line.split("\t")[1])
                continue
            pass_, thread, start, end, kind = line.rstrip("\n").split("\t")
            if pass_ == "":
                its.append(cur)
                cur = []
                continue
            prefix = {"serial": SERIAL, "whole": WHOLE}.get(kind, "")
            side = BESIDE if pass_.startswith(BESIDE) else ""
            cur.append((side + prefix + pass_[len(side):], int(thread), float(start), float(end)))
    return its, threads


def pool_threads(its, threads=None):
    """The pool's size: as the timeline says, else the threads that ran a
    task (which misses a thread that never did)."""
    return threads or len({t for it in its for (_, t, _, _) in it if t >= 0}) or 1


def passes(it, p, keep=None):
    """The main path's passes of one iteration (those in `keep`, when
    given), in order of their start: (name, start, end, work, join, tail);
    work counts what ran beside the pass within its span."""
    by = {}
    beside = []
    for name, t, s, e in it:
        if name.startswith(BESIDE):
            beside.append((s, e))
            continue
        if keep is not None and name not in keep:
            continue
        by.setdefault(name, []).append((t, s, e))
    out = []
    for name, recs in by.items():
        start = min(s for _, s, _ in recs)
        end = max(e for _, _, e in recs)
        work = sum(e - s for _, s, e in recs)
        work += sum(max(0.0, min(e, end) - max(s, start)) for s, e in beside)
        first = {}
        last = {}
        for t, s, e in recs:
            first[t] = min(first.get(t, s), s)
            last[t] = max(last.get(t, e), e)
        starter = min(first, key=first.get)
        others = [first[t] - start for t in first if t != starter]
        others += [end - start] * max(0, p - len(first))
        join = sum(others) / len(others) if others else 0.0
        ends = sorted(last.values())
        tail = ends[-1] - ends[-2] if len(ends) > 1 else (end - start if p > 1 else 0.0)
        out.append((name, start, end, work, join, tail))
    out.sort(key=lambda r: r[1])
    return out


def summarise(path):
    its, threads = read(path)
    # The first iterations allocate what the others reuse.
    its = its[2:] if len(its) > 4 else its
    p = pool_threads(its, threads)
    # The passes of most iterations (a relocation's draw is not one).
    seen = {}
    for it in its:
        for name in {r[0] for r in it}:
            seen[name] = seen.get(name, 0) + 1
    keep = {n for n, c in seen.items() if 2 * c >= len(its)}
    rows = {}
    gaps, totals, each_gap = [], [], {}
    for it in its:
        ps = passes(it, p, keep)
        if not ps:
            continue
        for name, s, e, w, j, t in ps:
            rows.setdefault(name, []).append((e - s, w / p, j, t, e - s - w / p))
        for a, b in zip(ps, ps[1:]):
            each_gap.setdefault(f"{a[0]} → {b[0]}", []).append(max(0.0, b[1] - a[2]))
        gaps.append(sum(max(0.0, b[1] - a[2]) for a, b in zip(ps, ps[1:])))
        totals.append(ps[-1][2] - ps[0][1])
    ms = lambda xs: 1e3 * statistics.median(xs)
    print(f"## {path}: {len(its)} iterations on {p} threads, first pass to last {ms(totals):.3f} ms (median)\n")
    print("| pass | wall ms | work / p ms | join ms | tail ms | lost ms |")
    print("|---|---|---|---|---|---|")
    order = sorted(rows, key=lambda n: -statistics.median(r[0] for r in rows[n]))
    lost_sum = 0.0
    for n in order:
        r = rows[n]
        cols = [ms([x[i] for x in r]) for i in range(5)]
        if n.startswith(SERIAL) or n.startswith(WHOLE):
            # One thread by design (the scaling model counts it so), or a
            # parallel pass whose tasks were not timed: its wall only.
            print(f"| {n} | {cols[0]:.3f} | | | | |")
            continue
        lost_sum += cols[4]
        print(f"| {n} | " + " | ".join(f"{c:.3f}" for c in cols) + " |")
    print(f"| between passes | {ms(gaps):.3f} | | | | {ms(gaps):.3f} |")
    print(f"\nlost in passes and between them: {lost_sum + ms(gaps):.3f} ms of {ms(totals):.3f} ms an iteration\n")
    print("| between | µs (median) |")
    print("|---|---|")
    for k, v in each_gap.items():
        print(f"| {k} | {1e6 * statistics.median(v):.1f} |")
    print()


def check():
    # Two threads; pass a: thread 0 runs 0-4, thread 1 joins at 1 and runs
    # 1-3, then draws beside it 3-4: wall 4, work 7, join 1, tail 1 (4 - 3).
    # A gap of 1, then pass b on thread 0 alone (5-7): join = wall 2, tail 2.
    import os
    import tempfile
    lines = ["a\t0\t0\t2\ttask", "a\t1\t1\t3\ttask", "a\t0\t2\t4\ttask", "beside: d\t1\t3\t4\twhole", "b\t0\t5\t7\ttask", "s\t0\t7\t7.5\tserial", "\t0\t7.5\t7.5\ttask"]
    def written(head):
        with tempfile.NamedTemporaryFile("w", suffix=".tsv", delete=False) as f:
            f.write("".join(h + "\n" for h in head) + "\n".join(lines) + "\n")
        out = read(f.name)
        os.unlink(f.name)
        return out
    its, threads = written([])
    assert len(its) == 1 and threads is None and pool_threads(its, threads) == 2
    # A pool of 3 whose third thread ran no task: the header says 3.
    its3, threads3 = written(["#threads\t3"])
    assert its3 == its and pool_threads(its3, threads3) == 3
    ps = passes(its[0], 2)
    assert [r[0] for r in ps] == ["a", "b", SERIAL + "s"], ps
    name, s, e, w, j, t = ps[0]
    assert (s, e, w, j, t) == (0, 4, 7, 1, 1), ps[0]
    name, s, e, w, j, t = ps[1]
    assert (s, e, w, j, t) == (5, 7, 2, 2, 2), ps[1]
    print("timeline: ok")


if __name__ == "__main__":
    if sys.argv[1:] == ["--check"]:
        check()
    elif len(sys.argv) < 2:
        sys.exit(__doc__)
    else:
        for path in sys.argv[1:]:
            summarise(path)
