#!/usr/bin/env python3
"""The thread-scaling model: schedules the tasks of a one-thread encode's
task profile (`src/profile.rs`, feature `task-profile`) on p workers and
prints the predicted time of an iteration and the speed-up at each p.

    python3 benches/scaling_model.py [--fork-join-us US] PROFILE...
    python3 benches/scaling_model.py --check     (the model's own test)

Each iteration is the sequence of passes the profile recorded: a serial
section takes its time at any p; a parallel pass takes the time of a greedy
schedule of its tasks, in order, on p workers (each task to the first free
worker, as rayon's work stealing roughly does), plus a fork-join cost per
pass (`--fork-join-us`, printed both with it and without); a last row
schedules each pass's longest tasks first. Rayon does neither exactly; the
two rows show how much the order of the tasks matters. What the loop runs
beside the gradient (passes named `beside: ...`: the next batch's draw and
its sort into bricks) takes its serial sections on one worker and its
tasks in the gradient's pool. The model knows
nothing of memory bandwidth, caches shared by more cores, or frequency
changes, so it is an upper bound on what the schedule allows; set it beside
`benches/scaling.sh` on the machine itself.
"""
import argparse
import heapq
import statistics

# The prefix of what the loop runs beside its passes (src/profile.rs `beside`).
BESIDE = "beside: "


def iterations(path):
    """Lists of (pass, [task seconds]) or (pass, -seconds) per iteration."""
    out, cur = [], []
    for line in open(path):
        name, secs = line.rstrip("\n").split("\t")
        secs = float(secs)
        if name == "":
            out.append(cur)
            cur = []
        elif secs < 0:
            cur.append((name, secs))
        elif cur and isinstance(cur[-1][1], list) and cur[-1][0] == name:
            cur[-1][1].append(secs)
        else:
            cur.append((name, [secs]))
    return out


def makespan(tasks, p, longest_first=False):
    """Each task to the first free worker, in order, or longest first."""
    free = [0.0] * p
    for t in sorted(tasks, reverse=True) if longest_first else tasks:
        heapq.heappush(free, heapq.heappop(free) + t)
    return max(free)


def predict(its, p, fork_join, longest_first=False):
    total = 0.0
    for it in its:
        side_serial = sum(-v for n, v in it if n.startswith(BESIDE) and not isinstance(v, list))
        side_tasks = [t for n, v in it if n.startswith(BESIDE) and isinstance(v, list) for t in v]
        main = [(n, v) for n, v in it if not n.startswith(BESIDE)]
        if p == 1:
            total += sum(-v if not isinstance(v, list) else sum(v) for _, v in it)
            continue
        # The tasks beside join the largest pass of the iteration.
        largest = max((i for i, (n, v) in enumerate(main) if isinstance(v, list)), key=lambda i: sum(main[i][1]), default=None)
        t_main = 0.0
        for i, (n, v) in enumerate(main):
            if not isinstance(v, list):
                t_main += -v
            else:
                tasks = v + side_tasks if i == largest else v
                t_main += makespan(tasks, p, longest_first) + fork_join
        total += max(t_main, side_serial + makespan(side_tasks, p, longest_first))
    return total / len(its)


def check():
    """The model on a made-up profile whose schedule is known by hand."""
    import os
    import tempfile
    # Two iterations, each: a serial section of 1 s; a pass of four tasks
    # (3, 1, 1, 1 s); the draw beside it, a 0.5 s stream and two 1 s tasks.
    one = ["s\t-1", "p\t3", "p\t1", "p\t1", "p\t1", "beside: draw: stream\t-0.5", "beside: draw: x\t1", "beside: draw: x\t1", "\t0"]
    with tempfile.NamedTemporaryFile("w", suffix=".tsv", delete=False) as f:
        f.write("\n".join(one * 2) + "\n")
    try:
        its = iterations(f.name)
    finally:
        os.unlink(f.name)
    assert len(its) == 2 and its[0][1] == ("p", [3.0, 1.0, 1.0, 1.0]), its
    assert makespan([3, 1, 1, 1], 2) == 3 and makespan([1, 1, 1, 1], 2) == 2
    assert predict(its, 1, 0.0) == 9.5
    # Two workers: the pass and the draw's tasks (3, 1, 1, 1, 1, 1) take 4 s
    # after the serial second; a fork-join cost adds once per pass.
    assert predict(its, 2, 0.0) == 5.0 and abs(predict(its, 2, 0.25) - 5.25) < 1e-12
    # Many workers: the longest task sets the pass; the draw (0.5 + 1) fits beside.
    assert predict(its, 16, 0.0) == 4.0
    # In order, a long task last waits; longest first, it does not.
    assert makespan([1, 1, 1, 3], 2) == 4 and makespan([1, 1, 1, 3], 2, True) == 3
    assert predict(its, 2, 0.0, longest_first=True) == 5.0
    print("scaling_model.py: the model's checks pass")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fork-join-us", type=float, default=5.0)
    ap.add_argument("--threads", default="1,2,4,8,16")
    ap.add_argument("--check", action="store_true", help="check the model on a made-up profile and exit")
    ap.add_argument("profiles", nargs="*")
    a = ap.parse_args()
    if a.check:
        check()
        return
    counts = [int(x) for x in a.threads.split(",")]
    for path in a.profiles:
        its = iterations(path)[5:]  # the first iterations warm the caches
        if not its:
            raise SystemExit(f"{path}: no iterations recorded (built without --features gsenc/task-profile?)")
        n = len(its)
        share = {}
        for it in its:
            for name, v in it:
                share[name] = share.get(name, 0.0) + (sum(v) if isinstance(v, list) else -v)
        one = sum(share.values()) / n
        print(f"## {path}: {n} iterations, {one * 1e3:.3f} ms an iteration at 1 thread")
        print()
        print("| pass | ms at 1 thread | share | tasks (median) | 16-worker schedule / ideal (median) |")
        print("|---|---|---|---|---|")
        for name, s in sorted(share.items(), key=lambda kv: -kv[1]):
            runs = [v for it in its for nm, v in it if nm == name]
            if isinstance(runs[0], list):
                tasks = statistics.median(len(v) for v in runs)
                imb = statistics.median(makespan(v, 16) / (sum(v) / 16) for v in runs if sum(v) > 0)
                print(f"| {name} | {s / n * 1e3:.3f} | {100 * s / n / one:.1f} % | {tasks:g} | {imb:.2f} |")
            else:
                print(f"| {name} | {s / n * 1e3:.3f} | {100 * s / n / one:.1f} % | serial | |")
        print()
        print("| threads | " + " | ".join(str(p) for p in counts) + " |")
        print("|---|" + "---|" * len(counts))
        for fj, lpt in ((0.0, False), (a.fork_join_us, False), (a.fork_join_us, True)):
            cells = []
            for p in counts:
                t = predict(its, p, fj * 1e-6, lpt)
                cells.append(f"{t * 1e3:.3f} ms ({one / t:.2f}x)")
            print(f"| fork-join {fj:g} us{', longest first' if lpt else ''} | " + " | ".join(cells) + " |")
        print()


if __name__ == "__main__":
    main()
