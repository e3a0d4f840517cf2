"""The sampled closed loop as an explicit state space, derived from the loop's elements.

Sample by sample (Fig. 6): the encoder angle theta and the measured torque T are read; every
velocity estimate (``ClosedLoop.elements``, each realised by :meth:`Element.realization`) is
updated; the impedance law Eq. (8) gives T_ref = -(P_gain theta + D_gain v_d) (theta_ref = 0);
the PI of Eq. (7) acts on T_ref - T; velocity compensation adds VC v_vc (Eq. 6); the voltage goes
through the delay element and the zero-order hold into the sampled plant. The controller's
structure (haa_sym.model.structures) fixes the gains: the torque reference is also fed forward
with K_ff = P_r - P_m (the feed-forward; for a current command, the whole T_ref/(k_t N)), and a
structure without a PI or compensation has them zero (its elements then have no states).

It serves the evaluators where eigenvalues are the answer (the spectral radius, the points the
certified polynomial test leaves open) and :func:`to_statespace`. The tests check it against
:mod:`haa_sym.check.reference`, which builds the same loop with its own algebra.

Closed-loop state ``[plant x, one block of states per distinct element (velocity estimates,
PI integral, delay)]``; inputs ``[T_dist, r]`` where ``r`` is injected at the cut point;
outputs ``[T_meas, theta, port velocity, y]`` where ``y`` returns to the cut point with negative
sign (so the loop transfer r -> y is the ``L`` of 1/(1+L)).
"""
from __future__ import annotations

import numpy as np

from haa_sym.errors import ParameterError

__all__ = ["CUTS", "INPUT_NAMES", "OUTPUT_NAMES", "CONTROLLER_INPUTS", "CONTROLLER_OUTPUTS",
           "closed_loop_batch", "closed_loop_eigenvalues", "controller_batch", "to_statespace"]

CUTS = (None, "T_ref", "PI")
INPUT_NAMES = ("T_dist", "r")
OUTPUT_NAMES = ("T_meas", "theta_encoder", "port_velocity", "y")
# The controller alone (what the nonlinear simulation closes around the continuous plant): it
# reads the encoder angle and the torque signal, takes a torque feed-forward and an angle set
# point, and gives the voltage applied after the delay and the torque reference.
CONTROLLER_INPUTS = ("theta_encoder", "T_meas", "T_ff", "theta_ref")
CONTROLLER_OUTPUTS = ("V", "T_ref")


def _layout(loop, start=None):
    """States of the closed loop: the plant's, then each distinct element's, by role
    (``start``: where the first element's states begin; default after the plant's)."""
    el = loop.elements
    roles = ["F_d", "F_vc"] + (["F_port"] if loop.options.structure.port == "encoder_average" else []) + \
        ["I_z", "z_delay"]
    blocks, owner = [], {}
    start = loop.plant.Phi.shape[0] if start is None else start
    for role in roles:
        for other, (_s, e) in owner.items():      # an element met before shares its states
            if el[other] == el[role] and role.startswith("F"):
                owner[role] = owner[other]
                break
        else:
            owner[role] = (start, el[role])
            blocks.append((role, start, el[role].realization()))
            start += el[role].order
    return owner, blocks, start


def closed_loop_batch(loop, P_gain, D_gain, beta=None, alpha=None, cut: str | None = None):
    """``(A, B, C, D)`` of the closed loop at k gain points, shapes (k, n, n) ... (k, 4, 2).

    ``P_gain``, ``D_gain``, ``beta``, ``alpha`` broadcast to shape (k,); ``cut`` in
    {None, "T_ref", "PI"} opens the loop at the torque reference or the PI output.
    """
    if cut not in CUTS:
        raise ValueError(f"cut = {cut!r}; allowed: {list(CUTS)}")
    pl, opt = loop.plant, loop.options
    P, D, P_t, I_t, VC, K_ff = _gains(loop, P_gain, D_gain, beta, alpha)
    k = P.shape[0]
    owner, blocks, n = _layout(loop)
    nx, nin = pl.Phi.shape[0], len(INPUT_NAMES)
    width = n + nin                                # every signal is a row over [state, inputs]
    i_r = n + INPUT_NAMES.index("r")

    def plant_row(name):
        r = np.zeros(width)
        r[:nx] = pl.C[loop.plant_output(name)]
        return r

    rows = np.zeros((k, n, width))
    rows[:, :nx, :nx] = pl.Phi
    rows[:, :nx, n + INPUT_NAMES.index("T_dist")] = pl.Gamma[:, 2]
    th, T = _bcast(plant_row("theta_encoder"), k), _bcast(plant_row(loop.torque_output), k)
    sig = _controller_flow(loop, owner, rows, P, D, P_t, I_t, VC, th, T, cut=cut,
                           r=_bcast(_unit(i_r, width), k), K_ff=K_ff)
    rows[:, :nx] += pl.Gamma[None, :, 0, None] * sig["V"][:, None, :]
    port = sig["port"] if opt.structure.port == "encoder_average" else _bcast(plant_row(opt.structure.port), k)
    y = {None: np.zeros((k, width)), "T_ref": sig["imp"], "PI": -sig["u_pi"]}[cut]
    out = np.stack([T, th, port, y], axis=1)
    return rows[:, :, :n], rows[:, :, n:], out[:, :, :n], out[:, :, n:]


def _gains(loop, P_gain, D_gain, beta, alpha):
    ctrl = loop.params.controller
    beta = ctrl.beta if beta is None else beta
    alpha = ctrl.alpha if alpha is None else alpha
    P, D, beta, alpha = (np.atleast_1d(np.asarray(v, float)) for v in np.broadcast_arrays(P_gain, D_gain, beta, alpha))
    # P_t on the torque error, K_ff = P_r - P_m on the reference alone (0.0 for the paper's)
    return (P, D, beta * loop.P_m0, beta * loop.const[1], alpha * loop.const[2],
            beta * (loop.const[0] - loop.P_m0))


def _unit(i, width):
    r = np.zeros(width)
    r[i] = 1.0
    return r


def _bcast(r, k):
    return np.broadcast_to(r, (k, r.shape[-1]))


def _controller_flow(loop, owner, rows, P, D, P_t, I_t, VC, th, T, *, cut=None, r=None, T_ff=None,
                     theta_ref=None, K_ff=None):
    """The controller's signal flow of one sample (Fig. 6), every signal a row over the caller's
    [states, inputs]; writes each element's state update into ``rows`` (shape (k, n, width)).

    ``th``, ``T``: the encoder angle and the torque signal the loop reads; ``r`` is injected at
    ``cut``; ``T_ff`` (a torque feed-forward) and ``theta_ref`` (the set point of Eq. 8) are
    optional rows; ``K_ff`` (k,) the structure's gain from T_ref straight to the command (the PI's
    output ``u_pi`` includes it: the torque controller's whole output). Returns the signals ``V`` (applied, after the delay), ``T_ref``, ``imp``,
    ``u_pi`` and ``port`` (the port's velocity estimate, when the port reads one).
    """
    k, width = th.shape
    written: set[int] = set()

    def element(role, u):
        """Output of element ``role`` driven by signal ``u`` (k, width); writes its state update."""
        s, e = owner[role]
        A, B, C, Dm = e.realization()
        m = e.order
        xs = np.zeros((m, width))
        xs[:, s:s + m] = np.eye(m)
        if s not in written:
            rows[:, s:s + m] = A @ xs + B[None, :, 0, None] * u[:, None, :]
            written.add(s)
        return (C @ xs)[0] + Dm[0, 0] * u

    v_d = element("F_d", th)
    v_vc = element("F_vc", th)
    err = th if theta_ref is None else th - theta_ref
    imp = P[:, None] * err + D[:, None] * v_d               # Eq. (8): T_ref = T_ff - imp
    T_ref = r if cut == "T_ref" else (-imp if T_ff is None else T_ff - imp)
    e = T_ref - T
    u_pi = P_t[:, None] * e + I_t[:, None] * element("I_z", e)
    if K_ff is not None and np.any(K_ff):
        u_pi = u_pi + K_ff[:, None] * T_ref
    V_k = (r if cut == "PI" else u_pi) + VC[:, None] * v_vc
    V = element("z_delay", V_k)
    port = element("F_port", th) if loop.options.structure.port == "encoder_average" else None
    return {"V": V, "T_ref": T_ref, "imp": imp, "u_pi": u_pi, "port": port}


def controller_batch(loop, P_gain, D_gain, beta=None, alpha=None):
    """``(A, B, C, D)`` of the sampled controller alone at k gain points: the same elements and
    signal flow as :func:`closed_loop_batch`, with the plant's signals as inputs.

    Inputs :data:`CONTROLLER_INPUTS` (rad, Nm, Nm, rad), outputs :data:`CONTROLLER_OUTPUTS`
    (the voltage applied after the delay, V; the torque reference, Nm); shapes (k, m, m),
    (k, m, 4), (k, 2, m), (k, 2, 4) with m the controller's order.
    """
    P, D, P_t, I_t, VC, K_ff = _gains(loop, P_gain, D_gain, beta, alpha)
    k = P.shape[0]
    owner, _blocks, m = _layout(loop, start=0)
    width = m + len(CONTROLLER_INPUTS)
    rows = np.zeros((k, m, width))
    sig_in = {name: _bcast(_unit(m + i, width), k) for i, name in enumerate(CONTROLLER_INPUTS)}
    sig = _controller_flow(loop, owner, rows, P, D, P_t, I_t, VC, sig_in["theta_encoder"],
                           sig_in["T_meas"], T_ff=sig_in["T_ff"], theta_ref=sig_in["theta_ref"], K_ff=K_ff)
    out = np.stack([sig[n] for n in CONTROLLER_OUTPUTS], axis=1)
    return rows[:, :, :m], rows[:, :, m:], out[:, :, :m], out[:, :, m:]


def closed_loop_eigenvalues(loop, points, chunk_bytes: int = 64 << 20) -> np.ndarray:
    """Eigenvalues of the closed-loop state matrix at gain points, shape (k, order).

    ``points`` is (4, k): rows P_gain, D_gain, beta, alpha. One ``numpy.linalg.eigvals`` call
    per chunk of stacked matrices (``chunk_bytes`` of them at a time).
    """
    pts = np.asarray(points, dtype=float).reshape(4, -1)
    order = _layout(loop)[2]
    out = np.empty((pts.shape[1], order), complex)
    step = max(1, chunk_bytes // (8 * order * order))
    for c in range(0, pts.shape[1], step):
        sl = slice(c, c + step)
        A = closed_loop_batch(loop, *pts[:, sl])[0]
        bad = ~np.isfinite(A).all(axis=(1, 2))
        if bad.any():
            # finite inputs whose products overflow (beta = 1e308): numpy's LinAlgError named nothing
            P, D, b, a = pts[:, sl][:, np.argmax(bad)]
            raise ParameterError(f"the closed loop at P_gain = {P:g}, D_gain = {D:g}, beta = {b:g}, alpha = {a:g} "
                                 "overflows (its state matrix is not finite); allowed: gains and parameters "
                                 "whose closed loop is finite")
        out[sl] = np.linalg.eigvals(A)
    return out


def to_statespace(loop, P_gain: float, D_gain: float, beta=None, alpha=None, cut: str | None = None):
    """The closed loop at one gain point as a python-control ``StateSpace`` with named signals.

    Inputs ``T_dist`` (Nm) and ``r`` (injected at ``cut``: the torque reference, Nm, or the PI
    output, V); outputs ``T_meas`` (Nm), ``theta_encoder`` (rad), ``port_velocity`` (rad/s) and
    ``y`` (what returns to the cut point, negative feedback). Sampling time ``Ts``.
    Needs python-control (``pip install 'haa_sym[control]'``).
    """
    try:
        import control
    except ImportError:
        raise ImportError("to_statespace needs python-control: pip install 'haa_sym[control]'") from None
    A, B, C, D = (m[0] for m in closed_loop_batch(loop, P_gain, D_gain, beta, alpha, cut))
    return control.ss(A, B, C, D, loop.params.controller.Ts, inputs=list(INPUT_NAMES),
                      outputs=list(OUTPUT_NAMES), name=f"haa_closed_loop_cut_{cut}")
