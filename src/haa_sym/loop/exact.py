"""Exact transfer polynomials of a sampled plant, from its double-precision matrices.

The sampled plant's eigenvalues cluster near z = 1 at fast sampling, where the roots of a
polynomial in the monomial basis are sensitive to its coefficients: rounding alone moves them by
~1e-8 at Ts = 0.5 ms. So the characteristic polynomial and the adjugate are computed *exactly*
(Faddeev-LeVerrier in integer arithmetic on the dyadic rationals that the doubles are) and each
coefficient is rounded once, at the end.
"""
from __future__ import annotations

import functools
import math
from fractions import Fraction

import numpy as np

__all__ = ["charpoly_adjugate", "transfer_polynomials", "polymul", "polysub", "to_float", "bilinear"]


def _dyadic_scale(M: np.ndarray) -> tuple[list[list[int]], int]:
    """Integers ``K`` and exponent ``E`` with ``M == K / 2**E`` exactly."""
    E = 0
    ratios = [[float(x).as_integer_ratio() for x in row] for row in M]
    for row in ratios:
        for _, den in row:
            E = max(E, den.bit_length() - 1)
    return [[num << (E - (den.bit_length() - 1)) for num, den in row] for row in ratios], E


def charpoly_adjugate(Phi: np.ndarray):
    """Exact ``det(zI - Phi)`` and ``adj(zI - Phi)``.

    Returns ``(c, Ms)``: ``c`` descending Fractions (c[0] = 1) and ``Ms`` the list of Fraction
    matrices with ``adj(zI - Phi) = sum_k Ms[k] z^(n-1-k)``.
    """
    if not np.all(np.isfinite(Phi)):
        raise ValueError("Phi has non-finite entries")
    K, E = _dyadic_scale(Phi)
    cs, Ms_int = _faddeev_leverrier(K, keep=True)
    # det(zI - K/2^E) = sum_j cs[j] 2^(-E j) z^(n-j); adj coefficient of z^(n-1-k) is Ms[k] 2^(-E k)
    c = [Fraction(cj, 1 << (E * j)) for j, cj in enumerate(cs)]
    Ms = [[[Fraction(v, 1 << (E * k)) for v in row] for row in Mi] for k, Mi in enumerate(Ms_int)]
    return c, Ms


def _faddeev_leverrier(K: list[list[int]], keep: bool = False):
    """Integer characteristic polynomial of the integer matrix ``K`` (descending, c[0] = 1) by
    Faddeev-LeVerrier, and with ``keep`` the integer matrices M_0..M_(n-1) of its adjugate
    (otherwise only the current M_k is held). Returns ``(cs, Ms)`` (``Ms`` None without keep)."""
    n = len(K)
    Mk = [[int(i == j) for j in range(n)] for i in range(n)]
    cs, Ms = [1], ([Mk] if keep else None)
    for k in range(1, n + 1):
        cols = list(zip(*Mk))
        AM = [[sum(a * b for a, b in zip(K[i], cols[j])) for j in range(n)] for i in range(n)]
        tr = sum(AM[i][i] for i in range(n))
        if tr % k:
            raise ArithmeticError("Faddeev-LeVerrier: inexact division")  # cannot happen
        c = -tr // k
        cs.append(c)
        Mk = [[AM[i][j] + (c if i == j else 0) for j in range(n)] for i in range(n)]
        if keep and k < n:
            Ms.append(Mk)
    if any(any(v for v in row) for row in Mk):
        raise ArithmeticError("Cayley-Hamilton check failed")  # cannot happen in exact arithmetic
    return cs, Ms


def transfer_polynomials(Phi: np.ndarray, Gamma: np.ndarray, C: np.ndarray):
    """Exact ``d(z) = det(zI - Phi)`` and numerators ``N[o][i](z) = C_o adj(zI - Phi) Gamma_i``.

    All polynomials descending, as lists of Fractions; numerators have degree n - 1.

    The same numbers as :func:`charpoly_adjugate`, in integers throughout (Fractions only for
    the results): with Phi = K / 2^E, M_k = K M_(k-1) + c_k I gives adj(zI - Phi) Gamma_i
    column by column from the recursion v_k = K v_(k-1) + c_k g_i, n^2 products a step instead
    of the n^3 of each stored M_k times Gamma in Fractions (whose gcds made a 35-state plant
    take minutes).
    """
    if not np.all(np.isfinite(Phi)):
        raise ValueError("Phi has non-finite entries")
    K, E = _dyadic_scale(Phi)
    Gi, Eg = _dyadic_scale(np.asarray(Gamma, dtype=float).T)     # rows: the inputs
    Ci, Ec = _dyadic_scale(np.asarray(C, dtype=float))
    n = len(K)
    cs, _ = _faddeev_leverrier(K)
    d = [Fraction(cj, 1 << (E * j)) for j, cj in enumerate(cs)]
    cols = []                   # cols[i][k]: M_k g_i (integers)
    for g in Gi:
        v = list(g)
        seq = [v]
        for k in range(1, n):
            v = [sum(a * b for a, b in zip(K[r], v)) + cs[k] * g[r] for r in range(n)]
            seq.append(v)
        cols.append(seq)
    # coefficient of z^(n-1-k): C_o M_k g_i / 2^(E k + Eg + Ec)
    nums = [[[Fraction(sum(a * b for a, b in zip(co, cols[i][k])), 1 << (E * k + Eg + Ec))
              for k in range(n)] for i in range(len(Gi))] for co in Ci]
    return d, nums


def polymul(*polys):
    """Product of descending coefficient lists (exact if the inputs are)."""
    out = [Fraction(1)]
    for p in polys:
        res = [Fraction(0)] * (len(out) + len(p) - 1)
        for i, a in enumerate(out):
            if a:
                for j, b in enumerate(p):
                    res[i + j] += a * b
        out = res
    return out


def polysub(a, b):
    """a - b for descending coefficient lists (exact if the inputs are)."""
    n = max(len(a), len(b))
    a = [Fraction(0)] * (n - len(a)) + list(a)
    b = [Fraction(0)] * (n - len(b)) + list(b)
    return [x - y for x, y in zip(a, b)]


def to_float(p) -> np.ndarray:
    """Correctly rounded doubles of exact coefficients."""
    return np.array([float(x) for x in p])



@functools.lru_cache(maxsize=None)
def _bilinear_matrix(n: int) -> tuple[tuple[int, ...], ...]:
    """Row k: ascending integer coefficients of (1 + s)^k (1 - s)^(n - k)."""
    rows = []
    for k in range(n + 1):
        plus = [math.comb(k, i) for i in range(k + 1)]
        minus = [math.comb(n - k, i) * (-1) ** i for i in range(n - k + 1)]
        row = [0] * (n + 1)
        for i, x in enumerate(plus):
            for j, y in enumerate(minus):
                row[i + j] += x * y
        rows.append(tuple(row))
    return tuple(rows)


def bilinear(p) -> list[Fraction]:
    """Exact bilinear (Cayley) transform of a polynomial in z: ascending coefficients of
    ``q(s) = (1 - s)^n p((1 + s)/(1 - s))``, n = len(p) - 1, for ``p`` descending.

    z = (1 + s)/(1 - s) maps |z| < 1 onto Re s < 0, so p is Schur stable iff q is Hurwitz
    stable (a root at z = -1 lowers the degree of q). Roots crowding at z = 1 under fast
    sampling, z = 1 + Ts delta with small Ts delta, land at s = Ts delta/(2 + Ts delta) near
    s = 0, where the low-order coefficients of q resolve them to full relative precision: the
    monomial coefficients of p cannot (docs/model.md, "Fast sampling"). Computed in integers
    over the common denominator, so the only rounding is the caller's, once per coefficient.
    """
    p = [Fraction(x) for x in p]
    n = len(p) - 1
    den = 1
    for x in p:
        den = den * x.denominator // math.gcd(den, x.denominator)
    a = [int(x * den) for x in reversed(p)]                  # ascending integers
    T = _bilinear_matrix(n)
    q = [0] * (n + 1)
    for k, ak in enumerate(a):
        if ak:
            for j, t in enumerate(T[k]):
                if t:
                    q[j] += ak * t
    return [Fraction(v, den) for v in q]
