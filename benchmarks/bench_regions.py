"""Speed of a 200 x 200 region map, measured side by side in one run (``make bench``).

For the nominal configuration (N_av = 4) and for N_av = 50, on P_gain log 1..20000 x D_gain lin 1..50:

(1) haa_sym's generated evaluators:
    - stability map: the certified Routh-Hurwitz decision on the bilinear basis;
    - stability + spectral radius (the radius from stacked eigenvalues, ``radius=True``);
    - full map: stability, phase margin of the impedance loop and passivity (``region_map``,
      radius off) and with the radius;
(2) numpy ``linalg.eigvals`` on the stacked closed-loop matrices A(P, D) = A0 + P A1 + D A2
    (built by broadcasting from ``haa_sym.reference``, so construction costs nothing);
(3) python-control building the same closed loop point by point (``ss``, ``c2d``, ``tf``,
    ``feedback``, ``poles``, ``stability_margins``) on a random sample of points, extrapolated
    to 40,000 points.

Then, whole processes as a user runs them (fresh interpreter, compiled-code cache warm):
(4) ``haa-sym regions`` on a 300 x 300 grid (stability, PM, passivity, npz written) against a
    plain script that builds the stacked closed-loop matrices and calls ``numpy.linalg.eigvals``
    (stability only), nominal and N_av = 50;
(5) ``haa-sym reproduce --out DIR``, what ``make paper`` runs after ``make derive``.

Prints the timings and the ratios and writes ``benchmarks/results.json``. Every in-process timing
is the best of ``REPEATS`` runs, every whole-process timing one run. The decisions of (1), (2)
and (3) are compared on the points each saw.
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from haa_sym import ClosedLoop, load_params
from haa_sym.reference import closed_loop_matrices
from haa_sym.regions import grid, region_map

REPEATS = 3
N_SAMPLE_CONTROL = 20
HERE = Path(__file__).resolve().parent


def best(fn, repeats=REPEATS):
    out, times = None, []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def control_point(params, P, D):
    """One point with python-control: the closed loop and the impedance-loop margins."""
    import control as ct
    from haa_sym.plant import continuous_plant
    ctrl, Ts, N = params.controller, params.controller.Ts, params.controller.N_av
    cp = continuous_plant(params.plant)
    rows = [cp.output_names.index("T_sensor"), cp.output_names.index("theta_encoder")]
    G = ct.c2d(ct.ss(cp.A, cp.B[:, :1], cp.C[rows], 0), Ts, method="zoh")   # V_m -> (T, theta)
    PI = ct.tf([ctrl.P_t + ctrl.I_t * Ts, -ctrl.P_t], [1, -1], Ts)          # Eq. (7)
    F = ct.tf([1] + [0] * (N - 1) + [-1], [N * Ts] + [0] * N, Ts)           # averaging filter
    VCF = ctrl.alpha * cp.VC0 * F                                           # Eq. (6)
    # V = PI (-T - P theta - D F theta) + VC F theta  (Eq. 6-8, theta_ref = 0), as state space
    # with one integrator (a transfer-function sum would realise the PI pole twice, at z = 1)
    Fth = ct.series(ct.ss([], [], [], [[0.0, 1.0]], Ts), ct.tf2ss(F))      # (T, theta) -> v
    e = ct.parallel(ct.ss([], [], [], [[-1.0, -P]], Ts), -D * Fth)
    K = ct.parallel(ct.series(e, ct.tf2ss(PI)), ctrl.alpha * cp.VC0 * Fth)
    closed = ct.feedback(G, K, sign=1)
    stable = bool(np.all(np.abs(closed.poles()) < 1))
    # the impedance loop opened at T_lref, for its phase margin
    G_TV, G_thV = ct.ss2tf(G[0, 0]), ct.ss2tf(G[1, 0])
    vc = 1 - VCF * G_thV
    L_imp = (P + D * F) * PI * (G_thV / vc) / (1 + PI * G_TV / vc)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")       # 'poly' -> 'frd' fallback notice at every point
        margins = ct.stability_margins(L_imp)
    return stable, margins[1]


def run(n_P=200, n_D=200, configs=(("nominal (N_av = 4)", {}), ("N_av = 50", {"N_av": 50}))):
    params0 = load_params()
    P_grid, D_grid = grid(f"log:1:20000:{n_P}"), grid(f"lin:1:50:{n_D}")
    PP, DD = np.meshgrid(P_grid, D_grid, indexing="ij")
    P, D = PP.ravel(), DD.ravel()
    rows = []
    for label, changes in configs:
        params = params0.with_values(**changes)
        loop = ClosedLoop(params)
        loop.stability(P[:8], D[:8], radius=False)          # load / compile outside the timing
        t_dec, dec = best(lambda: loop.stability(P, D, radius=False))
        t_rad, _ = best(lambda: loop.stability(P, D, radius=True))
        t_full, m = best(lambda: region_map(params, P_grid, D_grid, radius=False, progress=False, loop=loop))
        t_full_r, _ = best(lambda: region_map(params, P_grid, D_grid, radius=True, progress=False, loop=loop), 1)
        A0 = closed_loop_matrices(loop, 0, 0)[0]
        A1 = closed_loop_matrices(loop, 1, 0)[0] - A0
        A2 = closed_loop_matrices(loop, 0, 1)[0] - A0

        def stacked():
            A = A0 + P[:, None, None] * A1 + D[:, None, None] * A2
            return np.abs(np.linalg.eigvals(A)).max(axis=1)
        t_eig, rho = best(stacked, 1 if changes.get("N_av", 4) > 10 else REPEATS)
        decided = np.abs(rho - 1) > 1e-6
        agree_eig = bool(np.array_equal(dec.stable.ravel()[decided], (rho < 1)[decided]))
        rng = np.random.default_rng(0)
        idx = rng.choice(P.size, N_SAMPLE_CONTROL, replace=False)
        t0 = time.perf_counter()
        ctl = [control_point(params, P[i], D[i]) for i in idx]
        t_ctl_pt = (time.perf_counter() - t0) / N_SAMPLE_CONTROL
        agree_ctl = sum(s == bool(dec.stable.ravel()[i]) for (s, _), i in zip(ctl, idx))
        rows.append({
            "config": label, "points": int(P.size), "closed_loop_order": int(A0.shape[0]),
            "generated_stability_s": t_dec, "generated_stability_radius_s": t_rad,
            "generated_full_map_s": t_full, "generated_full_map_with_radius_s": t_full_r,
            "numpy_stacked_eigvals_s": t_eig,
            "python_control_per_point_s": t_ctl_pt,
            "python_control_extrapolated_s": t_ctl_pt * P.size,
            "ratio_stability_vs_eigvals": t_eig / t_dec,
            "ratio_stability_radius_vs_eigvals": t_eig / t_rad,
            "ratio_stability_vs_python_control": t_ctl_pt * P.size / t_dec,
            "ratio_full_map_vs_python_control": t_ctl_pt * P.size / t_full,
            "decisions_agree_with_eigvals": agree_eig,
            "python_control_sample_agreeing": f"{agree_ctl}/{N_SAMPLE_CONTROL}",
            "map_stable_fraction": float(m.stable.mean()),
        })
    return rows


EIGVALS_SCRIPT = """
import sys, numpy as np
from haa_sym import ClosedLoop, load_params
from haa_sym.reference import closed_loop_matrices
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


def whole_process(n: int = 300) -> list[dict]:
    """(4): the CLI map against the stacked-eigvals script, each in a fresh process."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for N_av in (4, 50):
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
                         "decisions_agreeing_fraction": agree})
    return rows


def paper_run() -> float:
    """(5): ``haa-sym reproduce`` into a temporary directory, one whole-process run."""
    with tempfile.TemporaryDirectory() as tmp:
        return _timed([sys.executable, "-m", "haa_sym.cli", "reproduce", "--out",
                       os.path.join(tmp, "results")], tmp)


def main() -> int:
    rows = run()
    print(f"200 x 200 region map on {platform.processor() or platform.machine()}, "
          f"python {platform.python_version()} (best of {REPEATS})")
    for r in rows:
        print(f"\n{r['config']}: closed-loop order {r['closed_loop_order']}")
        print(f"  generated stability map            {r['generated_stability_s']:8.3f} s")
        print(f"  generated stability + radius       {r['generated_stability_radius_s']:8.3f} s")
        print(f"  generated full map (stab, PM, pass) {r['generated_full_map_s']:7.3f} s")
        print(f"  ... with the spectral radius       {r['generated_full_map_with_radius_s']:8.3f} s")
        print(f"  numpy eigvals, stacked             {r['numpy_stacked_eigvals_s']:8.3f} s")
        print(f"  python-control, extrapolated       {r['python_control_extrapolated_s']:8.1f} s "
              f"({1e3 * r['python_control_per_point_s']:.2f} ms/point on {N_SAMPLE_CONTROL} points)")
        print(f"  ratio stability vs eigvals         {r['ratio_stability_vs_eigvals']:8.1f} x")
        print(f"  ratio stability vs python-control  {r['ratio_stability_vs_python_control']:8.0f} x")
        print(f"  ratio full map vs python-control   {r['ratio_full_map_vs_python_control']:8.0f} x")
        print(f"  decisions agree with eigvals: {r['decisions_agree_with_eigvals']}; "
              f"python-control sample: {r['python_control_sample_agreeing']}")
    procs = whole_process()
    print("\nwhole processes (fresh interpreter), 300 x 300:")
    for r in procs:
        print(f"  N_av = {r['N_av']:2d}: haa-sym regions (full map) {r['cli_regions_full_map_s']:6.2f} s, "
              f"stacked-eigvals script (stability only) {r['eigvals_script_stability_only_s']:6.2f} s: "
              f"{r['ratio']:.1f} x; decisions agreeing {100 * r['decisions_agreeing_fraction']:.3f} %")
    t_paper = paper_run()
    print(f"\nhaa-sym reproduce (make paper after make derive): {t_paper:.1f} s")
    out = HERE / "results.json"
    out.write_text(json.dumps({"machine": platform.platform(), "rows": rows, "whole_process": procs,
                               "reproduce_s": t_paper}, indent=1) + "\n")
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
