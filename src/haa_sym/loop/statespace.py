"""The sampled closed loop as an explicit state space, derived from the loop's elements.

Sample by sample (Fig. 6): the encoder angle theta and the measured torque T are read; every
velocity estimate (``ClosedLoop.elements``, each realised by :meth:`Element.realization`) is
updated; the impedance law Eq. (8) gives T_ref = -(P_gain theta + D_gain v_d) (theta_ref = 0);
the PI of Eq. (7) acts on T_ref - T; velocity compensation adds VC v_vc (Eq. 6); the voltage goes
through the delay element and the zero-order hold into the sampled plant.

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

__all__ = ["CUTS", "INPUT_NAMES", "OUTPUT_NAMES", "closed_loop_batch", "closed_loop_eigenvalues",
           "to_statespace"]

CUTS = (None, "T_ref", "PI")
INPUT_NAMES = ("T_dist", "r")
OUTPUT_NAMES = ("T_meas", "theta_encoder", "port_velocity", "y")


def _layout(loop):
    """States of the closed loop: the plant's, then each distinct element's, by role."""
    el = loop.elements
    roles = ["F_d", "F_vc"] + (["F_port"] if loop.options.structure.port == "encoder_average" else []) + \
        ["I_z", "z_delay"]
    blocks, owner, start = [], {}, loop.plant.Phi.shape[0]
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
    ctrl, pl, opt = loop.params.controller, loop.plant, loop.options
    beta = ctrl.beta if beta is None else beta
    alpha = ctrl.alpha if alpha is None else alpha
    P, D, beta, alpha = (np.atleast_1d(np.asarray(v, float)) for v in np.broadcast_arrays(P_gain, D_gain, beta, alpha))
    k = P.shape[0]
    P_t, I_t, VC = beta * loop.const[0], beta * loop.const[1], alpha * loop.const[2]
    owner, blocks, n = _layout(loop)
    nx, nin = pl.Phi.shape[0], len(INPUT_NAMES)
    width = n + nin                                # every signal is a row over [state, inputs]
    i_r = n + INPUT_NAMES.index("r")

    def unit(i):
        r = np.zeros(width)
        r[i] = 1.0
        return r

    def plant_row(name):
        r = np.zeros(width)
        r[:nx] = pl.C[loop.plant_output(name)]
        return r

    def bcast(r):
        return np.broadcast_to(r, (k, width))

    rows = np.zeros((k, n, width))
    rows[:, :nx, :nx] = pl.Phi
    rows[:, :nx, n + INPUT_NAMES.index("T_dist")] = pl.Gamma[:, 2]

    def element(role, u):
        """Output of element ``role`` driven by signal ``u`` (k, width); writes its state update."""
        s, e = owner[role]
        A, B, C, Dm = e.realization()
        m = e.order
        xs = np.zeros((m, width))
        xs[:, s:s + m] = np.eye(m)
        if blocks_written.get(s) is None:
            rows[:, s:s + m] = A @ xs + B[None, :, 0, None] * u[:, None, :]
            blocks_written[s] = True
        return (C @ xs)[0] + Dm[0, 0] * u

    blocks_written: dict[int, bool] = {}
    th, T = bcast(plant_row("theta_encoder")), bcast(plant_row(loop.torque_output))
    v_d = element("F_d", th)
    v_vc = element("F_vc", th)
    imp = P[:, None] * th + D[:, None] * v_d               # Eq. (8), theta_ref = 0: T_ref = -imp
    T_ref = bcast(unit(i_r)) if cut == "T_ref" else -imp
    e = T_ref - T
    u_pi = P_t[:, None] * e + I_t[:, None] * element("I_z", e)
    V_k = (bcast(unit(i_r)) if cut == "PI" else u_pi) + VC[:, None] * v_vc
    V = element("z_delay", V_k)
    rows[:, :nx] += pl.Gamma[None, :, 0, None] * V[:, None, :]
    port = element("F_port", th) if opt.structure.port == "encoder_average" else bcast(plant_row(opt.structure.port))
    y = {None: np.zeros((k, width)), "T_ref": imp, "PI": -u_pi}[cut]
    out = np.stack([T, th, port, y], axis=1)
    return rows[:, :, :n], rows[:, :, n:], out[:, :, :n], out[:, :, n:]


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
