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
basis polynomials exactly, once per distinct plant and loop structure (a process-wide cache),
maps them by the bilinear transform z = (1 + s)/(1 - s) and rounds once; the generated code
decides gain points by a Routh-Hurwitz test certified against that rounding, and the few
points it cannot certify are decided from eigenvalues (docs/model.md, "Fast sampling").

Example
-------
>>> from haa_sym import load_params, ClosedLoop
>>> loop = ClosedLoop(load_params())                                      # doctest: +SKIP
>>> res = loop.stability(P_gain=[200, 20000], D_gain=[10, 50])            # doctest: +SKIP
>>> res.stable, res.spectral_radius                                       # doctest: +SKIP
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from haa_sym._version import version
from haa_sym.compiled.cache import BoundedCache, array_key
from haa_sym.compiled.generated import evaluators
from haa_sym.loop.exact import bilinear, polymul, polysub, to_float, transfer_polynomials
from haa_sym.errors import ParameterError
from haa_sym.io.progress import message
from haa_sym.model.params import Params, gain_array, gain_points
from haa_sym.model.elements import (Element, backward_difference, common_denominator, delay, frequency_responses,
                                    pi_integral)
from haa_sym.model import filters, structures
from haa_sym.model.filters import controller_filter
from haa_sym.compiled.layout import (COEF_FORMS, COEF_OUTPUTS, COEF_TERMS, FREQ_COLUMN, N_BASIS, TORQUE_GAINS,
                            gain_monomials)
from haa_sym.loop.options import LoopOptions
from haa_sym.loop.plant import DiscretePlant, continuous_plant, current_commanded, discretize, drive_states, with_lag
from haa_sym.loop.statespace import closed_loop_eigenvalues, to_statespace

__all__ = ["LoopCoefficients", "ClosedLoop", "StabilityResult", "FrequencyResponse", "FREQ_OUTPUTS", "loop_first"]

# A plant mode within this distance of z = 1 is a free rigid-body mode (the sampled plant cannot
# place it more accurately): with P_gain = 0 the loop keeps it (StabilityResult.marginal).
MARGINAL_TOL = 1e-9
FREQ_OUTPUTS = ("L_t", "L_imp", "Z", "H_T")
# Exact arithmetic (bases) and the plant's frequency responses are the costly parts of a
# ClosedLoop; maps, Table 2 and the option scoring build thousands over a handful of plants.
_PLANTS = BoundedCache()
_PLANT_POLYS = BoundedCache()
_BASES = BoundedCache()
_COEFFICIENTS = BoundedCache(64)


# The exact characteristic polynomial (Faddeev-LeVerrier in integers) costs about n^4 products
# of numbers growing to n x ~260 bits: measured on this 2-core machine 0.03 s at 13 states (a
# 5-body chain), 4 s at 35 (16 bodies), 100 s at 59 (28 bodies, the largest chain the generated
# capacity takes with N_av = 4): about 100 s x (n/59)^6. Above SLOW_EXACT_STATES a message says so
# before the work starts (--quiet silences it).
SLOW_EXACT_STATES = 30


def _exact_seconds(n_states: int) -> float:
    """Rough seconds of the exact step for a plant of ``n_states`` (see SLOW_EXACT_STATES)."""
    return 100.0 * (n_states / 59) ** 6


def _transfer_polynomials(plant: DiscretePlant, source: str = "the plant"):
    """Exact d(z) and the V_m numerators of ``plant`` (Faddeev-LeVerrier in integers), memoised."""
    def build():
        n = plant.Phi.shape[0]
        if n >= SLOW_EXACT_STATES:
            message(f"haa_sym: exact characteristic polynomial of the {n}-state plant of {source}: about "
                    f"{_exact_seconds(n):.0f} s (exact integer arithmetic, growing as states^6; once per "
                    "plant and sampling time in a process)")
        return transfer_polynomials(plant.Phi, plant.Gamma[:, :1], plant.C)
    return _PLANT_POLYS.get(array_key(plant.Phi, plant.Gamma[:, :1], plant.C), build)


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
    """Stability of the closed loop at gain points (arrays of the points' shape).

    ``stable``: every closed-loop pole in |z| < 1. ``n_unstable``: the number of poles with
    |z| > 1. ``spectral_radius``: max |z| of the poles, from the eigenvalues of the explicit
    closed loop (:mod:`haa_sym.loop.statespace`); NaN where not asked for. ``refined``: the points
    whose generated decision could not be certified against rounding (a pole within rounding
    distance of |z| = 1) and were decided from the eigenvalues instead. ``marginal``: points
    with a pole at z = 1 that no gain moves: the plant has a free rigid-body mode (a mode within
    :data:`MARGINAL_TOL` of z = 1, e.g. the leg with K_L2 = 0) and P_gain = 0, so nothing feeds
    its position back; reported not stable (not asymptotically stable), where the rounding of
    the sampled plant would otherwise put the pole on either side of the circle.
    """

    stable: np.ndarray
    spectral_radius: np.ndarray
    refined: np.ndarray = field(repr=False)
    n_unstable: np.ndarray = field(repr=False, default=None)
    marginal: np.ndarray = field(repr=False, default=None)


def _finite_array(name: str, value) -> np.ndarray:
    # gains (P_gain, D_gain, beta, alpha) follow the one rule of haa_sym.model.params.gain_array;
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
        How the generated functions run (see :mod:`haa_sym.compiled.generated`).
    basis : bool
        Build the exact characteristic-polynomial basis (needed by :meth:`stability`; default).
    """

    def __init__(self, params: Params, options: LoopOptions | None = None, backend: str = "auto",
                 basis: bool = True):
        self.params = params
        # the structure's file-backed defaults (sensor damping, port body) for this actuator
        self.options = (options or LoopOptions()).resolved(params.plant.topology)
        self.backend = backend
        ctrl = params.controller
        # before the plant is compiled and sampled and the elements are built: a chain or a
        # filter beyond every generated capacity would cost minutes of symbolic and exact
        # arithmetic (N_av = 10**6, a 50-body chain) only to be refused at the end
        self._check_reach(params, evaluators(backend).capacities)
        # the drive's lag (a continuous state) and dead time (the delay line) are part of the
        # sampled plant (haa_sym.loop.plant.discretize): every analysis of this loop sees them
        drive = params.drive
        self.structure = structures.get(ctrl.structure)
        # a current-commanded motor (structure "impedance_current"): the electrical state is
        # imposed and the command is the current; the drive's lag and delay act on it
        current = self.structure.command == "current"
        self.plant: DiscretePlant = _PLANTS.get(
            (params.plant, ctrl.Ts, backend, drive, current),
            lambda: discretize(with_lag(current_commanded(continuous_plant(params.plant, backend), current),
                                        drive.tau_drive), ctrl.Ts, drive.delay_drive))
        # chi = (z - 1) z^delay z^N_av d(z) + ...: integrator, delay, filter, plant states
        el = self.elements
        filter_order = common_denominator(el["F_d"], el["F_vc"])[0].__len__() - 1
        self.degree = self.plant.Phi.shape[0] + el["I_z"].order + el["z_delay"].order + filter_order
        caps = [c for c in evaluators(backend).capacities if c >= self.degree]
        if not caps:
            cap = max(evaluators(backend).capacities)
            what = f"N_av = {ctrl.N_av}" if ctrl.velocity_filter == "average" else \
                f"velocity_filter = {ctrl.velocity_filter!r}"
            raise ParameterError(
                f"{what} gives a closed loop of order {self.degree}, above the largest generated "
                f"capacity {cap}; allowed: N_av <= {cap - self.degree + filter_order} (with "
                f"delay = {self.options.structure.delay}; a larger capacity needs CAPACITIES in "
                "codegen/generate.py of a source tree and `make derive`)")
        self.capacity = caps[0]
        self.const, self.P_m0 = self._structure_gains(params)
        ports = [o for o in self.plant.output_names if o.startswith("dtheta_")] + ["encoder_average"]
        if self.options.structure.port not in ports:
            raise ParameterError(
                f"port = {self.options.structure.port!r} is not a velocity of the actuator "
                f"{params.source}; allowed: {ports} (its [sensors] port body is "
                f"{params.plant.topology.port!r}: port = 'dtheta_{params.plant.topology.port}')")
        # a plant mode within MARGINAL_TOL of z = 1: a free link (no stiffness to ground), whose
        # position only P_gain feeds back (the sensor and the velocity estimates do not see it)
        self.free_mode = bool(np.min(np.abs(np.linalg.eigvals(self.plant.Phi) - 1)) < MARGINAL_TOL)
        # basis=False: a loop used only for frequency responses or the explicit state space
        self.basis, self._z_basis = self._basis() if basis else (None, None)

    def _check_reach(self, params: Params, capacities) -> None:
        """Refuse a loop whose order exceeds the largest generated capacity, from counts alone.

        The order is at least the plant's states (3 for the motor and 2 per body of the chain)
        + the drive's (:func:`haa_sym.loop.plant.drive_states`: 1 for a lag, one per held
        command of the delay line) + 1 (the PI's integrator) + ``delay`` + the velocity filter's
        order; the exact order (after the filters' common denominator) is checked again once they
        are built. The plant and the filter are judged first, without the drive, so that each
        message names what to change.
        """
        top, ctrl, d = params.plant.topology, params.controller, self.options.structure.delay
        cap = max(capacities)
        n_x = len(top.state_names)
        n_f = filters.controller_filter_order(ctrl)
        if n_x + 1 + d + 1 > cap:       # even the smallest filter (order 1) does not fit
            bodies = (cap - 1 - d - 1 - 3) // 2
            raise ParameterError(
                f"{params.source}: the chain has too many states for the generated code: "
                f"{len(top.bodies)} bodies give {n_x} plant states (3 of the motor, 2 per body), a "
                f"closed loop of order >= {n_x + 2 + d}, above the largest generated capacity {cap}; "
                f"allowed: at most {bodies} bodies (with delay = {d} and a first-order filter; a larger "
                "capacity needs CAPACITIES in codegen/generate.py of a source tree and `make derive`)")
        if n_x + 1 + d + n_f > cap:
            room = cap - n_x - 1 - d
            if ctrl.velocity_filter == "average":
                what, allowed = f"N_av = {ctrl.N_av}", f"N_av <= {room}"
            else:
                what, allowed = (f"velocity_filter = {ctrl.velocity_filter!r} (order {n_f})",
                                 f"a velocity filter of order <= {room}")
            raise ParameterError(
                f"{what} gives a closed loop of order {n_x + 1 + d + n_f} with the {n_x} plant states "
                f"of {params.source}, above the largest generated capacity {cap}; allowed: {allowed} "
                f"(with delay = {d}; a larger capacity needs CAPACITIES in codegen/generate.py of a "
                "source tree and `make derive`)")
        drive = params.drive
        n_d = drive_states(drive, ctrl.Ts)
        if n_x + n_d + 1 + d + n_f > cap:
            lag = int(drive.tau_drive > 0)
            room = cap - n_x - 1 - d - n_f - lag          # held commands that still fit
            raise ParameterError(
                f"delay_drive = {drive.delay_drive!r} s: the drive adds {n_d} states to the sampled plant "
                f"({'1 of the lag tau_drive, ' if lag else ''}{n_d - lag} held commands of the delay line at "
                f"Ts = {ctrl.Ts!r} s), a closed loop of order {n_x + n_d + 1 + d + n_f} with the {n_x} plant "
                f"states of {params.source} and the velocity filter's {n_f}, above the largest generated "
                f"capacity {cap}; allowed: delay_drive <= {room * ctrl.Ts:g} s ({room} samples; with "
                f"delay = {d}; a larger capacity needs CAPACITIES in codegen/generate.py of a source tree "
                "and `make derive`)")

    def _structure_gains(self, params: Params):
        """``(const, P_m0)``: the generated functions' constants [P_r0, I_t0, VC0] of this
        structure (haa_sym.model.structures; layout.CONST's P_t0 is the gain on the torque
        reference, P_r0) and P_m0, the proportional gain on the measured torque (V/Nm at beta = 1)."""
        ctrl, st, pl = params.controller, self.structure, params.plant
        if st.name != structures.DEFAULT:
            missing = [k for k in ("k_t", "N", "R") if k not in pl.keys]
            if missing:
                raise ParameterError(f"structure = {st.name!r} needs the motor's {missing} of an actuator file "
                                     f"({params.source} has none); allowed: structure = 'paper'")
        if st.command == "current":             # u = T_ref / (k_t N), a current in A
            return np.array([1.0 / (pl.k_t * pl.N), 0.0, 0.0]), 0.0
        VC0 = self.plant.VC0 if st.velocity_compensation else 0.0
        # the feed-forward: T_ref through the motor's static inverse at stall, R/(k_t N) V/Nm
        P_r0 = ctrl.P_t0 + (pl.R / (pl.k_t * pl.N) if st.feedforward else 0.0)
        return np.array([P_r0, ctrl.I_t0, VC0]), ctrl.P_t0

    @property
    def torque_ratio(self) -> Fraction:
        """P_m0 / P_r0 exactly: the share of the reference's proportional gain that also acts on
        the measured torque (1 without feed-forward, 0 without a torque loop)."""
        P_r0 = Fraction(float(self.const[0]))
        return Fraction(float(self.P_m0)) / P_r0 if P_r0 else Fraction(0)

    # --- the characteristic polynomial -------------------------------------------------------
    def plant_output(self, name: str) -> int:
        """Row of the plant's output ``name`` (its C matrix and transfer numerators)."""
        return self.plant.output_names.index(name)

    @property
    def torque_output(self) -> str:
        return "T_sensor" if self.options.structure.torque_damping else "T_sensor_spring"

    @functools.cached_property
    def elements(self) -> dict:
        """The controller's elements (:mod:`haa_sym.model.elements`) in this loop, by role (built once
        per loop: their exact coefficients cost rational arithmetic).

        ``F_d`` the velocity estimate of the D term (Eq. 8), ``F_vc`` that of the velocity
        compensation (Eq. 6) (option ``filter``: the chosen ``velocity_filter`` on both, or on one
        with the backward difference on the other), ``F_port`` the estimate an averaged port reads,
        ``I_z`` the integral part of the torque PI (Eq. 7) and ``z_delay`` the computation delay.
        """
        ctrl, f = self.params.controller, self.options.structure.filter
        F = controller_filter(ctrl)
        diff = backward_difference(ctrl.Ts)
        F_d = F if f in ("both", "impedance") else diff
        # a structure without velocity compensation (or without a torque loop) has no F_vc and
        # no integrator: F_vc is F_d (no states of its own), I_z is zero (no state at z = 1)
        vc, pi = self.structure.velocity_compensation, self.structure.torque_loop
        return {"F_d": F_d, "F_vc": (F if f in ("both", "compensation") else diff) if vc else F_d,
                "F_port": F, "I_z": pi_integral(ctrl.Ts) if pi else Element("no_integral", (0,), (1,)),
                "z_delay": delay(self.options.structure.delay)}

    def _structure_key(self) -> tuple:
        """Everything the basis depends on: the sampled plant and the loop's structure."""
        p, el = self.plant, self.elements
        return (array_key(p.Phi, p.Gamma[:, :1], p.C), self.params.controller.Ts,
                tuple((e.numerator, e.denominator) for e in el.values()), self.torque_output,
                self.capacity, self.torque_ratio)

    def _exact_basis(self) -> list[list[Fraction]]:
        """Exact descending coefficients of b0..b7 in z (haa_sym.compiled.layout.GAIN_MONOMIALS), each of
        degree ``self.degree``.

        chi(z) is the return difference at V_m times (z - 1) z^d d(z) D(z), with D the common
        denominator of the two velocity estimates, F_d = A_d/D and F_vc = A_vc/D (Eq. 6-8). P_t
        D_gain and VC multiply the same polynomial when both estimates are one filter; they nearly
        cancel in parts of the plane, so chi uses (P_t D_gain - VC) b_d - VC (b_vc - b_d) with the
        difference exact (zero for filter = "both"). The structure (haa_sym.model.structures) sets
        the gains: P_t stands for P_r, the gain on the torque reference, and the torque path's
        own proportional gain P_m = ratio P_r (:attr:`torque_ratio`) scales b1.
        """
        el = self.elements
        d, nums = _transfer_polynomials(self.plant, self.params.source)
        n_T = nums[self.plant_output(self.torque_output)][0]
        n_th = nums[self.plant_output("theta_encoder")][0]
        D, (A_d, A_vc) = common_denominator(el["F_d"], el["F_vc"])
        I_num, I_den = el["I_z"].numerator, el["I_z"].denominator        # Ts z, z - 1
        z_num, z_den = el["z_delay"].numerator, el["z_delay"].denominator  # 1, z^d
        b_d = polymul(I_den, z_num, A_d, n_th)
        basis = [
            polymul(I_den, z_den, d, D),                                  # 1
            [self.torque_ratio * c for c in polymul(I_den, z_num, D, n_T)],  # P_t (P_m = ratio P_r)
            polymul(I_num, z_num, D, n_T),                                # I_t
            polymul(I_den, z_num, D, n_th),                               # P_t P_gain
            polymul(I_num, z_num, D, n_th),                               # I_t P_gain
            b_d,                                                          # P_t D_gain - VC
            polymul(I_num, z_num, A_d, n_th),                             # I_t D_gain
            polysub(polymul(I_den, z_num, A_vc, n_th), b_d),              # -VC (rest)
        ]
        assert len(basis) == N_BASIS
        return [[Fraction(0)] * (self.degree + 1 - len(b)) + list(b) for b in basis]

    def _basis(self) -> tuple[np.ndarray, np.ndarray]:
        """(bilinear, z) bases: (capacity+1) x 8 ascending coefficients of the bilinear
        transforms of z^(capacity - degree) b_j (the extra roots at z = 0, s = -1, change no
        decision), and degree+1 x 8 descending coefficients of b_j in z. Cached per structure.
        """
        def build():
            exact = self._exact_basis()
            pad = [Fraction(0)] * (self.capacity - self.degree)
            s_basis = np.array([to_float(bilinear(b + pad)) for b in exact]).T
            z_basis = np.array([to_float(b) for b in exact]).T
            for arr in (s_basis, z_basis):
                arr.setflags(write=False)
            return s_basis, z_basis
        return _BASES.get(self._structure_key(), build)

    def _points(self, P_gain, D_gain, beta, alpha) -> np.ndarray:
        ctrl = self.params.controller
        beta = ctrl.beta if beta is None else beta
        alpha = ctrl.alpha if alpha is None else alpha
        named = [(n, _finite_array(n, v)) for n, v in
                 (("P_gain", P_gain), ("D_gain", D_gain), ("beta", beta), ("alpha", alpha))]
        try:
            arrs = np.broadcast_arrays(*(v for _, v in named))
        except ValueError:
            shapes = ", ".join(f"{n} {v.shape}" for n, v in named)
            raise ParameterError(f"gain arrays of shapes {shapes} do not broadcast together; allowed: "
                                 "shapes that broadcast (one value each per gain point)") from None
        self._check_unread(arrs[2], arrs[3])
        return np.stack([a.ravel() for a in arrs]).reshape(4, -1), arrs[0].shape

    def require(self, feature: str, what: str) -> None:
        """Refuse ``what`` in one line when this loop's structure lacks ``feature``
        (:func:`haa_sym.model.structures.require`: "torque_loop", "voltage")."""
        structures.require(self.structure.name, feature, what)

    def _check_unread(self, beta, alpha) -> None:
        """Refuse a beta or alpha other than its neutral value for a structure that does not read
        it (haa_sym.model.structures.NEUTRAL): no torque PI to scale, no compensation."""
        for name, v in (("beta", beta), ("alpha", alpha)):
            neutral = structures.NEUTRAL[name]
            if name in self.structure.unread and np.any(np.asarray(v) != neutral):
                raise ParameterError(f"{name} = {np.asarray(v).ravel()[np.argmax(np.asarray(v).ravel() != neutral)]:g}: "
                                     f"structure = {self.structure.name!r} has no "
                                     f"{'torque PI' if name == 'beta' else 'velocity compensation'}; allowed: "
                                     f"{name} = {neutral:g}")

    def characteristic_polynomial(self, P_gain, D_gain, beta=None, alpha=None) -> np.ndarray:
        """Descending coefficients of chi (monic up to the factor N_av Ts) for one point."""
        pts, shape = self._points(P_gain, D_gain, beta, alpha)
        if pts.shape[1] != 1:
            raise ValueError("characteristic_polynomial takes one gain point")
        return self._z_basis @ np.array(gain_monomials(pts[:, 0], self.const))

    # --- evaluators -------------------------------------------------------------------------
    def stability(self, P_gain, D_gain, beta=None, alpha=None, *, radius: bool = False,
                  certify: bool = True) -> StabilityResult:
        """Stability decision (and optionally the spectral radius) of the closed loop at gain points.

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
            Also return the spectral radius of every point, from the eigenvalues of the explicit
            closed loop (costs about as much as a stacked ``numpy.linalg.eigvals``); default
            False: NaN except at refined points.
        certify : bool
            Re-decide from eigenvalues the points whose generated decision is not certified
            against the rounding of the characteristic polynomial (default). False returns the
            raw generated decision everywhere (for tests and benchmarks).

        Returns
        -------
        StabilityResult
            Every point is decided by the generated Routh-Hurwitz test of the bilinear
            transform of chi; its certificate (Kharitonov's vertex polynomials of the
            coefficients' rounding bound) says whether rounding could change the decision.

        Examples
        --------
        >>> from haa_sym import load_params, ClosedLoop
        >>> loop = ClosedLoop(load_params().with_values(Ts=1e-4))                 # doctest: +SKIP
        >>> bool(loop.stability(200.0, 10.0).stable)                              # doctest: +SKIP
        True
        """
        if self.basis is None:
            raise ValueError("this ClosedLoop was built with basis=False: no stability evaluator")
        pts, shape = self._points(P_gain, D_gain, beta, alpha)
        if pts.shape[1] == 0:
            # no points: an empty result of their shape (the generated driver cannot be called
            # with zero columns)
            none = np.zeros(shape, bool)
            return StabilityResult(none, np.full(shape, np.nan), none.copy(), np.zeros(shape, int), none.copy())
        ev = evaluators(self.backend)
        n_unstable, certified = (v.ravel() for v in ev.call_columns(
            f"haa_decide{self.capacity}", [self.basis, self.const, pts], 2))
        n_unstable = n_unstable.astype(int)
        refined = (certified < 0.5) if certify else np.zeros(n_unstable.shape, bool)
        rho = np.full(n_unstable.shape, np.nan)
        need = np.ones_like(refined) if radius else refined
        if need.any():
            eig = np.abs(closed_loop_eigenvalues(self, pts[:, need]))
            rho[need] = eig.max(axis=1)
            n_unstable[refined] = (eig[refined[need]] >= 1).sum(axis=1)
        # a free rigid-body mode of the plant stays at z = 1 when nothing feeds the position
        # back (P_gain = 0): the rounding of the sampled plant, not the loop, decides its side
        marginal = self.free_mode & (pts[0] == 0)
        stable = (n_unstable == 0) & ~marginal
        return StabilityResult(stable.reshape(shape), rho.reshape(shape), refined.reshape(shape),
                               n_unstable.reshape(shape), marginal.reshape(shape))

    def loop_coefficients(self, omega=None, beta=None, alpha=None, *, cached: bool = True) -> LoopCoefficients:
        """Gain-affine loop transfer functions on ``omega`` (rad/s; default: the options' grid).

        ``beta`` and ``alpha`` are scalars (default from params). One generated evaluation per
        frequency; the P_gain/D_gain dependence is then a 3-vector product (see
        :class:`LoopCoefficients`). ``cached=False`` for one-off frequencies (a root refinement),
        which would only push reused grids out of the bounded cache.
        """
        ctrl = self.params.controller
        omega = self.options.numerics.omega(ctrl.Ts) if omega is None else _finite_array("omega", omega).ravel()
        beta = float(_finite_array("beta", ctrl.beta if beta is None else beta))
        alpha = float(_finite_array("alpha", ctrl.alpha if alpha is None else alpha))
        el = self.elements
        if not cached:
            return self._loop_coefficients(omega, beta, alpha)
        key = (array_key(self.plant.Phi, self.plant.Gamma, self.plant.C, omega, self.const),
               tuple((e.numerator, e.denominator) for e in el.values()), self.torque_output,
               self.options.structure.port, beta, alpha, self.backend, self.P_m0)
        return _COEFFICIENTS.get(key, lambda: self._loop_coefficients(omega, beta, alpha))

    def _loop_coefficients(self, omega, beta, alpha) -> LoopCoefficients:
        ctrl, el = self.params.controller, self.elements
        averaged = self.options.structure.port == "encoder_average"
        port = "theta_encoder" if averaged else self.options.structure.port
        G = self.plant.frequency_response(omega, outputs=(self.torque_output, "theta_encoder", port),
                                          inputs=("V_m", "T_dist"))
        values = dict(zip(("G_TV", "G_Td", "G_thV", "G_thd", "G_pV", "G_pd"), G.reshape(6, -1)))
        # the elements in one stacked evaluation (the same values as one by one): at the few
        # frequencies of a refinement step their per-call cost dominated this function
        keys = ("F_d", "F_vc", "I_z", "z_delay") + (("F_port",) if averaged else ())
        values.update(zip(keys, frequency_responses([el[k] for k in keys], omega, ctrl.Ts)))
        if averaged:                      # the port reads the controller's velocity estimate
            F = values.pop("F_port")
            values["G_pV"], values["G_pd"] = F * values["G_thV"], F * values["G_thd"]
        phi = self._torque_path(omega)
        if phi is not None:
            # the kernel applies PI = P_r + I_t I_z to T_ref - T; the structure's measured torque
            # goes through P_m + I_t I_z: the same as the torque signal times phi = (P_m + I_t
            # I_z)/(P_r + I_t I_z) (beta cancels), and H_T = T/T_ref is the kernel's over phi
            values["G_TV"], values["G_Td"] = phi * values["G_TV"], phi * values["G_Td"]
        cols = np.empty((2 * len(FREQ_COLUMN), omega.size))
        for i, k in enumerate(FREQ_COLUMN):
            cols[2 * i], cols[2 * i + 1] = values[k].real, values[k].imag
        (out,) = evaluators(self.backend).call_columns(
            "haa_loopcoef", [cols, self.const, np.array([{"beta": beta, "alpha": alpha}[k] for k in TORQUE_GAINS])], 0)
        c = dict(zip(COEF_OUTPUTS, (out[:, 0::2] + 1j * out[:, 1::2]).T))
        if phi is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                c["H_T"] = c["H_T"] / phi if self.structure.torque_loop else np.full(omega.size, np.nan + 0j)
        forms = {f: np.stack([c[f"{f}.{t}"] for t in COEF_TERMS], axis=1) for f in COEF_FORMS}
        res = LoopCoefficients(omega=omega.copy(), Ts=ctrl.Ts, H_T=c["H_T"].copy(), **forms)
        for arr in (res.omega, res.H_T, *forms.values()):
            arr.setflags(write=False)
        return res

    def _torque_path(self, omega):
        """phi(e^{j w Ts}) = (P_m0 + I_t0 I_z)/(P_r0 + I_t0 I_z) on ``omega``, or None where it is 1
        (no feed-forward and a torque loop: the paper's flow, left bit for bit as it was)."""
        st = self.structure
        if st.torque_loop and not st.feedforward:
            return None
        if not st.torque_loop:
            return np.zeros(omega.size, complex)
        I_z = self.elements["I_z"]
        P_m0, P_r0, I_t0 = (Fraction(float(x)) for x in (self.P_m0, self.const[0], self.const[1]))
        num = [P_m0 * a + I_t0 * b for a, b in zip(I_z.denominator, I_z.numerator)]
        den = [P_r0 * a + I_t0 * b for a, b in zip(I_z.denominator, I_z.numerator)]
        return frequency_responses([Element("torque_path", num, den)], omega, self.params.controller.Ts)[0]

    def to_statespace(self, P_gain: float, D_gain: float, beta=None, alpha=None, cut: str | None = None):
        """The closed loop at one gain point as a python-control ``StateSpace`` with named signals
        (:func:`haa_sym.loop.statespace.to_statespace`); ``cut`` in {None, "T_ref", "PI"}.

        Examples
        --------
        >>> from haa_sym import load_params, ClosedLoop
        >>> sys = ClosedLoop(load_params()).to_statespace(200.0, 10.0)        # doctest: +SKIP
        >>> sys.input_labels, sys.output_labels                               # doctest: +SKIP
        (['T_dist', 'r'], ['T_meas', 'theta_encoder', 'port_velocity', 'y'])
        """
        P, D, b, a = self._points(P_gain, D_gain, beta, alpha)[0][:, 0]
        return to_statespace(self, P, D, b, a, cut)

    def frequency_response(self, omega, P_gain=0.0, D_gain=0.0, beta=None, alpha=None) -> "FrequencyResponse":
        """Loop transfer functions at ``omega`` (rad/s) for gain points.

        Returns a :class:`FrequencyResponse`: complex arrays of shape ``point_shape +
        (len(omega),)``, ``L_t`` (torque loop opened at the PI output), ``L_imp`` (impedance loop
        opened at the torque reference), ``Z`` (port impedance T_dist/velocity, every loop
        closed) and ``H_T`` (torque tracking T/T_ref, impedance loop open). Negative-feedback
        convention 1/(1+L). ``beta`` and ``alpha`` may vary per point (one coefficient
        evaluation per distinct pair).
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
        return FrequencyResponse(omega=omega, **{k: v.reshape(shape + (omega.size,)) for k, v in out.items()})

    # --- what the analyses share ----------------------------------------------------------------
    def gain_points(self, P_gain, D_gain, beta=None, alpha=None):
        """``(P, D, beta, alpha)``: the gain points as flat arrays (P_gain and D_gain broadcast
        together, C order) and one torque-loop pair (scalars; default the controller's), checked
        by the one rule of :func:`haa_sym.model.params.gain_array`."""
        P, D, _, _ = gain_points(P_gain, D_gain)
        ctrl = self.params.controller
        b = _finite_array("beta", ctrl.beta if beta is None else beta)
        a = _finite_array("alpha", ctrl.alpha if alpha is None else alpha)
        if b.size != 1 or a.size != 1:
            raise ParameterError(f"beta has {b.size} and alpha {a.size} values; allowed: one value each "
                                 "(the analysis holds the torque loop fixed)")
        self._check_unread(b, a)
        return P.ravel(), D.ravel(), float(b.ravel()[0]), float(a.ravel()[0])

    def provenance(self, **extra) -> dict:
        """What produced a result of this loop: parameters, options (file defaults resolved),
        versions, the generated-code hash, the backend that evaluated it, and ``extra``."""
        ev = evaluators(self.backend)
        return {"params": self.params.to_dict(), "options": self.options.to_dict(), "haa_sym": version(),
                "generated_source_sha256": ev.code.manifest["source_sha256"], **extra, "backend": ev.backend}


@dataclass(frozen=True)
class FrequencyResponse:
    """:meth:`ClosedLoop.frequency_response`: ``omega`` (rad/s) and the complex responses
    ``L_t``, ``L_imp``, ``Z``, ``H_T`` (point_shape + (n_omega,)); ``fr["Z"]`` reads a field by name."""

    omega: np.ndarray
    L_t: np.ndarray
    L_imp: np.ndarray
    Z: np.ndarray
    H_T: np.ndarray

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in FREQ_OUTPUTS:
            raise KeyError(name)
        return getattr(self, name)


def loop_first(fn):
    """Mark an analysis that takes the closed loop first (``fn(loop, ...)``): anything else in
    that place (a ``Params``, most often) is refused with a message saying what to pass."""
    @functools.wraps(fn)
    def wrapper(loop, *args, **kwargs):
        if not isinstance(loop, ClosedLoop):
            raise ParameterError(
                f"{fn.__name__}: the first argument is a {type(loop).__name__}; allowed: a haa_sym.ClosedLoop "
                f"(the analyses take the loop first: {fn.__name__}(ClosedLoop(params, options), ...))")
        return fn(loop, *args, **kwargs)
    return wrapper
