"""The contract between code generation and runtime: every vector that crosses it, by name.

Both ``codegen/kernels.py`` (which writes the CasADi functions) and the runtime
(:mod:`haa_sym.loop.closed_loop`) read the layouts below; nothing across that boundary is a positional
vector or a magic offset written twice. This module imports neither sympy nor CasADi: the
functions take whatever arithmetic the caller works in (CasADi SX/MX or numpy arrays).

The gain layout
---------------
Every feedback path of the loop enters through the one actuated input V_m, so the closed-loop
characteristic polynomial is affine in a few *gain monomials* (matrix determinant lemma):

    chi(z) = sum_j g_j b_j(z)

with basis polynomials b_j fixed per sampled plant and loop structure (``haa_sym.loop.closed_loop``) and
g_j products of the torque PI gains P_t = beta P_t0, I_t = beta I_t0 (Eq. 7), the velocity
compensation VC = alpha VC0 (Eq. 6) and the impedance gains P_gain, D_gain (Eq. 8).
:data:`GAIN_MONOMIALS` lists them; ``g_5 = P_t D_gain - VC`` is kept as one difference
because the two nearly cancel in parts of the gain plane and must be rounded together.
"""
from __future__ import annotations

__all__ = ["CONST", "POINT", "TORQUE_GAINS", "GAIN_MONOMIALS", "N_BASIS", "torque_gains",
           "gain_monomials", "gain_monomial_bounds", "FREQ_COLUMN", "COEF_FORMS", "COEF_TERMS",
           "COEF_OUTPUTS", "SIM_CAPACITIES", "SIM_FRICTION_CAP", "SIM_EXO", "SIM_COLUMNS", "SIM_U",
           "sim_ctrl_layout", "sim_plant_layout", "sim_function_names", "Slices"]

# Per-loop constants, per-point gains (the order of the generated functions' inputs).
CONST = ("P_t0", "I_t0", "VC0")              # V/Nm, V/(Nm s), V s/rad (Eq. 6 at alpha = 1)
POINT = ("P_gain", "D_gain", "beta", "alpha")  # Nm/rad, Nms/rad, -, -
TORQUE_GAINS = ("beta", "alpha")

# Each monomial is a sum of signed products of named factors (P_t, I_t, VC, P_gain, D_gain).
GAIN_MONOMIALS: tuple[tuple[str, tuple[tuple[int, tuple[str, ...]], ...]], ...] = (
    ("1", ((1, ()),)),
    ("P_t", ((1, ("P_t",)),)),
    ("I_t", ((1, ("I_t",)),)),
    ("P_t*P_gain", ((1, ("P_t", "P_gain")),)),
    ("I_t*P_gain", ((1, ("I_t", "P_gain")),)),
    ("P_t*D_gain-VC", ((1, ("P_t", "D_gain")), (-1, ("VC",)))),
    ("I_t*D_gain", ((1, ("I_t", "D_gain")),)),
    ("-VC", ((-1, ("VC",)),)),
)
N_BASIS = len(GAIN_MONOMIALS)


def torque_gains(beta, alpha, const):
    """Eq. (6)-(7): ``{P_t, I_t, VC}`` from the scales beta, alpha and ``const`` (:data:`CONST`)."""
    P_t0, I_t0, VC0 = (const[i] for i in range(len(CONST)))
    return {"P_t": beta * P_t0, "I_t": beta * I_t0, "VC": alpha * VC0}


def _factors(point, const, absolute=None):
    P, D, beta, alpha = (point[i] for i in range(len(POINT)))
    f = {"P_gain": P, "D_gain": D, **torque_gains(beta, alpha, const)}
    return {k: absolute(v) for k, v in f.items()} if absolute else f


def _product(names, f, one):
    out = one
    for n in names:
        out = out * f[n]
    return out


def gain_monomials(point, const, one=1.0) -> list:
    """g_j of :data:`GAIN_MONOMIALS` at ``point`` (:data:`POINT`), in the caller's arithmetic.

    ``one`` is the unit of that arithmetic (e.g. ``np.ones(k)`` for k points at once).
    """
    f = _factors(point, const)
    out = []
    for _, terms in GAIN_MONOMIALS:
        g = None
        for sign, names in terms:
            t = _product(names, f, one)
            t = t if sign > 0 else -t
            g = t if g is None else g + t
        out.append(g)
    return out


def gain_monomial_bounds(point, const, absolute, one=1.0) -> list:
    """Upper bounds of |g_j| that also cover the rounding of a difference (sum of |terms|)."""
    f = _factors(point, const, absolute)
    out = []
    for _, terms in GAIN_MONOMIALS:
        g = None
        for _sign, names in terms:
            t = _product(names, f, one)
            g = t if g is None else g + t
        out.append(g)
    return out


# The loop-coefficient function takes one column per frequency: complex values (re, im) of
# the sampled plant's responses (measured torque T, encoder angle theta and port velocity p,
# each from V_m and from T_dist) and of the controller elements at z = exp(j w Ts)
# (haa_sym.model.elements): the velocity estimates feeding the D term and the compensation, the PI's
# integral part Ts z/(z - 1) and the delay z^-d. (A port that reads the velocity estimate gets
# its G_pV, G_pd from the estimate times the encoder's responses.)
FREQ_COLUMN = ("G_TV", "G_Td", "G_thV", "G_thd", "G_pV", "G_pd",
               "F_d", "F_vc", "I_z", "z_delay")
# Its output: for each gain-affine form, the complex coefficients of (1, P_gain, D_gain), then
# the torque tracking H_T = T / T_lref (impedance loop open).
COEF_FORMS = ("L_t", "L_imp", "Z_num", "Z_den")
COEF_TERMS = ("1", "P_gain", "D_gain")
COEF_OUTPUTS = tuple(f"{form}.{t}" for form in COEF_FORMS for t in COEF_TERMS) + ("H_T",)


# --- The nonlinear simulation (haa_sym.analysis.simulate) -----------------------------------
# Per sample k the driver (codegen/driver.c, haa_simulate) calls the sample function once, then a
# plant step n_sub times. Sizes are capacities: the runtime pads the plant's states to nx and the
# controller's to nc with zeros (a padded state has zero rows and columns, so it stays zero).
# (nx, nc): plant-state and controller-state capacities, one set of functions each; the
# smallest that fits is used (HyQ at N_av = 4: 7 and 4).
SIM_CAPACITIES = ((8, 8), (8, 64), (16, 64))
SIM_FRICTION_CAP = 4          # Coulomb friction torques: the rotor and up to three bodies
# Exogenous inputs of one sample: the external torque on the port body (Nm), the torque
# feed-forward (Nm), the angle set point (rad), the torque sensor's noise sample (Nm), and the
# offset of the sample's end from its nominal instant minus its start's (s, jitter).
SIM_EXO = ("T_dist", "T_ff", "theta_ref", "noise_T", "delta")
# The held plant input over one sample (over each piece of it with a fractional drive delay, the
# command then the delayed one, codegen/driver.c): the voltage (V) and the external torque (Nm).
SIM_U = ("V", "T_dist")
# One row per sample, what the sample function reports (the CSV columns after ``time``, and the
# saturation flag: 1 when the held command was clipped). ``voltage`` is the held command: a voltage
# (V), or for a current-commanded structure the current command (A).
SIM_COLUMNS = ("theta", "velocity", "torque", "torque_ref", "voltage", "current", "saturated")


class Slices:
    """Named slices of one flat vector: ``lay["Ac"]`` is a slice, ``lay.shape["Ac"]`` its
    (rows, cols) in column-major order (CasADi's dense layout), ``lay.size`` the total."""

    def __init__(self, fields):
        self.slice, self.shape, start = {}, {}, 0
        for name, (r, c) in fields:
            self.slice[name] = slice(start, start + r * c)
            self.shape[name] = (r, c)
            start += r * c
        self.size = start

    def __getitem__(self, name):
        return self.slice[name]

    def names(self):
        return tuple(self.slice)


def sim_ctrl_layout(nx: int, nc: int) -> Slices:
    """The sample function's parameter vector: the controller (``Ac``, ``Bc``, ``Cc``, ``Dc`` of
    ``haa_sym.loop.statespace.controller_batch``), the plant's output rows it reads (encoder angle,
    torque signal, motor current, port velocity), the two windows of the held command (the first
    clip, then the second: centre ``c_w1 x``, ``c_w2 x`` and half-width ``w1``, ``w2``; a voltage
    command: the current limit's voltage window, centre the back-EMF k_w dtheta_m, half-width
    R I_max (V), then the supply, 0 and V_max; a current command: 0 and I_max (A), then the
    supply's currents, centre -k_w dtheta_m / R and half-width V_max / R), and the encoder and
    torque quanta (rad, Nm; 0 = off)."""
    n_in, n_out = 4, 2
    return Slices([("Ac", (nc, nc)), ("Bc", (nc, n_in)), ("Cc", (n_out, nc)), ("Dc", (n_out, n_in)),
                   ("c_theta", (1, nx)), ("c_T", (1, nx)), ("c_I", (1, nx)), ("c_v", (1, nx)),
                   ("c_w1", (1, nx)), ("w1", (1, 1)), ("c_w2", (1, nx)), ("w2", (1, 1)),
                   ("q_theta", (1, 1)), ("q_T", (1, 1))])


def sim_plant_layout(kind: str, nx: int) -> Slices:
    """The plant step's parameter vector, by kind: ``zoh`` (``Phi``, ``Gamma`` over Ts),
    ``jitter`` (``Phi``, ``Gamma`` over Ts/n_sub, ``M`` = [A, B] of the continuous plant for the
    interval's correction and ``inv_n`` = 1/n_sub), ``etd`` (one ETDRK4 substep of length h:
    ``Ph``, ``Gh`` over h/2, ``P``, ``G`` over h; the friction torques' columns through the
    phi-functions, ``Qh`` = (h/2) phi1(A h/2) Fcol and ``F1``, ``F2``, ``F3`` = h f_i(A h) Fcol of
    Cox and Matthews; friction rows ``Fsel``, torques ``Fc``, 1/velocity scale ``inv_vs`` and
    ``lin``, the friction slopes Fc / v_s already in A for the bodies at stick, else 0)."""
    nu, nf = len(SIM_U), SIM_FRICTION_CAP
    if kind == "zoh":
        return Slices([("Phi", (nx, nx)), ("Gamma", (nx, nu))])
    if kind == "jitter":
        return Slices([("Phi", (nx, nx)), ("Gamma", (nx, nu)), ("M", (nx, nx + nu)), ("inv_n", (1, 1))])
    if kind == "etd":
        return Slices([("Ph", (nx, nx)), ("Gh", (nx, nu)), ("P", (nx, nx)), ("G", (nx, nu)),
                       ("Qh", (nx, nf)), ("F1", (nx, nf)), ("F2", (nx, nf)), ("F3", (nx, nf)),
                       ("Fsel", (nf, nx)), ("Fc", (nf, 1)), ("inv_vs", (1, 1)), ("lin", (nf, 1))])
    raise ValueError(f"plant step kind = {kind!r}; allowed: {list(SIM_PLANT_KINDS)}")


SIM_PLANT_KINDS = ("zoh", "jitter", "etd")


def sim_function_names(nx: int, nc: int) -> dict[str, str]:
    """The generated functions of capacity (nx, nc): ``sample`` and one plant step per kind."""
    return {"sample": f"haa_sim_sample_{nx}_{nc}",
            **{k: f"haa_sim_{k}_{nx}" for k in SIM_PLANT_KINDS}}
