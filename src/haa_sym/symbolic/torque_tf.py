"""Eq. (3)-(6): the torque transfer function with velocity compensation, G_tVC.

``derive_g_tvc`` eliminates the unknowns of Eq. (1) with the velocity loop
``V_m = V + VC_gain * s * theta_L1`` closed (no averaging filter, as in Sec. 3.1) and returns
T_l / V of Eq. (2). ``paper_g_tvc`` is Eq. (3) built from the printed p1, q1, q2, q3 (Eq. 4).
"""
from __future__ import annotations

import sympy as sp

from haa_sym.symbolic.chain import cramer_solve
from haa_sym.symbolic.eom import laplace_equations, load_torque, plant_symbols, s

VC = sp.Symbol("VC_gain")  # the velocity-compensation transfer function, kept general
alpha = sp.Symbol("alpha", positive=True)


def derive_g_tvc_fraction(p: dict | None = None, vc=VC):
    """T_l/V with V_m = V + vc*s*theta_L1, derived from Eq. (1)-(2), as ``(num, den, ring)``.

    The Laplace equations are linear in the unknowns; Cramer's rule with fraction-free
    determinants (Bareiss, sympy's DomainMatrix) over the polynomial ring in the parameters,
    s, V and VC_gain gives theta_m and theta_L1 exactly, in a fraction of a second (sympy's
    ``solve`` + ``cancel`` on expressions took minutes). ``num``/``den`` are ring elements;
    ``ring.to_sympy`` turns them into expressions.
    """
    p, unknowns, eqs = laplace_equations(p)
    V = sp.Symbol("V")
    subs = {sp.Symbol("V_m"): V + vc * s * unknowns[2], sp.Symbol("T_fr"): 0, sp.Symbol("T_dist"): 0}
    sol, det, ring = cramer_solve([e.subs(subs) for e in eqs], unknowns, {V})
    th_m, th_1 = sol[unknowns[1]], sol[unknowns[2]]                  # times det
    K, D, N = (ring.from_sympy(p[k]) for k in ("K_hd", "D_hd", "N"))
    # Eq. (2): T_l = (K_hd + s D_hd)(theta_m/N - theta_L1)
    num = (K + ring.from_sympy(s) * D) * (th_m - N * th_1)
    den = N * det * ring.from_sympy(V)
    return num, den, ring


def derive_g_tvc(p: dict | None = None, vc=VC) -> sp.Expr:
    """:func:`derive_g_tvc_fraction` as an (uncancelled) sympy expression num/den."""
    num, den, ring = derive_g_tvc_fraction(p, vc)
    return ring.to_sympy(num) / ring.to_sympy(den)


def same_rational(num, den, expr: sp.Expr, ring) -> bool:
    """Whether num/den (elements of ``ring``) equals the rational expression ``expr``: the
    cross-multiplied polynomial identity, decided exactly in the ring (no ``cancel``)."""
    e_num, e_den = sp.fraction(sp.together(expr))
    field = ring.get_field()
    e_num, e_den = field.from_sympy(e_num), field.from_sympy(e_den)
    # e_num = a/b, e_den = c/d with a, b, c, d in the field's polynomial ring (= ring's)
    a, b, c, d = e_num.numer, e_num.denom, e_den.numer, e_den.denom
    return num * b * c == den * a * d


def paper_polynomials(p: dict | None = None) -> dict[str, sp.Expr]:
    """p1, q1, q2, q3 exactly as printed in Eq. (4)."""
    p = p or plant_symbols()
    JL2 = p["J_L2"] * s**2 + p["B_L2"] * s + p["K_L2"]
    JL1 = p["J_L1"] * s**2 + p["B_L1"] * s
    p1 = JL2 * JL1 + (JL2 + JL1) * (p["D_p"] * s + p["K_p"])
    q1 = (p["L"] * s + p["R"]) * (p["J_m"] * s**2 + p["B_m"] * s + (p["D_hd"] * s + p["K_hd"]) / p["N"]**2) \
        + p["k_t"] * p["k_w"] * s
    q2 = p["N"] / p["k_t"] * (p["L"] * s + p["R"]) * (p["J_m"] * s**2 + p["B_m"] * s) + p["N"] * p["k_w"] * s
    q3 = p["k_t"] / p["N"] * (p["J_L2"] * s**2 + p["B_L2"] * s + p["D_p"] * s + p["K_p"] + p["K_L2"]) \
        * (p["D_hd"] * s + p["K_hd"])
    return {"p1": sp.expand(p1), "q1": sp.expand(q1), "q2": sp.expand(q2), "q3": sp.expand(q3)}


def paper_g_tvc(p: dict | None = None, vc=VC) -> sp.Expr:
    """Eq. (3): k_t (D_hd s + K_hd) p1 / (N (p1 q1 + (q2 - VC_gain s) q3))."""
    p = p or plant_symbols()
    P = paper_polynomials(p)
    return p["k_t"] * (p["D_hd"] * s + p["K_hd"]) * P["p1"] / (
        p["N"] * (P["p1"] * P["q1"] + (P["q2"] - vc * s) * P["q3"]))


def vc_gain_exact(p: dict | None = None) -> sp.Expr:
    """Eq. (5): the VC_gain that makes q2 - VC_gain s vanish (a transfer function in s)."""
    p = p or plant_symbols()
    return p["N"] / p["k_t"] * (p["L"] * s + p["R"]) * (p["J_m"] * s + p["B_m"]) + p["N"] * p["k_w"]


def vc_gain_simplified(p: dict | None = None, a=alpha) -> sp.Expr:
    """Eq. (6): alpha N / k_t (R B_m + k_t k_w)."""
    p = p or plant_symbols()
    return a * p["N"] / p["k_t"] * (p["R"] * p["B_m"] + p["k_t"] * p["k_w"])


def pi_torque(P_t, I_t, Ts, z):
    """Eq. (7), both printed forms: (P_t + I_t Ts z/(z-1), (P_t + I_t Ts)(z - P_t/(P_t+I_t Ts))/(z-1))."""
    return (P_t + I_t * z * Ts / (z - 1),
            (P_t + I_t * Ts) * (z - P_t / (P_t + I_t * Ts)) / (z - 1))


__all__ = ["VC", "alpha", "derive_g_tvc", "derive_g_tvc_fraction", "same_rational", "paper_polynomials", "paper_g_tvc", "vc_gain_exact",
           "vc_gain_simplified", "pi_torque", "load_torque", "plant_symbols"]
