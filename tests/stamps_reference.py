"""An INDEPENDENT simulation of a model on a log's own stamps (shared by the tests of
haa_sym.fit.model.simulate_stamps: tests/test_fit_model_stamps.py and
tests/test_fit_model_stamps_integrator.py): sample by sample, every switch of the delayed command
inside an interval its own sub-interval, each one exact by scipy's expm of [[A, B], [0, 0]] (the
command held), a segment restarting from its own initial state. No code of haa_sym.fit is used,
so that it can judge the modal recursion there."""
from __future__ import annotations

import numpy as np
import scipy.linalg

from haa_sym.analysis.sweep import blas_limits


def jittered_log(seed: int, n: int = 300, gap_at: int = 150):
    """Stamps (s) with intervals of 0.5-3 ms (jitter of the ITregear logs' kind) and a 50 ms gap
    before sample ``gap_at`` (a second segment), and a white Gaussian command (n, 1)."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5e-3, 3e-3, n))
    t -= t[0]
    t[gap_at:] += 0.05
    return t, rng.standard_normal((n, 1))


def reference_stamps(model, delay: float, t, u, starts, x0s) -> np.ndarray:
    """The outputs (n, ny) of ``model`` (its ``A``, ``B``, ``C``; the first input) on stamps ``t``
    (s) with the command ``u`` delayed by ``delay`` (s), segments from ``starts`` each from its
    state in ``x0s``; BLAS on one thread (hundreds of small exponentials: threads only contend,
    30x slower on a loaded machine)."""
    with blas_limits(1):
        return _run(model, delay, t, u, starts, x0s)


def _run(mm, d, t, u, starts, x0s):
    n = mm.A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = mm.A, mm.B[:, 0]
    ends = list(starts[1:]) + [t.size]
    ys, sw = [], t + d
    for s, e, x0 in zip(starts, ends, x0s):
        x = np.array(x0, float)
        for k in range(s, e):
            ys.append(mm.C @ x)
            if k == e - 1:
                break
            ev = [t[k]] + list(sw[(sw > t[k]) & (sw < t[k + 1])]) + [t[k + 1]]
            for a0, a1 in zip(ev[:-1], ev[1:]):
                j = max(np.searchsorted(t, a0 - d + 1e-12, side="right") - 1, 0)   # the command in effect
                E = scipy.linalg.expm(M * (a1 - a0))
                x = E[:n, :n] @ x + E[:n, n] * u[j, 0]
    return np.array(ys)
