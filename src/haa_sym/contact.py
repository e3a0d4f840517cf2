"""Stability in contact with a stiff environment (Sec. 5).

The environment is a spring of stiffness K_L2 on the leg inertia (Fig. 13 of the paper, a linear
spring at a distance from the HAA axis); the scan replaces K_L2 by each environment stiffness and
decides closed-loop stability, by default with the impedance loop open (the torque loop alone).
For any actuator file the spring replaces the ground stiffness K_<port> of the port body
([sensors] port), which the file must therefore give.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from haa_sym.loop import ClosedLoop, LoopOptions
from haa_sym.params import ParameterError, Params, gain_array, gain_points

__all__ = ["contact_stability", "contact_intervals", "ContactIntervals", "intervals", "CONTACT_MODES"]

CONTACT_MODES = ("replace", "add")


def _port_key(params: Params) -> str:
    from haa_sym.actuator import Topology
    top = params.plant.topology
    key = f"K_{top.port}"
    if key not in top.parameter_keys and not isinstance(top, Topology):
        raise ParameterError(
            f"{params.source}: the model has no parameter {key} (the port's stiffness to ground, "
            f"which the contact scan replaces by the environment's); allowed: a model whose "
            f"parameter {key} (Nm/rad) is the stiffness acting on the port")
    if key not in top.parameter_keys:
        raise ParameterError(
            f"{params.source} [bodies.{top.port}]: the port body {top.port!r} has no stiffness to "
            f"ground K ({key}), which the contact scan replaces by the environment's; allowed: an "
            f"actuator whose port body has K (e.g. K = {{ value = 0.0 }} for none)")
    return key


def _radius(params, key, K, P_gain, D_gain, beta, alpha, options, base):
    from haa_sym.statespace import closed_loop_batch
    loop = ClosedLoop(params.with_values(**{key: float(K) + base}), options, basis=False)
    return np.abs(np.linalg.eigvals(closed_loop_batch(loop, P_gain, D_gain, beta, alpha)[0][0])).max()


def contact_stability(params: Params, K_env, *, P_gain: float = 0.0, D_gain: float = 0.0,
                      options: LoopOptions | None = None, beta: float | None = None,
                      alpha: float | None = None, progress: bool | None = None, mode: str = "replace"):
    """Stability decision and spectral radius for each environment stiffness ``K_env`` (Nm/rad).

    Returns ``(stable, spectral_radius)`` arrays of ``K_env``'s length, from the eigenvalues of
    the explicit closed loop: every stiffness is a new plant with a single gain point, where an
    eigenvalue solve is cheaper than the exact characteristic-polynomial basis.

    Example
    -------
    >>> K = np.logspace(0, 5, 400)
    >>> stable, rho = contact_stability(load_params(), K)                   # doctest: +SKIP
    >>> intervals(K, ~stable)                                               # doctest: +SKIP
    [(73.6..., 3418.4...)]                  # the grid points; contact_intervals: 71.84-3441.6
    """
    from tqdm.auto import tqdm

    P_gain, D_gain, beta, alpha = gain_points(P_gain, D_gain, beta, alpha)
    K_env = gain_array("K_env", K_env).ravel()
    key = _port_key(params)
    base = _base(params, key, mode)
    rho = np.empty(K_env.size)
    for i, K in enumerate(tqdm(K_env, desc="contact stiffness", leave=False,
                               disable=None if progress is None else not progress)):
        rho[i] = _radius(params, key, K, P_gain, D_gain, beta, alpha, options, base)
    return rho < 1, rho


def _base(params, key, mode):
    if mode not in CONTACT_MODES:
        raise ParameterError(f"mode = {mode!r}; allowed: {list(CONTACT_MODES)} (the environment "
                             f"stiffness replaces {key}, as the paper reads it, or adds to it)")
    return 0.0 if mode == "replace" else float(getattr(params.plant, key))


@dataclass(frozen=True)
class ContactIntervals:
    """Environment stiffnesses (Nm/rad) where the closed loop is unstable, ends exact.

    ``unstable``: maximal intervals (K_lo, K_hi) of the scanned range with a closed-loop pole
    outside the unit circle; an end inside the range is where the spectral radius crosses 1,
    located by Brent's method to a relative ``rtol``; an end at the range's edge is that edge.
    ``mode`` says whether K_env replaced the port body's ground stiffness (the paper's reading)
    or was added to it; ``K_env``, ``spectral_radius``: the scan that bracketed the ends.
    """

    unstable: list
    key: str
    mode: str
    rtol: float
    K_env: np.ndarray = field(repr=False)
    spectral_radius: np.ndarray = field(repr=False)


def contact_intervals(params: Params, K_range=(1.0, 1e5), *, n_scan: int = 400, P_gain: float = 0.0,
                      D_gain: float = 0.0, options: LoopOptions | None = None, beta: float | None = None,
                      alpha: float | None = None, mode: str = "replace", rtol: float = 1e-12,
                      progress: bool | None = None) -> ContactIntervals:
    """Where contact with an environment spring K_env (on the port body) destabilises the loop.

    The spectral radius is scanned on ``n_scan`` log-spaced stiffnesses of ``K_range``; every
    change of stability between neighbours is bracketed and its stiffness located by Brent's
    method on (spectral radius - 1) in log K, to a relative ``rtol`` (default 1e-12, well inside
    the 1e-9 the analysis promises; the radius itself comes from eigenvalues accurate to about
    1e-13). An unstable island narrower than the scan step can be missed: raise ``n_scan``.

    Parameters
    ----------
    K_range : (float, float)
        Environment stiffnesses, Nm/rad, 0 < K_lo < K_hi.
    mode : {"replace", "add"}
        K_env replaces the port body's ground stiffness (default; the paper: "an environment with
        a stiffness K_L2 between 72 and 3500 Nm/rad") or is added to the file's.
    P_gain, D_gain : float
        Impedance gains (default 0: the torque loop alone, as the paper).

    Examples
    --------
    >>> r = contact_intervals(load_params())                             # doctest: +SKIP
    >>> r.unstable                                                       # doctest: +SKIP
    """
    from scipy.optimize import brentq
    K_lo, K_hi = (float(v) for v in gain_array("K_env", K_range).ravel()[:2])
    if not 0 < K_lo < K_hi:
        raise ParameterError(f"K_range = {tuple(K_range)!r}; allowed: 0 < K_lo < K_hi (Nm/rad)")
    if isinstance(n_scan, bool) or not isinstance(n_scan, int) or n_scan < 2:
        raise ParameterError(f"n_scan = {n_scan!r}; allowed: an integer >= 2")
    P_gain, D_gain, beta, alpha = gain_points(P_gain, D_gain, beta, alpha)
    key = _port_key(params)
    base = _base(params, key, mode)
    K = np.logspace(np.log10(K_lo), np.log10(K_hi), n_scan)
    stable, rho = contact_stability(params, K, P_gain=P_gain, D_gain=D_gain, options=options, beta=beta,
                                    alpha=alpha, progress=progress, mode=mode)

    def f(logK):
        return _radius(params, key, np.exp(logK), P_gain, D_gain, beta, alpha, options, base) - 1.0

    ends = []
    for i in np.flatnonzero(stable[1:] != stable[:-1]):
        ends.append(float(np.exp(brentq(f, np.log(K[i]), np.log(K[i + 1]), xtol=1e-300, rtol=rtol))))
    out, start = [], (K_lo if not stable[0] else None)
    for i, e in zip(np.flatnonzero(stable[1:] != stable[:-1]), ends):
        if stable[i]:                                   # stable -> unstable: an interval starts
            start = e
        else:
            out.append((start, e))
            start = None
    if start is not None:
        out.append((start, K_hi))
    return ContactIntervals(out, key, mode, rtol, K, rho)


def intervals(x, flag) -> list[tuple[float, float]]:
    """Maximal runs [x_first, x_last] of consecutive samples where ``flag`` is true.

    >>> intervals([1, 2, 3, 4, 5], [False, True, True, False, True])
    [(2.0, 3.0), (5.0, 5.0)]
    """
    x, flag = np.asarray(x), np.asarray(flag, bool)
    out, start = [], None
    for i, f in enumerate(flag):
        if f and start is None:
            start = i
        if not f and start is not None:
            out.append((float(x[start]), float(x[i - 1])))
            start = None
    if start is not None:
        out.append((float(x[start]), float(x[-1])))
    return out
