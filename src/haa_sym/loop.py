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
from haa_sym.exact import polymul, to_float, transfer_polynomials
from haa_sym.params import ParameterError, Params
from haa_sym.plant import OUTPUTS, DiscretePlant, continuous_plant, discretize

__all__ = ["LoopOptions", "ClosedLoop", "StabilityResult", "PORTS", "FREQ_OUTPUTS"]

PORTS = ("dtheta_L1", "dtheta_L2", "encoder_average")
# Half-width of the band around spectral radius 1 where points are re-decided by eigenvalues:
# ten times the worst radius error of the monomial-basis Schur-Cohn bisection measured over the
# paper's configurations (9e-7 at Ts = 0.5 ms, delay 1; tests/test_evaluators.py).
REFINE_BAND = 1e-5
FREQ_OUTPUTS = ("L_t", "L_imp", "Z", "H_T")


@dataclass(frozen=True)
class LoopOptions:
    """Modelling choices the paper leaves open; defaults are stated in ``docs/model.md``."""

    delay: int = 0
    torque_damping: bool = True
    port: str = "dtheta_L1"

    def __post_init__(self):
        if self.delay not in (0, 1) or isinstance(self.delay, bool):
            raise ParameterError(f"delay = {self.delay!r}; allowed: 0 or 1 (samples)")
        if not isinstance(self.torque_damping, bool):
            raise ParameterError(f"torque_damping = {self.torque_damping!r}; allowed: True or False")
        if self.port not in PORTS:
            raise ParameterError(f"port = {self.port!r}; allowed: {list(PORTS)}")


@dataclass(frozen=True)
class StabilityResult:
    """``stable``: all closed-loop poles in |z| < 1; ``spectral_radius``: max |z| of the poles;
    ``refined``: the points decided by eigenvalues because the bisected radius was within the
    refinement band of 1."""

    stable: np.ndarray
    spectral_radius: np.ndarray
    refined: np.ndarray = field(repr=False)


def _finite_array(name: str, value) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        bad = arr[~np.isfinite(arr)].ravel()[0]
        raise ParameterError(f"{name} contains {float(bad)!r}; allowed: finite numbers")
    return arr


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

    def _basis(self) -> np.ndarray:
        """Ascending coefficients (capacity+1) x 7 of b0..b6, padded with roots at z = 0."""
        p, ctrl, opt = self.plant, self.params.controller, self.options
        d, nums = transfer_polynomials(p.Phi, p.Gamma[:, :1], p.C)
        n_T = nums[OUTPUTS.index(self.torque_output)][0]
        n_th = nums[OUTPUTS.index("theta_L1")][0]
        N = ctrl.N_av
        Ts = Fraction(ctrl.Ts)
        zN = [Fraction(1)] + [Fraction(0)] * N                     # z^N
        zm1 = [Fraction(1), Fraction(-1)]                          # z - 1
        zNm1 = [Fraction(1)] + [Fraction(0)] * (N - 1) + [Fraction(-1)]  # z^N - 1
        z1 = [Fraction(1), Fraction(0)]
        zd = [Fraction(1)] + [Fraction(0)] * opt.delay
        # chi(z) / (N Ts): return difference at V_m times (z-1) z^(N+d) d(z), Eq. (6)-(8)
        basis = [
            polymul(zm1, zN, zd, d),                               # 1
            polymul(zm1, zN, n_T),                                 # P_t
            polymul([Ts], z1, zN, n_T),                            # I_t
            polymul(zm1, zN, n_th),                                # P_t P_gain
            polymul([Ts], z1, zN, n_th),                           # I_t P_gain
            polymul([1 / (N * Ts)], zm1, zNm1, n_th),              # P_t D_gain - VC
            polymul([Fraction(1, N)], z1, zNm1, n_th),             # I_t D_gain
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
        g = np.array([1, P_t, I_t, P_t * P, I_t * P, P_t * D - VC, I_t * D])
        asc = self.basis @ g
        return asc[self.capacity - self.degree:][::-1]

    # --- evaluators -------------------------------------------------------------------------
    def stability(self, P_gain, D_gain, beta=None, alpha=None, *,
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

        refine_band : float
            Points whose bisected radius lies within this distance of 1 are re-decided from the
            eigenvalues of the closed-loop state matrix (``haa_sym.reference``); 0 disables.

        Returns
        -------
        StabilityResult
            Arrays of the broadcast shape. Every point is decided by the generated Schur-Cohn
            test and its radius bisected (40 halvings). Near z = 1 the monomial coefficients
            limit that radius to ~1e-6 at Ts = 0.5 ms (~1e-8 at 1 ms, see docs/model.md), hence
            the refinement band.
        """
        pts, shape = self._points(P_gain, D_gain, beta, alpha)
        f = evaluators(self.backend)[f"haa_stab{self.capacity}"]
        kmax, rho = f(self.basis, self.const, pts)
        rho = np.array(rho).ravel()
        stable = np.array(kmax).ravel() < 1
        refined = np.abs(rho - 1) < refine_band
        if refined.any():
            from haa_sym.reference import spectral_radius
            for i in np.flatnonzero(refined):
                rho[i] = spectral_radius(self, *pts[:, i])
                stable[i] = rho[i] < 1
        return StabilityResult(stable.reshape(shape), rho.reshape(shape), refined.reshape(shape))

    def frequency_response(self, omega, P_gain=0.0, D_gain=0.0, beta=None, alpha=None) -> dict:
        """Loop transfer functions at ``omega`` (rad/s) for gain points.

        Returns a dict of complex arrays of shape ``point_shape + (len(omega),)`` with keys
        ``L_t`` (torque loop opened at the PI output), ``L_imp`` (impedance loop opened at the
        torque reference), ``Z`` (port impedance T_dist/velocity, every loop closed) and ``H_T``
        (torque tracking T/T_ref, impedance loop open). Negative-feedback convention 1/(1+L).
        """
        omega = _finite_array("omega", omega).ravel()
        pts, shape = self._points(P_gain, D_gain, beta, alpha)
        port = "dtheta_L1" if self.options.port == "encoder_average" else self.options.port
        G = self.plant.frequency_response(omega, outputs=(self.torque_output, "theta_L1", port),
                                          inputs=("V_m", "T_dist"))
        Gr = np.empty((12, omega.size))
        Gr[0::2] = G.reshape(6, -1).real
        Gr[1::2] = G.reshape(6, -1).imag
        ctrl = self.params.controller
        struct = np.array([ctrl.Ts, ctrl.N_av, self.options.delay,
                           1.0 if self.options.port == "encoder_average" else 0.0])
        n_pt, n_w = pts.shape[1], omega.size
        f = evaluators(self.backend)["haa_freq"]
        out = np.array(f(np.tile(Gr, n_pt), np.tile(omega * ctrl.Ts, n_pt)[None, :], self.const,
                         np.repeat(pts, n_w, axis=1), struct))
        resp = out[0::2] + 1j * out[1::2]
        return {k: resp[i].reshape(shape + (n_w,)) for i, k in enumerate(FREQ_OUTPUTS)}
