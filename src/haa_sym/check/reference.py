"""Independent reference: the closed loop by block interconnection (numpy and scipy.signal).

Used by the tests, the benchmarks and the reproduction's cross-check to check the evaluators
(:class:`haa_sym.ClosedLoop`, which work on the characteristic polynomial, on loop algebra in the
frequency domain and on :mod:`haa_sym.loop.statespace`). It is built from the parameters and the loop
options alone, with its own algebra:

* the plant: the continuous state space of the actuator (the generated or compiled plant function, the one
  thing it shares with the evaluators; the tests check that against an independent assembly of
  the equations of motion), sampled by ``scipy.signal.cont2discrete(..., "zoh")``; the rows of
  the rotor-side sensors of a chain (the current estimate k_t N I_m, the motor-side encoder
  theta_m / N) are assembled here from the state names, not read from the plant function; the
  drive (``[drive]``: lag and dead time on the command) by its own construction, a lag block in
  series and a fast-rate lifting of the delay on a sub-step grid (:func:`_drive_plant`), not by
  :mod:`haa_sym.loop.plant`'s lag state and modified z-transform;
* the velocity estimate (its own table :data:`VELOCITY_ESTIMATES`, keyed by the names of the
  registry :mod:`haa_sym.model.filters`): the average as an FIR filter; the low-pass filters as the
  backward difference followed by the analog prototype w_c/(s + w_c) or
  w_c^2/(s^2 + sqrt(2) w_c s + w_c^2) realised in state space and mapped by
  ``scipy.signal.cont2discrete(..., "bilinear")``; the
  PI's integral Ts/(1 - z^-1) and the delay z^-d; transfer functions realised by
  ``scipy.signal.tf2ss``;
* velocity compensation VC = alpha N/k_t (R B_m + k_t k_w) (Eq. 6) from the parameters (an
  actuator written in code as a sympy model: the VC0 it declares);
* the static part (impedance law Eq. 8, PI gains Eq. 7, compensation, the sums) as an
  interconnection matrix u = K y + E w of the blocks' outputs y and the external inputs w,
  closed by y = (I - D K)^-1 (C x + D E w), as python-control's ``interconnect`` does.

Closed-loop inputs ``[T_dist, r]`` (``r`` injected at the cut point), outputs
``[T_meas, theta, port velocity, y]`` where ``y`` returns to the cut point with negative sign.
The functions take a ``ClosedLoop`` only to read its ``params`` and ``options``.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from haa_sym.errors import ParameterError
from haa_sym.loop.plant import continuous_plant
from haa_sym.model.actuator import CURRENT, ROTOR, Topology
from haa_sym.model.structures import get as get_structure

__all__ = ["closed_loop_matrices", "plant_matrices", "closed_loop_eigenvalues", "spectral_radius", "frequency_response",
           "VELOCITY_ESTIMATES", "register_velocity_estimate"]


def _own_output_row(plant, cont, name):
    """The reference's own row of a rotor-side sensor of a chain, assembled from the state
    names and the motor's parameters (not read from the plant function): the current estimate
    k_t N I_m (``[sensors] torque = "current"``, both torque outputs), the motor-side encoder
    theta_m / N (``encoder = "rotor"``) and the rotor's port velocity dtheta_m / N (``port =
    "rotor"``, an actuator without bodies). None for every other output."""
    top = plant.topology
    if not isinstance(top, Topology):
        return None
    row = np.zeros(len(cont.state_names))
    if name in ("T_sensor", "T_sensor_spring") and top.sensor == CURRENT:
        row[cont.state_names.index("I_m")] = plant.k_t * plant.N
    elif name == "theta_encoder" and top.encoder == ROTOR:
        row[cont.state_names.index("theta_m")] = 1.0 / plant.N
    elif name == f"dtheta_{ROTOR}":                  # a rotor-only actuator's port velocity
        row[cont.state_names.index("dtheta_m")] = 1.0 / plant.N
    else:
        return None
    return row


def _zoh_plant(params, outputs):
    """The sampled plant as the reference builds it: ``(A, B, C, D)`` at Ts, inputs ``[V_m,
    T_dist]``, the rows ``outputs``; with the drive of ``params.drive`` when it has one
    (:func:`_drive_plant`)."""
    # scipy.signal takes about 0.7 s to import (docs/startup.md): only the cross-check pays it
    from scipy.signal import cont2discrete
    cont = continuous_plant(params.plant)
    C = np.array([cont.C[cont.output_names.index(o)] if (own := _own_output_row(params.plant, cont, o)) is None
                  else own for o in outputs])
    B = cont.B[:, [0, 2]]                                # V_m, T_dist
    A = cont.A
    if get_structure(params.controller.structure).command == "current":
        # the current imposed: the electrical equation dropped, the current's column of A (the
        # motor torque k_t N I_m on the mechanics) the command's; a sensor row of I_m reads nothing
        i = cont.state_names.index("I_m")
        B = np.delete(np.column_stack([A[:, i], B[:, 1]]), i, axis=0)
        A, C = np.delete(np.delete(A, i, axis=0), i, axis=1), np.delete(C, i, axis=1)
    drive = params.drive
    if drive.tau_drive > 0 or drive.delay_drive > 0:
        return _drive_plant(A, B, C, params.controller.Ts, drive.tau_drive, drive.delay_drive)
    Ad, Bd, Cd, Dd, _ = cont2discrete((A, B, C, np.zeros((len(outputs), 2))),
                                      params.controller.Ts, method="zoh")
    return Ad, Bd, Cd, Dd


def plant_matrices(params, outputs=("T_sensor", "theta_encoder")):
    """The reference's sampled plant ``(A, B, C, D)`` (inputs ``[V_m, T_dist]``, rows
    ``outputs``), drive included: what the tests compare ``ClosedLoop.plant`` with."""
    return _zoh_plant(params, list(outputs))


#: The largest number of sub-steps per sample the reference lifts a drive's delay on.
MAX_SUBSTEPS = 1000


def _substeps(delay: float, Ts: float) -> tuple[int, int]:
    """``(M, D)``: the fewest sub-steps M <= MAX_SUBSTEPS of Ts with ``delay = D Ts / M`` exactly
    (within 1e-9 of a sub-step).

    Raises
    ------
    ParameterError
        No such M: the reference (and so a cross-check) cannot build this delay exactly.
    """
    from fractions import Fraction
    q = Fraction(delay / Ts).limit_denominator(MAX_SUBSTEPS)
    if abs(float(q) - delay / Ts) > 1e-9 * max(1.0, delay / Ts):
        raise ParameterError(
            f"delay_drive = {delay!r} s: the independent reference lifts the drive's delay on sub-steps "
            f"Ts/M (Ts = {Ts!r} s), and this delay is no whole number of them for any M <= {MAX_SUBSTEPS}; "
            f"allowed for a cross-check: a multiple of Ts/{MAX_SUBSTEPS} (the analyses themselves take any delay)")
    return q.denominator, q.numerator


def _drive_plant(A, B, C, Ts, tau, delay):
    """The sampled plant behind the drive, by fast-rate lifting (independent of
    :mod:`haa_sym.loop.plant`'s lag state and modified z-transform).

    1. The lag 1/(tau s + 1) is a block of its own (``scipy.signal.tf2ss``) connected in series
       in front of the plant's command input (column 0 of ``B``); the torque input (column 1)
       bypasses it.
    2. The sample Ts is cut into M sub-steps h = Ts/M, M the fewest with the delay a whole
       number D of sub-steps (:func:`_substeps`: 137 of Ts/100 for 1.37 Ts, 2 of Ts/5 for
       0.4 Ts). The series system is sampled at h by ``scipy.signal.cont2discrete(..., "zoh")``.
    3. Over one sample k the drive's output at sub-step i is the command of the sample that was
       held D sub-steps earlier: ``u[k - q]``, q = ceil((D - i)/M) (0: the current command).
       The M sub-steps are stepped one by one, each a linear map of the sample's start state,
       the held past commands u[k-1] .. u[k-L] (L = ceil(D/M)) and the inputs (u[k], T_dist[k]);
       their product is the sampled plant with the past commands as states (a shift register).

    Exact (no approximation) for a delay on the sub-step grid; the rounding of M products is
    what separates it from the modified z-transform (about 1e-13 measured, tests/test_loop_drive.py).
    """
    from scipy.signal import cont2discrete, tf2ss
    n, m = B.shape
    if tau > 0:
        a_l, b_l, c_l, d_l = tf2ss([1.0], [tau, 1.0])
        k = a_l.shape[0]
        A = np.block([[A, B[:, :1] @ c_l], [np.zeros((k, n)), a_l]])
        B = np.vstack([np.hstack([B[:, :1] @ d_l, B[:, 1:]]), np.hstack([b_l, np.zeros((k, m - 1))])])
        C = np.hstack([C, np.zeros((C.shape[0], k))])
        n += k
    M, D = _substeps(delay, Ts) if delay > 0 else (1, 0)
    Ad, Bd, *_ = cont2discrete((A, B, C, np.zeros((C.shape[0], m))), Ts / M, method="zoh")
    L = -(-D // M)
    # a row of the sub-step state over [x (n), u[k-1] .. u[k-L] (L), u[k], T_dist[k]]
    width = n + L + m
    X = np.zeros((n, width))
    X[:, :n] = np.eye(n)
    for i in range(M):
        q = -(-(D - i) // M) if i < D else 0
        col = n + q - 1 if q else n + L                  # the held command the drive gives now
        U = np.zeros((m, width))
        U[0, col] = 1.0
        U[1:, n + L + 1:] = np.eye(m - 1)
        X = Ad @ X + Bd @ U
    Phi = np.zeros((n + L, n + L))
    Gam = np.zeros((n + L, m))
    Phi[:n], Gam[:n] = X[:, :n + L], X[:, n + L:]
    if L:
        Gam[n, 0] = 1.0                                  # u[k-1] at k+1 is u[k]
        Phi[n + 1:, n:n + L - 1] = np.eye(L - 1)         # the rest shift by one sample
    return Phi, Gam, np.hstack([C, np.zeros((C.shape[0], L))]), np.zeros((C.shape[0], m))


def _vc0(plant) -> float:
    """Eq. (6) at alpha = 1, N/k_t (R B_m + k_t k_w), from the motor's parameters of a chain; an
    actuator written in code (haa_sym.symbolic.model) declares its own VC0, read from its plant
    function (the one number shared with the evaluators then, besides the plant)."""
    if isinstance(plant.topology, Topology):
        return plant.N / plant.k_t * (plant.R * plant.B_m + plant.k_t * plant.k_w)
    return continuous_plant(plant).VC0


def _tf_block(b, a):
    """(A, B, C, D) of b(z^-1)/a(z^-1) (coefficients in powers of z^-1), by scipy's tf2ss."""
    from scipy.signal import tf2ss
    b, a = np.atleast_1d(np.asarray(b, float)), np.atleast_1d(np.asarray(a, float))
    if len(a) == 1 and len(b) == 1:
        return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[b[0] / a[0]]])
    n = max(len(a), len(b))
    b = np.concatenate([b, np.zeros(n - len(b))])
    a = np.concatenate([a, np.zeros(n - len(a))])
    return tf2ss(b, a)


def _average(ctrl):
    """The average of N_av first differences as an FIR filter."""
    N, Ts = ctrl.N_av, ctrl.Ts
    b = np.zeros(N + 1)
    b[0], b[N] = 1 / (N * Ts), -1 / (N * Ts)
    return [_tf_block(b, np.r_[1.0, np.zeros(N)])]


def _analog_lowpass(num, den):
    """The backward difference followed by the analog prototype num(s)/den(s) (descending powers,
    functions of w_c) mapped by the bilinear transform."""
    def realise(ctrl):
        from scipy.signal import cont2discrete, tf2ss
        Ts, w_c = ctrl.Ts, 2 * math.pi * ctrl.f_c
        # the analog prototype in state space, then the bilinear map in state-space form (well
        # conditioned at fast sampling, where the discrete polynomial's roots crowd at z = 1)
        A, B, C, D = tf2ss(num(w_c), den(w_c))
        # scale the states (diagonal balancing of [[A, B], [C, D]]): the companion form's states
        # differ by powers of w_c, which costs digits in the frequency responses near Nyquist
        _, (scale, _) = scipy.linalg.matrix_balance(np.block([[A, B], [C, D]]), permute=False, separate=True)
        s = scale[:A.shape[0]]
        A, B, C = A * s[None, :] / s[:, None], B / s[:, None], C * s[None, :]
        lowpass = cont2discrete((A, B, C, D), Ts, method="bilinear")[:4]
        return [_tf_block([1 / Ts, -1 / Ts], [1.0]), lowpass]
    return realise


# The reference's own realisation of every velocity filter of haa_sym.model.filters, by name: ctrl (a
# haa_sym.model.params.Controller) -> SISO blocks (A, B, C, D) in series, theta -> v_F. Deliberately a
# table of its own rather than a field of the registry's entries: the registry is what this
# module checks, so its entries never carry (or call) the reference's algebra, and nothing here
# reads their transfer functions; tests/test_model_filters.py checks that both tables have the same keys.
VELOCITY_ESTIMATES = {
    "average": _average,
    "lowpass1": _analog_lowpass(lambda w_c: [w_c], lambda w_c: [1.0, w_c]),
    "butterworth2": _analog_lowpass(lambda w_c: [w_c ** 2], lambda w_c: [1.0, math.sqrt(2) * w_c, w_c ** 2]),
}


def register_velocity_estimate(name: str, realise) -> None:
    """Add the reference's realisation of a filter registered in :mod:`haa_sym.model.filters`:
    ``realise(ctrl)`` -> list of SISO ``(A, B, C, D)`` in series, theta -> velocity."""
    if name in VELOCITY_ESTIMATES:
        raise ValueError(f"the reference already realises velocity_filter = {name!r}")
    VELOCITY_ESTIMATES[name] = realise


def _velocity_estimate_blocks(ctrl):
    """The velocity estimate theta -> v_F as blocks in series: [(name, (A,B,C,D), y, u)], and
    the series links {input: output of the block before}."""
    try:
        realise = VELOCITY_ESTIMATES[ctrl.velocity_filter]
    except KeyError:
        raise LookupError(f"the reference has no realisation of velocity_filter = {ctrl.velocity_filter!r}; "
                          "add one with haa_sym.reference.register_velocity_estimate") from None
    parts = realise(ctrl)
    n = len(parts)
    blocks = [(f"F{i}", abcd, ["v_F" if i == n - 1 else f"v_F{i}"], ["u_F" if i == 0 else f"u_F{i}"])
              for i, abcd in enumerate(parts)]
    return blocks, {f"u_F{i}": f"v_F{i - 1}" for i in range(1, n)}


def _blocks(params, options, torque_output):
    """The dynamic blocks: (name, (A, B, C, D), output names, input names), and the velocity
    estimate's series links (input name: output name). A block the structure does not use (the
    integral without a torque loop, an estimate only the absent compensation would read) is left
    out, so that no uncoupled state adds an eigenvalue."""
    ctrl = params.controller
    st = get_structure(ctrl.structure)
    port_body = options.structure.port != "encoder_average"
    outs = [torque_output, "theta_encoder"] + ([options.structure.port] if port_body else [])
    blocks = [("plant", _zoh_plant(params, outs), [f"y_{o}" for o in ("T", "th", "p")[:len(outs)]],
               ["u_V", "u_Tdist"])]
    f = options.structure.filter
    uses_F = f in ("both", "impedance") or not port_body or (f == "compensation" and st.velocity_compensation)
    uses_diff = f == "compensation" or (f == "impedance" and st.velocity_compensation)
    links = {}
    if uses_F:
        estimate, links = _velocity_estimate_blocks(ctrl)
        blocks += estimate
    if uses_diff:
        blocks.append(("diff", _tf_block([1 / ctrl.Ts, -1 / ctrl.Ts], [1.0]), ["v_diff"], ["u_diff"]))
    # backward Euler (Eq. 7) with the state in N s (the integral itself), so it is scaled like e
    if st.torque_loop:
        blocks.append(("integral", (np.eye(1), ctrl.Ts * np.eye(1), np.eye(1), ctrl.Ts * np.eye(1)), ["y_I"],
                       ["u_I"]))
    if options.structure.delay:
        d = options.structure.delay                                 # a shift register of d samples
        shift = (np.eye(d, k=-1), np.eye(d, 1), np.eye(1, d, d - 1), np.zeros((1, 1)))
        blocks.append(("delay", shift, ["y_del"], ["u_del"]))
    return blocks, links


def _batch(loop, P_gain, D_gain, beta=None, alpha=None, cut=None):
    params = loop.params
    opt = loop.options.resolved(params.plant.topology)        # the file's sensor and port defaults
    ctrl, pl = params.controller, params.plant
    beta = ctrl.beta if beta is None else beta
    alpha = ctrl.alpha if alpha is None else alpha
    P, D, beta, alpha = (np.atleast_1d(np.asarray(v, float)).ravel()
                         for v in np.broadcast_arrays(P_gain, D_gain, beta, alpha))
    k = P.size
    st = get_structure(ctrl.structure)
    # the structure's gains from its definition (docs/model.md, "Controller structures"): the PI
    # on e, the feed-forward R/(k_t N) T_ref (scaled by beta with the PI), the compensation, or
    # for a current command T_ref/(k_t N) alone
    P_t, I_t = beta * ctrl.P_t0, beta * ctrl.I_t0
    VC = alpha * _vc0(pl) if st.velocity_compensation else 0.0 * alpha
    K_ff = beta * (pl.R / (pl.k_t * pl.N)) if st.feedforward else 0.0 * beta
    if st.command == "current":
        P_t, I_t, K_ff = 0.0 * beta, 0.0 * beta, np.full(k, 1.0 / (pl.k_t * pl.N))
    damped = opt.structure.torque_damping
    blocks, links = _blocks(params, opt, "T_sensor" if damped else "T_sensor_spring")
    ys = [y for _, _, yn, _ in blocks for y in yn]
    us = [u for _, _, _, un in blocks for u in un]
    ws = ["T_dist", "r"]
    nx = sum(b[1][0].shape[0] for b in blocks)
    Ab = np.zeros((nx, nx)); Bb = np.zeros((nx, len(us)))
    Cb = np.zeros((len(ys), nx)); Db = np.zeros((len(ys), len(us)))
    i = 0
    for _, (A, B, C, Dm), yn, un in blocks:
        m = A.shape[0]
        r0, c0 = ys.index(yn[0]), us.index(un[0])
        Ab[i:i + m, i:i + m] = A
        Bb[i:i + m, c0:c0 + B.shape[1]] = B
        Cb[r0:r0 + C.shape[0], i:i + m] = C
        Db[r0:r0 + C.shape[0], c0:c0 + B.shape[1]] = Dm
        i += m
    # signals as rows over [y, w], per point: shape (k, ny + nw)
    width = len(ys) + len(ws)

    def sig(name, scale=None):
        r = np.zeros((k, width))
        r[:, ys.index(name) if name in ys else len(ys) + ws.index(name)] = 1.0 if scale is None else scale
        return r
    th = sig("y_th")
    v_F = sig("v_F") if "v_F" in ys else None
    v_diff = sig("v_diff") if "v_diff" in ys else v_F
    v_d = v_F if opt.structure.filter in ("both", "impedance") else v_diff
    v_vc = v_F if opt.structure.filter in ("both", "compensation") else v_diff
    imp = P[:, None] * th + D[:, None] * v_d                                  # Eq. (8)
    T_ref = sig("r") if cut == "T_ref" else -imp
    e = T_ref - sig("y_T")
    y_I = sig("y_I") if "y_I" in ys else np.zeros((k, width))
    u_pi = P_t[:, None] * e + I_t[:, None] * y_I + K_ff[:, None] * T_ref      # Eq. (7), feed-forward
    # no compensation: no estimate it would read (v_vc None), VC zero
    V_k = (sig("r") if cut == "PI" else u_pi) + (0.0 if v_vc is None else VC[:, None] * v_vc)
    inputs = {"u_V": sig("y_del") if opt.structure.delay else V_k, "u_Tdist": sig("T_dist"), "u_F": th,
              "u_diff": th, "u_I": e, "u_del": V_k, **{u: sig(y) for u, y in links.items()}}
    KE = np.stack([inputs[u] for u in us], axis=1)                           # (k, nu, ny + nw)
    K, E = KE[:, :, :len(ys)], KE[:, :, len(ys):]
    port = v_F if opt.structure.port == "encoder_average" else sig("y_p")
    y_cut = {None: np.zeros((k, width)), "T_ref": imp, "PI": -u_pi}[cut]
    Z = np.stack([sig("y_T"), th, port, y_cut], axis=1)                      # (k, 4, ny + nw)
    Zy, Zw = Z[:, :, :len(ys)], Z[:, :, len(ys):]
    M = np.linalg.inv(np.eye(len(ys)) - Db @ K)                              # y = M (C x + D E w)
    A_cl = Ab + Bb @ K @ M @ Cb
    B_cl = Bb @ (K @ M @ Db @ E + E)
    C_cl = Zy @ M @ Cb
    D_cl = Zy @ M @ Db @ E + Zw
    return A_cl, B_cl, C_cl, D_cl


def closed_loop_matrices(loop, P_gain: float, D_gain: float, beta: float | None = None,
                         alpha: float | None = None, cut: str | None = None):
    """``(A, B, C, D)`` of the sampled closed loop at one gain point; ``cut`` in {None, "T_ref", "PI"}."""
    return tuple(m[0] for m in _batch(loop, P_gain, D_gain, beta, alpha, cut))


def closed_loop_eigenvalues(loop, points, chunk: int = 2048) -> np.ndarray:
    """Eigenvalues of the closed-loop state matrix at gain points (4, k), shape (k, order)."""
    pts = np.asarray(points, dtype=float).reshape(4, -1)
    out = []
    for c in range(0, pts.shape[1], chunk):
        out.append(np.linalg.eigvals(_batch(loop, *pts[:, c:c + chunk])[0]))
    return np.concatenate(out) if out else np.empty((0, 0), complex)


def spectral_radius(loop, P_gain, D_gain, beta=None, alpha=None) -> float:
    """max |eig| of the closed-loop state matrix at one gain point."""
    return float(np.abs(np.linalg.eigvals(closed_loop_matrices(loop, P_gain, D_gain, beta, alpha)[0])).max())


def _tf(A, B, C, D, omega, Ts, out, inp):
    z = np.exp(1j * np.asarray(omega) * Ts)
    M = z[:, None, None] * np.eye(A.shape[0]) - A
    X = np.linalg.solve(M, np.broadcast_to(B[:, inp:inp + 1], (len(z), A.shape[0], 1)))[..., 0]
    return X @ C[out] + D[out, inp]


def frequency_response(loop, omega, P_gain, D_gain, beta=None, alpha=None,
                       which=("L_t", "L_imp", "H_T", "Z")) -> dict:
    """``L_t``, ``L_imp``, ``Z``, ``H_T`` of :meth:`ClosedLoop.frequency_response` (those named in
    ``which``), by state space."""
    Ts = loop.params.controller.Ts
    res = {}
    if "L_t" in which:
        A, B, C, D = closed_loop_matrices(loop, P_gain, D_gain, beta, alpha, cut="PI")
        res["L_t"] = _tf(A, B, C, D, omega, Ts, 3, 1)
    if "L_imp" in which or "H_T" in which:
        A, B, C, D = closed_loop_matrices(loop, P_gain, D_gain, beta, alpha, cut="T_ref")
        res["L_imp"] = _tf(A, B, C, D, omega, Ts, 3, 1)
        res["H_T"] = _tf(A, B, C, D, omega, Ts, 0, 1)
    if "Z" in which:
        A, B, C, D = closed_loop_matrices(loop, P_gain, D_gain, beta, alpha)
        res["Z"] = 1 / _tf(A, B, C, D, omega, Ts, 2, 0)
    return res
