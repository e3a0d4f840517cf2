"""How a command scales with workers (issue 27, item 4): time, speedup, efficiency, and the
critical path that bounds the speedup.

The command (a preset or any ``haa-sym`` command line after ``--``) is run in this process
(``haa_sym.cli.main``) on 1, 2, ..., N worker processes (one thread each; N the machine's cores
unless given), started and warmed (haa_sym imported) before the timing, their start timed apart
(``--scheduler local:N`` pays it on every command). ``--backend`` says which: ``pool`` (default),
the local worker processes of ``--scheduler local:N`` (:class:`haa_sym.io.pool.LocalPool`); or
``dask``, a dask.distributed ``LocalCluster`` on 127.0.0.1 given to the command by address, as
a cluster of the two-terminal recipe is (its scheduler's dispatch per task is larger). Every run's output must have the bytes of the
first (the npz's arrays; a CSV whole), else the script fails.

The prediction for M workers (``--predict``, default 16) comes from one more run, on 1 worker (the
tasks' own durations, not sharing a core) with the tasks sized as for M workers (tasks are
sized to the workers: more workers, smaller tasks, shorter chains):

- work W: the sum of the tasks' compute times;
- serial S: the time in which no task ran and none was waiting to run (the command's own
  computation between and around the task lists: it does not shrink with workers);
- dispatch d: the time in which no task ran while some were submitted (each task's trip through
  the scheduler to the single worker); on M workers these trips overlap, so it is counted with the
  work, ``(W + d) / M`` (before issue 27's second round it was counted in S, which erred long);
- longest chain C: the heaviest chain of tasks that waited for one another
  (:data:`haa_sym.io.tasks.TRACE`: a ``run`` waits for the previous ``run``'s tasks; a
  ``stream`` follow-up for the task that asked for it), each link with its share of d;
- predicted time on M workers: ``S + max(C, (W + d) / M)``, and the bound on the speedup
  ``T(1) / (S + C)`` however many workers (the critical path S + C);
- with ``--whole``, the whole command's: the fixed part F (of the fastest whole ``local:1`` run,
  probed (:data:`PROBE`): from its launch to its first task's submission and from its last task
  list's return to its end), plus what starting and stopping M workers costs the command's
  process more than one (its CPU time, :func:`cluster_cpu`: the forks and the dispatcher thread
  are in that process, so it is serial on any machine; the workers' own starts are not, on M
  cores), plus that prediction, against that run.

``--whole R`` also times the whole command as a user runs it, ``python -m haa_sym.cli ...
--scheduler local:N`` in a new process (imports, the cluster's start and stop, every task), for
N = 1, 2, ..., alternating, R rounds (each run probed, so that its time splits into the task
lists' span, from the first task's submission to the last task list's return, and F outside it:
the span's speedup is what the workers give, F is what they cannot): each round's local:1 /
local:N ratio is taken from runs a few seconds apart (the other jobs of a shared machine change within a minute), and the JSON keeps
every run with the cores free before it. Each round also runs N copies of the local:1 command at
once against one alone (:func:`whole_runs`): a reference for what this machine gives this
command's work done N times side by side.

Before each run it measures how many of n cores are free now (:func:`capacity`: n spinning
processes against one; the load average of a shared virtual machine does not say it).

Prints a table and writes ``results_scale_<preset>.json`` into ``$HAA_SYM_BENCH_DIR`` (default
bench-results/). Not part of ``make bench``.

Usage: python benchmarks/bench_scale.py [--workers N] [--predict M] [--preset nonlinear|schedule]
       [--backend pool|dask] [--repeats R] [--whole R] [--no-warm] [-- haa-sym ARGS ...]
"""
from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from timing import ROOT, Run

# the nonlinear map: HyQ with a 24 V supply and 0.02 Nm of rotor friction, 60 x 40 points
LIMITS = "\n[limits]\nV_max = 24.0\nFc_m = 0.02\n"
PRESETS = {
    "nonlinear": ["regions", "--params", "{limits_file}", "--P-gain", "log:10:20000:60", "--D-gain", "lin:1:50:40",
                  "--nonlinear", "--out", "{out}.npz"],
    "schedule": ["schedule", "--out", "{out}.csv"],
}


def _spin(_=None) -> float:
    """Seconds of a fixed pure-Python loop (about 0.5 s on an idle core)."""
    t, s = time.perf_counter(), 0
    for i in range(5_000_000):
        s += i
    return time.perf_counter() - t


def capacity(n: int) -> float:
    """How many cores this process gets now: n processes spinning at once, their speed summed,
    against one alone (2.0 on two idle cores; less when other jobs use them). The load average
    alone does not say it on a shared or virtual machine."""
    import multiprocessing as mp
    with mp.get_context("spawn").Pool(n) as pool:
        pool.map(_spin, range(n))                         # the processes started
        one = min(pool.apply(_spin) for _ in range(2))
        times = pool.map(_spin, range(n), chunksize=1)
    return min(float(n), sum(one / t for t in times))


def _warm(client) -> None:
    """Import haa_sym's task modules on every worker (the first task would do it, timed)."""
    def imports():
        import haa_sym.analysis.nonlinear_map  # noqa: F401
        import haa_sym.design.schedule  # noqa: F401
    client.run(imports)


def _output_bytes(path: Path) -> bytes:
    """What must not change with the workers: an npz's arrays (its meta names the scheduler), a
    CSV's bytes."""
    if path.suffix == ".npz":
        z = np.load(path)
        return b"".join(k.encode() + z[k].tobytes() for k in sorted(z.files) if k != "meta")
    return path.read_bytes()


def _union(intervals) -> float:
    total, end = 0.0, -np.inf
    for a, b in sorted(intervals):
        if b <= end:
            continue
        total += b - max(a, end)
        end = b
    return total


def analyse(trace: list, stream: list, t0: float, t1: float) -> dict:
    """Work, serial part and longest chain of one run (module docstring)."""
    dur, span = {}, {}
    for rec in stream:
        for ss in rec.get("startstops", ()):
            if ss.get("action") == "compute":
                dur[rec["key"]] = dur.get(rec["key"], 0.0) + ss["stop"] - ss["start"]
                span.setdefault(rec["key"], []).append((ss["start"], ss["stop"]))
    keys = [r["key"] for r in trace]
    missing = [k for k in keys if k not in dur]
    longest: dict = {}
    for r in trace:                        # submission order: every "after" key came earlier
        longest[r["key"]] = dur.get(r["key"], 0.0) + max((longest.get(k, 0.0) for k in r["after"]), default=0.0)
    intervals = [iv for k in keys for iv in span.get(k, ())]
    busy = _union([(max(a, t0), min(b, t1)) for a, b in intervals if b > t0 and a < t1])
    # from a task's submission to its end it is running or waiting to run: idle time inside these
    # spans is dispatch, outside them the command's own serial computation
    ends = {k: max(b for _, b in span[k]) for k in span}
    live = _union([(max(r["submitted"], t0), min(ends[r["key"]], t1)) for r in trace
                   if r["key"] in ends and "submitted" in r and ends[r["key"]] > t0])
    dispatch = max(0.0, live - busy)
    gap = dispatch / max(1, len(keys))
    links: dict = {}
    for r in trace:
        links[r["key"]] = dur.get(r["key"], 0.0) + gap + max((links.get(k, 0.0) for k in r["after"]), default=0.0)
    return {"tasks": len(keys), "tasks_missing_from_stream": len(missing), "work_s": float(sum(dur.values())),
            "busy_s": busy, "idle_s": (t1 - t0) - busy, "dispatch_s": dispatch, "serial_s": (t1 - t0) - live,
            "longest_chain_s": max(links.values(), default=0.0),
            "longest_chain_without_dispatch_s": max(longest.values(), default=0.0),
            "longest_task_s": max(dur.values(), default=0.0)}


@contextlib.contextmanager
def _serving(pool, spec: str):
    """``--scheduler spec`` (local:N) runs on ``pool``, started and warm, for the block (every
    module that took :func:`haa_sym.io.tasks.cluster` by name)."""
    import haa_sym.design.schedule as schedule
    from haa_sym.io import tasks
    real = tasks.cluster

    @contextlib.contextmanager
    def warm(s):
        if s == spec:
            yield pool
        else:
            with real(s) as got:
                yield got
    tasks.cluster = schedule.cluster = warm
    try:
        yield
    finally:
        tasks.cluster = schedule.cluster = real


def run_once(argv: list[str], n: int, out: Path, sized_for: int | None = None, backend: str = "pool") -> dict:
    """One timed run of the command on ``n`` warm workers (``backend``: module docstring);
    ``sized_for``: its tasks sized as for that many workers (:meth:`TaskRunner.workers` patched
    in this process)."""
    from haa_sym.cli import main
    from haa_sym.io import tasks
    if sized_for is not None:
        real = tasks.TaskRunner.workers
        tasks.TaskRunner.workers = lambda self: sized_for
        try:
            return run_once(argv, n, out, backend=backend)
        finally:
            tasks.TaskRunner.workers = real
    t = time.perf_counter()
    with _warm_workers(n, backend) as (spec, recorder):
        start_s = time.perf_counter() - t
        tasks.TRACE = []
        t0 = time.time()
        p0 = time.perf_counter()
        rc = main([*argv, "-q", "--scheduler", spec])
        wall = time.perf_counter() - p0
        t1 = time.time()
        stream = recorder.get_task_stream(start=t0 - 1)
        trace, tasks.TRACE = tasks.TRACE, None
    if rc != 0:
        raise SystemExit(f"the command failed (exit {rc}): {' '.join(argv)}")
    return {"workers": n, "seconds": wall, "cluster_start_s": start_s, **analyse(trace, stream, t0, t1),
            "output": _output_bytes(out)}


@contextlib.contextmanager
def _warm_workers(n: int, backend: str):
    """(the --scheduler value, what records the task stream) of ``n`` started, warm workers of
    ``backend`` (module docstring)."""
    from haa_sym.io import tasks
    if backend == "pool":
        # imported before the forks: the workers inherit them (as a command's workers do)
        import haa_sym.analysis.nonlinear_map  # noqa: F401
        import haa_sym.design.schedule  # noqa: F401
        spec = f"local:{n}"
        with tasks.cluster(spec) as pool, _serving(pool, spec):
            yield spec, pool
        return
    import distributed
    with distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None, worker_dashboard_address=None,
                                  silence_logs=logging.ERROR) as cl, distributed.Client(cl) as client:
        client.wait_for_workers(n)
        _warm(client)
        client.get_task_stream()                       # start recording
        yield cl.scheduler_address, client


#: Run in a new process as ``python -c PROBE ARGS``: the command as a user runs it, with the time
#: its first task was submitted and the time its last task list returned printed as JSON on the
#: last line of stderr (absolute ``time.time()``, the clock the caller reads around the process).
PROBE = """
import json, sys, time
import haa_sym.io.tasks as tasks
tasks.TRACE, last = [], [0.0]
def timed(name):
    orig = getattr(tasks.TaskRunner, name)
    def f(self, *a, **k):
        out = orig(self, *a, **k)
        if name != "start":
            last[0] = time.time()
            return out
        def collect():
            r = out()
            last[0] = time.time()
            return r
        return collect
    setattr(tasks.TaskRunner, name, f)
for name in ("run", "stream", "start"):
    timed(name)
from haa_sym.cli import end, main
try:
    code = main(sys.argv[1:])
except SystemExit as e:
    code = e.code
first = min((t["submitted"] for t in tasks.TRACE), default=0.0)
print(json.dumps({"first_submit": first, "last_return": last[0]}), file=sys.stderr)
end(code)                                   # as haa-sym ends (haa_sym.cli.entry)
"""


#: Run as ``python -c CLUSTER_CPU N``: the command process's CPU seconds (all its threads: the
#: forks and the pool's dispatcher live in it) to start and stop ``--scheduler local:N``
#: (haa_sym.io.tasks.cluster, as a command does), printed as JSON on the last line of stdout.
CLUSTER_CPU = """
import json, resource, sys
import haa_sym.design.schedule                         # the command's imports, not timed
from haa_sym.io.tasks import cluster
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
c = cpu()
with cluster(f"local:{int(sys.argv[1])}"):
    up = cpu()
print(json.dumps({"start_s": up - c, "stop_s": cpu() - up}))
"""


def cluster_cpu(n: int, repeats: int = 3) -> dict:
    """The command process's CPU seconds to start and stop ``local:n`` (the fastest of
    ``repeats`` runs, each in a new process): serial whatever the cores (the forks and the
    dispatcher's work are in that process), while each worker's own start runs in its process,
    beside the others on a machine with the cores for them."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src")] + [p for p in [os.environ.get("PYTHONPATH")]
                                                                            if p])}
    best = None
    for _ in range(repeats):
        proc = subprocess.run([sys.executable, "-c", CLUSTER_CPU, str(n)], env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"local:{n} did not start: {proc.stderr.strip()[-400:]}")
        got = json.loads(proc.stdout.strip().splitlines()[-1])
        if best is None or got["start_s"] + got["stop_s"] < best["start_s"] + best["stop_s"]:
            best = got
    return best


def _copy_argv(argv: list[str], out: Path, k: int) -> list[str]:
    """``argv`` writing to its own file (copy ``k`` of the reference's concurrent runs)."""
    i = argv.index("--out") + 1
    return [*argv[:i], str(out.with_name(f"{out.stem}.copy{k}{out.suffix}")), *argv[i + 1:]]


def whole_runs(argv: list[str], workers: int, rounds: int, out: Path) -> dict:
    """The whole command in a new process (``python -m haa_sym.cli ... --scheduler local:N``),
    N = 1..workers alternating, ``rounds`` times; every run's wall time, the cores free and the
    load before it, and whether its output has the bytes of the first.

    And each round a reference for what the machine gives this command: ``workers`` copies of the
    local:1 command started at once (each its own process, worker and output file), against the
    local:1 run of the same round: ``workers * t(local:1) / t(copies)``. The copies share no
    scheduler and wait at no barrier, but each has its own scheduler, client and serial part on
    the same cores, so it is a reference, not a bound (one local:N command beat it by up to 5 %
    in the rounds of 2026-11-26): a local:N speedup well below it is the command's to improve; a
    reference well below ``workers`` is the machine's (cores that are not whole cores for this
    code, e.g. two hyperthreads or a shared virtual machine's)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT / "src")] + [p for p in [os.environ.get("PYTHONPATH")]
                                                                            if p])}
    runs, first, copies = [], None, []

    def command(args, n):
        return [sys.executable, "-m", "haa_sym.cli", *args, "-q", "--scheduler", f"local:{n}"]
    for r in range(rounds):
        for n in range(1, workers + 1):
            load, cores = os.getloadavg()[0], capacity(workers)
            # probed (PROBE): the same command in one process, with the two marks that split its
            # time into the task lists' span and the part outside them (F)
            t0, t = time.time(), time.perf_counter()
            proc = subprocess.run([sys.executable, "-c", PROBE, *command(argv, n)[3:]], env=env, capture_output=True,
                                  text=True)
            wall, t1 = time.perf_counter() - t, time.time()
            if proc.returncode != 0:
                raise SystemExit(f"the command failed (exit {proc.returncode}): {proc.stderr.strip()[-400:]}")
            marks = json.loads(proc.stderr.strip().splitlines()[-1])
            before, after = marks["first_submit"] - t0, t1 - marks["last_return"]
            got = _output_bytes(out)
            first = got if first is None else first
            runs.append({"round": r, "workers": n, "seconds": wall, "cores_available_before": round(cores, 2),
                         "load_1min_before": round(load, 2), "same_output": got == first,
                         "before_first_task_s": before, "after_last_task_s": after,
                         "task_lists_s": wall - before - after})
            print(f"  whole command, round {r + 1}, local:{n}: {wall:6.2f} s, of which {wall - before - after:.2f} s "
                  f"from the first task's submission to the last task list's return (cores free before "
                  f"{cores:.2f} of {workers}, load {load:.2f})", flush=True)
        if workers > 1:
            t = time.perf_counter()
            procs = [subprocess.Popen(command(_copy_argv(argv, out, k), 1), env=env, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.PIPE, text=True) for k in range(workers)]
            errs = [p.communicate()[1] for p in procs]
            wall = time.perf_counter() - t
            for p, e in zip(procs, errs):
                if p.returncode != 0:
                    raise SystemExit(f"a copy of the command failed (exit {p.returncode}): {e.strip()[-400:]}")
            alone = runs[-workers]["seconds"]                 # this round's local:1
            copies.append(workers * alone / wall)
            print(f"  {workers} copies of local:1 at once, round {r + 1}: {wall:6.2f} s against {alone:.2f} s alone: "
                  f"{copies[-1]:.2f}x (the reference)", flush=True)
    # the fixed part F: that of the fastest local:1 run (the one the prediction is compared with)
    best1 = min((x for x in runs if x["workers"] == 1), key=lambda x: x["seconds"])
    fixed = {"before_first_task_s": best1["before_first_task_s"], "after_last_task_s": best1["after_last_task_s"],
             "fixed_s": best1["before_first_task_s"] + best1["after_last_task_s"], "seconds": best1["seconds"]}
    print(f"  whole command local:1, best: {fixed['seconds']:.2f} s, of which {fixed['before_first_task_s']:.2f} s "
          f"before its first task and {fixed['after_last_task_s']:.2f} s after its last", flush=True)
    by_n = {n: [x["seconds"] for x in runs if x["workers"] == n] for n in range(1, workers + 1)}
    ratios = {n: [a / b for a, b in zip(by_n[1], by_n[n])] for n in range(2, workers + 1)}
    span = {n: [x["task_lists_s"] for x in runs if x["workers"] == n] for n in range(1, workers + 1)}
    inside = {str(n): [a / b for a, b in zip(span[1], span[n])] for n in range(2, workers + 1)}
    return {"runs": runs, "same_output": all(x["same_output"] for x in runs),
            "best_s": {str(n): min(v) for n, v in by_n.items()},
            "median_s": {str(n): statistics.median(v) for n, v in by_n.items()},
            "speedup_of_best": {str(n): min(by_n[1]) / min(by_n[n]) for n in ratios},
            "speedup_per_round": {str(n): v for n, v in ratios.items()},
            "copies_speedup_per_round": copies, "fixed": fixed, "task_lists_speedup_per_round": inside,
            "cores_available_before": [x["cores_available_before"] for x in runs]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="up to N workers (default: the cores)")
    ap.add_argument("--predict", type=int, default=16, help="predict the time on M workers (default 16)")
    ap.add_argument("--preset", choices=sorted(PRESETS), default="nonlinear")
    ap.add_argument("--backend", choices=["pool", "dask"], default="pool",
                    help="the warm runs' workers: local:N's processes (pool) or a dask LocalCluster by address")
    ap.add_argument("--repeats", type=int, default=1, help="runs per worker count, the fastest kept")
    ap.add_argument("--whole", type=int, default=0, metavar="R",
                    help="also time the whole command (--scheduler local:N, a new process) R rounds, N alternating")
    ap.add_argument("--no-warm", action="store_true",
                    help="only the whole-command rounds and the critical path (no warm-cluster table)")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- haa-sym ARGS (with --out FILE)")
    args = ap.parse_args()
    bench = Run("bench_scale.py")
    with tempfile.TemporaryDirectory() as tmp:
        limits_file = Path(tmp) / "hyq_haa_limits.toml"
        limits_file.write_text((ROOT / "model" / "hyq_haa.toml").read_text() + LIMITS)
        command = args.command[1:] if args.command[:1] == ["--"] else args.command
        if command:
            argv, name = command, "custom"
            out = Path(argv[argv.index("--out") + 1])
        else:
            name = args.preset
            argv = [a.format(limits_file=limits_file, out=Path(tmp) / "out") for a in PRESETS[name]]
            out = Path(argv[argv.index("--out") + 1])
        rows = []
        whole = whole_runs(argv, args.workers, args.whole, out) if args.whole else None
        for n in range(1, 1 + (1 if args.no_warm else args.workers)):
            best = None
            for _ in range(max(1, args.repeats)):
                load, cores = os.getloadavg()[0], capacity(n)
                r = run_once(argv, n, out, backend=args.backend)
                r["cores_available_before"] = round(cores, 2)
                r["load_1min_before"] = round(load, 2)
                r["load_1min_after"] = round(os.getloadavg()[0], 2)
                if best is None or r["seconds"] < best["seconds"]:
                    best = r
            rows.append(best)
            print(f"{n:2d} worker(s): {best['seconds']:7.2f} s (cluster start {best['cluster_start_s']:.1f} s), "
                  f"work {best['work_s']:.2f} s in {best['tasks']} tasks, serial {best['serial_s']:.2f} s, longest "
                  f"chain {best['longest_chain_s']:.2f} s; load {best['load_1min_before']:.2f} -> "
                  f"{best['load_1min_after']:.2f}, cores available before {best['cores_available_before']:.2f} "
                  f"of {n}", flush=True)
        # the chains of the predicted cluster: tasks sized for --predict workers, run on one
        chain = run_once(argv, 1, out, sized_for=args.predict, backend=args.backend)
        print(f" 1 worker, tasks sized for {args.predict}: {chain['seconds']:.2f} s, work {chain['work_s']:.2f} s "
              f"in {chain['tasks']} tasks, serial {chain['serial_s']:.2f} s, dispatch {chain['dispatch_s']:.2f} s, "
              f"longest chain {chain['longest_chain_s']:.2f} s", flush=True)
    same = all(r["output"] == rows[0]["output"] for r in rows + [chain]) and (whole is None or whole["same_output"])
    for r in rows + [chain]:
        del r["output"]
    one = rows[0]
    for r in rows:
        r["speedup"] = one["seconds"] / r["seconds"]
        r["efficiency"] = r["speedup"] / r["workers"]
    # the prediction for M workers from the run on one worker with tasks sized for M (task
    # durations not inflated by sharing the cores; the chains of M's task sizes)
    S, W, C, d = chain["serial_s"], chain["work_s"], chain["longest_chain_s"], chain["dispatch_s"]
    critical = S + C
    M = args.predict
    predict = {m: S + max(C, (W + d) / m) for m in sorted({2, M})}
    print()
    print(f"{'workers':>7} {'seconds':>8} {'speedup':>8} {'efficiency':>10}")
    for r in rows:
        print(f"{r['workers']:7d} {r['seconds']:8.2f} {r['speedup']:8.2f} {r['efficiency']:10.2f}")
    print(f"critical path (tasks sized for {M} workers): serial {S:.2f} s + longest task chain {C:.2f} s = "
          f"{critical:.2f} s; work {W:.2f} s, dispatch {d:.2f} s; speedup bound T(1) / critical path = "
          f"{one['seconds'] / critical:.1f}")
    for m in predict:
        print(f"predicted on {m} workers: S + max(C, (W + d) / {m}) = {predict[m]:.1f} s, "
              f"{one['seconds'] / predict[m]:.1f}x the measured 1 worker")
    fixed = None
    if whole is not None:
        # what a whole command pays outside its task lists (Python's start, the imports, the
        # workers' start and stop, the output), probed in the fastest local:1 run; the whole command on
        # M workers is predicted as that plus the warm prediction plus what starting and stopping
        # M workers costs the command's process more than one (its CPU time, measured here: the
        # forks and the dispatcher's work for each worker, serial on any machine)
        fixed = whole["fixed"]["fixed_s"]
        cpu = {m: cluster_cpu(m) for m in sorted({1, 2, M})}
        more = {m: max(0.0, sum(cpu[m].values()) - sum(cpu[1].values())) for m in predict}
        whole["fixed_s"] = fixed
        whole["cluster_cpu_s"] = {str(m): v for m, v in cpu.items()}
        whole["cluster_more_s"] = {str(m): v for m, v in more.items()}
        whole["predicted_s"] = {str(m): fixed + more[m] + t for m, t in predict.items()}
        print(f"starting and stopping local:N costs the command's process (CPU): "
              + ", ".join(f"{m} worker(s) {cpu[m]['start_s']:.2f} + {cpu[m]['stop_s']:.2f} s" for m in cpu))
        print(f"whole command: fixed part {fixed:.2f} s (probed: before the first task and after the last), "
              f"{fixed + more[M]:.2f} s with {M} workers' start and stop; predicted on {M} workers "
              f"{whole['predicted_s'][str(M)]:.1f} s, "
              f"{whole['best_s']['1'] / whole['predicted_s'][str(M)]:.1f}x the best whole local:1 command")
        for n in range(2, args.workers + 1):
            per = ", ".join(f"{x:.2f}x" for x in whole["speedup_per_round"][str(n)])
            inside = ", ".join(f"{x:.2f}x" for x in whole["task_lists_speedup_per_round"][str(n)])
            print(f"whole command local:1 -> local:{n}: best {whole['best_s']['1']:.2f} s -> {whole['best_s'][str(n)]:.2f} s "
                  f"({whole['speedup_of_best'][str(n)]:.2f}x); per round {per}; the task lists' span alone per "
                  f"round {inside}; cores free before the runs "
                  f"{min(whole['cores_available_before']):.2f}-{max(whole['cores_available_before']):.2f} of "
                  f"{args.workers}")
        if whole["copies_speedup_per_round"]:
            n = args.workers
            per = ", ".join(f"{x:.2f}x" for x in whole["copies_speedup_per_round"])
            share = ", ".join(f"{a / c:.2f}" for a, c in zip(whole["speedup_per_round"][str(n)],
                                                              whole["copies_speedup_per_round"]))
            print(f"the reference ({n} copies of local:1 at once): per round {per}; local:{n}'s speedup / the "
                  f"reference's per round {share}")
    print(f"same output at every worker count: {same}; machine: {bench.info['cpu_model']}, "
          f"{bench.info['cpu_count']} cores")
    res = {"command": ["haa-sym", *argv], "preset": name, "backend": args.backend, "rows": rows, "chain_run": chain, "same_output": same,
           "critical_path_s": critical, "serial_s": S, "longest_chain_s": C, "work_s": W, "dispatch_s": d,
           "predicted_s": {str(m): t for m, t in predict.items()},
           "speedup_bound": one["seconds"] / critical, "whole_command": whole}
    print(f"wrote {bench.write(f'results_scale_{name}.json', res)}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
