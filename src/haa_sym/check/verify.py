"""``python -m haa_sym.check.verify``: check the paper's equations and claims, one row each.

Symbolic rows use sympy (haa_sym.symbolic), each importing it itself: ``haa-sym`` imports this
module for its ``verify`` command, and no other command may pay sympy's import (about 0.4 s;
tests/test_cli_startup.py). Numeric rows use the generated evaluators on the
parameter file (default the bundled HyQ file). Each row prints PASS, FAIL or N/A (a row that
does not apply to this actuator, with the reason) with the numbers behind it; the exit status is
non-zero if any row fails. Nothing is compared against a typed-in expectation of the result:
the symbolic rows test identities, the numeric rows test the paper's stated inequalities.

Every actuator (``--params FILE``) gets the generic rows: its chain's state space == its Laplace
form, the generalised Eq. (3)-(5) (or why it does not apply), Eq. (6) and (7), and the generated
(or compiled) plant == the symbolic state space at the file's values. The HyQ topology also gets
the paper's rows (Eq. 1-5 as printed, p1, q1, q2, q3, and the claims of Sec. 3).
"""
from __future__ import annotations

import argparse
import random
import sys
import time
from dataclasses import dataclass

import numpy as np

from haa_sym.errors import CompilerError, StaleGeneratedCode
from haa_sym.compiled.generated import evaluators
from haa_sym.loop import ClosedLoop
from haa_sym.loop.plant import continuous_plant
from haa_sym.analysis.torque import torque_loop_margins
from haa_sym.model.actuator import CURRENT, HYQ, MOTOR_DOMAIN, Topology
from haa_sym.errors import ParameterError
from haa_sym.model.params import Params, load_params
from haa_sym.model.structures import STRUCTURES
from haa_sym.compiled.layout import gain_monomials
from haa_sym.loop.exact import transfer_polynomials
from haa_sym.model.elements import frequency_responses

LOAD_KEYS = ("J_L1", "B_L1", "J_L2", "B_L2", "K_L2", "K_p", "D_p")


@dataclass
class Row:
    claim: str
    ok: bool
    numbers: str
    note: str = ""
    applies: bool = True            # False: N/A for this actuator (``numbers`` says why)

    @property
    def status(self) -> str:
        return "N/A " if not self.applies else "PASS" if self.ok else "FAIL"


def _rational_params(params: Params, syms: dict, **override) -> dict:
    import sympy as sp
    vals = {k: sp.nsimplify(v, rational=True) for k, v in params.plant.as_dict().items()}
    vals.update({k: sp.nsimplify(v, rational=True) for k, v in override.items()})
    return {syms[k]: vals[k] for k in HYQ.parameter_keys}


def row_state_space(params: Params) -> Row:
    """The state space (used for code generation) and Eq. (1) give the same transfer matrix."""
    import sympy as sp
    from haa_sym.symbolic import eom
    ss = eom.state_space()
    syms = ss.symbols
    p, unknowns, eqs = eom.laplace_equations(syms)
    rng = random.Random(1)
    worst = 0
    for _ in range(5):
        # rational points: a rational identity of bounded degree checked exactly in QQ
        sub = {syms[k]: sp.Rational(rng.randint(1, 97), rng.randint(1, 13)) for k in HYQ.parameter_keys}
        s0 = sp.Rational(rng.randint(1, 500), rng.randint(1, 7))
        # xreplace, not subs: every symbol gets a rational at once, the same expressions at a
        # twentieth of subs's cost (subs re-walks and re-matches each expression per symbol)
        A, B, C = (sp.Matrix(M.xreplace(sub)).applyfunc(sp.Rational) for M in (ss.A, ss.B, ss.C))
        G_ss = C * (s0 * sp.eye(7) - A).LUsolve(B)
        at_point = [ei.xreplace({**sub, eom.s: s0}) for ei in eqs]
        for j, inp in enumerate(eom.INPUT_NAMES):
            e = [sp.together(ei.xreplace({sp.Symbol(n): sp.Integer(n == inp) for n in eom.INPUT_NAMES}))
                 for ei in at_point]
            M, rhs = sp.linear_eq_to_matrix([sp.numer(x) for x in e], unknowns)
            sol = M.LUsolve(rhs)
            th_m, th_1 = sol[1], sol[2]
            T_l = (sub[syms["K_hd"]] + s0 * sub[syms["D_hd"]]) * (th_m / sub[syms["N"]] - th_1)
            worst = max(worst, abs(sp.Rational(G_ss[0, j] - T_l)), abs(sp.Rational(G_ss[2, j] - th_1)))
    return Row("Eq. (1)-(2): state space == Laplace form (T_l, theta_L1 from V_m, T_fr, T_dist)",
               worst == 0, f"exact rational check at 5 random (params, s): max |diff| = {worst}",
               "corrected: T_fr, T_dist are torques on J_m, J_L2 (printed as added to angles); "
               "k_w in V s/rad")


def row_gtvc() -> Row:
    from haa_sym.symbolic import torque_tf as tt
    t = time.time()
    num, den, ring = tt.derive_g_tvc_fraction()
    same = tt.same_rational(num, den, tt.paper_g_tvc(), ring)
    return Row("Eq. (3)-(4): derived G_tVC == the paper's formula (p1, q1, q2, q3)", same,
               f"num_derived * den_paper - num_paper * den_derived == 0 in Q[params, s, V, VC_gain]: "
               f"{same} ({time.time() - t:.1f} s)")


def row_vc_exact() -> Row:
    import sympy as sp
    from haa_sym.symbolic import eom, torque_tf as tt
    syms = eom.plant_symbols()
    P = tt.paper_polynomials(syms)
    vc = tt.vc_gain_exact(syms)
    resid = sp.expand(P["q2"] - vc * eom.s)
    # with Eq. (5) in the loop, G_tVC must be k_t (D_hd s + K_hd) / (N q1): q1 has no load parameter
    num, den, ring = tt.derive_g_tvc_fraction(vc=vc)
    load_free = syms["k_t"] * (syms["D_hd"] * eom.s + syms["K_hd"]) / (syms["N"] * P["q1"])
    loads = sorted(str(x) for x in load_free.free_symbols if str(x) in LOAD_KEYS)
    same = tt.same_rational(num, den, load_free, ring)
    ok = resid == 0 and same and not loads
    return Row("Eq. (5): q2 - VC_gain s == 0, and G_tVC then has no load parameter", ok,
               f"q2 - VC_gain s = {resid}; G_tVC == k_t (D_hd s + K_hd)/(N q1) exactly: {same}; "
               f"load symbols in it: {loads or 'none'}")


def row_vc_simplified() -> Row:
    import sympy as sp
    from haa_sym.symbolic import eom, torque_tf as tt
    syms = eom.plant_symbols()
    d = sp.expand(tt.vc_gain_exact(syms).subs({syms["L"]: 0, syms["J_m"]: 0})
                  - tt.vc_gain_simplified(syms, 1))
    return Row("Eq. (6) is Eq. (5) with L = 0, J_m = 0 (alpha = 1)", d == 0, f"difference = {d}")


def row_p1_roots(params: Params) -> list[Row]:
    import sympy as sp
    from haa_sym.symbolic import eom, torque_tf as tt
    syms = eom.plant_symbols()
    rows = []
    for cfg in sorted(params.configurations):
        pc = params.configuration(cfg)
        p1 = tt.paper_polynomials(syms)["p1"]
        # the rational values once (nsimplify is the costly part); xreplace: every symbol at once
        sub = _rational_params(pc, syms, K_L2=0)
        r0 = sp.Poly(p1.xreplace(sub), eom.s)
        roots = sorted((complex(z) for z in r0.nroots(n=30)), key=lambda z: -z.real)
        real = all(abs(z.imag) < 1e-12 for z in roots)
        zero = abs(roots[0]) < 1e-12
        # the pole at zero of G_tVC (Eq. 3, alpha = 0.94) cancels with z1 = 0
        P = {k: v.xreplace(sub) for k, v in tt.paper_polynomials(syms).items()}
        vc = tt.vc_gain_simplified(syms, sp.Rational(94, 100)).xreplace(sub)
        num = sp.Poly(syms["k_t"].subs(sub) * (sub[syms["D_hd"]] * eom.s + sub[syms["K_hd"]]) * P["p1"], eom.s)
        den = sp.Poly(sub[syms["N"]] * (P["p1"] * P["q1"] + (P["q2"] - vc * eom.s) * P["q3"]), eom.s)
        pole0 = den.eval(0) == 0 and num.eval(0) == 0
        g = sp.gcd(num, den)
        cancelled = sp.Poly(sp.quo(den, g), eom.s).eval(0) != 0
        rows.append(Row(f"Sec. 3.1 ({cfg} leg, K_L2 = 0): p1 has 4 real roots z4<z3<z2<z1=0; "
                        "G_tVC's pole at 0 cancels", real and zero and len(roots) == 4 and pole0 and cancelled,
                        "roots of p1 [1/s]: " + ", ".join(f"{z.real:.6g}" for z in roots)
                        + f"; numerator and denominator vanish at s=0: {pole0}; after cancelling: "
                        f"no pole at 0: {cancelled}"))
        pk = sp.Poly(p1.xreplace(_rational_params(pc, syms)), eom.s)
        rk = sorted((complex(z) for z in pk.nroots(n=30)), key=lambda z: -z.real)
        nearest = rk[:2]
        ok = all(abs(z.imag) > 0 for z in nearest) and abs(nearest[0] - nearest[1].conjugate()) < 1e-9
        rows.append(Row(f"Sec. 3.1 ({cfg} leg, K_L2 = {pc.plant.K_L2}): the roots of p1 nearest the "
                        "imaginary axis are complex", ok,
                        "roots of p1: " + ", ".join(f"{z.real:.4g}{z.imag:+.4g}j" for z in rk)))
    return rows


def row_pi() -> Row:
    import sympy as sp
    from haa_sym.symbolic import torque_tf as tt
    P_t, I_t, Ts, z = sp.symbols("P_t I_t T_s z", positive=True)
    a, b = tt.pi_torque(P_t, I_t, Ts, z)
    d = sp.cancel(a - b)
    zero = sp.solve(sp.numer(sp.together(a)), z)
    ok = d == 0 and len(zero) == 1 and sp.simplify(zero[0] - P_t / (P_t + I_t * Ts)) == 0
    return Row("Eq. (7): both forms of PI_t(z) are equal; zero at P_t/(P_t + I_t Ts)", ok,
               f"difference = {d}; zero = {zero}")


def corners(params: Params):
    for cfg in sorted(params.configurations):
        for K in sorted({c["K_L2"] for c in params.configurations.values()}):
            yield cfg, K, params.configuration(cfg).with_values(K_L2=K)


def row_torque_margins(params: Params) -> list[Row]:
    rows = []
    for cfg, K, p in corners(params):
        loop = ClosedLoop(p)
        m = torque_loop_margins(loop)
        stable = bool(loop.stability(0.0, 0.0).stable)
        ok = stable and m.distance_deg > 30 and abs(m.gm_db) > 12
        rows.append(Row(
            f"Sec. 3.2: torque loop (beta = {p.controller.beta:g}, alpha = {p.controller.alpha:g}) at "
            f"J_L2 = {p.plant.J_L2}, K_L2 = {K}: PM > 30 deg, GM > 12 dB", ok,
            f"closed loop stable: {stable}; PM = {', '.join(f'{x:.2f}' for x in m.phase_margins_deg)} deg at "
            f"{', '.join(f'{x:.2f}' for x in m.gain_crossovers)} rad/s; GM = {', '.join(f'{x:.2f}' for x in m.gain_margins_db)} dB at "
            f"{', '.join(f'{x:.1f}' for x in m.phase_crossovers)} rad/s",
            f"P_t = {p.controller.P_t0:g} beta, I_t = {p.controller.I_t0:g} beta (Eq. 7; Table 2's "
            "caption rounds P_t to 0.38); loop opened at the PI output, P_gain = D_gain = 0, "
            "N_av-sample averaged velocity in the compensation, no computation delay"))
    return rows


def row_alpha_range(params: Params) -> Row:
    alphas = np.linspace(0, 1, 101)
    worst = []
    ok = True
    for cfg, K, p in corners(params):
        res = ClosedLoop(p).stability(0.0, 0.0, alpha=alphas, radius=True)
        ok &= bool(res.stable.all())
        worst.append(f"{cfg}/K_L2={K}: max rho = {res.spectral_radius.max():.6f}")
    return Row("Sec. 3.2: torque loop stable for every alpha in [0, 1] (101 values, 4 corners)", ok,
               "; ".join(worst))


# --- generic rows: any actuator topology ----------------------------------------------------
def row_chain_state_space(params: Params, n_points: int = 3) -> Row:
    """The chain's state space (code generation) and its Laplace form give the same transfer
    matrix, every output from every input, exactly at random rational (parameters, s)."""
    import sympy as sp
    from haa_sym.symbolic import chain
    top = params.plant.topology
    ss = chain.state_space(top)
    syms = ss.symbols
    _, unknowns, eqs, outputs = chain.laplace_equations(top, syms)
    rng = random.Random(1)
    worst, n = 0, len(top.state_names)
    for _ in range(n_points):
        sub = {syms[k]: sp.Rational(rng.randint(1, 97), rng.randint(1, 13)) for k in top.parameter_keys}
        s0 = sp.Rational(rng.randint(1, 500), rng.randint(1, 7))
        # xreplace: all symbols to rationals at once (row_state_space)
        A, B, C = (sp.Matrix(M.xreplace(sub)) for M in (ss.A, ss.B, ss.C))
        G_ss = C * (s0 * sp.eye(n) - A).LUsolve(B)
        at_point = [ei.xreplace({**sub, chain.s: s0}) for ei in eqs]
        outs_at_point = [y.xreplace({**sub, chain.s: s0}) for y in outputs]
        for j, inp in enumerate(top.input_names):
            e = [sp.together(ei.xreplace({sp.Symbol(x): sp.Integer(x == inp) for x in top.input_names}))
                 for ei in at_point]
            M, rhs = sp.linear_eq_to_matrix([sp.numer(x) for x in e], unknowns)
            sol = dict(zip(unknowns, M.LUsolve(rhs)))
            for i, y in enumerate(outs_at_point):
                val = y.xreplace(sol)
                worst = max(worst, abs(sp.Rational(sp.nsimplify(G_ss[i, j] - val))))
    nb, nc = len(top.bodies), len(top.couplings)
    return Row(f"Chain equations ({nb} bod{'y' if nb == 1 else 'ies'}, {nc} coupling{'' if nc == 1 else 's'}): state space "
               "== Laplace form, every output from V_m, T_fr, T_dist", worst == 0,
               f"exact rational check at {n_points} random (params, s), {len(outputs)} x 3 transfer "
               f"functions: max |diff| = {worst}")


def row_exact_vc_generalised(params: Params) -> Row:
    """Eq. (3)-(5) for any chain: with the exact compensation (Eq. 5, or N k_w for the current
    estimate), the measured torque / V depends on the motor and the gearbox alone, when it
    applies (:func:`haa_sym.symbolic.chain.exact_vc_condition`)."""
    from haa_sym.symbolic import chain, torque_tf as tt
    top = params.plant.topology
    rotor_side = top.encoder == "rotor" or top.sensor == CURRENT
    if top.sensor == CURRENT:
        claim = ("Eq. (3)-(5) generalised, torque from the current: with VC_gain = N k_w, "
                 "G_tVC = k_t N I_m / V = N k_t/(L s + R) (no parameter after the rotor)")
    elif rotor_side:
        claim = ("Eq. (3)-(5) generalised, motor-side encoder: with the exact VC_gain of Eq. (5), "
                 "G_tVC = N k_t/(L s + R) (no parameter after the rotor)")
    else:
        claim = ("Eq. (3)-(5) generalised: with the exact VC_gain of Eq. (5), G_tVC = k_t (K + s D)/(N q1) "
                 "of the gearbox alone (no parameter of the bodies after it)")
    applies, why = chain.exact_vc_condition(top)
    if not applies:
        return Row(claim, True, f"does not apply: {why}", applies=False)
    t = time.time()
    syms = chain.symbols(top)
    vc = chain.exact_vc_gain(top, syms)
    num, den, ring = chain.torque_tf_fraction(top, syms, vc=vc)
    expected = chain.load_free_g_tvc(top, syms)
    same = tt.same_rational(num, den, expected, ring)
    g = top.gearbox                     # None for a rotor-only actuator
    motor = set(MOTOR_DOMAIN) | ({f"K_{g.name}", f"D_{g.name}"} if g else set())
    loads = sorted(str(x) for x in expected.free_symbols if str(x) not in motor and str(x) != "s")
    spring = top.sensor != CURRENT and not top.torque_damping
    return Row(claim, same and not loads,
               f"{why}; derived == expected exactly in Q[params, s, V]: {same}; parameters after "
               f"the {'rotor' if rotor_side else 'gearbox'} in it: {loads or 'none'}"
               + ("; the sensor reads the spring alone: times K/(K + s D)" if spring else "")
               + f" ({time.time() - t:.1f} s)")


def row_plant_values(params: Params) -> Row:
    """The generated (or compiled) plant function == the actuator's sympy model
    (``symbolic_model(actuator)``: the chain's state space, or a model written in code) at the values."""
    import sympy as sp
    from haa_sym.symbolic.chain import symbolic_model
    top = params.plant.topology
    cp = continuous_plant(params.plant)
    m = symbolic_model(top)
    syms = m.symbols
    sub = {syms[k]: sp.nsimplify(v, rational=True) for k, v in params.plant.as_dict().items()}
    rel = 0.0
    for name, M, num in (("A", m.A, cp.A), ("B", m.B, cp.B), ("C", m.C, cp.C)):
        exact = np.array(M.subs(sub).evalf(30).tolist(), dtype=float)
        scale = np.maximum(np.abs(exact), np.abs(exact).max() * 1e-300)
        rel = max(rel, float(np.max(np.abs(num - exact) / np.where(exact != 0, scale, 1.0))))
    vc0 = float(m.VC0.subs(sub).evalf(30))
    rel = max(rel, abs(cp.VC0 - vc0) / abs(vc0) if vc0 else abs(cp.VC0))
    chain_ = isinstance(top, Topology)
    where = "generated" if top.fingerprint in _manifest_topologies() else \
        ("compiled from the file" if chain_ else "compiled from the model")
    what = "symbolic state space" if chain_ else "the model's A, B, C"
    vc = "VC0 == N/k_t (R B_m + k_t k_w)" if chain_ else "VC0 == the model's"
    return Row(f"Plant function ({where}, {top.function_name}) == {what} at the "
               f"values; {vc}", rel < 1e-12,
               f"max relative difference over A, B, C, VC0: {rel:.3g} (tolerance 1e-12)")


def _manifest_topologies() -> dict:
    return evaluators().code.manifest["topologies"]


def run(params: Params) -> list[Row]:
    if params.plant.topology == HYQ:
        rows = [row_state_space(params)]
        rows += [row_gtvc(), row_vc_exact(), row_vc_simplified()]
        rows += row_p1_roots(params)
        rows.append(row_pi())
        rows += row_torque_margins(params)
        rows.append(row_alpha_range(params))
        rows.append(row_plant_values(params))
        return rows + row_structures(params)
    if not isinstance(params.plant.topology, Topology):       # a sympy model written in code
        return [row_pi(), row_plant_values(params)]
    return generic_rows(params)


def generic_rows(params: Params) -> list[Row]:
    """The rows every actuator gets (``run`` gives HyQ the paper's rows instead of the first two)."""
    return [row_chain_state_space(params), row_exact_vc_generalised(params), row_vc_simplified(),
            row_pi(), row_plant_values(params)] + row_structures(params)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m haa_sym.check.verify", description=__doc__.splitlines()[0])
    ap.add_argument("--params", default=None, help="parameter file (default model/hyq_haa.toml)")
    args = ap.parse_args(argv)
    try:
        params = load_params(args.params)
        evaluators()  # refuse stale or damaged generated code before the slow symbolic rows
        rows = run(params)
    except (ParameterError, StaleGeneratedCode, CompilerError) as exc:
        print(f"haa-sym: error: {exc}", file=sys.stderr)
        return 2
    for i, r in enumerate(rows, 1):
        print(f"{i:2d} {r.status}  {r.claim}")
        print(f"          {r.numbers}")
        if r.note:
            print(f"          note: {r.note}")
    n_fail = sum(r.applies and not r.ok for r in rows)
    n_na = sum(not r.applies for r in rows)
    print(f"{len(rows) - n_fail - n_na} passed, {n_fail} failed"
          + (f", {n_na} not applicable" if n_na else ""))
    return 1 if n_fail else 0



# --- the controller structures (haa_sym.model.structures; docs/model.md, "Controller structures") --
#: The torque loop's values a file without one is checked with (the rows test identities, which
#: hold at any values): the paper's PI and compensation scale.
_STRUCTURE_DEFAULTS = {"P_t0": 0.382, "I_t0": 18.0, "beta": 1.0, "alpha": 0.94}


def _with_structure(params: Params, name: str) -> Params:
    """``params`` with ``structure = name``: the keys it reads from the file ([controller] or
    [controller.<name>]), else the paper's structure's of the file, else :data:`_STRUCTURE_DEFAULTS`."""
    ctrl = params.controller
    own = {k: getattr(ctrl, k) for k in STRUCTURES[ctrl.structure].keys}
    pool = {**_STRUCTURE_DEFAULTS, **ctrl.alternatives.get("paper", {}), **ctrl.alternatives.get(name, {}), **own}
    keys = {k: pool[k] for k in STRUCTURES[name].keys}
    return params.with_values(structure=name, **keys)


def row_structures(params: Params) -> list[Row]:
    """Each controller structure's closed loop, derived in sympy from its own block equations
    (u = P_r T_ref - P_m T + I_t I_z e + VC F_vc theta, e = T_ref - T, T_ref = -(P_gain + D_gain
    F_d) theta, V = z^-d u, theta, T and the port velocity from V and T_dist through the sampled
    plant): the characteristic polynomial of :class:`ClosedLoop` (its exact basis times the gain
    monomials) is the derived return difference times the loop's denominators (d(z), the
    delay's, the integrator's, the lcm of the estimates'), up to one constant factor, exactly
    at random rational z and gains; the port impedance Z = T_dist / velocity of the generated
    kernels equals the derived one on the options' grid (the plant's and the elements' responses
    substituted, 1e-9); the loop's constants are the structure's definition (R/(k_t N),
    1/(k_t N)) to 2 ulp."""
    import sympy as sp
    from fractions import Fraction
    rng = random.Random(24)
    names = ("GTV", "GTd", "GthV", "Gthd", "GpV", "Gpd", "F_d", "F_vc", "I_z", "zd")
    S = dict(zip(names, sp.symbols(names)))
    Pg, Dg, P_r, P_m, I_t, VC, T_dist, V = sp.symbols("P_gain D_gain P_r P_m I_t VC T_dist V")
    # the derivation, once for every structure: the structure only sets P_r, P_m, I_t, VC
    th = S["GthV"] * V + S["Gthd"] * T_dist
    T = S["GTV"] * V + S["GTd"] * T_dist
    T_ref = -(Pg + Dg * S["F_d"]) * th
    u = P_r * T_ref - P_m * T + I_t * S["I_z"] * (T_ref - T) + VC * S["F_vc"] * th
    V_sol = sp.solve(sp.Eq(V, S["zd"] * u), V)[0]
    Rd = sp.expand(1 - S["zd"] * sp.diff(u, V))                  # the return difference at V
    vel = sp.cancel((S["GpV"] * V_sol + S["Gpd"] * T_dist) / T_dist)
    Z_expr = sp.lambdify(list(S.values()) + [Pg, Dg, P_r, P_m, I_t, VC], 1 / vel, "numpy")

    def horner(c, x):
        v = Fraction(0)
        for ci in c:
            v = v * x + ci
        return v

    def sym_poly(c):
        n = len(c) - 1
        return sum(sp.Rational(ci.numerator, ci.denominator) * sp.Symbol("z") ** (n - i) for i, ci in enumerate(c))

    rows = []
    for name, st in STRUCTURES.items():
        t = time.time()
        p = _with_structure(params, name)
        loop = ClosedLoop(p)
        pl, ctrl, el = p.plant, p.controller, loop.elements
        d, nums = transfer_polynomials(loop.plant.Phi, loop.plant.Gamma[:, [0, 2]], loop.plant.C)
        averaged = loop.options.structure.port == "encoder_average"
        port = "theta_encoder" if averaged else loop.options.structure.port
        rowsof = {"T": loop.plant_output(loop.torque_output), "th": loop.plant_output("theta_encoder"),
                  "p": loop.plant_output(port)}
        k = pl.k_t * pl.N
        want = {"paper": (ctrl.P_t0, ctrl.P_t0, ctrl.I_t0, loop.plant.VC0),
                "torque_pi": (ctrl.P_t0, ctrl.P_t0, ctrl.I_t0, 0.0),
                "torque_pi_ff": (ctrl.P_t0 + pl.R / k, ctrl.P_t0, ctrl.I_t0, 0.0),
                "impedance_current": (1.0 / k, 0.0, 0.0, 0.0)}[name]
        got = (float(loop.const[0]), float(loop.P_m0), float(loop.const[1]), float(loop.const[2]))
        const_ok = all(abs(g - w) <= 2 * np.spacing(abs(w)) for g, w in zip(got, want))
        # the loop's denominators, from the elements' own (sympy's lcm of the estimates')
        zs = sp.Symbol("z")
        lcm = sp.Poly(sp.lcm(sym_poly(el["F_d"].denominator), sym_poly(el["F_vc"].denominator)), zs)
        lcm_c = [Fraction(int(c.p), int(c.q)) for c in lcm.all_coeffs()]
        exact = loop._exact_basis()
        ratios = set()
        for _ in range(3):
            pt = [Fraction(rng.randint(1, 3000)), Fraction(rng.randint(0, 50)), Fraction(1), Fraction(0)]
            if "beta" in st.keys:
                pt[2] = Fraction(rng.randint(1, 8), 4)
            if "alpha" in st.keys:
                pt[3] = Fraction(rng.randint(0, 10), 10)
            g = gain_monomials(pt, [Fraction(c) for c in got[:1] + got[2:]], Fraction(1))
            chi = [sum(gj * bj[i] for gj, bj in zip(g, exact)) for i in range(len(exact[0]))]
            gains = {P_r: pt[2] * Fraction(got[0]), P_m: pt[2] * Fraction(got[1]), I_t: pt[2] * Fraction(got[2]),
                     VC: pt[3] * Fraction(got[3]), Pg: pt[0], Dg: pt[1]}
            for z0 in (Fraction(rng.randint(2, 40), rng.randint(2, 9)), Fraction(-7, 3)):
                dz = horner(d, z0)
                val = {"GTV": horner(nums[rowsof["T"]][0], z0) / dz, "GthV": horner(nums[rowsof["th"]][0], z0) / dz,
                       "I_z": horner(el["I_z"].numerator, z0) / horner(el["I_z"].denominator, z0),
                       "zd": horner(el["z_delay"].numerator, z0) / horner(el["z_delay"].denominator, z0),
                       **{f: horner(el[f].numerator, z0) / horner(el[f].denominator, z0) for f in ("F_d", "F_vc")}}
                Den = dz * horner(el["z_delay"].denominator, z0) * horner(el["I_z"].denominator, z0) * horner(lcm_c, z0)
                rd = Rd.xreplace({**{S[n]: sp.Rational(v.numerator, v.denominator) for n, v in val.items()},
                                  **{s_: sp.Rational(v.numerator, v.denominator) for s_, v in gains.items()}})
                ratios.add(sp.Rational(horner(chi, z0).numerator, horner(chi, z0).denominator) / (rd * sp.Rational(
                    Den.numerator, Den.denominator)))
        chi_ok = len(ratios) == 1 and next(iter(ratios)) != 0
        # Z on the options' grid (every 50th frequency) at one gain point
        w = loop.options.omega(ctrl.Ts)[::50]
        P0, D0 = 0.3 * rng.randint(1, 3000), 0.01 * rng.randint(0, 500)
        G = loop.plant.frequency_response(w, outputs=(loop.torque_output, "theta_encoder", port),
                                          inputs=("V_m", "T_dist")).reshape(6, -1)
        E = dict(zip(("F_d", "F_vc", "I_z", "zd", "F_port"),
                     frequency_responses([el[k_] for k_ in ("F_d", "F_vc", "I_z", "z_delay", "F_port")], w, ctrl.Ts)))
        if averaged:
            G[4], G[5] = E["F_port"] * G[2], E["F_port"] * G[3]
        alpha = 1.0 if "alpha" in st.keys else 0.0
        Z_sym = Z_expr(*G, E["F_d"], E["F_vc"], E["I_z"], E["zd"], P0, D0, got[0], got[1], got[2], alpha * got[3])
        Z_loop = loop.frequency_response(w, P0, D0, 1.0, alpha).Z
        z_err = float(np.max(np.abs(Z_loop - Z_sym) / np.abs(Z_sym)))
        rows.append(Row(f"Controller structure {name!r} ({st.summary}): chi and Z equal their derivation from "
                        "the structure's equations (sympy)", chi_ok and const_ok and z_err < 1e-9,
                        f"chi / (return difference x denominators) one constant at 3 gain points x 2 rational z: "
                        f"{chi_ok}; constants (P_r0, P_m0, I_t0, VC0) = the definition to 2 ulp: {const_ok}; "
                        f"Z at {w.size} frequencies: max relative difference {z_err:.2g} (tolerance 1e-9) "
                        f"({time.time() - t:.1f} s)"))
    return rows


if __name__ == "__main__":
    sys.exit(main())
