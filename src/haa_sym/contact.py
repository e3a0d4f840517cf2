"""Stability in contact with a stiff environment (Sec. 5).

The environment is a spring of stiffness K_L2 on the leg inertia (Fig. 13 of the paper, a linear
spring at a distance from the HAA axis); the scan replaces K_L2 by each environment stiffness and
decides closed-loop stability, by default with the impedance loop open (the torque loop alone).
For any actuator file the spring replaces the ground stiffness K_<port> of the port body
([sensors] port), which the file must therefore give.
"""
from __future__ import annotations

import numpy as np

from haa_sym.loop import ClosedLoop, LoopOptions
from haa_sym.params import ParameterError, Params, gain_array, gain_points

__all__ = ["contact_stability", "intervals"]


def contact_stability(params: Params, K_env, *, P_gain: float = 0.0, D_gain: float = 0.0,
                      options: LoopOptions | None = None, beta: float | None = None,
                      alpha: float | None = None, progress: bool | None = None):
    """Stability decision and spectral radius for each environment stiffness ``K_env`` (Nm/rad).

    Returns ``(stable, spectral_radius)`` arrays of ``K_env``'s length, from the eigenvalues of
    the explicit closed loop: every stiffness is a new plant with a single gain point, where an
    eigenvalue solve is cheaper than the exact characteristic-polynomial basis.

    Example
    -------
    >>> K = np.logspace(0, 5, 400)
    >>> stable, rho = contact_stability(load_params(), K)                   # doctest: +SKIP
    >>> intervals(K, ~stable)                                               # doctest: +SKIP
    [(73.6..., 3418.4...)]
    """
    from tqdm.auto import tqdm

    from haa_sym.actuator import Topology
    from haa_sym.statespace import closed_loop_batch
    P_gain, D_gain, beta, alpha = gain_points(P_gain, D_gain, beta, alpha)
    K_env = gain_array("K_env", K_env).ravel()
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
    stable = np.empty(K_env.size, bool)
    rho = np.empty(K_env.size)
    for i, K in enumerate(tqdm(K_env, desc="contact stiffness", leave=False,
                               disable=None if progress is None else not progress)):
        loop = ClosedLoop(params.with_values(**{key: float(K)}), options, basis=False)
        rho[i] = np.abs(np.linalg.eigvals(closed_loop_batch(loop, P_gain, D_gain, beta, alpha)[0][0])).max()
        stable[i] = rho[i] < 1
    return stable, rho


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
