"""Any geared, compliant chain (a :class:`~haa_sym.model.actuator.Topology`) as symbolic equations.

The generalisation of Eq. (1)-(2) (docs/model.md, "The chain equations"):

    L dI_m/dt     = V_m - R I_m - k_w dtheta_m
    J_m ddtheta_m = k_t I_m - B_m dtheta_m + T_rotor / N + T_fr
    J_X ddtheta_X = sum of coupling torques on X - B_X dtheta_X - K_X theta_X (+ T_dist on the port)

where a coupling between a and b transmits T = K (theta_a - theta_b) + D (dtheta_a - dtheta_b)
(theta_rotor = theta_m / N), acting +T on b and -T on a; T_rotor is the gearbox's torque on its
"rotor" end, reflected to the motor by 1/N. For the HyQ topology this is exactly
:func:`haa_sym.symbolic.eom.state_space` (same sympy expressions, so the same generated code).

:func:`state_space` gives (A, B, C) with named states, inputs and outputs; :func:`laplace_equations`
the same model in the Laplace domain (the form of the printed Eq. 1); :func:`torque_tf_fraction`
the transfer function V -> measured torque with the velocity compensation
V_m = V + VC_gain s theta_encoder closed (Cramer's rule, as :mod:`haa_sym.symbolic.torque_tf`);
:func:`exact_vc_condition` and :func:`load_free_g_tvc` the generalisation of Eq. (3)-(5).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import sympy as sp
from sympy.polys.matrices import DomainMatrix

from haa_sym.model.actuator import CURRENT, ROTOR, Actuator, Topology
from haa_sym.symbolic.model import LinearActuatorModel, Parameter

s = sp.Symbol("s")
VC = sp.Symbol("VC_gain")

__all__ = ["s", "VC", "ChainStateSpace", "symbols", "state_space", "actuator_model", "symbolic_model", "laplace_equations",
           "torque_tf_fraction", "exact_vc_condition", "exact_vc_gain", "load_free_g_tvc", "vc_gain_exact",
           "sensor_outputs",
           "vc_gain_simplified"]


def symbols(top: Topology) -> dict[str, sp.Symbol]:
    """One symbol per flat parameter name: positive where the domain is > 0, else nonnegative."""
    return {k: sp.Symbol(k, positive=True) if d == ">0" else sp.Symbol(k, nonnegative=True)
            for k, d in top.domain.items()}


@dataclass(frozen=True)
class ChainStateSpace:
    """``dx/dt = A x + B u``, ``y = C x`` with symbolic entries and named signals."""

    A: sp.Matrix
    B: sp.Matrix
    C: sp.Matrix
    symbols: dict
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]


def _angle(name: str, th: dict, p: dict):
    return th["m"] / p["N"] if name == ROTOR else th[name]


def coupling_torque(c, p: dict, th: dict, dth: dict, *, damping: bool = True):
    """T = K (theta_a - theta_b) + D (dtheta_a - dtheta_b) of coupling ``c`` (Eq. 2 for the gearbox)."""
    T = p[f"K_{c.name}"] * (_angle(c.a, th, p) - _angle(c.b, th, p))
    if damping:
        T += p[f"D_{c.name}"] * (_angle(c.a, dth, p) - _angle(c.b, dth, p))
    return T


def sensor_outputs(top: Topology, p: dict, I_m, th: dict, dth: dict) -> list:
    """The loop's role outputs ``[T_sensor, T_sensor_spring, theta_encoder]`` (docs/model.md,
    "Actuator files", sensors table).

    A torque sensor on a coupling measures its transmitted torque with and without the damping
    term (Eq. 2); ``torque = "current"`` estimates the output torque from the motor current,
    k_t N I_m (Nm at the output; both outputs, there is no damping term). The encoder reads a
    body's angle, or with ``encoder = "rotor"`` the rotor angle referred to the output,
    theta_m / N (rad).
    """
    if top.sensor == CURRENT:
        T = T_spring = p["k_t"] * p["N"] * I_m
    else:
        sc = top.sensor_coupling
        T = coupling_torque(sc, p, th, dth, damping=True)
        T_spring = coupling_torque(sc, p, th, dth, damping=False)
    return [T, T_spring, _angle(top.encoder, th, p)]


def _net_torques(top: Topology, p: dict, th: dict, dth: dict) -> dict:
    """Sum of coupling torques on every body and on "rotor" (+T on b, -T on a)."""
    net = {name: 0 for name in (ROTOR,) + top.body_names}
    for c in top.couplings:
        T = coupling_torque(c, p, th, dth)
        net[c.b] += T
        net[c.a] -= T
    return net


def equations_of_motion(top: Topology, p: dict | None = None):
    """The chain in the time domain: returns (p, x, u, xdot) with xdot a list of expressions."""
    p = p or symbols(top)
    x = sp.symbols(top.state_names)
    u = sp.symbols(top.input_names)
    I_m, th_m, dth_m = x[:3]
    th = {"m": th_m, **{b.name: x[3 + 2 * i] for i, b in enumerate(top.bodies)}}
    dth = {"m": dth_m, **{b.name: x[4 + 2 * i] for i, b in enumerate(top.bodies)}}
    V_m, T_fr, T_dist = u
    net = _net_torques(top, p, th, dth)
    # a rotor-only actuator's port is the rotor: T_dist at the output acts on it through 1/N
    on_rotor = T_dist / p["N"] if top.port == ROTOR else 0
    xdot = [(V_m - p["R"] * I_m - p["k_w"] * dth_m) / p["L"], dth_m,
            (p["k_t"] * I_m - p["B_m"] * dth_m + net[ROTOR] / p["N"] + T_fr + on_rotor) / p["J_m"]]
    for b in top.bodies:
        rhs = net[b.name] - p[f"B_{b.name}"] * dth[b.name]
        if b.ground:
            rhs -= p[f"K_{b.name}"] * th[b.name]
        if b.name == top.port:
            rhs += T_dist
        xdot += [dth[b.name], rhs / p[f"J_{b.name}"]]
    return p, x, u, xdot, th, dth


def state_space(top: Topology, p: dict | None = None) -> ChainStateSpace:
    """Linear state space of the chain with the outputs of ``top.output_names``."""
    p, x, u, xdot, th, dth = equations_of_motion(top, p)
    xv, uv = sp.Matrix(x), sp.Matrix(u)
    f = sp.Matrix(xdot)
    A = f.jacobian(xv)
    B = f.jacobian(uv)
    y = sp.Matrix(sensor_outputs(top, p, x[0], th, dth) + [dth[b.name] for b in top.bodies]
                  + ([dth["m"] / p["N"]] if top.port == ROTOR else []))
    C = y.jacobian(xv)
    return ChainStateSpace(A=sp.simplify(A), B=sp.simplify(B), C=C, symbols=p,
                           states=top.state_names, inputs=top.input_names, outputs=top.output_names)


def symbolic_model(actuator: Actuator) -> LinearActuatorModel:
    """The :class:`~haa_sym.symbolic.model.LinearActuatorModel` the code generator compiles for
    ``actuator``: a chain's (:func:`actuator_model`), or a model written in code itself."""
    return actuator if isinstance(actuator, LinearActuatorModel) else actuator_model(actuator)


@functools.lru_cache(maxsize=None)
def actuator_model(top: Topology):
    """The chain as a :class:`~haa_sym.symbolic.model.LinearActuatorModel`: :func:`state_space`,
    its parameters with domains and units, and VC0 = Eq. (6) at alpha = 1 (what the code
    generator compiles; the matrices are the same sympy objects, so the same generated code)."""
    ss = state_space(top)
    units = top.units
    return LinearActuatorModel(
        name=top.source, states=top.state_names, inputs=top.input_names, outputs=top.output_names,
        parameters=tuple(Parameter(k, d, units[k]) for k, d in top.domain.items()),
        A=ss.A, B=ss.B, C=ss.C, VC0=vc_gain_simplified(ss.symbols, 1), port=top.port,
        torque_damping=top.torque_damping, source=top.source)


def laplace_equations(top: Topology, p: dict | None = None):
    """The chain in the Laplace domain, in the form of the printed Eq. (1) (T_fr, T_dist as
    torques; see :mod:`haa_sym.symbolic.eom`).

    Returns ``(p, unknowns, equations, outputs)``: unknowns ``(I_m, theta_m, theta_X...)``, each
    equation ``lhs - rhs`` (= 0) with the inputs ``V_m, T_fr, T_dist`` free, and ``outputs``
    the expressions of ``top.output_names`` in the unknowns.
    """
    p = p or symbols(top)
    I_m, th_m = sp.symbols("I_m theta_m")
    th = {"m": th_m, **{b.name: sp.Symbol(f"theta_{b.name}") for b in top.bodies}}
    dth = {k: s * v for k, v in th.items()}
    V_m, T_fr, T_dist = sp.symbols(top.input_names)
    net = _net_torques(top, p, th, dth)
    Jm = (p["J_m"] * s + p["B_m"]) * s
    on_rotor = T_dist / p["N"] if top.port == ROTOR else 0
    eqs = [I_m - (V_m - p["k_w"] * s * th_m) / (p["L"] * s + p["R"]),
           th_m - (p["k_t"] * I_m + net[ROTOR] / p["N"] + T_fr + on_rotor) / Jm]
    for b in top.bodies:
        Jx = (p[f"J_{b.name}"] * s + p[f"B_{b.name}"]) * s
        rhs = net[b.name] + (T_dist if b.name == top.port else 0)
        if b.ground:
            rhs -= p[f"K_{b.name}"] * th[b.name]
        eqs.append(th[b.name] - rhs / Jx)
    outputs = sensor_outputs(top, p, I_m, th, dth) + [dth[b.name] for b in top.bodies] \
        + ([dth["m"] / p["N"]] if top.port == ROTOR else [])
    unknowns = (I_m, th_m) + tuple(th[b.name] for b in top.bodies)
    return p, unknowns, eqs, outputs


def torque_tf_fraction(top: Topology, p: dict | None = None, vc=VC):
    """Measured torque / V with V_m = V + vc s theta_encoder (T_fr = T_dist = 0), as
    ``(num, den, ring)``: the sensor's torque (with or without damping, ``top.torque_damping``).

    Cramer's rule with fraction-free determinants (DomainMatrix) over the polynomial ring in
    the parameters, s, V and VC_gain, as :func:`haa_sym.symbolic.torque_tf.derive_g_tvc_fraction`.
    """
    p, unknowns, eqs, outputs = laplace_equations(top, p)
    V = sp.Symbol("V")
    enc = outputs[2]                                        # theta_X, or theta_m / N
    subs = {sp.Symbol("V_m"): V + vc * s * enc, sp.Symbol("T_fr"): 0, sp.Symbol("T_dist"): 0}
    # N a generator even where no equation holds it (a rotor-only actuator: no gearbox)
    sol, det, ring = cramer_solve([e.subs(subs) for e in eqs], unknowns, {V, p["N"]})   # sol times det
    # the measured torque is linear in the unknowns: substitute each by its Cramer numerator
    T = sp.expand(outputs[0 if top.torque_damping else 1] * p["N"])      # clear 1/N of theta_rotor
    num = ring.zero
    for u in unknowns:
        coef = T.coeff(u)
        if coef != 0:
            num += ring.from_sympy(coef) * sol[u]
    den = det * ring.from_sympy(p["N"] * V)
    return num, den, ring


def cramer_solve(eqs, unknowns, extra_gens=frozenset()):
    """Exact solution of linear equations ``eqs`` (expressions = 0) in ``unknowns``.

    Returns ``(numerators, det, ring)``: each unknown is ``numerators[u] / det``, all elements of
    the polynomial ring over QQ in every other symbol (and ``extra_gens``). Cramer's rule with
    fraction-free determinants (Bareiss, sympy's DomainMatrix): seconds where sympy's ``solve``
    and ``cancel`` on expressions took minutes. Denominators of the equations are cleared first
    (they are nonzero polynomials).
    """
    eqs = [sp.numer(sp.together(e)) for e in eqs]
    M, rhs = sp.linear_eq_to_matrix(eqs, unknowns)
    gens = sorted(M.free_symbols | rhs.free_symbols | set(extra_gens), key=str)
    ring = sp.QQ[tuple(gens)]
    A = DomainMatrix([[ring.from_sympy(M[i, j]) for j in range(M.cols)] for i in range(M.rows)],
                     M.shape, ring)

    def column_replaced(k):                                 # det(A with column k = rhs)
        rows = [[ring.from_sympy(rhs[i, 0]) if j == k else A[i, j].element for j in range(M.cols)]
                for i in range(M.rows)]
        return DomainMatrix(rows, M.shape, ring).det()
    return {u: column_replaced(k) for k, u in enumerate(unknowns)}, A.det(), ring


def vc_gain_exact(p: dict) -> sp.Expr:
    """Eq. (5): N/k_t (L s + R)(J_m s + B_m) + N k_w (motor parameters only)."""
    return p["N"] / p["k_t"] * (p["L"] * s + p["R"]) * (p["J_m"] * s + p["B_m"]) + p["N"] * p["k_w"]


def vc_gain_simplified(p: dict, a=1) -> sp.Expr:
    """Eq. (6): alpha N / k_t (R B_m + k_t k_w); at alpha = 1 this is VC0 of every topology."""
    return a * p["N"] / p["k_t"] * (p["R"] * p["B_m"] + p["k_t"] * p["k_w"])


def exact_vc_condition(top: Topology) -> tuple[bool, str]:
    """Whether the generalised Eq. (3)-(5) applies, and why (not).

    Three placements make the measured torque / V independent of every body after the gearbox
    (:func:`load_free_g_tvc`, with the compensation :func:`exact_vc_gain`):

    * the torque sensor on the gearbox and the encoder on the gearbox's output body: the motor
      equation reads V_m = N q1 T_c / (k_t (K + s D)) + q2 theta_1, and VC_gain s = q2 (Eq. 5)
      leaves T_c / V = k_t (K + s D) / (N q1);
    * the torque sensor on the gearbox and a motor-side encoder (theta_m / N): Eq. (5) cancels
      the rotor's own dynamics, (J_m s + B_m) s theta_m = k_t I_m - T_c / N, and the back-EMF,
      so T_c / V = N k_t / (L s + R);
    * the torque from the current (k_t N I_m) and a motor-side encoder: VC_gain = N k_w cancels
      the back-EMF alone and k_t N I_m / V = N k_t / (L s + R).
    """
    if top.sensor == CURRENT:
        if top.encoder == ROTOR:
            return True, ("torque from the motor current (k_t N I_m), encoder on the rotor: "
                          "VC_gain = N k_w cancels the back-EMF")
        return False, (f"the torque is the current estimate but the encoder reads body "
                       f"{top.encoder!r}, not the rotor: the compensation feeds back that body's "
                       "velocity, not the back-EMF's")
    g = top.gearbox
    out = g.b if g.a == ROTOR else g.a
    if top.sensor != g.name:
        return False, (f"the torque sensor is on coupling {top.sensor!r}, not on the gearbox "
                       f"{g.name!r}: the measured torque depends on the bodies between them")
    if top.encoder == ROTOR:
        return True, (f"torque sensor on the gearbox {g.name!r}, encoder on the rotor: Eq. (5) "
                      "cancels the rotor's dynamics and the back-EMF")
    if top.encoder != out:
        return False, (f"the encoder reads body {top.encoder!r}, not the gearbox's output body "
                       f"{out!r}: q2 theta_{out} is not what the compensation feeds back")
    return True, f"torque sensor on the gearbox {g.name!r}, encoder on its output body {out!r}"


def exact_vc_gain(top: Topology, p: dict) -> sp.Expr:
    """The compensation gain of :func:`exact_vc_condition`: N k_w for the current estimate (the
    back-EMF alone), else Eq. (5) (:func:`vc_gain_exact`)."""
    return p["N"] * p["k_w"] if top.sensor == CURRENT else vc_gain_exact(p)


def load_free_g_tvc(top: Topology, p: dict) -> sp.Expr:
    """The generalised Eq. (3) with the compensation of :func:`exact_vc_gain`, where
    :func:`exact_vc_condition` applies.

    Encoder on the gearbox's output body: k_t (K + s D) / (N q1), with
    q1 = (L s + R)(J_m s^2 + B_m s + (K + s D)/N^2) + k_t k_w s of the gearbox's K, D. Encoder on
    the rotor (or the current estimate): N k_t / (L s + R). Times K/(K + s D) when a gearbox
    sensor reads the spring alone; negated when the gearbox is written [body, "rotor"] (its
    torque is then counted the other way)."""
    if top.sensor == CURRENT:
        return p["N"] * p["k_t"] / (p["L"] * s + p["R"])
    g = top.gearbox
    K, D = p[f"K_{g.name}"], p[f"D_{g.name}"]
    sign = 1 if g.a == ROTOR else -1
    spring = 1 if top.torque_damping else K / (K + s * D)
    if top.encoder == ROTOR:
        return sign * p["N"] * p["k_t"] / (p["L"] * s + p["R"]) * spring
    q1 = (p["L"] * s + p["R"]) * (p["J_m"] * s**2 + p["B_m"] * s + (K + s * D) / p["N"]**2) \
        + p["k_t"] * p["k_w"] * s
    meas = (K + s * D) if top.torque_damping else K
    return sign * p["k_t"] * meas / (p["N"] * q1)
