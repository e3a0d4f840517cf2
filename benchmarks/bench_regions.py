"""haa_sym's own timings and the whole-process targets, measured in one run (``make bench``).

The baselines of the 200 x 200 map (python-control per point, numpy stacked eigvals + batched
frequency responses) are measured side by side with haa_sym's maps in
``benchmarks/bench_baselines.py`` (``results_baselines.json``); the exact curves in
``benchmarks/bench_boundary.py``. Here:

(1) the 200 x 200 map, P_gain log 1..20000 x D_gain lin 1..50, nominal (N_av = 4) and N_av = 50,
    from haa_sym's generated evaluators:
    - stability map: the certified Routh-Hurwitz decision on the bilinear basis;
    - full map: stability, phase margin of the impedance loop and passivity
      (``region_map(loop, P, D, method="grid")``, every point decided). The phase margin is
      now the exact one (every crossover located, ``haa_sym.analysis.margins``; rule
      "distance": min over crossovers of |PM| < 30 deg) where it used to be interpolated on
      the frequency grid: the full map's time includes that and is not comparable with
      numbers measured before;
    - full map with the spectral radius (``radius=True``: stacked eigenvalues of the explicit
      closed loop, what ``--radius`` costs), nominal only: at N_av = 50 it costs about what the
      numpy baseline's stacked eigvals of 40,000 58 x 58 matrices cost on the same two threads
      (``numpy_eigvals_stability_s`` in ``results_baselines.json``, tens of seconds that
      ``make bench`` spends once). Its radii check the decisions on every point farther than
      1e-6 from |z| = 1 (at N_av = 50 bench_baselines checks them against its eigenvalues).
Then, whole processes as a user runs them (fresh interpreter, compiled-code cache warm), at the
sizes of the issue's targets:
(2) ``haa-sym regions`` (stability, PM, passivity, npz written) against a plain script that
    builds the stacked closed-loop matrices and calls ``numpy.linalg.eigvals`` (stability only):
    1000 x 1000 at N_av = 4 (target: at least 20x) and 250 x 250 at N_av = 50 (target: 50x);
(3) ``haa-sym reproduce --out DIR``, what ``make paper`` runs after ``make derive``.

Prints the timings and writes ``results_regions.json`` into ``$HAA_SYM_BENCH_DIR`` (default
``bench-results/``, git-ignored). In-process timings are the best of
``REPEATS`` runs (the radius map one run), every whole-process timing one run.
"""
from __future__ import annotations

import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from timing import REPEATS, Run, best
from haa_sym import ClosedLoop, grid, load_params, region_map

BAND = 1e-6
HERE = Path(__file__).resolve().parent
# (grid side, N_av, the target ratio: stacked-eigvals script / haa-sym regions)
WHOLE_PROCESS = ((1000, 4, 20.0), (250, 50, 50.0))




def run(n_P=200, n_D=200, configs=(("nominal (N_av = 4)", {}), ("N_av = 50", {"N_av": 50}))):
    params0 = load_params()
    P_grid, D_grid = grid(f"log:1:20000:{n_P}"), grid(f"lin:1:50:{n_D}")
    PP, DD = np.meshgrid(P_grid, D_grid, indexing="ij")
    P, D = PP.ravel(), DD.ravel()
    rows = []
    for label, changes in configs:
        params = params0.with_values(**changes)
        loop = ClosedLoop(params)
        region_map(loop, P_grid[:4], D_grid[:4], method="grid", progress=False)   # load outside the timing
        t_dec, dec = best(lambda: loop.stability(P, D, radius=False))
        t_full, m = best(lambda: region_map(loop, P_grid, D_grid, radius=False, method="grid", progress=False))
        t_full_r, decided, disagree = None, None, None
        if loop.degree < 30:
            t_full_r, mr = best(lambda: region_map(loop, P_grid, D_grid, radius=True, method="grid",
                                                   progress=False), 1)
            rho = mr.spectral_radius.ravel()
            decided = np.abs(rho - 1) > BAND
            disagree = int((dec.stable.ravel()[decided] != (rho < 1)[decided]).sum())
            decided = int(decided.sum())
        rows.append({
            "config": label, "points": int(P.size), "closed_loop_order": int(loop.degree),
            "generated_stability_s": t_dec,
            "generated_full_map_s": t_full, "generated_full_map_with_radius_s": t_full_r,
            "decided_points_vs_eigenvalues": decided,
            "decisions_disagreeing_with_eigenvalues": disagree,
            "map_stable_fraction": float(m.stable.mean()),
        })
    return rows


EIGVALS_SCRIPT = """
import sys, numpy as np
from haa_sym import ClosedLoop, load_params
from haa_sym.check.reference import closed_loop_matrices
n, N_av = int(sys.argv[1]), int(sys.argv[2])
loop = ClosedLoop(load_params().with_values(N_av=N_av), basis=False)
A0 = closed_loop_matrices(loop, 0, 0)[0]
A1 = closed_loop_matrices(loop, 1, 0)[0] - A0
A2 = closed_loop_matrices(loop, 0, 1)[0] - A0
P, D = np.meshgrid(np.logspace(0, np.log10(20000), n), np.linspace(1, 50, n), indexing="ij")
P, D = P.ravel(), D.ravel()
stable = np.empty(P.size, bool)
for s in range(0, P.size, 2000):
    A = A0 + P[s:s + 2000, None, None] * A1 + D[s:s + 2000, None, None] * A2
    stable[s:s + 2000] = np.abs(np.linalg.eigvals(A)).max(axis=1) < 1
np.save(sys.argv[3], stable)
"""


def _timed(cmd: list[str], cwd: str) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def whole_process() -> list[dict]:
    """(2): the CLI map against the stacked-eigvals script, each in a fresh process."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n, N_av, target in WHOLE_PROCESS:
            t_cli = _timed([sys.executable, "-m", "haa_sym.cli", "regions", "--set", f"N_av={N_av}",
                            "--P-gain", f"log:1:20000:{n}", "--D-gain", f"lin:1:50:{n}",
                            "--out", os.path.join(tmp, "m.npz")], tmp)
            t_eig = _timed([sys.executable, "-c", EIGVALS_SCRIPT, str(n), str(N_av),
                            os.path.join(tmp, "s.npy")], tmp)
            with np.load(os.path.join(tmp, "m.npz")) as f:
                cli_stable = f["stable"].ravel()
            agree = float((np.load(os.path.join(tmp, "s.npy")) == cli_stable).mean())
            rows.append({"N_av": N_av, "grid": f"{n} x {n}", "cli_regions_full_map_s": t_cli,
                         "eigvals_script_stability_only_s": t_eig, "ratio": t_eig / t_cli,
                         "target_ratio": target, "target_met": bool(t_eig / t_cli >= target),
                         "decisions_agreeing_fraction": agree})
    return rows


def paper_run() -> float:
    """(3): ``haa-sym reproduce`` into a temporary directory, one whole-process run."""
    with tempfile.TemporaryDirectory() as tmp:
        return _timed([sys.executable, "-m", "haa_sym.cli", "reproduce", "--out",
                       os.path.join(tmp, "results")], tmp)


def main() -> int:
    bench = Run("bench_regions.py")
    rows = run()
    print(f"200 x 200 region map on {platform.processor() or platform.machine()}, "
          f"python {platform.python_version()} (best of {REPEATS}; the radius map one run)")
    for r in rows:
        print(f"\n{r['config']}: closed-loop order {r['closed_loop_order']}")
        print(f"  generated stability map             {r['generated_stability_s']:8.3f} s")
        print(f"  generated full map (stab, PM, pass) {r['generated_full_map_s']:8.3f} s")
        if r["generated_full_map_with_radius_s"] is None:
            print("  ... with the spectral radius        not timed (a stacked eigvals: bench_baselines)")
            continue
        print(f"  ... with the spectral radius        {r['generated_full_map_with_radius_s']:8.3f} s")
        print(f"  decisions vs eigenvalues: {r['decisions_disagreeing_with_eigenvalues']} disagree "
              f"on {r['decided_points_vs_eigenvalues']} points farther than {BAND:g} from |z| = 1")
    print("  (baselines: benchmarks/bench_baselines.py)")
    procs = whole_process()
    print("\nwhole processes (fresh interpreter):")
    for r in procs:
        print(f"  {r['grid']:>11s}, N_av = {r['N_av']:2d}: haa-sym regions (full map) {r['cli_regions_full_map_s']:6.2f} s, "
              f"stacked-eigvals script (stability only) {r['eigvals_script_stability_only_s']:6.2f} s: "
              f"{r['ratio']:.1f} x (target {r['target_ratio']:.0f} x: {'met' if r['target_met'] else 'NOT met'}); "
              f"decisions agreeing {100 * r['decisions_agreeing_fraction']:.3f} %")
    t_paper = paper_run()
    print(f"\nhaa-sym reproduce (make paper after make derive): {t_paper:.1f} s")
    out = bench.write("results_regions.json", {"rows": rows, "whole_process": procs, "reproduce_s": t_paper})
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
