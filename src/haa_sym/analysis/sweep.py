"""Frequency-domain reductions over many gain points at once (Sec. 4 phase margin, Sec. 5 passivity).

Because the impedance law Eq. (8) enters every loop linearly (see ``codegen/kernels.py``), the
loop gains of a whole P_gain x D_gain grid are one matrix product ``X @ c.T`` with the rows
x = (1, P_gain, D_gain) and the generated per-frequency coefficients ``c`` of
:meth:`haa_sym.loop.closed_loop.ClosedLoop.loop_coefficients`. The functions here reduce such products,
chunk by chunk, to one number per point: the phase margin and the passivity phase excess.
"""
from __future__ import annotations

import contextlib
import functools
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from threadpoolctl import ThreadpoolController

__all__ = ["gain_rows", "monomial_rows", "product_form", "phase_excess", "colgate_factor", "blas_limits",
           "run_chunks", "BLAS_THREADS", "SWEEP_THREADS", "CHUNK"]


# BLAS threads during a gain-grid sweep. Its products, (512 x 6) @ (6 x 1000) per chunk, are too
# small for OpenBLAS threads to pay; the extra threads spin waiting for work and, on a machine
# whose cores are busy with other processes, take turns with them (measured on this 2-core
# machine under load, two runs: a 200 x 200 region map 5.1-5.7 s with OpenBLAS's 2 threads,
# 2.4-3.0 s with 1).
BLAS_THREADS = 1
# Threads sharing the chunks of a region map instead: the generated C (ctypes) and numpy's
# products and ufuncs release the GIL, so two chunk workers with single-threaded BLAS use both
# cores (measured: 200 x 200 map 1.26 -> 0.86 s nominal, 1.67 -> 1.01 s at N_av = 50; identical maps).
SWEEP_THREADS = min(2, os.cpu_count() or 1)
# Points per chunk: small enough for the (chunk x n_omega) products to stay in cache (measured:
# 512 points beat 2048 by ~30%).
CHUNK = 512


def run_chunks(work, n: int, *, blas_threads: int | None = BLAS_THREADS, bar=None) -> None:
    """Call ``work(slice)`` on the chunks of ``range(n)``, shared by :data:`SWEEP_THREADS` threads
    (the generated C and numpy's products release the GIL; each call writes its own slices),
    with BLAS limited to ``blas_threads``; ``bar.update`` (a progress bar) after each chunk."""
    chunks = [slice(s, min(s + CHUNK, n)) for s in range(0, n, CHUNK)]
    with blas_limits(blas_threads):
        if SWEEP_THREADS > 1 and len(chunks) > 1:
            with ThreadPoolExecutor(SWEEP_THREADS) as pool:
                for sl in pool.map(lambda sl: (work(sl), sl)[1], chunks):
                    if bar is not None:
                        bar.update(sl.stop - sl.start)
        else:
            for sl in chunks:
                work(sl)
                if bar is not None:
                    bar.update(sl.stop - sl.start)


def blas_limits(threads: int | None):
    """Context manager limiting BLAS to ``threads`` threads (threadpoolctl); None: no change.
    Used around the sweeps (``region_map``, ``passivity``) with :data:`BLAS_THREADS`."""
    if threads is None:
        return contextlib.nullcontext()
    return _controller().limit(limits=int(threads), user_api="blas")


@functools.lru_cache(maxsize=None)
def _controller():
    # one scan of the loaded libraries per process: threadpool_limits() rescans at every call
    # (1.7 ms; Table 2 and the option scores make thousands of sweeps)
    return ThreadpoolController()


def gain_rows(P_gain, D_gain) -> np.ndarray:
    """Rows x = (1, P_gain, D_gain) of flat point arrays, shape (n, 3)."""
    P = np.asarray(P_gain, dtype=float).ravel()
    D = np.asarray(D_gain, dtype=float).ravel()
    return np.stack([np.ones_like(P), P, D], axis=1)


def monomial_rows(X: np.ndarray) -> np.ndarray:
    """Rows (1, P, D, P^2, P D, D^2) of the gain rows ``X``, shape (n, 6)."""
    P, D = X[:, 1], X[:, 2]
    return np.stack([X[:, 0], P, D, P * P, P * D, D * D], axis=1)


def product_form(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Coefficients (6, n_omega) of (a . x) * conj(b . x) on :func:`monomial_rows` (complex).

    The product of two gain-affine forms is a quadratic form in x = (1, P, D); written on the
    six monomials, a whole grid is one real matrix product per real/imaginary part.
    """
    bc = np.conj(b)
    return np.stack([a[:, 0] * bc[:, 0],
                     a[:, 0] * bc[:, 1] + a[:, 1] * bc[:, 0],
                     a[:, 0] * bc[:, 2] + a[:, 2] * bc[:, 0],
                     a[:, 1] * bc[:, 1],
                     a[:, 1] * bc[:, 2] + a[:, 2] * bc[:, 1],
                     a[:, 2] * bc[:, 2]])


def colgate_factor(omega: np.ndarray, Ts: float, colgate: str) -> np.ndarray:
    """exp(-j s w Ts/2) with s = +1 ("subtract"), -1 ("add") or 0 ("none") (Colgate, Sec. 5)."""
    s = {"subtract": 1.0, "add": -1.0, "none": 0.0}[colgate]
    return np.exp(-1j * s * omega * Ts / 2)


def phase_excess(X: np.ndarray, Z_num: np.ndarray, Z_den: np.ndarray, omega: np.ndarray,
                 Ts: float, colgate: str = "subtract"):
    """Worst excess of the corrected phase of Z beyond +-90 deg at every row of ``X``.

    Parameters
    ----------
    X : (n, 3) array
        Gain rows from :func:`gain_rows`.
    Z_num, Z_den : (n_omega, 3) complex arrays
        Z = (Z_num @ x) / (Z_den @ x) (``LoopCoefficients``).
    omega : (n_omega,) array
        Frequencies up to Nyquist, rad/s.
    Ts : float
        Sampling time, s.
    colgate : {"subtract", "add", "none"}
        Sign of the w Ts/2 correction of the phase of Z.

    Returns
    -------
    excess_deg : (n,) array
        max over omega of |corrected phase of Z| - 90, degrees: <= 0 means within +-90 deg
        (passive when the closed loop is also stable).
    w_worst : (n,) array
        The frequency of that maximum, rad/s.

    Uses |phase| - 90 = asin(-cos(phase)) so that one minimum of Re/|.| over omega suffices.
    """
    n = X.shape[0]
    if n == 0:
        return np.full(0, np.nan), np.full(0, np.nan)
    Q = product_form(Z_num, Z_den) * colgate_factor(omega, Ts, colgate)
    M = monomial_rows(X)
    Wr = M @ Q.real                          # W = Z_num.x conj(Z_den.x) e^{-j s w Ts/2}:
    Wi = M @ Q.imag                          # its phase is the corrected phase of Z
    cos = Wr / np.sqrt(Wr * Wr + Wi * Wi)
    j = np.argmin(cos, axis=1)
    worst = cos[np.arange(n), j]
    return np.degrees(np.arcsin(np.clip(-worst, -1.0, 1.0))), omega[j]
