"""The controller's elements, each defined once as an exact discrete transfer function.

An :class:`Element` is a proper rational function of z with exact (Fraction) coefficients.
Every view of it derives from that one definition:

* its factor in the characteristic polynomial (:meth:`Element.numerator`,
  :meth:`Element.denominator`; ``haa_sym.loop.closed_loop`` multiplies them exactly);
* its frequency response at z = exp(j w Ts) (:meth:`Element.frequency_response`), evaluated in
  whichever basis, z or w = z - 1, bounds the rounding more tightly at that frequency: near z = 1
  (slow frequencies, fast sampling) a difference such as z^N - 1 loses every digit in the z basis
  but none in the w basis, where w = -2 sin^2(x/2) + j sin x is computed without cancellation;
* its part of the explicit closed-loop state space (:meth:`Element.realization`, the observable
  canonical form; ``haa_sym.loop.statespace``).

The velocity estimates built from them (the average, backward difference and Tustin low-pass
filters) are a registry of their own, :mod:`haa_sym.model.filters`. The integral part of the torque
PI (Eq. 7, backward Euler) is Ts z / (z - 1) and the computation delay is z^-d.

Example
-------
>>> from haa_sym.model.elements import pi_integral
>>> I = pi_integral(1e-3)
>>> [float(c) for c in I.numerator], [float(c) for c in I.denominator]
([0.001, 0.0], [1.0, -1.0])
"""
from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from functools import lru_cache
from typing import Sequence

import numpy as np

__all__ = ["Element", "frequency_responses", "backward_difference", "tustin", "pi_integral", "delay", "common_denominator"]


def _trim(p: Sequence[Fraction]) -> tuple[Fraction, ...]:
    p = list(p)
    while len(p) > 1 and p[0] == 0:
        p.pop(0)
    return tuple(Fraction(c) for c in p)


def _mul(a, b):
    out = [Fraction(0)] * (len(a) + len(b) - 1)
    for i, x in enumerate(a):
        if x:
            for j, y in enumerate(b):
                out[i + j] += x * y
    return _trim(out)


def _add(a, b):
    n = max(len(a), len(b))
    a = [Fraction(0)] * (n - len(a)) + list(a)
    b = [Fraction(0)] * (n - len(b)) + list(b)
    return _trim([x + y for x, y in zip(a, b)])


def _divmod(a, b):
    """Exact polynomial division (descending coefficients): (quotient, remainder)."""
    a, b = list(_trim(a)), _trim(b)
    if len(a) < len(b):
        return (Fraction(0),), _trim(a)
    q = [Fraction(0)] * (len(a) - len(b) + 1)
    for i in range(len(q)):
        c = a[i] / b[0]
        q[i] = c
        if c:
            for j, y in enumerate(b):
                a[i + j] -= c * y
    return _trim(q), _trim(a[len(q):] or [0])


def _monic(p):
    return tuple(c / p[0] for c in p)


def _gcd(a, b):
    a, b = _trim(a), _trim(b)
    while any(b):
        a, b = b, _divmod(a, b)[1]
    return _monic(a)


def _taylor_shift(p: Sequence[Fraction]) -> tuple[Fraction, ...]:
    """Coefficients of p(1 + w) in w, ascending, from p(z) descending (exact)."""
    out = [Fraction(0)]
    for c in p:                        # Horner in z = 1 + w: out = out * (1 + w) + c
        nxt = out + [Fraction(0)]
        for k in range(len(out)):
            nxt[k + 1] += out[k]
        nxt[0] += c
        out = nxt
    while len(out) > 1 and out[-1] == 0:
        out.pop()
    return tuple(out)


@lru_cache(maxsize=512)
def _bases(p_desc: tuple) -> tuple[np.ndarray, np.ndarray]:
    """p's float coefficients in z (descending) and in w = z - 1 (ascending), each rounded once
    from the exact ones; cached, since every frequency evaluation needs both."""
    cz = np.array([float(c) for c in p_desc])
    cw = np.array([float(c) for c in _taylor_shift(p_desc)])
    cz.flags.writeable = cw.flags.writeable = False
    return cz, cw


def _evaluate(p_desc: Sequence[Fraction], x: np.ndarray) -> np.ndarray:
    """p(exp(j x)) with the smaller of the z- and w-basis rounding bounds per frequency."""
    z = np.exp(1j * x)
    w = -2.0 * np.sin(x / 2) ** 2 + 1j * np.sin(x)      # z - 1 without cancellation
    cz, cw = _bases(tuple(p_desc))                        # cw ascending in w
    vz = np.zeros_like(z)
    for c in cz:
        vz = vz * z + c
    vw = np.zeros_like(w)
    for c in cw[::-1]:
        vw = vw * w + c
    # rounding bounds of Horner: sum |c_k| |base|^k (up to the same factor in both bases)
    bz = np.abs(cz).sum() * np.ones(x.shape)
    aw = np.abs(w)
    bw = np.zeros(x.shape)
    for c in np.abs(cw)[::-1]:
        bw = bw * aw + c
    return np.where(bw <= bz, vw, vz)


def frequency_responses(elements: Sequence["Element"], omega, Ts: float) -> list[np.ndarray]:
    """Every element's :meth:`Element.frequency_response` at ``omega`` (rad/s, 1-D), at once.

    The same arithmetic as one element at a time, row by row (equal to the last bit): the
    numerators and denominators are stacked, each padded with leading zeros in z (trailing in w),
    which Horner's steps carry as exact zeros, and both bases are evaluated in one pass. A loop's
    few elements then cost one pass of array operations instead of one per polynomial: the
    per-call cost that dominates the evaluations at a handful of frequencies (a root refinement).
    """
    x = np.asarray(omega, dtype=float).ravel() * Ts
    polys = [p for e in elements for p in (e.numerator, e.denominator)]
    if not polys:
        return []
    bases = [_bases(tuple(p)) for p in polys]
    m = max(cz.size for cz, _ in bases)
    CZ, CW = np.zeros((len(polys), m)), np.zeros((len(polys), m))
    for i, (cz, cw) in enumerate(bases):
        CZ[i, m - cz.size:] = cz
        CW[i, :cw.size] = cw
    z = np.exp(1j * x)
    w = -2.0 * np.sin(x / 2) ** 2 + 1j * np.sin(x)      # z - 1 without cancellation
    vz = np.zeros((len(polys), x.size), complex)
    for c in CZ.T:
        vz = vz * z + c[:, None]
    vw = np.zeros((len(polys), x.size), complex)
    for c in CW.T[::-1]:
        vw = vw * w + c[:, None]
    # each row's bound summed over its own coefficients, as _evaluate sums them
    bz = np.array([np.abs(cz).sum() for cz, _ in bases])[:, None]
    aw = np.abs(w)
    bw = np.zeros((len(polys), x.size))
    for c in np.abs(CW).T[::-1]:
        bw = bw * aw + c[:, None]
    v = np.where(bw <= bz, vw, vz)
    return [v[2 * i] / v[2 * i + 1] for i in range(len(elements))]


@dataclass(frozen=True)
class Element:
    """A proper discrete transfer function numerator(z) / denominator(z), exact coefficients.

    Parameters
    ----------
    name : str
        What it is, for messages and state names.
    numerator, denominator : tuple of Fraction
        Descending coefficients in z; ``len(numerator) <= len(denominator)`` (proper).
    """

    name: str
    numerator: tuple
    denominator: tuple

    def __post_init__(self):
        num, den = _trim(self.numerator), _trim(self.denominator)
        if not any(den):
            raise ValueError(f"{self.name}: zero denominator")
        if len(num) > len(den):
            raise ValueError(f"{self.name}: improper transfer function")
        object.__setattr__(self, "numerator", num)
        object.__setattr__(self, "denominator", den)

    @property
    def order(self) -> int:
        """Number of states of a minimal-length realization (degree of the denominator)."""
        return len(self.denominator) - 1

    def __mul__(self, other: "Element") -> "Element":
        return Element(f"{self.name}*{other.name}", _mul(self.numerator, other.numerator),
                       _mul(self.denominator, other.denominator))

    def frequency_response(self, omega, Ts: float) -> np.ndarray:
        """Complex value at z = exp(j omega Ts), omega in rad/s (any shape)."""
        x = np.asarray(omega, dtype=float) * Ts
        return _evaluate(self.numerator, x) / _evaluate(self.denominator, x)

    def realization(self):
        """``(A, B, C, D)`` floats of the observable canonical form (x[k+1] = A x + B u,
        y = C x + D u); an order-0 element is a pure gain (empty A)."""
        den = [c / self.denominator[0] for c in self.denominator]
        num = [Fraction(0)] * (len(den) - len(self.numerator)) + \
              [c / self.denominator[0] for c in self.numerator]
        n = len(den) - 1
        D = num[0]
        # num/den = D + (num - D den)/den; observable form: A = [-a | I], B = (num - D den)[1:]
        b = [num[k] - D * den[k] for k in range(1, n + 1)]
        A = np.zeros((n, n))
        for k in range(n):
            A[k, 0] = -float(den[k + 1])
            if k + 1 < n:
                A[k, k + 1] = 1.0
        B = np.array([[float(c)] for c in b]).reshape(n, 1)
        C = np.zeros((1, n))
        if n:
            C[0, 0] = 1.0
        return A, B, C, np.array([[float(D)]])


def _fraction(x: float) -> Fraction:
    return Fraction(float(x))


def backward_difference(Ts: float) -> Element:
    """(theta[k] - theta[k-1]) / Ts = (z - 1) / (Ts z)."""
    return Element("backward_difference", (Fraction(1), Fraction(-1)), (_fraction(Ts), Fraction(0)))


def tustin(analog_den: Sequence[float], w_c: float, Ts: float, name: str) -> Element:
    """w_c^n / analog_den(s) with s = (2/Ts)(z - 1)/(z + 1) (Tustin, no prewarping), exact in
    the floats given; analog_den ascending in s is [w_c^n, ..., 1]."""
    n = len(analog_den) - 1
    k = Fraction(2) / _fraction(Ts)
    zm1, zp1 = (Fraction(1), Fraction(-1)), (Fraction(1), Fraction(1))
    den = (Fraction(0),)
    for i, a in enumerate(analog_den):       # a_i s^i (z+1)^n = a_i k^i (z-1)^i (z+1)^(n-i)
        term = (_fraction(a) * k ** i,)
        for _ in range(i):
            term = _mul(term, zm1)
        for _ in range(n - i):
            term = _mul(term, zp1)
        den = _add(den, term)
    num = (_fraction(w_c) ** n,)
    for _ in range(n):
        num = _mul(num, zp1)
    return Element(name, num, den)


def pi_integral(Ts: float) -> Element:
    """The integral part of Eq. (7) in backward Euler: Ts z / (z - 1)."""
    return Element("pi_integral", (_fraction(Ts), Fraction(0)), (Fraction(1), Fraction(-1)))


def delay(d: int) -> Element:
    """z^-d: the computation delay between sampling and the applied voltage."""
    return Element(f"delay{d}", (Fraction(1),), (Fraction(1),) + (Fraction(0),) * d)


def common_denominator(*elements: Element):
    """``(D, [A_i])``: the monic least common multiple D(z) of the denominators and the
    numerators A_i(z) with element_i = A_i / D, exact (memoised: every closed loop of a sweep
    over plants asks for the same few)."""
    D, nums = _common_denominator(tuple((e.numerator, e.denominator) for e in elements))
    return D, list(nums)


@lru_cache(maxsize=256)
def _common_denominator(parts: tuple):
    D = (Fraction(1),)
    elements = [Element("", n, d) for n, d in parts]
    for e in elements:
        den = _monic(e.denominator)
        D = _monic(_divmod(_mul(D, den), _gcd(D, den))[0])
    nums = []
    for e in elements:
        q, r = _divmod(D, _monic(e.denominator))
        assert not any(r)
        nums.append(_mul(tuple(c / e.denominator[0] for c in e.numerator), q))
    return D, tuple(nums)
