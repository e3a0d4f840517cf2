"""Translate the sympy model of an actuator (a :class:`~haa_sym.symbolic.model.LinearActuatorModel`,
from a chain topology or written in code) into a CasADi Function.

Used by ``make derive`` (codegen/generate.py, the built-in actuators) and by the runtime when an
actuator has no generated code (haa_sym.compiled.plant_code): the only place the compile step needs sympy.
"""
from __future__ import annotations

import casadi as ca
import sympy as sp

from haa_sym.symbolic.model import LinearActuatorModel


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


def plant_function(model: LinearActuatorModel, name: str | None = None) -> ca.Function:
    """``name(p) -> (A, B, C, VC0)``: the model's state space (Eq. 1-2 for HyQ) and VC0 (Eq. 6
    at alpha = 1), exactly as written (no simplification, no floats).

    ``p`` is the plant vector in the order of ``model.parameter_keys``; ``name`` defaults to
    ``model.function_name`` (a chain's is its topology's, ``Topology.function_name``).
    """
    keys = model.parameter_keys
    p = ca.SX.sym("p", len(keys))
    syms = model.symbols
    env = {syms[k]: p[i] for i, k in enumerate(keys)}

    def mat(M: sp.Matrix) -> ca.SX:
        return ca.vertcat(*[ca.horzcat(*[to_sx(M[i, j], env) for j in range(M.cols)])
                            for i in range(M.rows)])

    vc0 = to_sx(model.VC0, env)
    return ca.Function(name or model.function_name, [p], [mat(model.A), mat(model.B), mat(model.C), vc0],
                       ["p"], ["A", "B", "C", "VC0"])
