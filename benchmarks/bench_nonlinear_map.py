"""Benchmark of ``regions --nonlinear`` (issue 19: a 100 x 50 nonlinear map in under a minute).

HyQ at beta = 3 (so the map holds converging points, limit cycles and growing points), P_gain
log 100..20000 x D_gain lin 1..50, 100 x 50 points, 1 Nm disturbance step, 1 s per point (the
default ``duration``), limits: 24 V supply, 4096-count encoder, 0.01 Nm torque quantum (limits
that act on every step, so no point is decided by the linear regime alone). Side by side in one
run: :func:`nonlinear_map` in-process (its default: the tasks one after the other) against the
same tasks on two dask threads (the C loop releases the GIL, the Python part does not), the
linear ``region_map`` of the same grid for scale, and optionally (``--cluster``) over a
two-worker dask LocalCluster. Writes ``results_nonlinear_map.json`` into ``$HAA_SYM_BENCH_DIR``.

Usage: python benchmarks/bench_nonlinear_map.py [--cluster]
"""
from __future__ import annotations

import sys
import time

import numpy as np

from timing import Run, best
from haa_sym import ClosedLoop, load_params
import haa_sym.analysis.nonlinear_map as nm
from haa_sym.analysis.nonlinear_map import nonlinear_map
from haa_sym.analysis.regions import region_map
from haa_sym.model.limits import Limits

LIMITS = Limits(V_max=24.0, encoder_counts=4096, torque_resolution=0.01)
N_P, N_D = 100, 50
TARGET_S = 60.0


def main() -> int:
    run = Run("bench_nonlinear_map.py")
    loop = ClosedLoop(load_params().with_values(beta=3.0))
    P, D = np.geomspace(100.0, 20000.0, N_P), np.linspace(1.0, 50.0, N_D)
    nonlinear_map(loop, P[:2], D[:2], limits=LIMITS, progress=False)           # compile, load
    t_one, m = best(lambda: nonlinear_map(loop, P, D, limits=LIMITS, progress=False), repeats=2)
    nm.IN_PROCESS_THREADS = 2
    t_two, m2 = best(lambda: nonlinear_map(loop, P, D, limits=LIMITS, progress=False), repeats=2)
    nm.IN_PROCESS_THREADS = 1
    t_lin, _ = best(lambda: region_map(loop, P, D), repeats=2)
    same = bool(np.array_equal(m.nonlinear_class, m2.nonlinear_class))
    samples = m.meta["samples_simulated"]          # the first runs and the longer reruns
    res = {"grid": [N_P, N_D], "limits": LIMITS.active, "duration_each_s": m.meta["duration"], "beta": 3.0,
           "counts": m.counts(), "longer_rounds": m.meta["longer_rounds"],
           "points_run_longer": int((m.run_duration > m.meta["duration"]).sum()), "in_process_s": t_one, "two_dask_threads_s": t_two,
           "ratio_two_threads_vs_default": t_one / t_two, "controller_steps_per_s": samples / t_one,
           "linear_region_map_s": t_lin, "same_classes_threads": same, "target_s": TARGET_S}
    print(f"{N_P} x {N_D} nonlinear map ({m.meta['duration']:g} s per point, {samples:,} controller steps): "
          f"{t_one:.2f} s in-process (target {TARGET_S:g} s: {'met' if t_one < TARGET_S else 'NOT met'}; "
          f"{samples / t_one:,.0f} steps/s with the classification), {t_two:.2f} s on two dask threads; "
          f"the linear map {t_lin:.3f} s; classes {m.counts()}; same classes: {same}")
    if "--cluster" in sys.argv[1:]:
        import distributed
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                      dashboard_address=None) as cl:
            t0 = time.perf_counter()
            mc = nonlinear_map(loop, P, D, limits=LIMITS, progress=False, scheduler=cl.scheduler_address)
            t_cl = time.perf_counter() - t0
        res["local_cluster_two_workers_s"] = t_cl
        res["same_classes_cluster"] = bool(np.array_equal(m.nonlinear_class, mc.nonlinear_class))
        print(f"two-worker LocalCluster: {t_cl:.2f} s (first run: workers load the library); same classes: "
              f"{res['same_classes_cluster']}")
    print(f"wrote {run.write('results_nonlinear_map.json', res)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
