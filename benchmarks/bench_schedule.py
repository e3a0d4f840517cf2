"""How the torque-gain schedule's time grows with the impedance grid, in-process and on a
two-worker dask.distributed LocalCluster, side by side in one run.

HyQ (model/hyq_haa.toml), requirements stable + PM >= 30 deg, beta 0.1..8 with tolerance 0.02,
leg retracted..extended; impedance grids P_gain log 1..2000 x D_gain lin 1..50 of 10 x 10,
20 x 15 and 40 x 25 points. In-process runs dask's threaded scheduler (2 threads); the cluster
has two worker processes of one thread each, started before the timing. Every schedule is
compared byte for byte (CSV) between the two. The maps decide the phase margin exactly now
(the maps' rule "distance", crossovers located exactly) and every answer is re-decided point by
point at every leg configuration (``lowered_by_point_check``: points whose beta that lowered;
it was ``lowered_by_exact_margins``, the separate exact-margin pass the maps no longer need):
times are not comparable with numbers measured before.

Prints a table and writes ``results_schedule.json`` into
``$HAA_SYM_BENCH_DIR`` (default ``bench-results/``, git-ignored).
Usage: python benchmarks/bench_schedule.py
"""
from __future__ import annotations

import time

import numpy as np

from timing import Run
from haa_sym import ClosedLoop, load_params
from haa_sym.design.schedule import schedule

GRIDS = ((10, 10), (20, 15), (40, 25))


def main() -> int:
    import distributed
    run = Run("bench_schedule.py")
    loop = ClosedLoop(load_params())
    results = {"rows": []}
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        client.run(lambda: __import__("haa_sym.design.schedule"))          # warm the workers' imports
        for n_P, n_D in GRIDS:
            P, D = np.geomspace(1.0, 2000.0, n_P), np.linspace(1.0, 50.0, n_D)
            t = time.perf_counter()
            local = schedule(loop, P, D, progress=False)
            t_local = time.perf_counter() - t
            t = time.perf_counter()
            remote = schedule(loop, P, D, progress=False, scheduler=client)
            t_cluster = time.perf_counter() - t
            same = local.csv_text() == remote.csv_text()
            row = {"grid": f"{n_P} x {n_D}", "points": n_P * n_D, "local_s": t_local, "cluster_s": t_cluster,
                   "same_bytes": same, "leg_configurations": local.n_configurations,
                   "feasible": int(local.feasible.sum()), "lowered_by_point_check": local.meta["lowered_by_point_check"]}
            results["rows"].append(row)
            print(f"{row['grid']:>8} ({row['points']:4d} points): in-process {t_local:6.1f} s, two-worker cluster "
                  f"{t_cluster:6.1f} s, same bytes: {same}, leg configurations {local.n_configurations}")
    r = results["rows"]
    print(f"time per point in-process: {r[0]['local_s'] / r[0]['points'] * 1e3:.1f} ms ({r[0]['grid']}) -> "
          f"{r[-1]['local_s'] / r[-1]['points'] * 1e3:.1f} ms ({r[-1]['grid']})")
    print(f"wrote {run.write('results_schedule.json', results)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
