"""Coulomb friction in the identification's model: the nonlinear simulation of a log and its
exact sensitivities (issue 23, item 2).

The friction is the simulation's own ``[limits]`` model (:mod:`haa_sym.model.limits`,
docs/simulate.md): on the rotor T = -Fc_m tanh(dtheta_m / v_s) through the plant's ``T_fr``
input column, on a body b T = -Fc_b tanh(dtheta_b / v_s) / J_b on its velocity's row, v_s the
file's ``friction_velocity``. The model is

    dx/dt = A x + B u + W T(x),   T_b = -Fc_b tanh(x[c_b] / v_s),   y = C x + D u,

u held over each interval [t_k, t_k+1) of the log (zero-order hold), the intervals dt_k any
positive numbers (a uniform log is the special case).

**The scheme: exact linear part, friction implicit at each substep's end, extrapolated.** Each
interval is cut into n_k = ceil(dt_k / max_substep) equal substeps h_k; per substep

    x+ = Phi(h) x + Gamma(h) u + Gamma_W(h) T,   T = T(x+),

Phi, Gamma, Gamma_W the exact zero-order hold of A with [B, W] (the linear plant, however stiff,
costs nothing and is exact), the friction torque held over the substep at its value at the end
(nf scalar equations solved by Newton: each is monotone in its T, one root in [-Fc, Fc]). Why
implicit: at stick the smooth model is a viscous slope Fc / v_s, and Fc / (v_s J) h is 10-100 on
a drive's rotor at a 2 ms sample (the RMD X8 SEA: J_m 3.5e-4 kg m^2, Fc_m 0.01 Nm, v_s 0.01
rad/s: 3,000 1/s); the end-point rule damps it as 1 / (1 + slope h), L-stable, where an explicit
stage diverges and the trapezoidal rule rings (ratio -> -1). It is first order: at a velocity
reversal the torque's switch falls, on average, half a substep early. The default (``order`` 2)
runs it twice, at h and h / 2, and takes 2 y(h / 2) - y(h) (Richardson): the mean of that shift
cancels, the stability function 2 / (1 - z/2)^2 - 1 / (1 - z) still goes to 0 for a stiff stick
slope, and the rms error against ``scipy.integrate.solve_ivp`` falls 3.7-3.8x a halving of h
below 0.5 ms on the test's log (docs/identify.md, "Friction and offsets"; what remains is where in a substep a reversal falls).
``max_substep`` (default :data:`DEFAULT_MAX_SUBSTEP`) is the coarse run's; identify chooses it per
fit (:func:`haa_sym.fit.identify.safe_substep`: the longest DEFAULT_MAX_SUBSTEP / 2^k whose
step-doubling error estimate is small on the logs), since the error at a given stick slope
h Fc / (v_s J) differs 30-300x between logs (it accumulates in a free rotor's angle).

**Matrices for every interval length, with exact derivatives.** Every interval has its own
length (a log's own stamps), so the ZOH comes from one eigendecomposition A = V diag(lambda) V^-1
per evaluation: Phi(h) = V diag(e^{lambda h}) V^-1, [Gamma, Gamma_W](h) = V diag(psi(lambda))
V^-1 [B, W] with psi(lambda) = h phi_1(lambda h), each for all intervals at once as one matrix
product of the modes' scalar functions (K, n) with a constant (n, n^2) matrix. The derivatives
along each key (dA, dB, dW exact from CasADi) are the Daleckii-Krein formulas with the first
divided difference split into its nodes (:class:`_Modal`): with X_j the solution of
A X - X A = dA_j off A's eigenbasis diagonal and Dd_j that diagonal,
d e^{A h} = e^{A h} X_j - X_j e^{A h} + h e^{A h} Dd_j and the same for its integral, so in the
shifted sensitivity sigma_j = s_j + X_j x no per-interval matrix depends on the key except
Psi1(h) (X_j [B, W] + d[B, W]_j) (n x (m + nf)): the per-key (K, n, n) matrices, 0.5 s of an
evaluation before, are gone. It divides by lambda_a - lambda_b: two coinciding modes (closer than
:data:`MODE_GAP` of the largest) are refused, and a nearly defective A (eigenvector matrix
condition above :data:`MAX_EIGVEC_COND`) too.

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
from haa_sym.fit.model import PlantModel, plant_derivatives, stamp_grid
from haa_sym.model.drive import DRIVE_KEYS

__all__ = ["Friction", "friction_entries", "simulate_friction", "simulate_friction_stamps", "DEFAULT_MAX_SUBSTEP",
           "MAX_EIGVEC_COND", "is_friction_key"]

#: Longest substep (s) of the friction integration's coarse run (the fine one halves it), and the
#: first one identify's default tries (:func:`haa_sym.fit.identify.safe_substep`). Measured
#: (docs/identify.md): the RMD X8 SEA with Fc_m at stick-slip against solve_ivp, rms 1.0e-3 of each
#: output's peak (the first-order scheme at 0.25 ms, the default before: 9.3e-4), at a third of
#: its substeps on the ITregear chirp.
DEFAULT_MAX_SUBSTEP = 5e-4
#: Condition number of the eigenvector matrix above which the modal formulas are refused.
MAX_EIGVEC_COND = 1e10
#: Smallest distance of two modes, relative to the largest |lambda| (at least 1 1/s), the modal
#: sensitivities accept: they divide by lambda_a - lambda_b (the Sylvester form of the divided
#: difference, :class:`_Modal`), which loses about log10(1 / gap) digits.
MODE_GAP = 1e-8
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
    """(e^w - 1) / w for complex w (1 at w = 0), without cancellation: e^w - 1 as
    expm1(x) cos(y) - 2 sin^2(y / 2) + i e^x sin(y) (w = x + i y), each term accurate to rounding."""
    w = np.asarray(w, complex)
    x, y = w.real, w.imag
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        em1 = np.expm1(x) * np.cos(y) - 2.0 * np.sin(0.5 * y) ** 2 + 1j * (np.exp(x) * np.sin(y))
        return np.where(w == 0, 1.0 + 0j, em1 / np.where(w == 0, 1.0, w))


def _phi_s(w: np.ndarray) -> np.ndarray:
    """int_0^1 tau e^{w tau} d tau = (e^w (w - 1) + 1) / w^2 for complex w: its series
    sum_k w^k / (k! (k + 2)) where |w| < 0.25 (14 terms: 0.25^14 / (14! 16) < 1e-20), the closed
    form elsewhere (e^w (w - 1) + 1 >= 0.03 there: at most 1.5 digits cancel)."""
    w = np.asarray(w, complex)
    small = np.abs(w) < 0.25
    out = np.empty_like(w)
    wl = w[~small]
    with np.errstate(over="ignore", invalid="ignore"):
        out[~small] = (np.exp(wl) * (wl - 1.0) + 1.0) / (wl * wl)
    ws = w[small]
    term, acc = np.ones_like(ws), np.full_like(ws, 0.5)
    # times the reciprocal: numpy divides a complex by a real k as (re, im) * (1 / k) (Smith's
    # rule with a zero imaginary part), the same numbers at a third of the time
    for k in range(1, 14):
        term = term * ws * (1.0 / k)
        acc = acc + term * (1.0 / (k + 2))
    out[small] = acc
    return out


@dataclass(frozen=True)
class _Modal:
    """A's eigenbasis and the keys' constant matrices, once per evaluation.

    With A = V diag(lam) V^-1 and At_j = V^-1 dA_j V: ``X`` (p, n, n) = V R_j V^-1, R_ab =
    At_ab / (lam_a - lam_b) off the diagonal (the solution of A X - X A = dA_j - Dd_j), ``Dd`` =
    V diag(At_aa) V^-1; then exactly (Daleckii-Krein, the first divided difference of exp split
    into its two nodes) d e^{A h} = e^{A h} X - X e^{A h} + h e^{A h} Dd, and for its integral
    d int_0^h e^{A s} ds = Psi1 X - X Psi1 + Psi_s Dd (Psi1 = int_0^h e^{A s} ds, Psi_s =
    int_0^h s e^{A s} ds): no per-interval matrix depends on the key but ``GY`` = Psi1 Y_j,
    Y_j = X_j [B, W] + d[B, W]_j. ``YT``: V^-1 Y_j."""

    lam: np.ndarray
    V: np.ndarray
    Vi: np.ndarray
    BWt: np.ndarray
    YT: np.ndarray
    X: np.ndarray
    Dd: np.ndarray
    A: np.ndarray
    BW: np.ndarray


def _modal(model: PlantModel, fr: Friction, sens: bool) -> _Modal:
    """:class:`_Modal` of ``model`` with the friction columns of ``fr``."""
    A = model.A
    n = A.shape[0]
    BW = np.column_stack([model.B, fr.W])
    lam, V = np.linalg.eig(A)
    cond = np.linalg.cond(V)
    if not cond < MAX_EIGVEC_COND:
        raise ParameterError(f"friction simulation: the plant matrix is nearly defective (eigenvector condition "
                             f"{cond:.3g}); allowed: a plant whose modes are distinct (fit without friction keys)")
    gap = np.where(np.eye(n, dtype=bool), np.inf, np.abs(lam[:, None] - lam[None, :]))
    scale = max(float(np.abs(lam).max()), 1.0)
    if not gap.min() > MODE_GAP * scale:
        raise ParameterError(f"friction simulation: two modes of the plant coincide (|lam_a - lam_b| = {gap.min():.3g} "
                             f"1/s); allowed: a plant whose modes are distinct (fit without friction keys)")
    Vi = np.linalg.inv(V)
    BWt = Vi @ BW
    p = model.dA.shape[0]
    X = np.zeros((p, n, n))
    Dd = np.zeros((p, n, n))
    YT = np.zeros((p, n, BW.shape[1]), complex)
    if sens:
        dBW = np.concatenate([model.dB, fr.dW], axis=2)
        off = ~np.eye(n, dtype=bool)
        diff = np.where(off, lam[:, None] - lam[None, :], 1.0)
        for j in range(p):
            At = Vi @ model.dA[j] @ V
            R = np.where(off, At / diff, 0.0)
            X[j] = (V @ R @ Vi).real
            Dd[j] = ((V * np.diag(At)) @ Vi).real
            YT[j] = Vi @ (X[j] @ BW + dBW[j])
    return _Modal(lam, V, Vi, BWt, YT, X, Dd, A, BW)


def _step_matrices(md: _Modal, h: np.ndarray, sens: bool):
    """Per substep length h (K,): Phi = e^{A h} (K, n, n), G = Psi1 [B, W], Gs = Psi_s [B, W]
    (K, n, mw) and, with ``sens``, GY = Psi1 Y_j (p, K, n, mw); each a product of the modes'
    scalar functions with a constant matrix (one GEMM each)."""
    n, mw = md.BWt.shape
    a = md.lam[None, :] * h[:, None]
    with np.errstate(over="ignore", invalid="ignore"):
        E = np.exp(a)
    psi = h[:, None] * _phi1(a)
    K = h.size
    Phi = (E @ (md.V.T[:, :, None] * md.Vi[:, None, :]).reshape(n, n * n)).real.reshape(K, n, n)
    WG = (md.V.T[:, :, None] * md.BWt[:, None, :]).reshape(n, n * mw)
    G = (psi @ WG).real.reshape(K, n, mw)
    if not (np.all(np.isfinite(Phi)) and np.all(np.isfinite(G))):
        raise ParameterError(f"friction simulation: the plant overflows over an interval of {h.max():.3g} s "
                             "(an unstable mode); allowed: shorter intervals or a stable plant")
    # the kernel reads C-order arrays (a complex array's .real is a strided view)
    Phi, G = np.ascontiguousarray(Phi), np.ascontiguousarray(G)
    if not sens:
        return Phi, G, None, None
    Gs = np.ascontiguousarray(((h[:, None] ** 2 * _phi_s(a)) @ WG).real.reshape(K, n, mw))
    p = md.YT.shape[0]
    WY = (md.V.T[None, :, :, None] * md.YT[:, :, None, :]).transpose(1, 0, 2, 3).reshape(n, p * n * mw)
    GY = np.ascontiguousarray((psi @ WY).real.reshape(K, p, n, mw).transpose(1, 0, 2, 3))
    return Phi, G, Gs, GY


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


def _run_c(f, md, nsub, h, mats, dl, dkey, u, fr: Friction, x0, s0, sens):
    Phi, G, Gs, GY = mats
    K, n = Phi.shape[0], Phi.shape[1]
    m = u.shape[1]
    p = md.X.shape[0] if sens else 0
    X = np.empty((K + 1, n))
    S = np.empty((p, K + 1, n))
    kterms = np.array([np.any(md.Dd[j]) or np.any(md.YT[j]) for j in range(md.X.shape[0])] or [0], np.int32)
    work = np.empty(5 * n)
    dummy = np.zeros(1)
    c = np.ascontiguousarray
    args = [ctypes.c_int(K), ctypes.c_int(n), ctypes.c_int(m), ctypes.c_int(len(fr.Fc)), ctypes.c_int(p),
            _ptr(nsub, ctypes.c_int), _ptr(h), _ptr(Phi), _ptr(G), _ptr(Gs if sens else dummy),
            _ptr(GY if sens else dummy), _ptr(md.Dd), _ptr(md.X), _ptr(c(md.A)), _ptr(c(md.BW)),
            _ptr(dl), ctypes.c_int(-1 if dkey is None else dkey), _ptr(kterms, ctypes.c_int),
            _ptr(u), _ptr(fr.sel, ctypes.c_int), _ptr(fr.Fc), ctypes.c_double(fr.v_s), _ptr(fr.key_index, ctypes.c_int),
            _ptr(x0), _ptr(s0 if sens else dummy), ctypes.c_int(int(sens)), _ptr(X), _ptr(S if sens else dummy),
            _ptr(work)]
    if f(*args):
        raise ParameterError("friction simulation: the implicit friction torque did not converge; allowed: a "
                             "smaller --set friction_velocity ratio or a shorter max_substep")
    return X, S


def _run_python(md, nsub, h, mats, dl, dkey, u, fr: Friction, x0, s0, sens):
    """The kernel's recursion in Python (no C compiler; and the tests' cross-check)."""
    Phi, G, Gs, GY = mats
    K, n = Phi.shape[0], Phi.shape[1]
    m, nf = u.shape[1], len(fr.Fc)
    p = md.X.shape[0] if sens else 0
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
            px = Phi[k] @ x
            a = px + G[k][:, :m] @ u[k]
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
                ut = np.concatenate([u[k], T])
                v = h[k] * px + Gs[k] @ ut
                for j in range(p):
                    pre = Phi[k] @ s[j] + md.Dd[j] @ v + GY[j, k] @ ut
                    if j == dkey:
                        pre = pre + dl[k] * (md.A @ xn + md.BW @ ut)
                    q = np.where(fr.key_index == j, -th, 0.0)
                    rc = pre[c] - md.X[j][c] @ xn
                    dTj = np.linalg.solve(np.eye(nf) - Dg[:, None] * M, Dg * rc + q)
                    s[j] = pre + H @ dTj
            x = xn
        X[k + 1] = x
        if sens:
            S[:, k + 1] = s
    return X, S


def _states(model, fr, md, dt, nsub, u, x0, s0, sens, dlen, dkey, backend, mats=None):
    """The scheme's states X (K + 1, n) at the interval ends and their derivatives S (p, K + 1, n)
    (the kernel's shifted variable undone: s = sigma - X_j x), ``nsub`` substeps per interval."""
    h = dt / nsub
    mats = mats or _step_matrices(md, h, sens)
    f = _kernel() if backend in ("auto", "c") else None
    if backend == "c" and f is None:
        raise ParameterError("friction simulation: backend 'c' without a C compiler; allowed: 'auto', 'python'")
    dl = np.zeros(dt.size) if dlen is None else np.ascontiguousarray(dlen / nsub, float)
    sig0 = (s0 + md.X @ x0) if sens else None
    args = (md, nsub, np.ascontiguousarray(h), mats, dl, dkey, u, fr, x0, sig0, sens)
    X, S = _run_c(f, *args) if f is not None else _run_python(*args)
    if sens:
        S -= np.einsum("jab,kb->jka", md.X, X)
    return X, S


def simulate_friction(model: PlantModel, fr: Friction, dt, u, x0=None, sensitivities: bool = True,
                      max_substep: float = DEFAULT_MAX_SUBSTEP, backend: str = "auto", substeps=None, s0=None,
                      order: int = 2, dlen=None, delay_key: int | None = None, _cache=None):
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
        Longest substep (s) of the coarse run (the extrapolation's second run halves it).
    backend : str
        ``"auto"`` (C when a compiler is found), ``"c"`` or ``"python"``.
    substeps : array (N - 1,) of int, optional
        Substeps per interval of the coarse run (default ceil(dt / max_substep)).
    s0 : array (p, n), optional
        The initial state's derivatives along the keys (default zero: x0 does not depend on them).
    order : int
        2 (default): Richardson's extrapolation 2 y(h / 2) - y(h) of the implicit end-point
        scheme; 1: the scheme alone at h (first order).
    dlen : array (N - 1,), optional
        d (interval length) / d (key ``delay_key``): an interval's ends that move with the delay
        (the delayed command's switches) give +-1; the scheme's exact derivative along it.
    delay_key : int, optional
        The key ``dlen`` belongs to.

    Returns
    -------
    y : array (N, ny)
    dy : array (p, N, ny) or None
    """
    dt = np.asarray(dt, float)
    u = np.ascontiguousarray(u, float)
    N, n = u.shape[0], model.A.shape[0]
    if dt.shape != (N - 1,) or not (np.all(dt > 0) or _cache is not None and np.all(dt >= 0)):
        raise ParameterError(f"friction simulation: {dt.shape} intervals for {N} samples; allowed: N - 1 "
                             "positive intervals")
    if order not in (1, 2):
        raise ParameterError(f"friction simulation: order = {order!r}; allowed: 1, 2")
    nsub = (np.maximum(1, np.ceil(dt / max_substep - 1e-9)) if substeps is None else substeps).astype(np.int32)
    x0 = np.zeros(n) if x0 is None else np.asarray(x0, float)
    p = model.dA.shape[0]
    s0 = np.zeros((p, n)) if s0 is None else np.ascontiguousarray(s0, float)
    md, mats = _cache if _cache is not None else (_modal(model, fr, sensitivities), (None, None))
    ui = np.ascontiguousarray(u[:-1])
    X, S = _states(model, fr, md, dt, nsub, ui, x0, s0, sensitivities, dlen, delay_key, backend, mats[0])
    if order == 2:
        # Richardson: the end-point scheme's error is c h + O(h^2) (L-stable: the extrapolated
        # stability function 2 / (1 - z/2)^2 - 1 / (1 - z) -> 0 for a stiff stick slope)
        X2, S2 = _states(model, fr, md, dt, 2 * nsub, ui, x0, s0, sensitivities, dlen, delay_key, backend,
                         mats[1])
        X, S = 2 * X2 - X, (2 * S2 - S if sensitivities else S)
    y = X @ model.C.T + u @ model.D.T
    if not sensitivities:
        return y, None
    dy = S @ model.C.T + X @ model.dC.transpose(0, 2, 1) + u @ model.dD.transpose(0, 2, 1)
    return y, dy


#: Chord steps of a segment's estimated initial state, from rest: the first is the linear part's
#: estimate (exact without friction), the next correct the stick/slip pattern it changes. Measured
#: (second-pass iterations of Levenberg-Marquardt): the stiffness ramp run 51 (20 segments) 12, 26,
#: 3 with 1, 2, 3 steps; the ITregear chirp 21 and 18 with 2 and 3.
STATE_STEPS = 3
#: A step smaller than this, relative to the segment's weighted outputs, ends them (the linear case)
STATE_STEP_RTOL = 1e-6
#: The later steps leave out the state directions whose free response is below this fraction of
#: the largest (the fast modes': on the ITregear SEA a pair at 1e5 1/s, seen at one stamp): along
#: them the outputs respond to the state through the friction, not as the linear part says (with
#: them the chirp's second pass took 22-24 iterations, without 8). The first step, the rank and
#: Kaufman's basis keep 1e-9 (exact without friction).
STATE_RCOND = 1e-3

def simulate_friction_stamps(model: PlantModel, fr: Friction, t: np.ndarray, u: np.ndarray, *, delay: float = 0.0,
                             delay_key: int | None = None, starts=(0,), estimate=(False,), y=None, weights=None,
                             sensitivities: bool = True, max_substep: float = DEFAULT_MAX_SUBSTEP,
                             order: int = 2):
    """The friction simulation on a log as measured: what :func:`haa_sym.fit.model.simulate_stamps`
    is for the linear model, with the same arguments and returns.

    The log's own stamps ``t`` with the command delayed by ``delay`` and switching inside the
    intervals (the one grid of both paths, :func:`haa_sym.fit.model.stamp_grid`); every segment
    (``starts``) simulated on its own, from rest or, where ``estimate``, from an initial state
    estimated on the weighted output error by :data:`STATE_STEPS` chord (quasi-Newton) steps from
    rest whose matrix is the linear part's free response (simulations without sensitivities); the
    keys' sensitivities at that state, projected onto the complement of the free response's
    directions (variable projection, Kaufman's Jacobian, as the linear path: exact without
    friction, the linear part's directions with it). ``delay_key``: the delay's derivative is the scheme's own, exact: the switches move
    with the delay, so the grid intervals they end or start lengthen or shorten (d length / d delay
    = +-1), each substep's by that over its count, at fixed substep counts.

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
    grid, ug, samp, moves = stamp_grid(t, u, delay, starts, on_stamps=delay_key is not None)
    md = _modal(model, fr, sensitivities)

    def run(g, x0, sens):
        a, b = samp[starts[g]], samp[ends[g] - 1]
        at = samp[starts[g]:ends[g]] - a
        uu = ug[a:b + 1]
        if b == a:                                          # a one-sample segment
            X = np.asarray(x0, float)[None]
            yy = X @ model.C.T + uu @ model.D.T
            if not sens:
                return yy, None
            return yy, np.zeros((p, 1, n)) @ model.C.T + X @ model.dC.transpose(0, 2, 1) + \
                uu @ model.dD.transpose(0, 2, 1)
        dt = np.diff(grid[a:b + 1])
        nsub = np.maximum(1, np.ceil(dt / max_substep - 1e-9)).astype(np.int32)
        # the substeps' matrices once per segment and call: every run below shares them (those
        # with the sensitivities' too, when the call has them)
        key = (g, sensitivities)
        if key not in mats:
            mats[key] = tuple(_step_matrices(md, dt / (k * nsub), sensitivities) for k in (1, 2)[:order]) + (None,)
        dlen = np.diff(moves[a:b + 1].astype(float)) if delay_key is not None else None
        yy, dd = simulate_friction(model, fr, dt, uu, x0=x0, sensitivities=sens, substeps=nsub, order=order,
                                   dlen=dlen, delay_key=delay_key, _cache=(md, mats[key]))
        return yy[at], (None if dd is None else dd[:, at])

    mats = {}
    lam, V, Vi = md.lam, md.V, md.Vi
    CV = model.C @ V
    ys, dys, bases = np.empty((N, ny)), (np.empty((p, N, ny)) if sensitivities else None), {}
    rank = 0
    for g, (s, e) in enumerate(zip(starts, ends)):
        x0 = np.zeros(n)
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
            # a fixed number of chord steps from rest, no line search: the state is then a smooth
            # function of the keys, which Levenberg-Marquardt needs (an iteration run to a
            # tolerance, restarted from the last state and with steps rejected, made the cost
            # depend on the fit's history: on the ITregear chirp 19-27 iterations of the second
            # pass instead of 8, and it stalled at steps of 1e-2 of the outputs until 8 simulations)
            for i in range(STATE_STEPS):
                res = (yw - run(g, x0, False)[0] / w).ravel()
                step = np.linalg.lstsq(Pw, res, rcond=1e-9 if i == 0 else STATE_RCOND)[0]
                x0 = x0 + step
                if np.linalg.norm(Pw @ step) <= STATE_STEP_RTOL * max(np.linalg.norm(yw), 1e-300):
                    break
        if sensitivities:
            ys[s:e], dys[:, s:e] = run(g, x0, True)
        else:
            ys[s:e] = run(g, x0, False)[0]
    if not sensitivities:
        return ys, None, rank
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
