"""Coulomb friction in the identification's model: the nonlinear simulation of a log and its
exact sensitivities (issue 23, item 2).

The friction is the simulation's own ``[limits]`` model (:mod:`haa_sym.model.limits`,
docs/simulate.md): on the rotor T = -Fc_m tanh(dtheta_m / v_s) through the plant's ``T_fr``
input column, on a body b T = -Fc_b tanh(dtheta_b / v_s) / J_b on its velocity's row, v_s the
file's ``friction_velocity``. The model is

    dx/dt = A x + B u + W T(x),   T_b = -Fc_b tanh(x[c_b] / v_s),   y = C x + D u,

u held over each interval [t_k, t_k+1) of the log (zero-order hold), the intervals dt_k any
positive numbers (a uniform log is the special case).

**The scheme: exact linear part, friction implicit at each substep's end.** Each interval is cut
into n_k = ceil(dt_k / max_substep) equal substeps h_k; per substep

    x+ = Phi(h) x + Gamma(h) u + Gamma_W(h) T,   T = T(x+),

Phi, Gamma, Gamma_W the exact zero-order hold of A with [B, W] (the linear plant, however stiff,
costs nothing and is exact), the friction torque held over the substep at its value at the end
(nf scalar equations solved by Newton: each is monotone in its T, one root in [-Fc, Fc]). Why
implicit: at stick the smooth model is a viscous slope Fc / v_s, and Fc / (v_s J) h is 10-100 on
a drive's rotor at a 2 ms sample (the RMD X8 SEA: J_m 3.5e-4 kg m^2, Fc_m 0.01 Nm, v_s 0.01
rad/s: 3,000 1/s); the end-point rule damps it as 1 / (1 + slope h), L-stable, where an explicit
stage diverges and the trapezoidal rule rings (ratio -> -1). It is first order in the friction
torque's change over a substep, which is small while sliding (T ~ +-Fc) and bounded by Fc per
reversal; ``max_substep`` (default :data:`DEFAULT_MAX_SUBSTEP`) sets that error, measured in
docs/identify.md ("Friction and offsets") against ``scipy.integrate.solve_ivp``.

**Matrices for every interval length, with exact derivatives.** Every interval has its own
length (a log's own stamps), so the ZOH comes from one eigendecomposition A = V diag(lambda) V^-1
per evaluation: Phi(h) = V diag(e^{lambda h}) V^-1, [Gamma, Gamma_W](h) = V diag(psi(lambda))
V^-1 [B, W] with psi(lambda) = h phi_1(lambda h); a batched matrix exponential per interval cost
46 s for 17,000 intervals here. The derivatives along each key (dA, dB, dW exact from CasADi)
are the Daleckii-Krein formulas: dPhi = V (F o V^-1 dA V) V^-1 with F_ij = h exp[a_i, a_j]
(a = lambda h; first divided difference of exp), dGamma = V ((Psi o V^-1 dA V) V^-1 [B, W] +
diag(psi) V^-1 [dB, dW]) with Psi_ij = h^2 exp[a_i, a_j, 0] (second divided difference),
evaluated without cancellation (:func:`_dd1`, :func:`_dd2`). A nearly defective A (eigenvector
matrix condition above :data:`MAX_EIGVEC_COND`) is refused: the modal formulas lose accuracy
there.

**The recursion** over samples and substeps (the state, the Newton solve and each key's
sensitivity, the step's exact derivative) is C (``friction_kernel.c``), compiled once like the
generated code (:class:`haa_sym.compiled.generated.Compiler`); without a C compiler the same
recursion runs in Python (same numbers, slow).
"""
from __future__ import annotations

import ctypes
import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from haa_sym.compiled.generated import Compiler, CompilerError, NoCompiler
from haa_sym.errors import ParameterError
from haa_sym.fit.model import PlantModel, plant_derivatives
from haa_sym.model.drive import DRIVE_KEYS

__all__ = ["Friction", "friction_entries", "simulate_friction", "simulate_friction_stamps", "DEFAULT_MAX_SUBSTEP",
           "MAX_EIGVEC_COND", "is_friction_key"]

#: Longest substep (s) of the friction integration: a 2 ms log sample is cut in 8. Measured
#: (docs/identify.md): the RMD X8 SEA with Fc_m at stick-slip, against solve_ivp.
DEFAULT_MAX_SUBSTEP = 2.5e-4
#: Condition number of the eigenvector matrix above which the modal formulas are refused.
MAX_EIGVEC_COND = 1e10
_KERNEL = Path(__file__).with_name("friction_kernel.c")
_NFMAX = 8


def is_friction_key(key: str) -> bool:
    """Whether ``key`` names a Coulomb friction torque of ``[limits]`` (``Fc_m``, ``Fc_<body>``)."""
    return key.startswith("Fc_")


@dataclass(frozen=True)
class Friction:
    """Where friction enters a :class:`~haa_sym.fit.model.PlantModel` and how strong it is.

    ``W (n, nf)``: the columns the torques enter (the model's states; states a model appends
    after the plant's, e.g. a drive lag, get zeros), ``dW (p, n, nf)`` their derivatives along
    the fitted keys, ``sel (nf,)`` the velocity state each opposes, ``Fc (nf,)`` Nm, ``v_s``
    rad/s, ``key_index (nf,)``: the fitted key that is Fc of the entry, or -1, ``names`` the
    entries (``"m"`` or a body)."""

    W: np.ndarray
    dW: np.ndarray
    sel: np.ndarray
    Fc: np.ndarray
    v_s: float
    key_index: np.ndarray
    names: tuple


def friction_entries(plant, keys, inputs, n_model: int, friction: dict, v_s: float) -> Friction:
    """The friction of ``plant`` for a model of ``inputs`` with ``n_model`` states.

    Parameters
    ----------
    plant : Plant
        The plant's parameters (``Params.plant``).
    keys : tuple of str
        The fitted keys (plant keys and ``Fc_*``): the derivatives' first axis.
    inputs : tuple of str
        The log's inputs: with ``current`` first the state ``I_m`` is not in the model (as in
        :func:`haa_sym.fit.model.open_loop_model`).
    n_model : int
        States of the model (the plant's, then any appended).
    friction : dict
        Entry (``"m"`` or a body name) -> Fc (Nm); entries of 0 that are not fitted are left out.
    v_s : float
        ``friction_velocity`` (rad/s).
    """
    top = plant.topology
    states = list(top.state_names)
    keep = [i for i, s in enumerate(states) if not (inputs[0] == "current" and s == "I_m")]
    # the drive's keys (tau_drive, delay_drive) act before the plant: zero derivatives of W
    plant_keys = tuple(k for k in keys if not is_friction_key(k) and k not in DRIVE_KEYS)
    _, B, _, _, dB, _ = plant_derivatives(plant, plant_keys)
    cols, dcols, sel, fc, kidx, names = [], [], [], [], [], []
    for name, value in sorted(friction.items()):
        key = f"Fc_{name}"
        if not value > 0 and key not in keys:
            continue
        if name == "m":
            j = states.index("dtheta_m")
            col, dcol = B[:, 1], dB[:, :, 1]
        else:
            j = states.index(f"dtheta_{name}")
            J = getattr(plant, f"J_{name}")
            col = np.eye(len(states))[j] / J
            dcol = np.zeros((len(plant_keys), len(states)))
            if f"J_{name}" in plant_keys:
                dcol[plant_keys.index(f"J_{name}"), j] = -1.0 / J ** 2
        c = np.zeros(n_model)
        c[:len(keep)] = col[keep]
        d = np.zeros((len(keys), n_model))
        for i, k in enumerate(keys):
            if k in plant_keys:
                d[i, :len(keep)] = dcol[plant_keys.index(k)][keep]
        cols.append(c)
        dcols.append(d)
        sel.append(keep.index(j))
        fc.append(float(value))
        kidx.append(keys.index(key) if key in keys else -1)
        names.append(name)
    if len(names) > _NFMAX:
        raise ParameterError(f"[limits]: {len(names)} friction entries; allowed: at most {_NFMAX}")
    nf = len(names)
    W = np.array(cols).T if nf else np.zeros((n_model, 0))
    dW = np.stack(dcols, axis=-1) if nf else np.zeros((len(keys), n_model, 0))
    return Friction(W, dW, np.array(sel, dtype=np.int32), np.array(fc, float), float(v_s),
                    np.array(kidx, dtype=np.int32), tuple(names))


def _phi1(w: np.ndarray) -> np.ndarray:
    """(e^w - 1) / w for complex w, without cancellation near 0 (Taylor series there)."""
    w = np.asarray(w, complex)
    small = np.abs(w) < 0.5
    out = np.empty_like(w)
    ws = w[small]
    term, acc = np.ones_like(ws), np.ones_like(ws)
    for k in range(2, 20):           # |w|^18 / 19! < 1e-22 at |w| = 0.5
        term = term * ws / k
        acc = acc + term
    out[small] = acc
    wl = w[~small]
    with np.errstate(over="ignore", invalid="ignore"):
        out[~small] = (np.exp(wl) - 1.0) / wl
    return out


def _dd1(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """exp[a, b] = (e^a - e^b) / (a - b) (e^a when a = b) without cancellation or overflow:
    e^p phi_1(q - p) with p the argument of larger real part."""
    swap = b.real > a.real
    p = np.where(swap, b, a)
    q = np.where(swap, a, b)
    with np.errstate(over="ignore", invalid="ignore"):
        return np.exp(p) * _phi1(q - p)


def _dd2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """exp[a, b, 0], the second divided difference of exp: a series when |a|, |b| < 1 (sum of
    h_n(a, b) / (n + 2)!, h_n the complete homogeneous polynomial), else divided by the larger
    of a, b: (exp[a, b] - exp[b, 0]) / a, which does not cancel for |a| >= 1."""
    a, b = np.broadcast_arrays(np.asarray(a, complex), np.asarray(b, complex))
    out = np.empty(a.shape, complex)
    small = np.maximum(np.abs(a), np.abs(b)) < 1.0
    sa, sb = a[small], b[small]
    h = np.ones_like(sa)              # h_0
    bn = np.ones_like(sa)             # b^n
    fact = 2.0
    acc = h / fact
    for n in range(1, 26):            # (n + 1) / (n + 2)! < 1e-26 at n = 25
        bn = bn * sb
        h = sa * h + bn
        fact *= n + 2
        acc = acc + h / fact
    out[small] = acc
    la, lb = a[~small], b[~small]
    big_a = np.abs(la) >= np.abs(lb)
    x = np.where(big_a, la, lb)
    y = np.where(big_a, lb, la)
    with np.errstate(over="ignore", invalid="ignore"):
        out[~small] = (_dd1(x, y) - _dd1(y, np.zeros_like(y))) / x
    return out


def _interval_matrices(model: PlantModel, W, dW, h: np.ndarray, sens: bool):
    """Phi (K, n, n), G = [Gamma, Gamma_W] (K, n, m + nf) at the substep lengths ``h`` (K,) and,
    with ``sens``, their derivatives (p, K, n, n), (p, K, n, m + nf)."""
    A = model.A
    BW = np.column_stack([model.B, W])
    lam, V = np.linalg.eig(A)
    cond = np.linalg.cond(V)
    if not cond < MAX_EIGVEC_COND:
        raise ParameterError(f"friction simulation: the plant matrix is nearly defective (eigenvector condition "
                             f"{cond:.3g}); allowed: a plant whose modes are distinct (fit without friction keys)")
    Vi = np.linalg.inv(V)
    a = lam[None, :] * h[:, None]                                   # (K, n)
    with np.errstate(over="ignore", invalid="ignore"):
        E = np.exp(a)
    psi = h[:, None] * _phi1(a)
    BWt = Vi @ BW                                                   # (n, mw)
    VE = V[None] * E[:, None, :]                                    # V diag(e^a): (K, n, n)
    Vpsi = V[None] * psi[:, None, :]
    Phi = (VE @ Vi).real
    G = (Vpsi @ BWt).real
    if not (np.all(np.isfinite(Phi)) and np.all(np.isfinite(G))):
        raise ParameterError(f"friction simulation: the plant overflows over an interval of {h.max():.3g} s "
                             "(an unstable mode); allowed: shorter intervals or a stable plant")
    if not sens:
        return Phi, G, None, None
    p = model.dA.shape[0]
    F = h[:, None, None] * _dd1(a[:, :, None], a[:, None, :])      # (K, n, n)
    Psi = h[:, None, None] ** 2 * _dd2(a[:, :, None], a[:, None, :])
    dPhi = np.empty((p,) + Phi.shape)
    dG = np.empty((p,) + G.shape)
    dBW = np.concatenate([model.dB, dW], axis=2)                    # (p, n, mw)
    for j in range(p):
        if not (np.any(model.dA[j]) or np.any(dBW[j])):
            # a key acting elsewhere (a friction torque, the delay, an initial state's direction)
            dPhi[j], dG[j] = 0.0, 0.0
            continue
        At = Vi @ model.dA[j] @ V
        dPhi[j] = (V @ (F * At) @ Vi).real
        dG[j] = (V @ (Psi * At) @ BWt + Vpsi @ (Vi @ dBW[j])).real
    return Phi, G, dPhi, dG


@functools.lru_cache(maxsize=1)
def _kernel():
    """The compiled recursion, or None without a C compiler (the Python loop then runs)."""
    try:
        lib = ctypes.CDLL(str(Compiler().build(_KERNEL, ("haa_fit_friction",))))
    except (NoCompiler, CompilerError):
        return None
    f = lib.haa_fit_friction
    f.restype = ctypes.c_int
    return f


def _ptr(a, kind=ctypes.c_double):
    return a.ctypes.data_as(ctypes.POINTER(kind))


def _run_c(f, nsub, Phi, G, dPhi, dG, u, fr: Friction, x0, s0, sens):
    K, n = Phi.shape[0], Phi.shape[1]
    m = u.shape[1]
    p = dPhi.shape[0] if sens else 0
    X = np.empty((K + 1, n))
    S = np.empty((p, K + 1, n))
    work = np.empty(3 * n)
    dummy = np.zeros(1)
    args = [ctypes.c_int(K), ctypes.c_int(n), ctypes.c_int(m), ctypes.c_int(len(fr.Fc)), ctypes.c_int(p),
            _ptr(nsub, ctypes.c_int), _ptr(Phi), _ptr(G), _ptr(dPhi if sens else dummy), _ptr(dG if sens else dummy),
            _ptr(u), _ptr(fr.sel, ctypes.c_int), _ptr(fr.Fc), ctypes.c_double(fr.v_s), _ptr(fr.key_index, ctypes.c_int),
            _ptr(x0), _ptr(s0 if sens else dummy), ctypes.c_int(int(sens)), _ptr(X), _ptr(S if sens else dummy),
            _ptr(work)]
    if f(*args):
        raise ParameterError("friction simulation: the implicit friction torque did not converge; allowed: a "
                             "smaller --set friction_velocity ratio or a shorter max_substep")
    return X, S


def _run_python(nsub, Phi, G, dPhi, dG, u, fr: Friction, x0, s0, sens):
    """The kernel's recursion in Python (no C compiler; and the tests' cross-check)."""
    K, n = Phi.shape[0], Phi.shape[1]
    m, nf = u.shape[1], len(fr.Fc)
    p = dPhi.shape[0] if sens else 0
    X = np.empty((K + 1, n))
    S = np.empty((p, K + 1, n))
    X[0] = x0
    if sens:
        S[:, 0] = s0
    T = np.zeros(nf)
    c = fr.sel
    tol = fr.Fc.sum() if fr.Fc.sum() > 0 else 1.0
    for k in range(K):
        x = X[k].copy()
        s = S[:, k].copy() if sens else None
        H = G[k][:, m:]
        M = H[c, :]
        for _ in range(nsub[k]):
            a = Phi[k] @ x + G[k][:, :m] @ u[k]
            for _it in range(100):
                th = np.tanh((a[c] + M @ T) / fr.v_s)
                Fv = T + fr.Fc * th
                nrm = np.abs(Fv).sum()
                if nrm <= 1e-15 * tol:
                    break
                Jm = np.eye(nf) + (fr.Fc / fr.v_s * (1 - th ** 2))[:, None] * M
                dT = np.linalg.solve(Jm, -Fv)
                lam = 1.0
                for _t in range(60):
                    T1 = T + lam * dT
                    if np.abs(T1 + fr.Fc * np.tanh((a[c] + M @ T1) / fr.v_s)).sum() < nrm:
                        break
                    lam *= 0.5
                moved = np.abs(T1 - T).sum()
                T = T1
                if moved <= 1e-16 * tol:
                    break
            th = np.tanh((a[c] + M @ T) / fr.v_s)
            T = -fr.Fc * th
            Dg = -fr.Fc / fr.v_s * (1 - th ** 2)
            xn = a + H @ T
            if sens:
                for j in range(p):
                    r = Phi[k] @ s[j] + dPhi[j, k] @ x + dG[j, k][:, :m] @ u[k] + dG[j, k][:, m:] @ T
                    q = np.where(fr.key_index == j, -th, 0.0)
                    dTj = np.linalg.solve(np.eye(nf) - Dg[:, None] * M, Dg * r[c] + q)
                    s[j] = r + H @ dTj
            x = xn
        X[k + 1] = x
        if sens:
            S[:, k + 1] = s
    return X, S


def simulate_friction(model: PlantModel, fr: Friction, dt, u, x0=None, sensitivities: bool = True,
                      max_substep: float = DEFAULT_MAX_SUBSTEP, backend: str = "auto", substeps=None, s0=None,
                      matrices=None):
    """Outputs and their sensitivities of the model with Coulomb friction, on a log's intervals.

    Parameters
    ----------
    model : PlantModel
        The continuous linear model and its derivatives along the fitted keys
        (:func:`haa_sym.fit.model.open_loop_model`); a fitted ``Fc_*`` key has zero derivatives there.
    fr : Friction
        :func:`friction_entries` of the same keys.
    dt : array (N - 1,)
        The intervals t_k+1 - t_k (s), each > 0.
    u : array (N, m)
        The inputs at the samples, u[k] held over [t_k, t_k+1).
    x0 : array (n,), optional
        The initial state (default rest).
    sensitivities : bool
        Also return dy / dp.
    max_substep : float
        Longest substep (s).
    backend : str
        ``"auto"`` (C when a compiler is found), ``"c"`` or ``"python"``.
    substeps : array (N - 1,) of int, optional
        Substeps per interval (default ceil(dt / max_substep)).
    s0 : array (p, n), optional
        The initial state's derivatives along the keys (default zero: x0 does not depend on them).
    matrices : tuple, optional
        (Phi, G, dPhi, dG) of these substeps (:func:`_interval_matrices`), when the caller has them.

    Returns
    -------
    y : array (N, ny)
    dy : array (p, N, ny) or None
    """
    dt = np.asarray(dt, float)
    u = np.ascontiguousarray(u, float)
    N, n = u.shape[0], model.A.shape[0]
    if dt.shape != (N - 1,) or not np.all(dt > 0):
        raise ParameterError(f"friction simulation: {dt.shape} intervals for {N} samples; allowed: N - 1 "
                             "positive intervals")
    nsub = (np.maximum(1, np.ceil(dt / max_substep - 1e-9)) if substeps is None else substeps).astype(np.int32)
    h = dt / nsub
    Phi, G, dPhi, dG = matrices or _interval_matrices(model, fr.W, fr.dW, h, sensitivities)
    x0 = np.zeros(n) if x0 is None else np.asarray(x0, float)
    p = model.dA.shape[0]
    s0 = np.zeros((p, n)) if s0 is None else np.ascontiguousarray(s0, float)
    f = _kernel() if backend in ("auto", "c") else None
    if backend == "c" and f is None:
        raise ParameterError("friction simulation: backend 'c' without a C compiler; allowed: 'auto', 'python'")
    args = (nsub, np.ascontiguousarray(Phi), np.ascontiguousarray(G),
            np.ascontiguousarray(dPhi) if sensitivities else None, np.ascontiguousarray(dG) if sensitivities else None,
            np.ascontiguousarray(u[:-1]), fr, x0, s0, sensitivities)
    X, S = _run_c(f, *args) if f is not None else _run_python(*args)
    y = X @ model.C.T + u @ model.D.T
    if not sensitivities:
        return y, None
    dy = S @ model.C.T + X @ model.dC.transpose(0, 2, 1) + u @ model.dD.transpose(0, 2, 1)
    return y, dy


#: Gauss-Newton steps of a segment's estimated initial state at most (friction makes the outputs
#: nonlinear in it; from rest the first step is the linear estimate, the next ones correct the
#: stick/slip pattern it changes), and the size of a step that ends them, relative to the
#: segment's weighted outputs (1e-6: far below the 1 % noise, so the fit's cost does not see it)
MAX_STATE_STEPS = 8
STATE_STEP_RTOL = 1e-6


def _stamp_grid(t: np.ndarray, u: np.ndarray, delay: float, starts, max_substep: float):
    """The simulation grid of a log's own stamps ``t`` with its first (command) input column delayed
    by ``delay`` (s): the stamps and the delayed command's switches t_j + delay inside a segment's
    span, the inputs on each grid interval (the command as the motor gets it, held from before a
    segment's start into it), and the substeps of each grid interval (ceil(length / max_substep)).
    The same grid as :func:`haa_sym.fit.model.simulate_stamps`' (its rule: a switch within 1e-9
    median periods of a stamp is the stamp).

    Returns
    -------
    grid (G,), ug (G, m), samp (N,) grid positions of the stamps, nsub (G - 1,) int.
    """
    N = t.size
    starts = np.asarray(starts, int)
    ends = np.append(starts[1:], N)
    tol = 1e-9 * float(np.median(np.diff(t))) if N > 1 else 0.0
    sw = t + delay
    seg_sw = np.searchsorted(t[starts], sw, side="right") - 1
    keep = (seg_sw >= 0) & (sw < t[np.maximum(ends[np.maximum(seg_sw, 0)] - 1, 0)] - tol)
    near = np.searchsorted(t, sw)
    on_stamp = (np.abs(t[np.clip(near, 0, N - 1)] - sw) <= tol) | (np.abs(t[np.clip(near - 1, 0, N - 1)] - sw) <= tol)
    sw = sw[keep & ~on_stamp & (delay > 0)]
    grid = np.concatenate([t, sw])
    order = np.argsort(grid, kind="stable")
    grid = grid[order]
    samp = np.flatnonzero(order < N)
    stamp_of = np.searchsorted(t, grid + tol, side="right") - 1
    cmd_of = np.clip(np.searchsorted(t, grid - delay + tol, side="right") - 1, 0, N - 1)
    ug = u[stamp_of].copy()
    ug[:, 0] = u[cmd_of, 0]
    nsub = np.maximum(1, np.ceil(np.diff(grid) / max_substep - 1e-9)).astype(np.int32)
    return grid, ug, samp, nsub


def simulate_friction_stamps(model: PlantModel, fr: Friction, t: np.ndarray, u: np.ndarray, *, delay: float = 0.0,
                             delay_key: int | None = None, starts=(0,), estimate=(False,), y=None, weights=None,
                             sensitivities: bool = True, max_substep: float = DEFAULT_MAX_SUBSTEP,
                             state_cache: dict | None = None):
    """The friction simulation on a log as measured: what :func:`haa_sym.fit.model.simulate_stamps`
    is for the linear model, with the same arguments and returns.

    The log's own stamps ``t`` with the command delayed by ``delay`` and switching inside the
    intervals (:func:`_stamp_grid`); every segment (``starts``) simulated on its own, from rest or,
    where ``estimate``, from an initial state estimated on the weighted output error by a chord
    (quasi-Newton) iteration whose matrix is the linear part's free response (at most
    :data:`MAX_STATE_STEPS` simulations without sensitivities; a step that raises the cost is
    quartered); the keys' sensitivities at that state, projected onto the complement of the free
    response's directions (variable projection, Kaufman's Jacobian, as the linear path: exact
    without friction, the linear part's directions with it). ``delay_key``: the
    delay's derivative by a forward difference of step 1e-4 ``delay`` (at least 1e-7 s) at the
    estimated states held fixed, on the same substeps (a count that changed would change the
    scheme's error by more than the difference measures); the recursion's own derivative would
    need the command's switch inside a substep.

    ``state_cache``: a dict kept by the caller between calls on one log: each estimated state
    starts from the last one found (the fit's next point is near; the iteration ends at the same
    minimum, in fewer steps).

    Returns
    -------
    y_model : (N, ny); dy : (p, N, ny) or None; rank : int, initial-state values estimated.
    """
    N, n = t.size, model.A.shape[0]
    ny = model.C.shape[0]
    p = model.dA.shape[0]
    starts = np.asarray(starts, int)
    ends = np.append(starts[1:], N)
    w = np.ones(ny) if weights is None else np.asarray(weights, float)

    def segments(d, nsub_of=None):
        grid, ug, samp, nsub = _stamp_grid(t, u, d, starts, max_substep)
        if nsub_of is not None and nsub_of.shape == nsub.shape:
            # the delay's difference: the same substeps as the grid it perturbs (a count that moved
            # by one would change the scheme's error by more than the difference measures)
            nsub = nsub_of
        out = []
        for s, e in zip(starts, ends):
            a, b = samp[s], samp[e - 1]
            out.append((np.diff(grid[a:b + 1]), ug[a:b + 1], nsub[a:b], samp[s:e] - a))
        return out, nsub

    def run(seg, x0, mdl, frc, sens, s0=None, mats=None):
        dt, ug, nsub, at = seg
        if dt.size == 0:                                    # a one-sample segment
            X = np.asarray(x0, float)[None]
            yy = X @ mdl.C.T + ug @ mdl.D.T
            if not sens:
                return yy, None
            S = (np.zeros((mdl.dA.shape[0], n)) if s0 is None else s0)[:, None]
            return yy, S @ mdl.C.T + X @ mdl.dC.transpose(0, 2, 1) + ug @ mdl.dD.transpose(0, 2, 1)
        yy, dd = simulate_friction(mdl, frc, dt, ug, x0=x0, sensitivities=sens, max_substep=max_substep,
                                   substeps=nsub, s0=s0, matrices=mats)
        return yy[at], (None if dd is None else dd[:, at])

    segs, nsub0 = segments(delay)
    lam, V = np.linalg.eig(model.A)
    Vi = np.linalg.inv(V)
    CV = model.C @ V
    x0s, ys, dys, bases = [], np.empty((N, ny)), (np.empty((p, N, ny)) if sensitivities else None), {}
    rank = 0
    for g, (seg, s, e) in enumerate(zip(segs, starts, ends)):
        # the substeps' matrices once per segment: every run below shares them
        mats = _interval_matrices(model, fr.W, fr.dW, seg[0] / seg[2], sensitivities) if seg[0].size else None
        x0 = np.zeros(n)
        if estimate[g] and state_cache is not None and state_cache.get(g) is not None:
            x0 = state_cache[g].copy()
        if estimate[g]:
            # the state's directions: the linear part's free response C e^{A (t_k - t_s)} at the
            # segment's stamps (exact without friction; with it, the chord of a quasi-Newton
            # iteration, and Kaufman's basis)
            tk = t[s:e] - t[s]
            Psi = np.einsum("oa,ka,as->kos", CV, np.exp(np.outer(tk, lam)), Vi).real        # (len, ny, n)
            Pw = (Psi / w[None, :, None]).reshape(-1, n)
            U, sv, _ = np.linalg.svd(Pw, full_matrices=False)
            r = int(np.sum(sv > 1e-9 * max(sv.max(), 1e-300)))
            bases[g] = U[:, :r]
            rank += r
            yw = y[s:e] / w
            best = None                 # (cost, x0) of the best state simulated
            for _ in range(MAX_STATE_STEPS):
                res = (yw - run(seg, x0, model, fr, False, None, mats)[0] / w).ravel()
                cost = float(res @ res)
                if best is not None and not cost < best[0]:
                    # the outputs are nonlinear in the state (friction): a step that raised the
                    # cost is quartered from the best state instead
                    x0 = best[1] + (x0 - best[1]) / 4
                    continue
                best = (cost, x0)
                step = np.linalg.lstsq(Pw, res, rcond=1e-9)[0]
                if np.linalg.norm(Pw @ step) <= STATE_STEP_RTOL * max(np.linalg.norm(yw), 1e-300):
                    break
                x0 = x0 + step
            x0 = best[1]
        x0s.append(x0)
        if estimate[g] and state_cache is not None:
            state_cache[g] = x0
        if sensitivities:
            ys[s:e], dys[:, s:e] = run(seg, x0, model, fr, True, None, mats)
        else:
            ys[s:e] = run(seg, x0, model, fr, False, None, mats)[0]
    if not sensitivities:
        return ys, None, rank
    if delay_key is not None:
        # a forward difference: its error, about h / delay = 1e-4 of the derivative, is far inside
        # what the Jacobian needs (Levenberg-Marquardt's steps and the intervals' 1e-2)
        h = max(1e-4 * delay, 1e-7)
        sg = segments(delay + h, nsub0)[0]
        yh = np.concatenate([run(sg[g], x0s[g], model, fr, False)[0] for g in range(len(starts))])
        dys[delay_key] = (yh - ys) / h
    for g, U in bases.items():                               # Kaufman: the initial state's directions out
        s, e = starts[g], ends[g]
        D = (dys[:, s:e] / w).reshape(p, -1)
        D -= (D @ U) @ U.T
        dys[:, s:e] = D.reshape(p, e - s, ny) * w
    return ys, dys, rank


def check_step(value: float, name: str) -> float:
    """``max_substep`` validated (s, > 0)."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ParameterError(f"{name} = {value!r}; allowed: a number > 0 (s)")
    return float(value)
