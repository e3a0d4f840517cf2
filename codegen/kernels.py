"""CasADi kernels of the discrete closed loop (Sec. 3): pure CasADi, no sympy.

The closed loop has one actuated input (V_m). With the measured torque T, the encoder angle
theta_L1, the averaging filters F_N(z) = (1 - z^-N)/(N Ts) of the D term (N = N_D) and of the
velocity compensation (N = N_VC), PI_t(z) of Eq. (7), the impedance law Eq. (8), velocity
compensation VC * F_NVC(z) * theta_L1 (Eq. 6) and a computation delay of ``d`` samples, the
characteristic polynomial is

    chi(z) = b0 + P_t b1 + I_t b2 + P_t P_gain b3 + I_t P_gain b4 + (P_t D_gain - VC) b5
             + I_t D_gain b6 - VC b7

where b7 is the exact difference of the compensation's and the D term's polynomials (zero when
both use the same average): P_t D_gain and VC nearly cancel in parts of the gain plane, so the
two must not be rounded separately.

with basis polynomials b_j fixed per discretised plant (see ``haa_sym.loop``). These kernels take
the basis and a gain point and return the Schur-Cohn (Jury) decision and the spectral radius,
and, per frequency, the gain-affine coefficients of the loop transfer functions in real
arithmetic (a gain sweep then costs one small matrix product per frequency grid, see
``haa_sym.regions``).
"""
from __future__ import annotations

import functools

import casadi as ca
import numpy as np

N_BASIS = 8
N_CONST = 3   # P_t0, I_t0, VC0
N_POINT = 4   # P_gain, D_gain, beta, alpha
# 2^-30 ~ 1e-9: below the ~1e-8 radius accuracy of the monomial basis at Ts = 1 ms
BISECTION_STEPS = 30


def gain_monomials(point, const):
    """The coefficients g_j of chi = sum_j g_j b_j for one gain point."""
    P, D, beta, alpha = point[0], point[1], point[2], point[3]
    P_t = beta * const[0]
    I_t = beta * const[1]
    VC = alpha * const[2]
    return ca.vertcat(1, P_t, I_t, P_t * P, I_t * P, P_t * D - VC, I_t * D, -VC)


@functools.lru_cache(maxsize=None)
def jury_function(cap: int) -> ca.Function:
    """Schur-Cohn test of a real polynomial of degree ``cap`` (ascending coefficients).

    Lattice form: with p_m and its reverse p*_m, k_m = p_m(0)/p*_m(0) and
    p_{m-1} = (p_m - k_m p*_m)/(z (1 - k_m^2)), p*_{m-1} = (p*_m - k_m p_m)/(1 - k_m^2).
    All roots lie in |z| < 1 iff every |k_m| < 1. Returns max_m |k_m| (stable iff < 1).
    Roots at z = 0 (leading zero coefficients, used to pad lower degrees) give k_m = 0.
    Cached: the decision and radius functions of one capacity share one copy in the C.
    """
    a = ca.SX.sym("a", cap + 1)
    inv_lead = 1 / a[cap]
    P = [a[i] * inv_lead for i in range(cap + 1)]
    S = P[::-1]
    kmax = ca.SX(0)
    for m in range(cap, 0, -1):
        k = P[0]  # S[0] is kept at 1 by the normalisation below
        kmax = ca.fmax(kmax, ca.fabs(k))
        # past an unstable step the remaining k's are meaningless; keep the arithmetic finite
        inv = 1 / ca.if_else(ca.fabs(k) < 1, 1 - k * k, 1)
        P, S = ([(P[i + 1] - k * S[i + 1]) * inv for i in range(m)],
                [(S[i] - k * P[i]) * inv for i in range(m)])
    return ca.Function(f"haa_jury{cap}", [a], [kmax], ["a"], ["kmax"])


def stability_function(cap: int, steps: int = BISECTION_STEPS) -> ca.Function:
    """Decision and spectral radius of chi for one gain point.

    Inputs: ``basis`` (cap+1 x 8, ascending coefficients of b_j), const [P_t0, I_t0, VC0],
    point [P_gain, D_gain, beta, alpha].
    Outputs: ``kmax`` of the Schur-Cohn test (stable iff < 1) and ``rho``, the spectral radius
    by ``steps`` halvings on chi(r z) (stable iff all roots inside |z| < r): linear on [0, 1] when stable,
    geometric on [1, Cauchy bound] when not, so rho <= 1 iff the test says stable.
    """
    jury = jury_function(cap)
    basis = ca.MX.sym("basis", cap + 1, N_BASIS)
    const = ca.MX.sym("const", N_CONST)
    point = ca.MX.sym("point", N_POINT)
    a = ca.mtimes(basis, gain_monomials(point, const))
    kmax = jury(a)
    stable = kmax < 1
    cauchy = 1 + ca.mmax(ca.fabs(a[:cap])) / ca.fabs(a[cap])
    lo = ca.if_else(stable, 0, 1)
    hi = ca.if_else(stable, 1, cauchy)
    # a_i r^(i - cap): chi(r z)/r^cap, scaled to keep the largest power bounded
    powers = ca.DM(np.arange(cap + 1, dtype=float) - cap)
    for _ in range(steps):
        r = ca.if_else(stable, (lo + hi) / 2, ca.sqrt(lo * hi))
        inside = jury(a * r ** powers) < 1
        lo = ca.if_else(inside, lo, r)
        hi = ca.if_else(inside, r, hi)
    return ca.Function(f"haa_stab{cap}", [basis, const, point], [kmax, hi],
                       ["basis", "const", "point"], ["kmax", "rho"])


def _c(re, im):
    return (re, im)


def _mul(a, b):
    return (a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0])


def _add(a, b):
    return (a[0] + b[0], a[1] + b[1])


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1])


def _scale(k, a):
    return (k * a[0], k * a[1])


def _div(a, b):
    den = b[0] * b[0] + b[1] * b[1]
    return ((a[0] * b[0] + a[1] * b[1]) / den, (a[1] * b[0] - a[0] * b[1]) / den)


N_PLANT_RESP = 12  # re/im of G_TV, G_Td, G_thV, G_thd, G_pV, G_pd
N_STRUCT = 6       # Ts, N_av, delay (samples), port_average (0/1), N_VC, N_D
N_TORQUE_GAINS = 2  # beta, alpha
# Every loop transfer below is affine in x = (1, P_gain, D_gain) or a ratio of two such forms,
# because the impedance law Eq. (8) enters linearly through the torque reference.
COEF_OUTPUTS = ("L_t", "L_imp", "Z_num", "Z_den")


def decision_function(cap: int) -> ca.Function:
    """Schur-Cohn decision without the radius, for one gain point.

    Inputs as :func:`stability_function` plus ``s_in`` and ``s_out``, the scalings
    r^(i - cap) of the ascending coefficients for r = 1 - band and r = 1 + band (passed in
    rather than computed: 2 x (cap+1) pow calls per point cost as much as a test).
    Outputs ``kmax``, ``k_in`` and ``k_out``: stable iff kmax < 1; k_in < 1 iff every root lies
    in |z| < 1 - band; k_out < 1 iff every root lies in |z| < 1 + band. A point with
    k_in >= 1 > k_out has its spectral radius within ``band`` of 1 and must be re-decided by
    eigenvalues.

    The test at 1 - band runs first: when it passes (most stable points) the point is stable and
    not near the boundary, the other two tests are skipped (short-circuit branch) and all three
    outputs are k_in. Otherwise all three run.
    """
    jury = jury_function(cap)
    basis = ca.MX.sym("basis", cap + 1, N_BASIS)
    const = ca.MX.sym("const", N_CONST)
    point = ca.MX.sym("point", N_POINT)
    s_in = ca.MX.sym("s_in", cap + 1)
    s_out = ca.MX.sym("s_out", cap + 1)
    a = ca.mtimes(basis, gain_monomials(point, const))
    k_in = jury(a * s_in)
    rest = ca.if_else(k_in < 1, ca.vertcat(k_in, k_in), ca.vertcat(jury(a), jury(a * s_out)), True)
    return ca.Function(f"haa_decide{cap}", [basis, const, point, s_in, s_out],
                       [rest[0], k_in, rest[1]],
                       ["basis", "const", "point", "s_in", "s_out"], ["kmax", "k_in", "k_out"])


def loop_coefficient_function() -> ca.Function:
    """Gain-affine coefficients of the loop transfer functions at one frequency.

    Inputs: ``G`` (12): the discretised plant's responses at z = exp(j w Ts) from V_m and T_dist
    to the measured torque T, the encoder angle theta_L1 and the port velocity p;
    ``wTs`` (w Ts, rad); ``const`` [P_t0, I_t0, VC0]; ``gains`` [beta, alpha];
    ``struct`` [Ts, N_av, delay, port_average, N_VC, N_D]: the averaging lengths of the port
    velocity (when averaged), the velocity compensation and the D term.

    Output ``coef`` (26 reals): for each of L_t, L_imp, Z_num, Z_den the complex coefficients
    (c_1, c_P, c_D), each as (re, im), so that, with x = (1, P_gain, D_gain),

    L_t   = c . x  torque loop opened at the PI output (VC loop and impedance loop closed;
                   P_gain = D_gain = 0 is the torque loop alone);
    L_imp = c . x  impedance loop opened at the torque reference T_lref (torque and VC loops closed);
    Z     = (Z_num . x) / (Z_den . x), the driving-port impedance T_dist / velocity (Sec. 5);

    then H_T = T / T_lref with the impedance loop open (re, im).
    Sign convention: negative feedback, closed loop 1/(1 + L).
    """
    G = ca.SX.sym("G", N_PLANT_RESP)
    wTs = ca.SX.sym("wTs")
    const = ca.SX.sym("const", N_CONST)
    gains = ca.SX.sym("gains", N_TORQUE_GAINS)
    struct = ca.SX.sym("struct", N_STRUCT)
    G_TV, G_Td, G_thV, G_thd, G_pV, G_pd = (_c(G[2 * i], G[2 * i + 1]) for i in range(6))
    beta, alpha = gains[0], gains[1]
    P_t, I_t, VC = beta * const[0], beta * const[1], alpha * const[2]
    Ts, N_av, delay, port_avg, N_vc, N_d = (struct[i] for i in range(6))
    # 1 - exp(-j x) = 2 sin^2(x/2) + j sin(x): no cancellation at low frequency
    def one_minus_expm(x):
        return _c(2 * ca.sin(x / 2) ** 2, ca.sin(x))
    zero = _c(0, 0)
    def average(N):                                                    # (1 - z^-N)/(N Ts)
        return _scale(1 / (N * Ts), one_minus_expm(N * wTs))
    F = average(N_d)                                                   # D term of Eq. (8)
    F_vc = average(N_vc)                                               # Eq. (6)
    F_port = average(N_av)                                             # averaged port velocity
    PI = _add(_c(P_t, 0), _div(_c(I_t * Ts, 0), one_minus_expm(wTs)))  # Eq. (7)
    zd = _c(ca.cos(delay * wTs), -ca.sin(delay * wTs))                 # z^-delay
    dPI = _mul(zd, PI)
    dVCF = _mul(zd, _scale(VC, F_vc))                                  # Eq. (6) on the filtered v
    vc_loop = _sub(_c(1, 0), _mul(dVCF, G_thV))                        # 1 - z^-d VC F G_thV
    R0 = _add(vc_loop, _mul(dPI, G_TV))                                # torque + VC loops closed
    # the impedance law imp = P_gain + D_gain F (Eq. 8) multiplies everything below
    A = _div(_mul(dPI, G_thV), R0)
    L_imp = (zero, A, _mul(F, A))
    L_t = (_div(_mul(dPI, G_TV), vc_loop), _div(_mul(dPI, G_thV), vc_loop),
           _div(_mul(_mul(dPI, F), G_thV), vc_loop))
    # every loop closed: R = R0 + imp dPI G_thV; V/T_dist = N/R with
    # N = (z^-d VC F - dPI imp) G_thd - dPI G_Td; port velocity/T_dist = pd + pV N/R
    r = (R0, _mul(dPI, G_thV), _mul(_mul(F, dPI), G_thV))
    n = (_sub(_mul(dVCF, G_thd), _mul(dPI, G_Td)), _scale(-1, _mul(dPI, G_thd)),
         _scale(-1, _mul(_mul(F, dPI), G_thd)))
    pick = lambda avg, other: (ca.if_else(port_avg > 0.5, avg[0], other[0]),
                               ca.if_else(port_avg > 0.5, avg[1], other[1]))
    pV = pick(_mul(F_port, G_thV), G_pV)
    pd = pick(_mul(F_port, G_thd), G_pd)
    Z_num = r
    Z_den = tuple(_add(_mul(pd, r[i]), _mul(pV, n[i])) for i in range(3))
    H_T = _div(_mul(dPI, G_TV), R0)
    out = [v for form in (L_t, L_imp, Z_num, Z_den) for c in form for v in c] + list(H_T)
    return ca.Function("haa_loopcoef", [G, wTs, const, gains, struct], [ca.vertcat(*out)],
                       ["G", "wTs", "const", "gains", "struct"], ["coef"])
