"""CasADi kernels of the discrete closed loop (Sec. 3): pure CasADi, no sympy.

The closed loop has one actuated input (V_m). With the measured torque T, the encoder angle
theta, the velocity estimates F_d (D term, Eq. 8) and F_vc (velocity compensation, Eq. 6), the
torque PI of Eq. (7), the impedance law Eq. (8) and a computation delay, the characteristic
polynomial is affine in the gain monomials of ``haa_sym.compiled.layout``:

    chi(z) = b0 + P_t b1 + I_t b2 + P_t P_gain b3 + I_t P_gain b4 + (P_t D_gain - VC) b5
             + I_t D_gain b6 - VC b7

with basis polynomials b_j fixed per sampled plant and loop structure, built exactly from the
controller's elements (``haa_sym.model.elements``, ``haa_sym.loop.closed_loop``); b7 is the exact difference of
the compensation's and the D term's polynomials (zero when both use the same estimate). The
stability kernel works on their bilinear transforms (z = (1 + s)/(1 - s), computed exactly),
where the poles that crowd at z = 1 under fast sampling stay resolved: it returns the
Routh-Hurwitz decision and whether the rounding of the coefficients could change it. Per
frequency the loop-coefficient kernel takes the plant's and the elements' responses and returns
the gain-affine coefficients of the loop transfer functions (a gain sweep then costs one small
matrix product per frequency grid, see ``haa_sym.analysis.regions``). Every vector crossing to the
runtime is laid out by name in ``haa_sym.compiled.layout``.
"""
from __future__ import annotations

import functools

import casadi as ca

from haa_sym.compiled import layout as L

N_BASIS, N_CONST, N_POINT = len(L.GAIN_MONOMIALS), len(L.CONST), len(L.POINT)
# Bound on the rounding error of each coefficient of q = basis @ g, in units of the unit
# roundoff times (|basis| @ |g|): the basis rounded once (1), the products (1), the gain
# monomials themselves (3, g_5 = P_t D_gain - VC is a difference), the 8-term sum (8), the
# normalisation (1); doubled for safety.
COEF_ERROR_ULPS = 32.0
UNIT_ROUNDOFF = 2.0 ** -53
# Kharitonov's four vertex polynomials of the interval family q +- e, ascending coefficients:
# +1 takes the upper end of the interval, -1 the lower; the pattern repeats every 4 powers.
KHARITONOV_PATTERNS = ((-1, -1, +1, +1), (+1, +1, -1, -1), (-1, +1, +1, -1), (+1, -1, -1, +1))


def gain_monomials(point, const):
    """The coefficients g_j of chi = sum_j g_j b_j for one gain point (haa_sym.compiled.layout)."""
    return ca.vertcat(*L.gain_monomials(point, const))


def gain_monomial_bounds(point, const):
    """Upper bounds of |g_j| that also cover the rounding of g_5 = P_t D_gain - VC."""
    return ca.vertcat(*L.gain_monomial_bounds(point, const, ca.fabs))


@functools.lru_cache(maxsize=None)
def routh_function(cap: int) -> ca.Function:
    """Routh-Hurwitz test of a real polynomial of degree ``cap`` (ascending coefficients).

    The Routh array of q(s) = sum_k a_k s^k: the first two rows hold the coefficients of even
    and odd distance from the leading one; each next row is r2_j = r0_(j+1) - (r0_0/r1_0)
    r1_(j+1). With a positive leading coefficient, the number of sign changes down the first
    column is the number of roots in Re s > 0 (Routh 1877). Outputs ``changes`` and ``regular``
    (0 when a first-column entry is zero or not finite: the singular case, left to the caller).
    Cached: the decision function of one capacity calls one shared copy in the C.
    """
    a = ca.SX.sym("a", cap + 1)
    desc = [a[cap - i] for i in range(cap + 1)]
    r0, r1 = desc[0::2], desc[1::2]
    first = [r0[0], r1[0]]
    for _ in range(cap - 1):
        m = r0[0] / r1[0]
        new = [r0[j + 1] - m * (r1[j + 1] if j + 1 < len(r1) else 0) for j in range(len(r0) - 1)]
        r0, r1 = r1, new
        first.append(r1[0])
    changes = ca.SX(0)
    regular = ca.SX(1)
    for i, f in enumerate(first):
        # |f| < inf is false for NaN as well as for +-inf
        regular = regular * (ca.fabs(f) > 0) * (ca.fabs(f) < ca.inf)
        if i:
            changes = changes + ca.fabs((first[i - 1] < 0) - (f < 0))
    return ca.Function(f"haa_routh{cap}", [a], [changes, regular], ["a"], ["changes", "regular"])


def decision_function(cap: int) -> ca.Function:
    """Stability decision of one gain point, certified against the rounding of chi.

    Inputs: ``basis`` (cap+1 x 8): ascending coefficients of the bilinear transforms
    q_j(s) = (1 - s)^cap b_j((1 + s)/(1 - s)) of the basis polynomials (computed exactly, rounded
    once; ``haa_sym.loop.closed_loop``), const [P_t0, I_t0, VC0], point [P_gain, D_gain, beta, alpha].

    chi is Schur stable iff q = basis @ g is Hurwitz stable. Outputs:
    ``n_unstable``  sign changes of q's Routh array = closed-loop poles outside |z| = 1;
    ``certified``   1 when every polynomial within the rounding bound e of q (|dq_k| <= e_k,
                    COEF_ERROR_ULPS) has the same decision: the Routh tests of Kharitonov's four
                    vertex polynomials agree with q's (for a stable q this is Kharitonov's
                    theorem: the whole interval family is Hurwitz), no Routh array is singular
                    and the leading coefficient's interval excludes 0. Otherwise 0: the caller
                    re-decides the point from eigenvalues.
    """
    routh = routh_function(cap)
    basis = ca.MX.sym("basis", cap + 1, N_BASIS)
    const = ca.MX.sym("const", N_CONST)
    point = ca.MX.sym("point", N_POINT)
    q = ca.mtimes(basis, gain_monomials(point, const))
    e = COEF_ERROR_ULPS * UNIT_ROUNDOFF * ca.mtimes(ca.fabs(basis), gain_monomial_bounds(point, const))
    # positive leading coefficient, largest coefficient 1: Routh's rule needs the sign and the
    # array stays in range
    scale = ca.sign(q[cap]) / ca.mmax(ca.fabs(q))
    q = q * scale
    e = e * ca.fabs(scale)
    changes, regular = routh(q)
    stable = changes < 0.5
    certified = regular * (q[cap] > e[cap])
    for pattern in KHARITONOV_PATTERNS:
        signs = ca.DM([pattern[k % 4] for k in range(cap + 1)])
        ch, reg = routh(q + signs * e)
        certified = certified * reg * ((ch < 0.5) == stable)
    return ca.Function(f"haa_decide{cap}", [basis, const, point], [changes, certified],
                       ["basis", "const", "point"], ["n_unstable", "certified"])


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


def loop_coefficient_function() -> ca.Function:
    """Gain-affine coefficients of the loop transfer functions at one frequency.

    Inputs: ``Gw``: one column per frequency, the complex values (re, im) named by
    ``haa_sym.compiled.layout.FREQ_COLUMN``: the sampled plant's responses from V_m and T_dist to the
    measured torque T, the encoder angle theta and the port velocity p, and the controller
    elements (``haa_sym.model.elements``) at z = exp(j w Ts): the velocity estimates of the D term
    (F_d) and of the compensation (F_vc), the PI's integral part I_z = Ts z/(z - 1) and the
    delay z^-d. ``const`` (layout.CONST) and ``gains`` (layout.TORQUE_GAINS).

    Output ``coef``: the complex values (re, im) named by ``layout.COEF_OUTPUTS``: for each of
    L_t, L_imp, Z_num, Z_den the coefficients of x = (1, P_gain, D_gain), so that

    L_t   = c . x  torque loop opened at the PI output (VC loop and impedance loop closed;
                   P_gain = D_gain = 0 is the torque loop alone);
    L_imp = c . x  impedance loop opened at the torque reference T_lref (torque and VC loops closed);
    Z     = (Z_num . x) / (Z_den . x), the driving-port impedance T_dist / velocity (Sec. 5);

    then H_T = T / T_lref with the impedance loop open.
    Sign convention: negative feedback, closed loop 1/(1 + L).
    """
    Gw = ca.SX.sym("Gw", 2 * len(L.FREQ_COLUMN))
    v = {name: _c(Gw[2 * i], Gw[2 * i + 1]) for i, name in enumerate(L.FREQ_COLUMN)}
    const = ca.SX.sym("const", N_CONST)
    gains = ca.SX.sym("gains", len(L.TORQUE_GAINS))
    g = L.torque_gains(gains[L.TORQUE_GAINS.index("beta")], gains[L.TORQUE_GAINS.index("alpha")], const)
    P_t, I_t, VC = g["P_t"], g["I_t"], g["VC"]
    G_TV, G_Td, G_thV, G_thd, G_pV, G_pd = (v[k] for k in ("G_TV", "G_Td", "G_thV", "G_thd", "G_pV", "G_pd"))
    F, F_vc, zd = v["F_d"], v["F_vc"], v["z_delay"]
    zero = _c(0, 0)
    PI = _add(_c(P_t, 0), _scale(I_t, v["I_z"]))                        # Eq. (7)
    dPI = _mul(zd, PI)
    dVCF = _mul(zd, _scale(VC, F_vc))                                  # Eq. (6) on the estimate
    vc_loop = _sub(_c(1, 0), _mul(dVCF, G_thV))                        # 1 - z^-d VC F_vc G_thV
    R0 = _add(vc_loop, _mul(dPI, G_TV))                                # torque + VC loops closed
    # the impedance law imp = P_gain + D_gain F_d (Eq. 8) multiplies everything below
    A = _div(_mul(dPI, G_thV), R0)
    L_imp = (zero, A, _mul(F, A))
    L_t = (_div(_mul(dPI, G_TV), vc_loop), _div(_mul(dPI, G_thV), vc_loop),
           _div(_mul(_mul(dPI, F), G_thV), vc_loop))
    # every loop closed: R = R0 + imp dPI G_thV; V/T_dist = N/R with
    # N = (z^-d VC F_vc - dPI imp) G_thd - dPI G_Td; port velocity/T_dist = pd + pV N/R
    r = (R0, _mul(dPI, G_thV), _mul(_mul(F, dPI), G_thV))
    n = (_sub(_mul(dVCF, G_thd), _mul(dPI, G_Td)), _scale(-1, _mul(dPI, G_thd)),
         _scale(-1, _mul(_mul(F, dPI), G_thd)))
    Z_num = r
    Z_den = tuple(_add(_mul(G_pd, r[i]), _mul(G_pV, n[i])) for i in range(3))
    H_T = _div(_mul(dPI, G_TV), R0)
    forms = dict(zip(L.COEF_FORMS, (L_t, L_imp, Z_num, Z_den)))
    values = {f"{form}.{t}": forms[form][i] for form in L.COEF_FORMS for i, t in enumerate(L.COEF_TERMS)}
    values["H_T"] = H_T
    out = [x for name in L.COEF_OUTPUTS for x in values[name]]
    return ca.Function("haa_loopcoef", [Gw, const, gains], [ca.vertcat(*out)],
                       ["Gw", "const", "gains"], ["coef"])
