"""CasADi kernels of the nonlinear sampled-data simulation (docs/simulate.md): pure CasADi.

Per sample the C driver (``codegen/driver.c``, ``haa_simulate``) calls the *sample* function
(measurements with quantisation and noise, the controller's linear update, the saturation of the
held voltage) and then a *plant step* ``n_sub`` times: the exact zero-order-hold transition
(``zoh``), the same with the sample interval stretched by the jitter (``jitter``), or one
exponential Runge-Kutta substep (``etd``, ETDRK4) when Coulomb friction acts between samples;
with a fractional drive delay the driver runs the plant step over the two pieces of the sample
interval in turn, each with its own held command and parameters (the kernels are unchanged).
The matrix exponentials (Phi, Gamma; the half and full substep transitions) come in as inputs,
computed by ``scipy.linalg.expm`` (CasADi has no code-generable expm). Every vector is laid out
by name in ``haa_sym.compiled.layout``.
"""
from __future__ import annotations

import casadi as ca

from haa_sym.compiled import layout as L

# The jittered interval Ts + delta is stepped as n_sub equal parts, each exp(M_aug Ts/n_sub)
# (Phi, Gamma of Ts/n_sub, exact) times exp(M_aug delta/n_sub), a Taylor series applied to the
# vector; the runtime picks n_sub so that |lambda_max delta| / n_sub <= 1/2, where 12 terms
# leave a truncation below 1e-13 of the state.
JITTER_TERMS = 12
# SX (every multiply written out: the fastest code) up to capacity SX_MAX, MX above: there the
# products with the padded dense matrices stay loops in the C (an SX sample function of
# capacity 64 is 13,000 lines of C and made the library take 10x longer to compile)
SX_MAX = 8


def _sym(*caps):
    return ca.SX if max(caps) <= SX_MAX else ca.MX


def _mat(par, lay, name):
    r, c = lay.shape[name]
    return ca.reshape(par[lay[name]], r, c)


def _quantise(v, q):
    # q = 0 switches the quantiser off; if_else keeps the division's NaN out of the result
    return ca.if_else(q > 0, ca.floor(v / q + 0.5) * q, v)


def sample_function(nx: int, nc: int) -> ca.Function:
    """``(x, xc, exo, par) -> (u, xc_next, y)`` of one sample (layout: SIM_EXO, SIM_U, SIM_COLUMNS,
    :func:`haa_sym.compiled.layout.sim_ctrl_layout`)."""
    lay = L.sim_ctrl_layout(nx, nc)
    SYM = _sym(nx, nc)
    x, xc = SYM.sym("x", nx), SYM.sym("xc", nc)
    exo, par = SYM.sym("exo", len(L.SIM_EXO)), SYM.sym("par", lay.size)
    e = {n: exo[i] for i, n in enumerate(L.SIM_EXO)}
    row = {n: _mat(par, lay, n) for n in ("c_theta", "c_T", "c_I", "c_v", "c_w1", "c_w2")}
    p = {n: par[lay[n]][0] for n in ("w1", "w2", "q_theta", "q_T")}
    theta = _quantise(ca.mtimes(row["c_theta"], x), p["q_theta"])
    T = _quantise(ca.mtimes(row["c_T"], x) + e["noise_T"], p["q_T"])
    uin = ca.vertcat(theta, T, e["T_ff"], e["theta_ref"])
    out = ca.mtimes(_mat(par, lay, "Cc"), xc) + ca.mtimes(_mat(par, lay, "Dc"), uin)
    xc_next = ca.mtimes(_mat(par, lay, "Ac"), xc) + ca.mtimes(_mat(par, lay, "Bc"), uin)
    # two windows, each centred on a row of the state (docs/simulate.md, "Saturate"): the drive's
    # current limit first, the supply last, so that the supply holds also where the back-EMF puts
    # the whole of the first window outside it. A voltage command: the voltages whose steady
    # current at the present speed is within +-I_max (centre k_w dtheta_m, half-width R I_max),
    # then +-V_max. A current command: +-I_max, then the currents the supply sustains at the
    # present speed (centre -k_w dtheta_m / R, half-width V_max / R)
    c1, c2 = ca.mtimes(row["c_w1"], x), ca.mtimes(row["c_w2"], x)
    u_1 = ca.fmin(ca.fmax(out[0], c1 - p["w1"]), c1 + p["w1"])
    V = ca.fmin(ca.fmax(u_1, c2 - p["w2"]), c2 + p["w2"])
    sat = ca.if_else(V == out[0], 0, 1)
    y = ca.vertcat(theta, ca.mtimes(row["c_v"], x), T, out[1], V, ca.mtimes(row["c_I"], x), sat)
    u = ca.vertcat(V, e["T_dist"])
    names = L.sim_function_names(nx, nc)
    return ca.Function(names["sample"], [x, xc, exo, par], [u, xc_next, y],
                       ["x", "xc", "exo", "par"], ["u", "xc_next", "y"])


def plant_step_function(kind: str, nx: int, nc: int) -> ca.Function:
    """``(x, u, s, par) -> x_next``: one plant step of ``kind`` (``s`` is the sample's jitter
    ``delta``, s; unused by ``zoh`` and ``etd``)."""
    lay = L.sim_plant_layout(kind, nx)
    nu = len(L.SIM_U)
    SYM = _sym(nx)
    x, u, s = SYM.sym("x", nx), SYM.sym("u", nu), SYM.sym("s")
    par = SYM.sym("par", lay.size)
    m = {n: _mat(par, lay, n) for n in lay.names()}
    if kind == "zoh":
        x_next = ca.mtimes(m["Phi"], x) + ca.mtimes(m["Gamma"], u)
    elif kind == "jitter":
        d = s * m["inv_n"][0]
        v = x
        for j in range(JITTER_TERMS, 0, -1):        # Horner: v = x + (d/j) M_aug v
            v = x + (d / j) * ca.mtimes(m["M"], ca.vertcat(v, u))
        x_next = ca.mtimes(m["Phi"], v) + ca.mtimes(m["Gamma"], u)
    else:
        def N(xx):                                  # Coulomb friction torques, smooth (tanh) model,
            v = ca.mtimes(m["Fsel"], xx)            # less the slope ``lin`` moved into A (at stick)
            return -m["Fc"] * ca.tanh(v * m["inv_vs"][0]) + m["lin"] * v

        def E(xx):                                  # half-substep transition, held u
            return ca.mtimes(m["Ph"], xx) + ca.mtimes(m["Gh"], u)

        # ETDRK4 (Cox and Matthews 2002): the linear part and a constant friction exactly
        Ex = E(x)
        n0 = N(x)
        a = Ex + ca.mtimes(m["Qh"], n0)
        na = N(a)
        b = Ex + ca.mtimes(m["Qh"], na)
        nb = N(b)
        c = E(a) + ca.mtimes(m["Qh"], 2 * nb - n0)
        nc_ = N(c)
        x_next = ca.mtimes(m["P"], x) + ca.mtimes(m["G"], u) + ca.mtimes(m["F1"], n0) \
            + 2 * ca.mtimes(m["F2"], na + nb) + ca.mtimes(m["F3"], nc_)
    name = L.sim_function_names(nx, nc)[kind]
    return ca.Function(name, [x, u, s, par], [x_next], ["x", "u", "s", "par"], ["x_next"])


def simulation_functions() -> list[ca.Function]:
    """Every capacity's sample function and plant steps (plant steps once per nx)."""
    fns, seen = [], set()
    for nx, nc in L.SIM_CAPACITIES:
        fns.append(sample_function(nx, nc))
        for kind in L.SIM_PLANT_KINDS:
            f = plant_step_function(kind, nx, nc)
            if f.name() not in seen:
                seen.add(f.name())
                fns.append(f)
    return fns
