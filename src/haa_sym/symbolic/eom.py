"""Eq. (1)-(2): the 3-inertia / 2-spring model of the HAA joint as a symbolic state space.

Corrections to the printed Eq. (1), kept explicit here:

* the printed equations add the torques ``T_fr`` and ``T_dist`` to the *angles* theta_m and
  theta_L2; physically (and in Fig. 5) they are torques on the rotor and on the leg inertia, so
  they enter as ``T_fr / ((J_m s + B_m) s)`` and ``T_dist / ((J_L2 s + B_L2) s)``;
* Table 1 gives k_w in Nms/rad; as a back-EMF constant its unit is V s/rad (same number in SI).

State ``x = [I_m, theta_m, dtheta_m, theta_L1, dtheta_L1, theta_L2, dtheta_L2]``,
input ``u = [V_m, T_fr, T_dist]``.
"""
from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from haa_sym.model.actuator import HYQ

STATE_NAMES = ("I_m", "theta_m", "dtheta_m", "theta_L1", "dtheta_L1", "theta_L2", "dtheta_L2")
INPUT_NAMES = ("V_m", "T_fr", "T_dist")
# Measured and port outputs: the torque sensor (Eq. 2) with and without its D_hd term, the
# encoder angle, and the two candidate port velocities of Sec. 5.
OUTPUT_NAMES = ("T_sensor", "T_sensor_spring", "theta_encoder", "dtheta_L1", "dtheta_L2")

s = sp.Symbol("s")


def plant_symbols() -> dict[str, sp.Symbol]:
    """The Table 1 symbols, all positive except the ones a file may set to zero."""
    nonneg = {"D_hd", "B_m", "B_L1", "B_L2", "K_L2", "D_p", "k_w"}
    return {
        k: sp.Symbol(k, nonnegative=True) if k in nonneg else sp.Symbol(k, positive=True)
        for k in HYQ.parameter_keys
    }


@dataclass(frozen=True)
class StateSpace:
    """``dx/dt = A x + B u``, ``y = C x`` with symbolic entries."""

    A: sp.Matrix
    B: sp.Matrix
    C: sp.Matrix
    symbols: dict


def load_torque(p: dict, th_m, dth_m, th_1, dth_1, *, damping: bool = True):
    """Eq. (2): torque transmitted by the harmonic drive, T_l = (K_hd + s D_hd)(theta_m/N - theta_L1)."""
    T = p["K_hd"] * (th_m / p["N"] - th_1)
    if damping:
        T += p["D_hd"] * (dth_m / p["N"] - dth_1)
    return T


def equations_of_motion(p: dict | None = None):
    """Eq. (1) in the time domain: returns (p, x, u, xdot) with xdot a list of expressions."""
    p = p or plant_symbols()
    x = sp.symbols(STATE_NAMES)
    u = sp.symbols(INPUT_NAMES)
    I_m, th_m, dth_m, th_1, dth_1, th_2, dth_2 = x
    V_m, T_fr, T_dist = u
    T_l = load_torque(p, th_m, dth_m, th_1, dth_1)
    T_leg = p["K_p"] * (th_1 - th_2) + p["D_p"] * (dth_1 - dth_2)  # leg flexibility K_p, D_p
    xdot = [
        (V_m - p["R"] * I_m - p["k_w"] * dth_m) / p["L"],
        dth_m,
        (p["k_t"] * I_m - p["B_m"] * dth_m - T_l / p["N"] + T_fr) / p["J_m"],
        dth_1,
        (T_l - T_leg - p["B_L1"] * dth_1) / p["J_L1"],
        dth_2,
        (T_leg - p["B_L2"] * dth_2 - p["K_L2"] * th_2 + T_dist) / p["J_L2"],
    ]
    return p, x, u, xdot


def state_space(p: dict | None = None) -> StateSpace:
    """Linear state space of Eq. (1) with the outputs of :data:`OUTPUT_NAMES`."""
    p, x, u, xdot = equations_of_motion(p)
    xv, uv = sp.Matrix(x), sp.Matrix(u)
    f = sp.Matrix(xdot)
    A = f.jacobian(xv)
    B = f.jacobian(uv)
    I_m, th_m, dth_m, th_1, dth_1, th_2, dth_2 = x
    y = sp.Matrix([
        load_torque(p, th_m, dth_m, th_1, dth_1, damping=True),
        load_torque(p, th_m, dth_m, th_1, dth_1, damping=False),
        th_1,
        dth_1,
        dth_2,
    ])
    C = y.jacobian(xv)
    return StateSpace(A=sp.simplify(A), B=sp.simplify(B), C=C, symbols=p)


def laplace_equations(p: dict | None = None):
    """Eq. (1) as printed (Laplace domain, with the torque corrections of the module docstring).

    Returns ``(p, unknowns, equations)`` with unknowns ``(I_m, theta_m, theta_L1, theta_L2)`` and
    inputs ``V_m, T_fr, T_dist`` as free symbols; each equation is ``lhs - rhs`` (= 0).
    """
    p = p or plant_symbols()
    I_m, th_m, th_1, th_2 = sp.symbols("I_m theta_m theta_L1 theta_L2")
    V_m, T_fr, T_dist = sp.symbols(INPUT_NAMES)
    Khd = p["K_hd"] + s * p["D_hd"]
    Kp = p["K_p"] + s * p["D_p"]
    Jm = (p["J_m"] * s + p["B_m"]) * s
    J1 = (p["J_L1"] * s + p["B_L1"]) * s
    J2 = (p["J_L2"] * s + p["B_L2"]) * s
    eqs = [
        I_m - (V_m / (p["L"] * s + p["R"]) - p["k_w"] * s * th_m / (p["L"] * s + p["R"])),
        th_m - (p["k_t"] * I_m / Jm - Khd / (p["N"] * Jm) * (th_m / p["N"] - th_1) + T_fr / Jm),
        th_1 - (-Kp / J1 * (th_1 - th_2) + Khd / J1 * (th_m / p["N"] - th_1)),
        th_2 - (Kp / J2 * (th_1 - th_2) - p["K_L2"] * th_2 / J2 + T_dist / J2),
    ]
    return p, (I_m, th_m, th_1, th_2), eqs
