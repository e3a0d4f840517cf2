"""Translate the sympy model of an actuator (haa_sym.symbolic.chain) into a CasADi Function.

Used by ``make derive`` (codegen/generate.py, the built-in actuators) and by the runtime when a
user's actuator file has a topology that was not generated (haa_sym.topology_code): the only
place the compile step needs sympy.
"""
from __future__ import annotations

import casadi as ca
import sympy as sp

from haa_sym.actuator import Topology
from haa_sym.symbolic.chain import state_space, vc_gain_simplified


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


def plant_function(topology: Topology) -> ca.Function:
    """``haa_plant_<fingerprint>(p) -> (A, B, C, VC0)``: the chain's state space (Eq. 1-2 for
    HyQ) and Eq. (6) at alpha = 1.

    ``p`` is the plant vector in the order of ``topology.parameter_keys``.
    """
    ss = state_space(topology)
    keys = topology.parameter_keys
    p = ca.SX.sym("p", len(keys))
    env = {ss.symbols[k]: p[i] for i, k in enumerate(keys)}

    def mat(M: sp.Matrix) -> ca.SX:
        return ca.vertcat(*[ca.horzcat(*[to_sx(M[i, j], env) for j in range(M.cols)])
                            for i in range(M.rows)])

    vc0 = to_sx(vc_gain_simplified(ss.symbols, 1), env)
    return ca.Function(topology.function_name, [p], [mat(ss.A), mat(ss.B), mat(ss.C), vc0],
                       ["p"], ["A", "B", "C", "VC0"])
