"""The exact passivity test's cost (issue 24): a 200 x 200 map with ``passivity=exact`` and the
same map with the paper's ``corrected_phase``, side by side in one process (target: within 5x).

Both maps are ``region_map(loop, P, D, method="grid")`` (every point decided: stability, phase
margin, passivity) on P_gain log 1..20000 x D_gain lin 1..50 of the bundled HyQ file; the exact
map's time includes building its aliasing sums (the memo is cleared before every run: a first
map pays them), and ``sums_s`` is that one-off part alone. Each is the best of ``REPEATS`` runs
after a warm-up (the generated code compiled, the plant's exact polynomials built). Prints the
times and the ratio; writes ``results_exact_passivity.json`` into ``$HAA_SYM_BENCH_DIR``
(default ``bench-results/``), which ``render_readme.py`` puts into docs/benchmarks.md.
"""
from __future__ import annotations

import json
import time

import numpy as np

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis import sampled_port
from haa_sym.analysis.regions import region_map
from haa_sym.loop.options import LoopOptions
from timing import REPEATS, Run

TARGET_RATIO = 5.0


def _clear():
    sampled_port._SUMS._items.clear()
    sampled_port._FORMS._items.clear()


def _time(loop, P, D, clear):
    best = np.inf
    for _ in range(REPEATS):
        if clear:                      # the exact map pays its sums every run
            _clear()
        t = time.perf_counter()
        m = region_map(loop, P, D, method="grid", progress=False)
        best = min(best, time.perf_counter() - t)
    return best, m


def main() -> dict:
    run = Run("bench_exact_passivity.py")
    P = np.logspace(0, np.log10(20000), 200)
    D = np.linspace(1, 50, 200)
    p = load_params()
    loops = {k: ClosedLoop(p, LoopOptions(passivity=k)) for k in ("corrected_phase", "exact")}
    region_map(loops["corrected_phase"], P[:5], D[:5], method="grid", progress=False)      # warm-up
    t_cp, m_cp = _time(loops["corrected_phase"], P, D, False)
    t_ex, m_ex = _time(loops["exact"], P, D, True)
    sums = np.inf
    w = loops["exact"].options.numerics.omega(p.controller.Ts)
    for _ in range(REPEATS):
        _clear()
        t = time.perf_counter()
        s = sampled_port.harmonic_sums(*sampled_port._loop_pieces(loops["exact"]), p.controller.Ts, w)
        sums = min(sums, time.perf_counter() - t)
    res = {"corrected_phase_s": t_cp, "exact_s": t_ex, "ratio": t_ex / t_cp, "sums_s": sums,
           "harmonics_each_side": int(s.K), "n_omega": int(w.size), "target_ratio": TARGET_RATIO,
           "repeats": REPEATS, "passive_corrected_phase": int(m_cp.passive.sum()),
           "passive_exact": int(m_ex.passive.sum()),
           "grid": "200 x 200, P_gain log 1..20000, D_gain lin 1..50, HyQ, method=grid"}
    print(json.dumps(res, indent=1))
    print(f"wrote {run.write('results_exact_passivity.json', res)}")
    return res


if __name__ == "__main__":
    main()
