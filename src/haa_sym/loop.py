"""The sampled closed loop of Sec. 3 and its generated evaluators.

Per sample k (Fig. 6): the encoder angle theta_L1[k] and the torque sensor T[k] are read;
the averaging filter of N_av first differences gives v[k] = (theta[k] - theta[k-N_av])/(N_av Ts);
the impedance law Eq. (8) gives T_ref = -P_gain theta - D_gain v (theta_ref = 0); the PI of Eq. (7)
(backward Euler) acts on T_ref - T; velocity compensation adds VC_gain v with Eq. (6); the
voltage is applied through a zero-order hold after ``delay`` samples.

Options the paper leaves open (:class:`LoopOptions`):

``delay``          computation delay between sampling and the applied voltage, 0 or 1 samples;
``torque_damping`` whether the measured torque includes the D_hd term of Eq. (2);
``port``           the velocity of the passivity port Z(z) = T_dist / velocity (Sec. 5):
                   "dtheta_L1" (sampled, the paper's wording), "dtheta_L2" (the inertia T_dist
                   acts on) or "encoder_average" (the filtered encoder velocity v).

Because every feedback path enters through the single input V_m, the characteristic polynomial
is affine in the gain monomials (see ``codegen/kernels.py``); :class:`ClosedLoop` builds its
basis polynomials once per plant, exactly, and the generated code evaluates gain points.

Example
-------
>>> from haa_sym import load_params, ClosedLoop
>>> loop = ClosedLoop(load_params())                                      # doctest: +SKIP
>>> res = loop.stability(P_gain=[200, 20000], D_gain=[10, 50])            # doctest: +SKIP
>>> res.stable, res.spectral_radius                                       # doctest: +SKIP
"""
from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from haa_sym.compiled import evaluators
from haa_sym.exact import polymul, polysub, to_float, transfer_polynomials
from haa_sym.params import ParameterError, Params, gain_array
from haa_sym.plant import OUTPUTS, DiscretePlant, continuous_plant, discretize

__all__ = ["LoopOptions", "LoopCoefficients", "ClosedLoop", "StabilityResult", "PORTS", "FREQ_OUTPUTS"]

PORTS = ("dtheta_L2", "dtheta_L1", "encoder_average")
# Half-width of the band around spectral radius 1 where points are re-decided by eigenvalues:
# at least three times the worst radius error of the monomial-basis Schur-Cohn bisection measured over the
# paper's configurations (9e-7 at Ts = 0.5 ms over 1,020 random points, tests/test_evaluators.py;
# 3e-6 at one map point of tests/test_regions.py, rho = 0.9959, still far from the band).
REFINE_BAND = 1e-5
FREQ_OUTPUTS = ("L_t", "L_imp", "Z", "H_T")


COLGATE = ("subtract", "add", "none")
FILTERS = ("both", "impedance", "compensation")
PM_LOOPS = ("impedance", "torque")
PM_RULES = ("min_abs", "worst")


@dataclass(frozen=True)
class LoopOptions:
    """Modelling choices the paper leaves open; each is discussed in ``docs/model.md``.

    The defaults are the combination that reproduces the most cells of Table 2
    (``haa-sym reproduce`` re-scores all combinations and writes the count to the report).

    Parameters
    ----------
    delay : {0, 1}
        Computation delay between sampling and the applied voltage, samples. Default 0.
    torque_damping : bool
        Whether the measured torque includes the D_hd term of Eq. (2). Default True.
    filter : {"both", "impedance", "compensation"}
        Where the N_av-sample averaging filter sits: on the velocity feeding both the D term of
        Eq. (8) and the velocity compensation of Eq. (6) (default, the paper's Sec. 3.4 and
        Fig. 6), on the D term only, or on the compensation only; the other path then uses the
        one-sample first difference (theta[k] - theta[k-1])/Ts.
    port : {"dtheta_L2", "dtheta_L1", "encoder_average"}
        Velocity of the passivity port Z = T_dist / velocity (Sec. 5): the inertia J_L2 that
        T_dist acts on (default), the sampled link velocity of the paper's wording, or the
        averaged encoder velocity the controller sees.
    colgate : {"subtract", "add", "none"}
        Colgate's sampled-data correction of the phase of Z: subtract w Ts/2 (the paper's
        wording, default), add it, or none.
    pm_loop : {"impedance", "torque"}
        Loop on which the phase margin of the region maps is measured: the impedance loop opened
        at the torque reference T_lref (default) or the torque loop opened at the PI output with
        the impedance loop closed.
    pm_rule : {"min_abs", "worst"}
        When |L| crosses 1 more than once: the crossover with the smallest |PM| (default; what
        Matlab's ``margin`` reports) or the smallest signed PM.
    n_omega : int
        Points of the log frequency grid from ``omega_min`` to Nyquist pi/Ts on which Z(z) and
        the loop gains are sampled. Default 1000 (the maps are unchanged up to 16000, see
        ``haa_sym.regions``).
    omega_min : float
        Lowest frequency of that grid, rad/s. Default 0.1.
    passivity_tol_deg : float
        A point is passive when the corrected phase of Z stays within 90 deg + this tolerance.
        A spring (Z ~ K/(j w)) sits at -90 deg as w -> 0, so a zero tolerance would decide
        such points by rounding. Default 1e-3.
    """

    delay: int = 0
    torque_damping: bool = True
    filter: str = "both"
    port: str = "dtheta_L2"
    colgate: str = "subtract"
    pm_loop: str = "impedance"
    pm_rule: str = "min_abs"
    n_omega: int = 1000
    omega_min: float = 0.1
    passivity_tol_deg: float = 1e-3

    def __post_init__(self):
        if self.delay not in (0, 1) or isinstance(self.delay, bool):
            raise ParameterError(f"delay = {self.delay!r}; allowed: 0 or 1 (samples)")
        if not isinstance(self.torque_damping, bool):
            raise ParameterError(f"torque_damping = {self.torque_damping!r}; allowed: True or False")
        for name, allowed in (("port", PORTS), ("filter", FILTERS), ("colgate", COLGATE), ("pm_loop", PM_LOOPS),
                              ("pm_rule", PM_RULES)):
            if getattr(self, name) not in allowed:
                raise ParameterError(f"{name} = {getattr(self, name)!r}; allowed: {list(allowed)}")
        if isinstance(self.n_omega, bool) or not isinstance(self.n_omega, int) or self.n_omega < 10:
            raise ParameterError(f"n_omega = {self.n_omega!r}; allowed: an integer >= 10")
        for name in ("omega_min", "passivity_tol_deg"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0 \
                    or (name == "omega_min" and v == 0):
                raise ParameterError(f"{name} = {v!r}; allowed: a finite number "
                                     f"{'> 0 (rad/s)' if name == 'omega_min' else '>= 0 (deg)'}")

    def to_dict(self) -> dict:
        return {f: getattr(self, f) for f in self.__dataclass_fields__}

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(cls.__dataclass_fields__)

    def omega(self, Ts: float) -> np.ndarray:
        """The frequency grid (rad/s) of this option set for sampling time ``Ts``."""
        w_max = np.pi / Ts * (1 - 1e-9)
        if self.omega_min >= w_max:
            raise ParameterError(f"omega_min = {self.omega_min!r} is not below Nyquist pi/Ts = {w_max:.6g} rad/s")
        return np.logspace(np.log10(self.omega_min), np.log10(w_max), self.n_omega)


@dataclass(frozen=True)
class LoopCoefficients:
    """Gain-affine loop transfer functions on a frequency grid (fixed beta, alpha).

    With x = (1, P_gain, D_gain): ``L_t @ x``, ``L_imp @ x`` and ``(Z_num @ x) / (Z_den @ x)``
    give the torque loop, the impedance loop and the port impedance at every ``omega``.
    Arrays are complex, shape (n_omega, 3); ``H_T`` (n_omega,) is the torque tracking T/T_lref.
    """

    omega: np.ndarray
    Ts: float
    L_t: np.ndarray
    L_imp: np.ndarray
    Z_num: np.ndarray
    Z_den: np.ndarray
    H_T: np.ndarray

    def evaluate(self, name: str, P_gain, D_gain) -> np.ndarray:
        """``L_t``, ``L_imp``, ``Z`` or ``H_T`` at gain points: shape point_shape + (n_omega,)."""
        P = np.asarray(P_gain, dtype=float)
        D = np.asarray(D_gain, dtype=float)
        P, D = np.broadcast_arrays(P, D)
        x = np.stack([np.ones_like(P), P, D], axis=-1)
        if name == "H_T":
            return np.broadcast_to(self.H_T, P.shape + self.H_T.shape).copy()
        if name == "Z":
            return (x @ self.Z_num.T) / (x @ self.Z_den.T)
        return x @ getattr(self, name).T


@dataclass(frozen=True)
class StabilityResult:
    """``stable``: all closed-loop poles in |z| < 1; ``spectral_radius``: max |z| of the poles;
    ``refined``: the points decided by eigenvalues because the bisected radius was within the
    refinement band of 1."""

    stable: np.ndarray
    spectral_radius: np.ndarray
    refined: np.ndarray = field(repr=False)


def _finite_array(name: str, value) -> np.ndarray:
    # gains (P_gain, D_gain, beta, alpha) follow the one rule of haa_sym.params.gain_array;
    # other arrays (omega) must be finite
    return gain_array(name, value)


class ClosedLoop:
    """The discrete closed loop of one plant, controller and option set.

    Parameters
    ----------
    params : Params
        Plant and controller (``Ts``, ``N_av``, default ``alpha``, ``beta``, ``P_t0``, ``I_t0``).
    options : LoopOptions, optional
    backend : {"auto", "compiled", "vm"}
        How the generated functions run (see :mod:`haa_sym.compiled`).
    """

    def __init__(self, params: Params, options: LoopOptions | None = None, backend: str = "auto"):
        self.params = params
        self.options = options or LoopOptions()
        self.backend = backend
        ctrl = params.controller
        self.plant: DiscretePlant = discretize(continuous_plant(params.plant, backend), ctrl.Ts)
        self.degree = ctrl.N_av + 8 + self.options.delay
        caps = [c for c in evaluators(backend).capacities if c >= self.degree]
        if not caps:
            raise ParameterError(
                f"N_av = {ctrl.N_av} gives a closed loop of order {self.degree}, above the largest "
                f"generated capacity {max(evaluators(backend).capacities)}; add a capacity to "
                "CAPACITIES in codegen/generate.py and run `make derive`")
        self.capacity = caps[0]
        self.const = np.array([ctrl.P_t0, ctrl.I_t0, self.plant.VC0])
        self.basis = self._basis()

    # --- the characteristic polynomial -------------------------------------------------------
    @property
    def torque_output(self) -> str:
        return "T_l" if self.options.torque_damping else "T_l_spring"

    @property
    def filter_lengths(self) -> tuple[int, int]:
        """(N_VC, N_D): samples averaged by the compensation and by the D term (option ``filter``)."""
        N = self.params.controller.N_av
        f = self.options.filter
        return (N if f in ("both", "compensation") else 1, N if f in ("both", "impedance") else 1)

    def _basis(self) -> np.ndarray:
        """Ascending coefficients (capacity+1) x 8 of b0..b7, padded with roots at z = 0."""
        p, ctrl, opt = self.plant, self.params.controller, self.options
        d, nums = transfer_polynomials(p.Phi, p.Gamma[:, :1], p.C)
        n_T = nums[OUTPUTS.index(self.torque_output)][0]
        n_th = nums[OUTPUTS.index("theta_L1")][0]
        N = ctrl.N_av                      # the longest average: z^N clears every denominator
        N_vc, N_d = self.filter_lengths
        Ts = Fraction(ctrl.Ts)

        def zpow(k):
            return [Fraction(1)] + [Fraction(0)] * k

        def zk_minus_1(k):
            return [Fraction(1)] + [Fraction(0)] * (k - 1) + [Fraction(-1)]
        zm1 = [Fraction(1), Fraction(-1)]                          # z - 1
        z1 = zpow(1)
        # chi(z): return difference at V_m times (z-1) z^(N+d) d(z), Eq. (6)-(8), where
        # F_k(z) z^N = z^(N-k) (z^k - 1)/(k Ts). P_t D_gain and VC multiply b_d and b_vc; they
        # nearly cancel in parts of the plane, so chi uses (P_t D_gain - VC) b_d - VC (b_vc - b_d)
        # with the difference exact (zero for filter = "both").
        b_d = polymul([1 / (N_d * Ts)], zm1, zpow(N - N_d), zk_minus_1(N_d), n_th)
        b_vc = polymul([1 / (N_vc * Ts)], zm1, zpow(N - N_vc), zk_minus_1(N_vc), n_th)
        basis = [
            polymul(zm1, zpow(N), zpow(opt.delay), d),                                # 1
            polymul(zm1, zpow(N), n_T),                                               # P_t
            polymul([Ts], z1, zpow(N), n_T),                                          # I_t
            polymul(zm1, zpow(N), n_th),                                              # P_t P_gain
            polymul([Ts], z1, zpow(N), n_th),                                         # I_t P_gain
            b_d,                                                                      # P_t D_gain - VC
            polymul([Fraction(1, N_d)], z1, zpow(N - N_d), zk_minus_1(N_d), n_th),    # I_t D_gain
            polysub(b_vc, b_d),                                                       # -VC (rest)
        ]
        out = np.zeros((self.capacity + 1, len(basis)))
        for j, b in enumerate(basis):
            asc = to_float(b)[::-1]
            # z^(cap - degree) * b: roots at the origin change neither stability nor the radius
            out[self.capacity - self.degree:][:len(asc), j] = asc
        return out

    def _points(self, P_gain, D_gain, beta, alpha) -> np.ndarray:
        ctrl = self.params.controller
        beta = ctrl.beta if beta is None else beta
        alpha = ctrl.alpha if alpha is None else alpha
        arrs = np.broadcast_arrays(*(_finite_array(n, v) for n, v in
                                     (("P_gain", P_gain), ("D_gain", D_gain), ("beta", beta), ("alpha", alpha))))
        return np.stack([a.ravel() for a in arrs]), arrs[0].shape

    def characteristic_polynomial(self, P_gain, D_gain, beta=None, alpha=None) -> np.ndarray:
        """Descending coefficients of chi (monic up to the factor N_av Ts) for one point."""
        pts, shape = self._points(P_gain, D_gain, beta, alpha)
        if pts.shape[1] != 1:
            raise ValueError("characteristic_polynomial takes one gain point")
        P, D, b, a = pts[:, 0]
        P_t, I_t, VC = b * self.const[0], b * self.const[1], a * self.const[2]
        g = np.array([1, P_t, I_t, P_t * P, I_t * P, P_t * D - VC, I_t * D, -VC])
        asc = self.basis @ g
        return asc[self.capacity - self.degree:][::-1]

    # --- evaluators -------------------------------------------------------------------------
    def stability(self, P_gain, D_gain, beta=None, alpha=None, *, radius: bool = True,
                  refine_band: float = REFINE_BAND) -> StabilityResult:
        """Stability decision and spectral radius of the closed loop at gain points.

        Parameters
        ----------
        P_gain : array_like
            Impedance stiffness (Nm/rad), Eq. (8).
        D_gain : array_like
            Impedance damping (Nms/rad), Eq. (8).
        beta, alpha : array_like, optional
            Torque-gain scale (Eq. 7) and velocity-compensation gain (Eq. 6); default from params.
            All four broadcast together.

        radius : bool
            Bisect the spectral radius (30 Schur-Cohn tests per point); False runs three tests
            per point (at radius 1 and 1 +- refine_band) and returns NaN radii except where
            refined by eigenvalues.
        refine_band : float
            Points whose bisected radius lies within this distance of 1 are re-decided from the
            eigenvalues of the closed-loop state matrix (``haa_sym.reference``); 0 disables.

        Returns
        -------
        StabilityResult
            Arrays of the broadcast shape. Every point is decided by the generated Schur-Cohn
            test and its radius bisected (30 halvings). Near z = 1 the monomial coefficients
            limit that radius to ~3e-6 at Ts = 0.5 ms (~1e-8 at 1 ms, see docs/model.md), hence
            the refinement band.
        """
        pts, shape = self._points(P_gain, D_gain, beta, alpha)
        ev = evaluators(self.backend)
        if radius:
            kmax, rho = (v.ravel() for v in ev.call_columns(
                f"haa_stab{self.capacity}", [self.basis, self.const, pts], 2))
            refined = np.abs(rho - 1) < refine_band
        else:
            powers = np.arange(self.capacity + 1) - self.capacity
            kmax, k_in, k_out = (v.ravel() for v in ev.call_columns(
                f"haa_decide{self.capacity}",
                [self.basis, self.const, pts, (1 - refine_band) ** powers, (1 + refine_band) ** powers], 2))
            rho = np.full(kmax.shape, np.nan)
            # radius within refine_band of 1: not every root inside 1 - band, all inside 1 + band
            refined = (k_in >= 1) & (k_out < 1)
        stable = kmax < 1
        if refined.any():
            from haa_sym.reference import spectral_radius
            for i in np.flatnonzero(refined):
                rho[i] = spectral_radius(self, *pts[:, i])
                stable[i] = rho[i] < 1
        return StabilityResult(stable.reshape(shape), rho.reshape(shape), refined.reshape(shape))

    def loop_coefficients(self, omega=None, beta=None, alpha=None) -> LoopCoefficients:
        """Gain-affine loop transfer functions on ``omega`` (rad/s; default: the options' grid).

        ``beta`` and ``alpha`` are scalars (default from params). One generated evaluation per
        frequency; the P_gain/D_gain dependence is then a 3-vector product (see
        :class:`LoopCoefficients`).
        """
        ctrl = self.params.controller
        omega = self.options.omega(ctrl.Ts) if omega is None else _finite_array("omega", omega).ravel()
        beta = float(_finite_array("beta", ctrl.beta if beta is None else beta))
        alpha = float(_finite_array("alpha", ctrl.alpha if alpha is None else alpha))
        port = "dtheta_L1" if self.options.port == "encoder_average" else self.options.port
        G = self.plant.frequency_response(omega, outputs=(self.torque_output, "theta_L1", port),
                                          inputs=("V_m", "T_dist"))
        Gr = np.empty((12, omega.size))
        Gr[0::2] = G.reshape(6, -1).real
        Gr[1::2] = G.reshape(6, -1).imag
        struct = np.array([ctrl.Ts, ctrl.N_av, self.options.delay,
                           1.0 if self.options.port == "encoder_average" else 0.0, *self.filter_lengths])
        f = evaluators(self.backend)["haa_loopcoef"]
        out = np.array(f(Gr, (omega * ctrl.Ts)[None, :], self.const, np.array([beta, alpha]), struct))
        c = out[0::2] + 1j * out[1::2]                      # 13 x n_w
        forms = {k: c[3 * i:3 * i + 3].T.copy() for i, k in enumerate(("L_t", "L_imp", "Z_num", "Z_den"))}
        return LoopCoefficients(omega=omega, Ts=ctrl.Ts, H_T=c[12].copy(), **forms)

    def frequency_response(self, omega, P_gain=0.0, D_gain=0.0, beta=None, alpha=None) -> dict:
        """Loop transfer functions at ``omega`` (rad/s) for gain points.

        Returns a dict of complex arrays of shape ``point_shape + (len(omega),)`` with keys
        ``L_t`` (torque loop opened at the PI output), ``L_imp`` (impedance loop opened at the
        torque reference), ``Z`` (port impedance T_dist/velocity, every loop closed) and ``H_T``
        (torque tracking T/T_ref, impedance loop open). Negative-feedback convention 1/(1+L).
        ``beta`` and ``alpha`` may vary per point (one coefficient evaluation per distinct pair).
        """
        omega = _finite_array("omega", omega).ravel()
        pts, shape = self._points(P_gain, D_gain, beta, alpha)
        out = {k: np.empty((pts.shape[1], omega.size), complex) for k in FREQ_OUTPUTS}
        pairs, inv = np.unique(pts[2:].T, axis=0, return_inverse=True)
        for j, (b, a) in enumerate(pairs):
            sel = np.flatnonzero(inv.ravel() == j)
            co = self.loop_coefficients(omega, b, a)
            for k in FREQ_OUTPUTS:
                out[k][sel] = co.evaluate(k, pts[0, sel], pts[1, sel])
        return {k: v.reshape(shape + (omega.size,)) for k, v in out.items()}
