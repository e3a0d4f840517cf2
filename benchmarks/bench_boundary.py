"""Exact boundaries (parameter-space method) against the grid evaluators, side by side in one run.

For the nominal configuration (N_av = 4) and N_av = 50, on the box P_gain 1..20000 x D_gain 1..50:

(1) the curves of one configuration: the stability boundary (``stability_boundary``) and the
    30 deg phase-margin curves (``phase_margin_curves``: now the outline of the low-PM region
    of the "distance" rule, the +-30 deg loci with the pieces where the loop is unstable or
    another crossover is nearer to -1 dropped, which takes exact phase margins along the loci:
    not comparable with numbers measured before);
(2) a 200 x 200 map of stability and PM < 30 deg classified from the curves
    (``classify_regions(passivity=False)``: segments of every row split by the stability and
    +-30/180 deg loci, probes decided with exact phase margins) against the same map from the
    generated grid evaluators (``region_map(method="grid", passivity=False)``, every point's
    crossovers located exactly); the decisions are compared on every point.
The full map (with passivity) from the curves against python-control and numpy (stacked eigvals)
is measured in ``benchmarks/bench_baselines.py``, which also checks it against eigenvalues.

Best of ``REPEATS`` runs. Prints a table and writes ``results_boundary.json`` into
``$HAA_SYM_BENCH_DIR`` (default ``bench-results/``, git-ignored).
Usage: python benchmarks/bench_boundary.py
"""
from __future__ import annotations


from timing import REPEATS, Run, best
from haa_sym import ClosedLoop, grid, load_params, region_map
from haa_sym.analysis.boundaries import boundaries, classify_regions, phase_margin_curves, stability_boundary





def main() -> int:
    run = Run("bench_boundary.py")
    P, D = grid("log:1:20000:200"), grid("lin:1:50:200")
    results = {"grid": "200 x 200",
               "repeats": REPEATS, "cases": {}}
    for name, changes in (("nominal (N_av = 4)", {}), ("N_av = 50", {"N_av": 50})):
        p = load_params().with_values(**changes)
        loop = ClosedLoop(p)
        t_st, b = best(lambda: stability_boundary(loop))
        t_pm, _ = best(lambda: phase_margin_curves(loop))
        t_all, _ = best(lambda: boundaries(loop, P_range=(1.0, 2e4), D_range=(1.0, 50.0)))
        t_cls, r = best(lambda: classify_regions(loop, b, P, D, passivity=False))
        st, low = r.stable, r.low_pm
        t_grid, m = best(lambda: region_map(loop, P, D, method="grid", passivity=False, progress=False))
        agree = {"stable_vs_grid": int((st == m.stable).sum()), "low_pm_vs_grid": int((low == m.low_pm).sum()),
                 "points": int(P.size * D.size)}
        row = {"stability_curves_s": t_st, "pm_curves_s": t_pm, "three_boundaries_s": t_all, "classify_map_s": t_cls,
               "grid_map_s": t_grid, "agree": agree}
        results["cases"][name] = row
        print(f"{name}: order {loop.degree}")
        print(f"  stability curves                      {t_st * 1e3:8.1f} ms")
        print(f"  30 deg phase-margin curves            {t_pm * 1e3:8.1f} ms")
        print(f"  all three (stability, PM, passivity)  {t_all * 1e3:8.1f} ms  (target 30 ms)")
        print(f"  map from the curves (stab, PM < 30)   {t_cls:8.3f} s")
        print(f"  map from the grid evaluators          {t_grid:8.3f} s  (curves / grid: {t_cls / t_grid:.2f})")
        print(f"  agreement: {agree}")
    print(f"wrote {run.write('results_boundary.json', results)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
