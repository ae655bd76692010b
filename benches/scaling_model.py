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
two rows show how much the order of the tasks matters. A task that forks
(a dense brick whose points run in parallel runs: records marked `head`,
`run`, `tail`) is scheduled as it runs: its runs become free to take when
its head ends (after a fork-join cost), and its tail when its last run
ends; a worker takes a free run before the pass's next task. What the loop runs
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


class Fork:
    """A task that forks: its head, then its runs in parallel, then its tail."""

    def __init__(self, head):
        self.head, self.runs, self.tail = head, [], 0.0

    def work(self):
        return self.head + sum(self.runs) + self.tail

    def __eq__(self, other):
        return isinstance(other, Fork) and (self.head, self.runs, self.tail) == (other.head, other.runs, other.tail)

    def __repr__(self):
        return f"Fork({self.head}, {self.runs}, {self.tail})"


def work(t):
    """The time a task takes on one worker."""
    return t.work() if isinstance(t, Fork) else t


def iterations(path):
    """Lists of (pass, [tasks]) or (pass, -seconds) per iteration; a task is
    its seconds, or a Fork."""
    out, cur = [], []
    for line in open(path):
        fields = line.rstrip("\n").split("\t")
        name, secs, part = fields[0], float(fields[1]), fields[2] if len(fields) > 2 else None
        if name == "":
            out.append(cur)
            cur = []
        elif secs < 0:
            cur.append((name, secs))
        else:
            if not (cur and isinstance(cur[-1][1], list) and cur[-1][0] == name):
                cur.append((name, []))
            tasks = cur[-1][1]
            if part is None:
                tasks.append(secs)
            elif part == "head":
                tasks.append(Fork(secs))
            elif part in ("run", "tail") and tasks and isinstance(tasks[-1], Fork):
                if part == "run":
                    tasks[-1].runs.append(secs)
                else:
                    tasks[-1].tail += secs
            else:
                raise SystemExit(f"{path}: a '{part}' record of {name!r} without its head")
    return out


def makespan(tasks, p, longest_first=False, fork_join=0.0):
    """Each task to the first free worker, in order, or longest first; a
    Fork's runs and tail as they become free (`schedule_forks`)."""
    order = sorted(tasks, key=work, reverse=True) if longest_first else tasks
    if any(isinstance(t, Fork) for t in order):
        return schedule_forks(order, p, fork_join)
    free = [0.0] * p
    for t in order:
        heapq.heappush(free, heapq.heappop(free) + t)
    return max(free)


def schedule_forks(order, p, fork_join):
    """The first free worker takes the earliest-listed run or tail that is
    free to start by then, or else the pass's next task, or else waits for
    the first run or tail to become free; a Fork's runs are free when its
    head ends (plus `fork_join`), its tail when its last run ends."""
    free = [0.0] * p
    queue = list(reversed(order))  # the pass's tasks, next last
    released = []  # [free at, listed at, seconds, fork state or None]
    listed, end = 0, 0.0
    while queue or released:
        w = heapq.heappop(free)
        ready = [r for r in released if r[0] <= w]
        if ready:
            item = min(ready, key=lambda r: (r[1], r[0]))
        elif queue:
            item = None
        else:
            item = min(released, key=lambda r: (r[0], r[1]))
        if item is None:
            t = queue.pop()
            listed += 1
            if isinstance(t, Fork):
                done = w + t.head
                state = {"left": len(t.runs), "last": done, "tail": t.tail, "listed": listed}
                released.extend([done + fork_join, listed, r, state] for r in t.runs)
                if not t.runs:
                    released.append([done, listed, t.tail, None])
            else:
                done = w + t
        else:
            released.remove(item)
            start, _, secs, state = item
            done = max(w, start) + secs
            if state is not None:
                state["left"] -= 1
                state["last"] = max(state["last"], done)
                if state["left"] == 0:
                    released.append([state["last"], state["listed"], state["tail"], None])
        end = max(end, done)
        heapq.heappush(free, done)
    return end


def predict(its, p, fork_join, longest_first=False):
    total = 0.0
    for it in its:
        side_serial = sum(-v for n, v in it if n.startswith(BESIDE) and not isinstance(v, list))
        side_tasks = [t for n, v in it if n.startswith(BESIDE) and isinstance(v, list) for t in v]
        main = [(n, v) for n, v in it if not n.startswith(BESIDE)]
        if p == 1:
            total += sum(-v if not isinstance(v, list) else sum(map(work, v)) for _, v in it)
            continue
        # The tasks beside join the largest pass of the iteration.
        largest = max((i for i, (n, v) in enumerate(main) if isinstance(v, list)), key=lambda i: sum(map(work, main[i][1])), default=None)
        t_main = 0.0
        for i, (n, v) in enumerate(main):
            if not isinstance(v, list):
                t_main += -v
            else:
                tasks = v + side_tasks if i == largest else v
                t_main += makespan(tasks, p, longest_first, fork_join) + fork_join
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
    # A task that forks: head 1, runs 2, 2, 2 after it, tail 1 after them;
    # two more tasks of 1. On two workers (by hand): the head and a task,
    # then two runs, the third run beside the last task, then the tail: 6.
    fork = ["p\t1\thead", "p\t2\trun", "p\t2\trun", "p\t2\trun", "p\t1\ttail", "p\t1", "p\t1", "\t0"]
    with tempfile.NamedTemporaryFile("w", suffix=".tsv", delete=False) as f:
        f.write("\n".join(fork) + "\n")
    try:
        its = iterations(f.name)
    finally:
        os.unlink(f.name)
    split = Fork(1.0)
    split.runs, split.tail = [2.0, 2.0, 2.0], 1.0
    assert its == [[("p", [split, 1.0, 1.0])]], its
    assert predict(its, 1, 0.0) == 10.0 and predict(its, 2, 0.0) == 6.0
    # Many workers: head, runs side by side, tail (4), whatever the order;
    # a fork-join cost delays the runs once more.
    assert makespan([1.0, 1.0, split], 8) == 4.0 and makespan([split, 1.0, 1.0], 8, fork_join=0.5) == 4.5
    # Had its parts been independent tasks, 8 workers would take 2.
    assert makespan([1.0, 2.0, 2.0, 2.0, 1.0, 1.0, 1.0], 8) == 2.0
    # A run with no head before it is a broken profile, not a task.
    with tempfile.NamedTemporaryFile("w", suffix=".tsv", delete=False) as f:
        f.write("p\t1\np\t2\trun\n\t0\n")
    try:
        iterations(f.name)
        raise AssertionError("a run without its head was read")
    except SystemExit as e:
        assert "without its head" in str(e), e
    finally:
        os.unlink(f.name)
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
                share[name] = share.get(name, 0.0) + (sum(map(work, v)) if isinstance(v, list) else -v)
        one = sum(share.values()) / n
        print(f"## {path}: {n} iterations, {one * 1e3:.3f} ms an iteration at 1 thread")
        print()
        print("| pass | ms at 1 thread | share | tasks, a fork's runs each (median) | 16-worker schedule / ideal (median) |")
        print("|---|---|---|---|---|")
        for name, s in sorted(share.items(), key=lambda kv: -kv[1]):
            runs = [v for it in its for nm, v in it if nm == name]
            if isinstance(runs[0], list):
                tasks = statistics.median(sum(len(t.runs) if isinstance(t, Fork) else 1 for t in v) for v in runs)
                imb = statistics.median(makespan(v, 16) / (sum(map(work, v)) / 16) for v in runs if sum(map(work, v)) > 0)
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
