"""Translate the sympy model (haa_sym.symbolic) into CasADi SX expressions."""
from __future__ import annotations

import casadi as ca
import sympy as sp

from haa_sym.params import PLANT_KEYS
from haa_sym.symbolic.eom import state_space
from haa_sym.symbolic.torque_tf import vc_gain_simplified


def to_sx(expr: sp.Expr, env: dict[sp.Symbol, ca.SX]) -> ca.SX:
    """Exact structural translation of a rational sympy expression (no floats introduced)."""
    if expr in env:
        return env[expr]
    if expr.is_Integer:
        return ca.SX(int(expr))
    if expr.is_Rational:
        return ca.SX(int(expr.p)) / ca.SX(int(expr.q))
    if expr.is_Float:
        raise ValueError(f"float constant {expr} in the symbolic model; use exact rationals")
    if expr.is_Add:
        out = ca.SX(0)
        for a in expr.args:
            out = out + to_sx(a, env)
        return out
    if expr.is_Mul:
        out = ca.SX(1)
        for a in expr.args:
            out = out * to_sx(a, env)
        return out
    if expr.is_Pow:
        base, ex = expr.args
        if ex.is_Integer:
            b = to_sx(base, env)
            return b ** int(ex) if int(ex) > 0 else 1 / b ** int(-ex)
    raise ValueError(f"cannot translate {expr!r} ({type(expr).__name__})")


def plant_function() -> ca.Function:
    """``haa_plant(p) -> (A, B, C, VC0)``: Eq. (1)-(2) state space and Eq. (6) at alpha = 1.

    ``p`` is the plant vector in the order of ``haa_sym.params.PLANT_KEYS``.
    """
    ss = state_space()
    p = ca.SX.sym("p", len(PLANT_KEYS))
    env = {ss.symbols[k]: p[i] for i, k in enumerate(PLANT_KEYS)}

    def mat(M: sp.Matrix) -> ca.SX:
        return ca.vertcat(*[ca.horzcat(*[to_sx(M[i, j], env) for j in range(M.cols)])
                            for i in range(M.rows)])

    vc0 = to_sx(vc_gain_simplified(ss.symbols, 1), env)
    return ca.Function("haa_plant", [p], [mat(ss.A), mat(ss.B), mat(ss.C), vc0],
                       ["p"], ["A", "B", "C", "VC0"])
