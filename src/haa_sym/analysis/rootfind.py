"""Vectorised bracketing root finding (every bracket of an array at once)."""
from __future__ import annotations

import numpy as np

__all__ = ["illinois"]


def illinois(f, a: np.ndarray, b: np.ndarray, fa: np.ndarray | None = None, fb: np.ndarray | None = None,
             *, xtol: float = 1e-13, steps: int = 60):
    """The Illinois variant of regula falsi on every bracket [a, b] at once (f(a), f(b) of
    opposite signs, or f(a) = 0); superlinear, the bracket kept.

    ``f`` maps an array of abscissae to an array of values. Returns ``(a, b)``, the final
    brackets, ``a`` on the side of the original ``a`` (f(a) >= 0 stays >= 0, < 0 stays < 0),
    within ``xtol`` (relative, plus absolute 1e-300) of each other or after ``steps`` steps.
    """
    a, b = np.array(a, float), np.array(b, float)
    fa = f(a) if fa is None else np.array(fa, float)
    fb = f(b) if fb is None else np.array(fb, float)
    a_side = fa >= 0
    side = np.zeros(a.size, int)
    for _ in range(steps):
        with np.errstate(invalid="ignore", divide="ignore"):
            x = (a * fb - b * fa) / (fb - fa)
        x = np.where(np.isfinite(x) & (x > np.minimum(a, b)) & (x < np.maximum(a, b)), x, 0.5 * (a + b))
        fx = f(x)
        with_a = (fx >= 0) == a_side                    # x replaces a; the root is in [x, b]
        fb = np.where(with_a, np.where(side == 1, 0.5 * fb, fb), fx)
        fa = np.where(with_a, fx, np.where(side == -1, 0.5 * fa, fa))
        a, b = np.where(with_a, x, a), np.where(with_a, b, x)
        side = np.where(with_a, 1, -1)
        if np.all(np.abs(b - a) <= xtol * (1 + np.abs(a))):
            break
    return a, b
