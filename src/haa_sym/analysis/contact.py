"""Stability and passivity in contact with a stiff environment (Sec. 5).

The environment is a spring of stiffness K_L2 on the leg inertia (Fig. 13 of the paper, a linear
spring at a distance from the HAA axis); the scan replaces K_L2 by each environment stiffness and
decides closed-loop stability, by default with the impedance loop open (the torque loop alone),
and, where the loop is stable, passivity of the port impedance Z(z) of that loop (as
:func:`haa_sym.analysis.passivity.passivity`). For any actuator file the spring replaces the ground
stiffness K_<port> of the port body ([sensors] port); a port body without one gets it as a new
stiffness to ground (:func:`contact_params`: the file's topology with K_<port> = 0, its own plant
function).

The paper's argument (Sec. 5): the torque loop alone is not passive at the port, so coupling it
to a passive environment (a spring) is not guaranteed to be stable, and a range of stiffnesses
destabilises it; :func:`contact_intervals` gives both the unstable and the stable but
non-passive stiffnesses, with exact ends.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from haa_sym.analysis.sampled_port import MEASURES, passivity_excess, passivity_tolerance
from haa_sym.analysis.sweep import BLAS_THREADS, blas_limits
from haa_sym.errors import ParameterError
from haa_sym.io.budget import check_memory, sweep_bytes
from haa_sym.loop import ClosedLoop, loop_first
from haa_sym.loop.statespace import closed_loop_batch
from haa_sym.model.actuator import ROTOR, Body, Topology
from haa_sym.model.params import Params, Plant, gain_array

__all__ = ["contact_stability", "contact_intervals", "contact_params", "ContactIntervals", "intervals",
           "CONTACT_MODES"]

CONTACT_MODES = ("replace", "add")


def contact_params(params: Params) -> tuple[Params, str, bool]:
    """The parameters the contact scan varies, the name of the stiffness it sets, and whether
    that stiffness was added (``(params, "K_<port>", added)``).

    The environment spring acts on the port body ([sensors] port) as a stiffness to ground. When
    the port body has one (``K`` in its ``[bodies.<port>]`` table) the scan sets it. When it has
    none, the plant variant of the file's topology with a stiffness to ground K_<port> on the
    port body, at 0, is scanned (its own plant function: generated if bundled, else compiled on
    first use): the variant at K_<port> = 0 is the file's plant, so the "replace" and "add" modes
    coincide there. A sympy model written in code (no topology to vary) must declare the
    parameter itself.
    """
    top = params.plant.topology
    key = f"K_{top.port}"
    if key in top.parameter_keys:
        return params, key, False
    if top.port == ROTOR:
        raise ParameterError(
            f"{params.source}: the port is the rotor of an actuator without [bodies], which has no stiffness "
            f"to ground ({key}) for the contact scan to vary; allowed: an actuator file whose port is a body "
            "([bodies.<name>], [sensors] port)")
    if not isinstance(top, Topology):
        raise ParameterError(
            f"{params.source}: the model has no parameter {key} (the port's stiffness to ground, "
            f"which the contact scan replaces by the environment's); allowed: a model whose "
            f"parameter {key} (Nm/rad) is the stiffness acting on the port")
    bodies = tuple(Body(b.name, ground=True) if b.name == top.port else b for b in top.bodies)
    variant = replace(top, bodies=bodies)
    plant = Plant(variant, **params.plant.as_dict(), **{key: 0.0})
    return replace(params, plant=plant), key, True


def _point(loop, P_gain, D_gain, beta, alpha):
    """One gain point as floats (beta, alpha None: the controller's); a contact scan has one."""
    P, D, beta, alpha = loop.gain_points(P_gain, D_gain, beta, alpha)
    for name, v in (("P_gain", P), ("D_gain", D)):
        if v.size != 1:
            raise ParameterError(f"{name} = {v.tolist()!r}; allowed: one value (the contact scan "
                                 "varies the environment stiffness at one gain point)")
    return float(P[0]), float(D[0]), beta, alpha


def _loop(loop, key, K, base) -> ClosedLoop:
    """``loop`` with the environment spring K (Nm/rad) on the port body."""
    return ClosedLoop(loop.params.with_values(**{key: float(K) + base}), loop.options, loop.backend, basis=False)


def _scanned(loop) -> tuple[ClosedLoop, str, bool]:
    """The loop whose port stiffness the scan sets (the plant variant of :func:`contact_params`
    when the port body has no stiffness to ground), the key and whether it was added."""
    params, key, added = contact_params(loop.params)
    return (ClosedLoop(params, loop.options, loop.backend, basis=False) if added else loop), key, added


def _radius(loop, P_gain, D_gain, beta, alpha) -> float:
    return np.abs(np.linalg.eigvals(closed_loop_batch(loop, P_gain, D_gain, beta, alpha)[0][0])).max()


def _excess(loop, P_gain, D_gain, beta, alpha) -> float:
    """Worst corrected phase of Z beyond +-90 deg on the options' frequency grid, as
    :func:`haa_sym.analysis.passivity.passivity` computes it (whatever the loop's stability)."""
    ex, _ = passivity_excess(loop, np.array([P_gain]), np.array([D_gain]), beta, alpha)
    return float(ex[0])


def _scan(loop, key, base, K_env, P_gain, D_gain, beta, alpha, progress, passivity):
    """Spectral radius and (where stable, if ``passivity``) phase excess at every stiffness."""
    # tqdm.auto imports asyncio (about 0.05 s): only a contact scan pays it, not every importer
    from tqdm.auto import tqdm
    rho = np.empty(K_env.size)
    excess = np.full(K_env.size, np.nan)
    for i, K in enumerate(tqdm(K_env, desc="contact stiffness", leave=False,
                               disable=None if progress is None else not progress)):
        lk = _loop(loop, key, K, base)
        rho[i] = _radius(lk, P_gain, D_gain, beta, alpha)
        if passivity and rho[i] < 1:
            excess[i] = _excess(lk, P_gain, D_gain, beta, alpha)
    return rho, excess


@loop_first
def contact_stability(loop, K_env, *, P_gain: float = 0.0, D_gain: float = 0.0, beta: float | None = None,
                      alpha: float | None = None, progress: bool | None = None, mode: str = "replace",
                      blas_threads: int | None = BLAS_THREADS):
    """Stability decision and spectral radius for each environment stiffness ``K_env`` (Nm/rad).

    Returns ``(stable, spectral_radius)`` arrays of ``K_env``'s length, from the eigenvalues of
    the explicit closed loop: every stiffness is a new plant with a single gain point, where an
    eigenvalue solve is cheaper than the exact characteristic-polynomial basis.

    Example
    -------
    >>> K = np.logspace(0, 5, 400)
    >>> stable, rho = contact_stability(ClosedLoop(load_params()), K)       # doctest: +SKIP
    >>> intervals(K, ~stable)                                               # doctest: +SKIP
    [(73.6..., 3418.4...)]                  # the grid points; contact_intervals: 71.84-3441.6
    """
    P_gain, D_gain, beta, alpha = _point(loop, P_gain, D_gain, beta, alpha)
    K_env = gain_array("K_env", K_env).ravel()
    loop, key, _ = _scanned(loop)
    with blas_limits(blas_threads):
        rho, _ = _scan(loop, key, _base(loop.params, key, mode), K_env, P_gain, D_gain, beta, alpha,
                       progress, passivity=False)
    return rho < 1, rho


def _base(params, key, mode):
    if mode not in CONTACT_MODES:
        raise ParameterError(f"mode = {mode!r}; allowed: {list(CONTACT_MODES)} (the environment "
                             f"stiffness replaces {key}, as the paper reads it, or adds to it)")
    return 0.0 if mode == "replace" else float(getattr(params.plant, key))


@dataclass(frozen=True)
class ContactIntervals:
    """Environment stiffnesses (Nm/rad) where the closed loop is unstable, or stable but not
    passive at the port; ends exact.

    ``unstable``: maximal intervals (K_lo, K_hi) of the scanned range with a closed-loop pole
    outside the unit circle; an end inside the range is where the spectral radius crosses 1,
    located by Brent's method to a relative ``rtol``; an end at the range's edge is that edge.
    ``not_passive``: maximal intervals where the loop is stable and the corrected phase of Z
    leaves +-(90 deg + ``passivity_tol_deg``) on the options' frequency grid (None when the scan
    skipped passivity); an end is where the phase excess crosses the tolerance (Brent, same
    ``rtol``), an end of an unstable interval, or the range's edge.
    ``mode`` says whether K_env replaced the port body's ground stiffness (the paper's reading)
    or was added to it; ``K_env``, ``spectral_radius``, ``phase_excess_deg`` (deg beyond +-90,
    NaN where unstable; None when skipped or under ``passivity = "exact"``): the scan that
    bracketed the ends; ``passivity_tol_deg``: the options' tolerance the excess was compared
    with; under ``passivity = "exact"`` the scan's measure is ``dissipation_deficit``
    (dimensionless) and its tolerance ``passivity_tol_exact`` instead (the paper's two None);
    ``ground_added``: the port body of the file has no stiffness to ground, so ``key`` is a new
    one on it (:func:`contact_params`; both modes then scan the same stiffnesses).
    """

    unstable: list
    key: str
    mode: str
    rtol: float
    K_env: np.ndarray = field(repr=False)
    spectral_radius: np.ndarray = field(repr=False)
    not_passive: list | None = None
    phase_excess_deg: np.ndarray | None = field(default=None, repr=False)
    passivity_tol_deg: float | None = None
    ground_added: bool = False
    dissipation_deficit: np.ndarray | None = field(default=None, repr=False)
    passivity_tol_exact: float | None = None

    @property
    def measure(self):
        """``(values, tolerance, name)`` of the scan's passivity measure, whichever test ran
        (None when the scan skipped passivity)."""
        if self.dissipation_deficit is not None:
            return self.dissipation_deficit, self.passivity_tol_exact, "dissipation_deficit"
        if self.phase_excess_deg is not None:
            return self.phase_excess_deg, self.passivity_tol_deg, "phase_excess_deg"
        return None


@loop_first
def contact_intervals(loop, K_range=(1.0, 1e5), *, n_scan: int = 400, P_gain: float = 0.0,
                      D_gain: float = 0.0, beta: float | None = None,
                      alpha: float | None = None, mode: str = "replace", rtol: float = 1e-12,
                      passivity: bool = True, progress: bool | None = None,
                      blas_threads: int | None = BLAS_THREADS) -> ContactIntervals:
    """Where contact with an environment spring K_env (on the port body) destabilises the loop,
    and where the loop stays stable but is not passive at the port.

    The spectral radius, and where it is below 1 the phase excess of Z (the worst corrected phase
    beyond +-90 deg on the options' frequency grid, as :func:`haa_sym.analysis.passivity.passivity`), are
    scanned on ``n_scan`` log-spaced stiffnesses of ``K_range``. Every change of stability
    between neighbours is bracketed and its stiffness located by Brent's method on (spectral
    radius - 1) in log K, to a relative ``rtol`` (default 1e-12, well inside the 1e-9 the
    analysis promises; the radius itself comes from eigenvalues accurate to about 1e-13). Every
    change of passivity between two stable neighbours is located the same way on (phase excess -
    ``passivity_tol_deg``): on a fixed frequency grid the excess is the maximum of finitely many
    functions continuous in K, hence continuous, and Brent's method applies. A passivity change
    that coincides with a change of stability (a stable, non-passive stiffness next to an
    unstable one) ends the non-passive interval at the end of the unstable one: there is nothing
    to decide about passivity in between.

    The passivity ends are exact for the options' frequency grid (``n_omega``, ``omega_min``),
    not for the continuum of frequencies: the excess is a maximum over the grid. Raising
    ``n_omega`` from 1000 to 4000 moved the end by 4.6e-5 relative on the harmonic-drive actuator
    (torque loop alone with its first PI, P_t0 = 0.01954 V/Nm, I_t0 = 0.9205 V/(Nm s), end
    5.28e4 Nm/rad; with the tuned PI of the file that loop has no passivity end: it is not passive
    anywhere it is stable, docs/tune.md) and by 1.2e-5 on HyQ (P_gain 1000, D_gain 9, end
    6.35e5 Nm/rad). Where the excess is flat in K its rounding, not ``rtol``, bounds the end: on
    HyQ at 6.35e5 Nm/rad the excess changes by 2.6e-3 deg per unit of ln K and the sampled
    plant's rounding moves it by up to 1.5e-10 deg (the same in the state-space reference),
    so that end is known to about 1e-7 relative.

    An unstable or non-passive island narrower than the scan step can be missed: raise
    ``n_scan``.

    Parameters
    ----------
    K_range : (float, float)
        Environment stiffnesses, Nm/rad, 0 < K_lo < K_hi.
    mode : {"replace", "add"}
        K_env replaces the port body's ground stiffness (default; the paper: "an environment with
        a stiffness K_L2 between 72 and 3500 Nm/rad") or is added to the file's.
    P_gain, D_gain : float
        Impedance gains (default 0: the torque loop alone, as the paper).
    passivity : bool
        Also find the stable, non-passive intervals (default); False skips the phase sweeps
        (``not_passive`` and ``phase_excess_deg`` are then None).
    blas_threads : int or None
        BLAS threads during the scan (its eigenvalue problems and solves are small; see
        :data:`haa_sym.analysis.sweep.BLAS_THREADS`): measured on this 2-core machine under load, the
        default scan took 7.7 s with OpenBLAS's 2 threads and 4.2 s with 1.

    Examples
    --------
    >>> r = contact_intervals(ClosedLoop(load_params()))                 # doctest: +SKIP
    >>> r.unstable, r.not_passive                                        # doctest: +SKIP
    """
    K_lo, K_hi = (float(v) for v in gain_array("K_env", K_range).ravel()[:2])
    if not 0 < K_lo < K_hi:
        raise ParameterError(f"K_range = {tuple(K_range)!r}; allowed: 0 < K_lo < K_hi (Nm/rad)")
    if isinstance(n_scan, bool) or not isinstance(n_scan, int) or n_scan < 2:
        raise ParameterError(f"n_scan = {n_scan!r}; allowed: an integer >= 2")
    # the scan keeps the stiffness, the radius and the excess of every point (24 B each) and
    # sweeps the frequency grid at one point at a time
    check_memory(24 * n_scan + sweep_bytes(1, loop.options.numerics.n_omega),
                 f"n_scan = {n_scan}: a contact scan of {n_scan} stiffnesses")
    P_gain, D_gain, beta, alpha = _point(loop, P_gain, D_gain, beta, alpha)
    loop, key, added = _scanned(loop)
    base = _base(loop.params, key, mode)
    K = np.logspace(np.log10(K_lo), np.log10(K_hi), n_scan)
    K[0], K[-1] = K_lo, K_hi                  # the range's edges exactly (they may be interval ends)
    with blas_limits(blas_threads):
        r = _locate(loop, key, base, K, P_gain, D_gain, beta, alpha, mode, rtol, passivity, progress)
    return replace(r, ground_added=added)


def _locate(loop, key, base, K, P_gain, D_gain, beta, alpha, mode, rtol, passivity, progress) -> ContactIntervals:
    """The scan on the stiffnesses ``K`` and Brent's method on every bracketed change."""
    # scipy.optimize takes about 0.25 s to import (docs/startup.md): only the commands that locate a root pay it
    from scipy.optimize import brentq
    rho, excess = _scan(loop, key, base, K, P_gain, D_gain, beta, alpha, progress, passivity)
    stable = rho < 1

    def root(g, i):
        return float(np.exp(brentq(g, np.log(K[i]), np.log(K[i + 1]), xtol=1e-300, rtol=rtol)))

    def radius(logK):
        return _radius(_loop(loop, key, np.exp(logK), base), P_gain, D_gain, beta, alpha) - 1.0

    ends = {i: root(radius, i) for i in np.flatnonzero(stable[1:] != stable[:-1])}
    unstable = _runs(float(K[0]), float(K[-1]), ~stable, ends)
    if not passivity:
        return ContactIntervals(unstable, key, mode, rtol, K, rho)
    tol = passivity_tolerance(loop)

    def excess_minus_tol(logK):
        return _excess(_loop(loop, key, np.exp(logK), base), P_gain, D_gain, beta, alpha) - tol

    with np.errstate(invalid="ignore"):
        not_passive = stable & (excess > tol)
    for i in np.flatnonzero(stable[1:] & stable[:-1] & (not_passive[1:] != not_passive[:-1])):
        ends[i] = root(excess_minus_tol, i)
    runs = _runs(float(K[0]), float(K[-1]), not_passive, ends)
    if MEASURES[loop.options.conventions.passivity] == "dissipation_deficit":
        return ContactIntervals(unstable, key, mode, rtol, K, rho, runs, dissipation_deficit=excess,
                                passivity_tol_exact=tol)
    return ContactIntervals(unstable, key, mode, rtol, K, rho, runs, excess, tol)


def _runs(K_lo, K_hi, flag, ends) -> list[tuple[float, float]]:
    """Maximal intervals where the scan's ``flag`` holds, each end the located stiffness
    ``ends[i]`` of the change between samples i and i + 1, or the range's edge."""
    out, start = [], (K_lo if flag[0] else None)
    for i in np.flatnonzero(flag[1:] != flag[:-1]):
        if flag[i + 1]:
            start = ends[i]
        else:
            out.append((start, ends[i]))
            start = None
    if start is not None:
        out.append((start, K_hi))
    return out


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
