"""The nonlinear sampled-data simulation (issue 19; docs/simulate.md).

The controller is the linear loop's own (:func:`haa_sym.loop.statespace.controller_batch`: the
same elements and signal flow as the closed loop the maps analyse), closed around the
continuous plant with the limits of the actuator file's ``[limits]`` section
(:mod:`haa_sym.model.limits`). Per sample instant t_k: the encoder angle and the torque signal
are read (torque-sensor noise added, both quantised), the controller updates, the voltage it
applies (after the delay) is clipped to the supply and the drive's current window and held; the
plant then runs to t_(k+1):

* no friction: the exact zero-order-hold transition (Phi, Gamma from ``scipy.linalg.expm``);
  with jitter, over the interval t_(k+1) - t_k = Ts + delta_k, exactly up to a 12-term series;
* Coulomb friction (smooth model T = -Fc tanh(v / v_s)): substeps of the exponential
  Runge-Kutta method ETDRK4 (Cox and Matthews 2002: the linear part and a constant friction
  torque exactly), 2^j per sample with j chosen per sample by step doubling against
  ``rtol`` x :data:`SAMPLE_TOL_FRACTION`.

The drive's section (:mod:`haa_sym.model.drive`) acts between the clip and the motor: the
clipped command goes through the dead time (whole samples: the driver's delay line; a fraction
f: the held command switches at t_k + f, the plant step split there into two exact pieces, the
ETDRK4 substeps of each from its own tables; with jitter at the same fraction of the stretched
interval) and then the lag (one more continuous state, :func:`haa_sym.loop.plant.with_lag`).
With every limit off the simulation is the linear closed loop with the drive to rounding.

The loop over samples is generated C (``codegen/sim_kernels.py``, ``codegen/driver.c``).

Example
-------
>>> from haa_sym import ClosedLoop, load_params
>>> sim = simulate(ClosedLoop(load_params()), 200.0, 5.0, experiment="disturbance-step",
...                amplitude=1.0, duration=0.5)                    # doctest: +SKIP
>>> sim.columns()["theta"][-1]                                      # doctest: +SKIP
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from haa_sym.analysis.oscillation import (SATURATING_FRACTION, VERDICTS, Oscillation, classify, limit_cycle,
                                          tail_start)
from haa_sym.analysis.sweep import blas_limits
from haa_sym.compiled import layout as L
from haa_sym.compiled.generated import evaluators
from haa_sym.errors import ParameterError
from haa_sym.io.budget import BYTES_PER_SAMPLE, check_memory
from haa_sym.loop import loop_first
from haa_sym.loop.plant import (CURRENT_STATE, LAG_STATE, continuous_plant, current_commanded, delay_split,
                                with_lag)
from haa_sym.loop.statespace import controller_batch
from haa_sym.model.actuator import ROTOR
from haa_sym.model.limits import Limits

__all__ = ["EXPERIMENTS", "FORCED_EXPERIMENTS", "CSV_COLUMNS", "Simulation", "SimulationBatch", "Continuation",
           "continuable", "JITTER_STREAM", "keep_from", "simulate",
           "simulate_batch", "DEFAULT_RTOL", "MAX_SAMPLES", "limits_act_every_step", "linear_verdict"]

#: The experiments (docs/simulate.md): what ``amplitude`` A is and where it enters.
EXPERIMENTS = {
    "disturbance-step": "a constant external torque of A Nm on the port body from t = 0",
    "torque-step": "a torque reference step of A Nm at t = 0 (added to the impedance law's)",
    "impedance-step": "a step of A rad of the impedance law's angle set point at t = 0",
    "deflection": "an initial angle of A rad of the port body, every other state at rest",
    "chirp": "a torque reference A sin(2 pi (f0 t + (f1 - f0) t^2 / (2 T))) Nm, f0 -> f1 over T",
}
#: Experiments that drive the loop for the whole run: their oscillation is the input's, so their
#: verdict is "forced response" (or diverged / growing), never "limit cycle"
FORCED_EXPERIMENTS = ("chirp",)
DEFAULT_AMPLITUDE = {"disturbance-step": 1.0, "torque-step": 1.0, "impedance-step": 0.1,
                     "deflection": 0.1, "chirp": 1.0}
#: The CSV's columns: time (s), theta (rad), velocity (rad/s), torque, torque_ref (Nm),
#: voltage (V), current (A).
CSV_COLUMNS = ("time",) + L.SIM_COLUMNS[:-1]
DEFAULT_RTOL = 1e-6          # error bound of the friction integrator's run, relative to each state's peak
# Per sample, step doubling holds the difference of two levels to SAMPLE_TOL_FRACTION rtol: at
# stick the samples' errors add up coherently (a creeping body errs the same way every sample),
# measured on HyQ (docs/simulate.md: rotor friction, 5,000 samples) to 1.1e-8 of the peak at
# rtol 1e-6, where a per-sample bound of rtol itself left 4e-6
SAMPLE_TOL_FRACTION = 1e-3
MAX_SUBSTEPS = 4096
LEVELS = 13                  # friction substeps per sample: 1, 2, 4, ..., 4096
# The friction slopes (fractions of Fc / v_s) a table may put into the exact linear part, by the
# number of friction entries (1, 2, 3, 4): len(SLOPES)^n tables of LEVELS levels each
SLOPES = ((0.0, 0.03, 0.06, 0.125, 0.25, 0.5, 0.75, 1.0), (0.0, 0.03, 0.06, 0.125, 0.25, 0.5, 0.75, 1.0),
          (0.0, 0.1, 0.3, 1.0), (0.0, 1.0))
# a hard cap whatever the memory; the memory budget (io.budget.BYTES_PER_SAMPLE) refuses earlier
MAX_SAMPLES = 50_000_000
CHIRP_F0 = 0.1               # Hz
JITTER_CLIP = 3.0            # the sample offsets are Gaussian clipped to +-3 sigma
#: The jitter's random stream: the child of the seed's ``SeedSequence`` with this spawn key
#: (``SeedSequence(seed).spawn(1)[0]``); the torque noise's is ``default_rng(seed)`` itself. Each
#: limit draws from its own stream, so that its draws up to a sample depend neither on the run's
#: length nor on the other limit (a longer run continues a shorter one: :func:`continuable`), and
#: the noise's draws are those of before 2026-11-26, when the jitter's followed the noise's n
#: draws in the one stream (docs/simulate.md, "The sampled-data model")
JITTER_STREAM = 0
# |lambda_max delta| / n_sub of each jitter substep's series (codegen/sim_kernels.py)
JITTER_STEP_BOUND = 0.5
#: The simulation's state of a current command held without a lag: the current the motor carried
#: over the last interval (every plant step sets it to its held command: :meth:`_Setup.hold_rows`)
HOLD_STATE = "I_held"


@dataclass(frozen=True)
class Simulation:
    """One simulated run: the CSV's columns (one row per sample instant; a run that overflowed
    ends before its first non-finite sample), the saturation flags, the time spent in saturation
    (s) and a detected limit cycle of the torque signal (``cycle_amplitude`` Nm, half
    peak-to-peak; ``cycle_frequency`` Hz; NaN when none: the ``oscillation``
    :func:`haa_sym.analysis.oscillation.limit_cycle` found in the torque signal's last half is not
    "sustained", or the experiment is forced; ``oscillation`` is None when a state overflowed).

    ``verdict`` is the run's one verdict (:data:`haa_sym.analysis.oscillation.VERDICTS`, the rules
    of :func:`haa_sym.analysis.oscillation.classify`); ``diverged_at`` the time (s) of the first
    non-finite sample (NaN if none); ``linear_stable`` and ``spectral_radius`` the linear loop's
    certified decision at the gain point (None and NaN for a loop built with ``basis=False``)."""

    time: np.ndarray
    theta: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    torque_ref: np.ndarray
    voltage: np.ndarray
    current: np.ndarray
    saturated: np.ndarray
    saturation_time: float
    cycle_amplitude: float
    cycle_frequency: float
    meta: dict = field(repr=False)
    oscillation: Oscillation | None = field(repr=False, default=None)
    verdict: str = "undecided"
    diverged_at: float = math.nan
    linear_stable: bool | None = None
    spectral_radius: float = math.nan

    def columns(self) -> dict[str, np.ndarray]:
        """The CSV columns by name, in :data:`CSV_COLUMNS` order."""
        return {c: getattr(self, c) for c in CSV_COLUMNS}

    @property
    def limit_cycle(self) -> bool:
        return bool(np.isfinite(self.cycle_amplitude))


@dataclass(frozen=True)
class SimulationBatch:
    """Summaries of simulations at k gain points: ``saturation_time`` (s), ``cycle_amplitude``
    (Nm), ``cycle_frequency`` (Hz), ``final_theta`` (rad, mean over the last tenth), ``growth``
    (the torque's peak-to-peak swing over the last quarter of the run over the quarter's before),
    ``oscillation`` (the kind :func:`haa_sym.analysis.oscillation.limit_cycle` found in the torque's
    last half: none, decaying, sustained, growing; "non-finite"), ``tail_saturation`` (the fraction
    of the last half's samples in saturation), ``continuations`` (with ``continue_to``: per point
    the :class:`Continuation` a longer run starts from) and ``status``: each point's verdict
    (:data:`haa_sym.analysis.oscillation.VERDICTS`, by :func:`haa_sym.analysis.oscillation.classify`
    from the run and the linear loop's decision; "undecided" where that is unknown and the run
    cannot tell)."""

    P_gain: np.ndarray
    D_gain: np.ndarray
    saturation_time: np.ndarray
    cycle_amplitude: np.ndarray
    cycle_frequency: np.ndarray
    final_theta: np.ndarray
    growth: np.ndarray
    status: np.ndarray
    meta: dict = field(repr=False)
    oscillation: np.ndarray | None = field(repr=False, default=None)
    tail_saturation: np.ndarray | None = field(repr=False, default=None)
    continuations: list | None = field(repr=False, default=None)


def _pad(M, rows, cols):
    out = np.zeros((rows, cols))
    M = np.atleast_2d(M)
    out[:M.shape[0], :M.shape[1]] = M
    return out


def _pack(lay: L.Slices, **parts) -> np.ndarray:
    v = np.zeros(lay.size)
    for name, val in parts.items():
        r, c = lay.shape[name]
        v[lay[name]] = _pad(np.reshape(val, (-1, 1)) if np.ndim(val) < 2 else val, r, c).ravel(order="F")
    return v


def _zoh(A, B, h):
    n, m = B.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n], aug[:n, n:] = A, B
    E = scipy.linalg.expm(aug * h)
    return E[:n, :n], E[:n, n:]


@functools.lru_cache(maxsize=16)
def _continuous(plant, backend):
    # a sweep of gains simulates one plant many times (evaluating it costs a CasADi call)
    return continuous_plant(plant, backend)


def _capacity(nx, nc):
    for cx, cc in L.SIM_CAPACITIES:
        if nx <= cx and nc <= cc:
            return cx, cc
    big = max(L.SIM_CAPACITIES)
    raise ParameterError(f"a plant of {nx} states with a controller of {nc} states exceeds the simulation's "
                         f"generated capacities {list(L.SIM_CAPACITIES)}; allowed: at most {big[0]} plant "
                         f"and {big[1]} controller states (fewer bodies or a smaller N_av)")


def _number(name, value, allowed, test):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
            or not math.isfinite(value) or not test(value):
        raise ParameterError(f"{name} = {value!r}; allowed: {allowed}")
    return float(value)


class _Setup:
    """Everything of one simulation but the gains' controller: plant matrices, limits, inputs."""

    def __init__(self, loop, limits, experiment, amplitude, duration, seed, chirp_f1, excitation=None,
                 scale_duration=None):
        params, ctrl = loop.params, loop.params.controller
        self.Ts = Ts = ctrl.Ts
        if experiment not in EXPERIMENTS:
            raise ParameterError(f"experiment = {experiment!r}; allowed: {list(EXPERIMENTS)}")
        amplitude = DEFAULT_AMPLITUDE[experiment] if amplitude is None else amplitude
        self.amplitude = _number("amplitude", amplitude, "a finite number", lambda v: True)
        duration = _number("duration", duration, "a finite number of seconds > 0", lambda v: v > 0)
        n = int(math.ceil(duration / Ts - 1e-9)) + 1
        if n > MAX_SAMPLES:
            raise ParameterError(f"duration = {duration!r} s is {n} samples at Ts = {Ts} s; allowed: at most "
                                 f"{MAX_SAMPLES} samples ({MAX_SAMPLES * Ts:g} s)")
        check_memory(n * BYTES_PER_SAMPLE, f"duration = {duration!r} s ({n} samples at Ts = {Ts:g} s)")
        if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
            raise ParameterError(f"seed = {seed!r}; allowed: an integer >= 0")
        lim = params.limits if limits is None else limits
        # the file's [limits] are named by the file, as parse_limits names them
        where = f"{params.source} [limits]" if limits is None else "limits"
        if not isinstance(lim, Limits):
            raise ParameterError(f"limits = {lim!r}; allowed: a haa_sym.model.limits.Limits or None "
                                 "(the parameter file's [limits])")
        self.limits, self.experiment, self.duration, self.n, self.seed = lim, experiment, duration, n, seed
        # the friction integrator's error scale: the no-friction run's state peaks over its first
        # scale_duration seconds (default the whole run; _run)
        self.scale_duration = duration if scale_duration is None else _number(
            "scale_duration", scale_duration, f"a number of seconds in (0, duration = {duration:g}]",
            lambda v: 0 < v <= duration)
        self.n_scale = min(n, int(math.ceil(self.scale_duration / Ts - 1e-9)) + 1)
        top = params.plant.topology
        motor = _continuous(params.plant, loop.backend)
        # a current-commanded structure (impedance_current): the plant without the electrical
        # state, the command its current (the linear loop's own current_commanded)
        self.current = current = loop.structure.command == "current"
        plant = current_commanded(motor, current)
        # the drive (haa_sym.model.drive; docs/simulate.md, "The drive"): its lag is one more
        # continuous state of the plant (the linear loop's own with_lag), so every plant step
        # below integrates it exactly; its dead time is the driver's delay line of commands
        self.drive = drive = params.drive
        cont = with_lag(plant, drive.tau_drive)
        self.whole, self.frac = delay_split(drive.delay_drive, Ts)
        # the sample interval's pieces: with a fractional delay f the held command switches at
        # t_k + f (the older command before, the newer after), else one piece; the jitter
        # stretches each piece in proportion (piece_frac)
        self.spans = (self.frac, Ts - self.frac) if self.frac else (Ts,)
        self.piece_frac = tuple(h / Ts for h in self.spans) if self.frac else (1.0,)
        A, B = cont.A, cont.B
        n_p = A.shape[0]                 # the linear loop's plant states (without its delay line)
        states, outs = cont.state_names, cont.output_names
        Cm = loop.plant.C[:, :n_p]       # the delay line's states are not the plant's (driver.c)
        # a current command without a lag is held, not a state: one more state, HOLD_STATE, that
        # every plant step sets to the command it held (no continuous dynamics: _hold), so that
        # the current the motor carried up to t_k is read at t_k like every other signal
        self.hold = n_p if current and not drive.tau_drive > 0 else None
        if self.hold is not None:
            A, B, Cm = _pad(A, n_p + 1, n_p + 1), _pad(B, n_p + 1, B.shape[1]), _pad(Cm, Cm.shape[0], n_p + 1)
            states = states + (HOLD_STATE,)
        self.nx = nx = A.shape[0]
        # the motor's voltage equation, row I_m of A and B of the motor (voltage-driven, no lag):
        # L dI/dt = V - R I - emf(x); for a current command its states but I_m are this plant's
        i_m = motor.state_names.index(CURRENT_STATE)
        L_m = 1.0 / motor.B[i_m, 0]
        R = -motor.A[i_m, i_m] * L_m
        emf = np.zeros(nx)
        for j, name in enumerate(motor.state_names):
            if j != i_m:
                emf[states.index(name)] = -motor.A[i_m, j] * L_m
        # the motor current: the state I_m, or for a current command the held command (the lag's
        # state u_lag with a lag); the torque signal's row takes its I_m coefficient there
        # (torque = "current": k_t N I), the rest of it being the current plant's own row
        i_cur = states.index(CURRENT_STATE) if not current else \
            (self.hold if self.hold is not None else states.index(LAG_STATE))
        c_T = Cm[outs.index(loop.torque_output)].copy()
        if current:
            c_T[i_cur] += motor.C[motor.output_names.index(loop.torque_output), i_m]
        self.rows = {"c_theta": Cm[outs.index("theta_encoder")], "c_T": c_T, "c_I": np.eye(nx)[i_cur],
                     "c_v": Cm[outs.index(f"dtheta_{top.port}")]}
        # the two windows of the held command (codegen/sim_kernels.py): the drive's current limit
        # first, the supply last (docs/simulate.md, "Saturate")
        I_max = math.inf if lim.I_max is None else lim.I_max
        V_max = math.inf if lim.V_max is None else lim.V_max
        if current:
            self.windows = dict(c_w1=np.zeros(nx), w1=I_max, c_w2=-emf / R, w2=V_max / R)
        else:
            self.windows = dict(c_w1=emf, w1=R * I_max, c_w2=np.zeros(nx), w2=V_max)
        turn = 2 * math.pi / (params.plant.N if top.encoder == "rotor" else 1.0)
        self.q_theta = 0.0 if lim.encoder_counts is None else turn / lim.encoder_counts
        self.q_T = lim.torque_resolution or 0.0
        iu = [cont.input_names.index("V_m"), cont.input_names.index("T_dist")]
        friction = {b: v for b, v in lim.friction.items() if v > 0}
        jitter = lim.jitter or 0.0
        if friction and jitter:
            raise ParameterError(f"{where}: jitter together with Coulomb friction is not supported; allowed: "
                                 "one of them (docs/simulate.md)")
        if jitter and JITTER_CLIP * jitter >= Ts / 2:
            raise ParameterError(f"{where}: jitter = {jitter!r} s rms; allowed: < Ts / {2 * JITTER_CLIP:g} = "
                                 f"{Ts / (2 * JITTER_CLIP):g} s (the sample instants must stay ordered)")
        # exogenous inputs
        exo = np.zeros((len(L.SIM_EXO), n))
        k = L.SIM_EXO.index
        t_nom = np.arange(n) * Ts
        A_ = self.amplitude
        if experiment == "disturbance-step":
            exo[k("T_dist")] = A_
        elif experiment == "torque-step":
            exo[k("T_ff")] = A_
        elif experiment == "impedance-step":
            exo[k("theta_ref")] = A_
        elif experiment == "chirp":
            f1 = 0.1 / Ts if chirp_f1 is None else _number("chirp_f1", chirp_f1, "a frequency > 0 (Hz)",
                                                          lambda v: v > 0)
            T_end = max(t_nom[-1], Ts)
            exo[k("T_ff")] = A_ * np.sin(2 * np.pi * (CHIRP_F0 * t_nom + (f1 - CHIRP_F0) * t_nom ** 2 / (2 * T_end)))
            self.chirp = (CHIRP_F0, f1)
        if excitation is not None:
            u = np.asarray(excitation, float)
            if experiment != "chirp" or u.shape != (n,) or not np.all(np.isfinite(u)):
                raise ParameterError(f"excitation: shape {u.shape} with experiment {experiment!r}; allowed: {n} "
                                     "finite samples (one per sample of the run) with experiment 'chirp'")
            exo[k("T_ff")] = A_ * u
        self.x0 = np.zeros(nx)
        if experiment == "deflection":
            # a rotor-only file's port is the rotor, whose state is theta_m
            self.x0[states.index("theta_m" if top.port == ROTOR else f"theta_{top.port}")] = A_
        if lim.torque_noise:
            exo[k("noise_T")] = lim.torque_noise * np.random.default_rng(seed).standard_normal(n)
        eps = np.zeros(n + 1)
        if jitter:
            rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(JITTER_STREAM,)))
            eps[1:] = np.clip(jitter * rng.standard_normal(n), -JITTER_CLIP * jitter, JITTER_CLIP * jitter)
            exo[k("delta")] = np.diff(eps)
        self.time = t_nom + eps[:n]
        self.exo = exo
        # plant step
        Bu = B[:, iu]
        if friction:
            self.kind = "etd"
            sel, col, fc = [], [], []
            for b, v in sorted(friction.items()):
                if b == "m":
                    sel.append(states.index("dtheta_m"))
                    col.append(B[:, cont.input_names.index("T_fr")])
                else:
                    j = states.index(f"dtheta_{b}")
                    sel.append(j)
                    col.append(np.eye(nx)[j] / getattr(params.plant, f"J_{b}"))
                fc.append(v)
            self.friction = (np.array(sel), np.array(col).T, np.array(fc))
            self.n_sub0 = None          # chosen per sample (_run)
        elif jitter:
            self.kind = "jitter"
            rho = np.abs(np.linalg.eigvals(A)).max()
            self.n_sub0 = max(1, int(math.ceil(rho * 2 * JITTER_CLIP * jitter / JITTER_STEP_BOUND)))
            if self.n_sub0 > MAX_SUBSTEPS:
                raise ParameterError(f"{where}: jitter = {jitter!r} s rms needs {self.n_sub0} substeps for this "
                                     f"plant; allowed: a jitter below {MAX_SUBSTEPS * JITTER_STEP_BOUND / (2 * JITTER_CLIP * rho):g} s")
            # per piece: Phi, Gamma over span / n_sub, the interval's stretch delta span / Ts
            self.plant_parts = [dict(zip(("Phi", "Gamma"), self.hold_rows(*_zoh(A, Bu, h / self.n_sub0))),
                                     inv_n=1.0 / self.n_sub0) for h in self.spans]
        else:
            self.kind = "zoh"
            self.n_sub0 = 1
        self.A, self.Bu, self.n_p = A, Bu, n_p
        self.zoh_parts = self._zoh_parts(loop, iu)
        if self.kind == "zoh":
            self.plant_parts = self.zoh_parts

    def drive_meta(self) -> dict:
        """The drive as the run applied it (s): lag, dead time and its split into whole samples
        and a fraction, and the order of the command's path (docs/simulate.md, "The drive")."""
        return {"tau_drive": self.drive.tau_drive, "delay_drive": self.drive.delay_drive,
                "delay_whole_samples": self.whole, "delay_fraction_s": self.frac,
                "order": "clip (supply, current window) -> delay -> lag -> motor",
                "command": "current" if self.current else "voltage"}

    def hold_rows(self, Phi, Gamma):
        """``Phi``, ``Gamma`` of a plant step (any length) with the row of :data:`HOLD_STATE` set to
        the held command, x_hold+ = u (a copy; unchanged without that state). The row is zero in
        the continuous A and B, so every other row of an exact or integrating step is untouched."""
        if self.hold is None:
            return Phi, Gamma
        Phi, Gamma = Phi.copy(), Gamma.copy()
        Phi[self.hold], Gamma[self.hold] = 0.0, 0.0
        Gamma[self.hold, 0] = 1.0
        return Phi, Gamma

    def _zoh_parts(self, loop, iu):
        """The exact ZOH transition (``Phi``, ``Gamma`` of the inputs [V, T_dist]) of each piece of
        the sample interval. Without a fractional delay they are the linear loop's own sampled
        plant (with every limit off the simulation then gives its numbers): its plant block, and
        the command's column where :func:`haa_sym.loop.plant.discretize` put it (the delay line's
        oldest state for a whole-sample delay). With one, the two pieces over f and Ts - f."""
        nx, n, pl = self.nx, self.n_p, loop.plant
        if self.frac:
            return [dict(zip(("Phi", "Gamma"), self.hold_rows(*_zoh(self.A, self.Bu, h)))) for h in self.spans]
        Gamma = pl.Gamma[:n, iu].copy()
        if self.whole:
            Gamma[:, 0] = pl.Phi[:n, n + self.whole - 1]
        return [dict(zip(("Phi", "Gamma"), self.hold_rows(_pad(pl.Phi[:n, :n], nx, nx), _pad(Gamma, nx, len(iu)))))]

    def etd_tables(self, fractions, cx, span=None):
        """The packed ETDRK4 substep parameters (``sim_plant_layout("etd", cx)``) of every row of
        ``fractions`` (tables, one fraction per friction entry) and every level j = 0 .. LEVELS - 1
        (2^j substeps per sample, h = span / 2^j; ``span`` the piece of the sample interval, default
        Ts), shape (len(fractions), LEVELS, plant size)
        flattened: friction entry b of table c has ``fractions[c][b]`` of its slope at v = 0,
        Fc / v_s, moved into the linear part (integrated exactly) and out of the explicit stages.

        Per table one expm at the finest half step of the block matrix [[A, B, W, 0, 0],
        [0, 0, 0, 0, 0], [0, 0, 0, I, 0], [0, 0, 0, 0, I], 0] (W: the friction columns), whose
        exponential's top row is [e^(A h), Gamma(h), h phi_1 W, h^2 phi_2 W, h^3 phi_3 W]; every
        coarser step by squaring (expm's own scaling and squaring, continued). All tables at
        once (batched expm and products): one table at a time, in Python, cost 0.05 s of a 0.08 s
        friction run (HyQ, 64 tables)."""
        sel, col, fc = self.friction
        n, nu, m = self.nx, self.Bu.shape[1], len(sel)
        fr = np.atleast_2d(np.asarray(fractions, float))
        nt = fr.shape[0]
        Fsel = np.zeros((m, n))
        Fsel[np.arange(m), sel] = 1.0
        inv_vs = 1.0 / self.limits.friction_velocity
        lin = fr * fc * inv_vs                                           # (nt, m)
        size, o = n + nu + 3 * m, n + nu
        K = np.zeros((nt, size, size))
        K[:, :n, :n] = self.A - np.einsum("im,tm,mj->tij", col, lin, Fsel)
        K[:, :n, n:o], K[:, :n, o:o + m] = self.Bu, col
        K[:, o:o + m, o + m:o + 2 * m] = np.eye(m)
        K[:, o + m:o + 2 * m, o + 2 * m:] = np.eye(m)
        h = (self.Ts if span is None else span) / 2 ** LEVELS    # the finest level's half step
        E = scipy.linalg.expm(K * h)
        tops = np.empty((LEVELS + 1, nt, n, size))     # tops[i]: over Ts / 2^(LEVELS - i)
        hs = h * 2.0 ** np.arange(LEVELS + 1)
        for i in range(LEVELS + 1):
            tops[i] = E[:, :n]
            if i < LEVELS:
                E = E @ E
        if self.hold is not None:                        # x_hold+ = u over every (sub)step
            tops[:, :, self.hold] = 0.0
            tops[:, :, self.hold, n] = 1.0
        lay = L.sim_plant_layout("etd", cx)
        out = np.zeros((nt, LEVELS, lay.size))

        def put(name, val):                              # val (nt, LEVELS, r', c') into its padded slot
            r, c = lay.shape[name]                       # column-major: a view (.., c, r) of the slot
            slot = out[:, :, lay[name]].reshape(nt, LEVELS, c, r)
            slot[:, :, :val.shape[3], :val.shape[2]] = np.swapaxes(val, 2, 3)

        lev = np.arange(LEVELS)                          # level j: the step over Ts / 2^j and its half
        full = tops[LEVELS - lev].swapaxes(0, 1)         # (nt, LEVELS, n, size), views
        half = tops[LEVELS - lev - 1].swapaxes(0, 1)
        hj = hs[LEVELS - lev][None, :, None, None]
        p1, p2, p3 = (full[..., o + k * m:o + (k + 1) * m] / hj ** (k + 1) for k in range(3))
        put("Ph", half[..., :n])
        put("Gh", half[..., n:o])
        put("P", full[..., :n])
        put("G", full[..., n:o])
        put("Qh", hj / 2 * (half[..., o:o + m] / (hj / 2)))
        put("F1", hj * (p1 - 3 * p2 + 4 * p3))
        put("F2", hj * (p2 - 2 * p3))
        put("F3", hj * (-p2 + 4 * p3))
        put("Fsel", np.broadcast_to(Fsel, (nt, LEVELS, m, n)))
        put("Fc", np.broadcast_to(fc[:, None], (nt, LEVELS, m, 1)))
        put("inv_vs", np.full((nt, LEVELS, 1, 1), inv_vs))
        put("lin", np.broadcast_to(lin[:, None, :, None], (nt, LEVELS, m, 1)))
        return out.ravel()


@dataclass(frozen=True)
class Continuation:
    """Where a run of one gain point stopped, and what of it the summaries of a longer run read
    (docs/simulate.md, "Nonlinear maps"): enough to continue it to a longer run that takes
    exactly the steps of one run from t = 0 (:func:`simulate_batch`'s ``start``).

    Attributes
    ----------
    k : int
        Samples done: the state is at the sample instant t_k.
    x, xc : ndarray
        The plant's and the controller's state (the generated loop's capacity-padded vectors).
    carry : ndarray
        The C loop's other state: the friction integrator's level and difference, the drive's
        delay line (:meth:`haa_sym.compiled.generated.Evaluators.run_simulation`).
    scale : ndarray or None
        The friction integrator's error scale (the no-friction run's peaks over the first
        ``scale_duration``; None without friction).
    keep_from : int
        The first sample whose outputs are kept: :func:`keep_from` of the longer run.
    rows : ndarray, (k - keep_from, len(SIM_COLUMNS))
        The outputs of samples keep_from .. k - 1.
    saturated_head : ndarray of int
        The samples before keep_from that were in saturation (the saturation time is over the
        whole run), by index: most points never saturate, and a task ships every point's state.
    torque_peak_head : float
        max |torque| over the samples before (the oscillation classifier's hysteresis floor).
    """

    k: int
    x: np.ndarray
    xc: np.ndarray
    carry: np.ndarray
    scale: np.ndarray | None
    keep_from: int
    rows: np.ndarray
    saturated_head: np.ndarray
    torque_peak_head: float


def keep_from(Ts: float, n: int) -> int:
    """The first sample whose outputs the verdict and the summaries of a run of ``n`` samples read:
    the oscillation classifier's tail (:func:`haa_sym.analysis.oscillation.tail_start` of the
    nominal instants, its default settle), the last half (tail saturation) and the last two
    quarters (growth) and tenth (final angle) of :func:`simulate_batch`."""
    return min(n // 2, n - 2 * max(1, n // 4), tail_start(np.arange(n) * Ts))


def continuable(setup: _Setup) -> bool:
    """Whether a run's inputs up to t do not depend on its length, so that a longer run can
    continue a shorter one: not the chirp (its sweep rate is set by the run's length); every other
    experiment and limit is (the torque noise and the jitter draw from their own seeded streams,
    :data:`JITTER_STREAM`; before 2026-11-26 the jitter's draws followed the noise's n in one
    stream, and noise with jitter was not)."""
    return setup.experiment not in FORCED_EXPERIMENTS


def _run(loop, setup: _Setup, P_gain, D_gain, controller=None, start: Continuation | None = None):
    """(y (n - k0, len(SIM_COLUMNS)), integrator info, end state (x, xc, carry, scale)) of one gain
    point from sample k0 = ``start.k`` (0 without ``start``) to the setup's last; ``controller``
    its (Ac, Bc, Cc, Dc) if already built (a batch builds them all in one call)."""
    Ac, Bc, Cc, Dc = controller if controller is not None else \
        (m[0] for m in controller_batch(loop, P_gain, D_gain))
    nc = Ac.shape[0]
    cx, cc = _capacity(setup.nx, nc)
    names = L.sim_function_names(cx, cc)
    ev = evaluators(loop.backend)
    ctrl = _pack(L.sim_ctrl_layout(cx, cc), Ac=Ac, Bc=Bc, Cc=Cc, Dc=Dc,
                 q_theta=setup.q_theta, q_T=setup.q_T,
                 **{k: v[None, :] for k, v in setup.rows.items()},
                 **{k: v[None, :] if np.ndim(v) else v for k, v in setup.windows.items()})
    if start is None:
        k0, x0, xc0, carry = 0, _pad(setup.x0[:, None], cx, 1).ravel(), np.zeros(cc), None
    else:
        k0, x0, xc0, carry = start.k, start.x, start.xc, start.carry
    exo = setup.exo[:, k0:]

    def run(n_sub, parts, kind=setup.kind, exo=exo, x0=x0, xc0=xc0, carry=carry, **kw):
        # one parameter vector (or set of tables) per piece of the sample interval, in turn
        plant = parts if isinstance(parts, np.ndarray) else \
            np.concatenate([_pack(L.sim_plant_layout(kind, cx), **p) for p in parts])
        y, x, xc, extra, c = ev.run_simulation(names["sample"], names[kind], n_sub, x0, xc0, exo, ctrl, plant,
                                               pieces=setup.piece_frac, whole=setup.whole, carry=carry, **kw)
        return y, extra, (x, xc, c)

    if setup.kind == "jitter":      # [A, B] padded block by block: the u columns follow all cx states
        M = np.hstack([_pad(setup.A, cx, cx), _pad(setup.Bu, cx, len(L.SIM_U))])
        parts = [dict(p, M=M) for p in setup.plant_parts]
        y, _e, end = run(setup.n_sub0, parts)
        return y, {"integrator": "jitter", "n_sub": setup.n_sub0}, end + (None,)
    if setup.kind == "zoh":
        y, _e, end = run(setup.n_sub0, setup.plant_parts)
        return y, {"integrator": "zoh", "n_sub": 1}, end + (None,)
    # Coulomb friction: the error is measured against each state's peak in the same run without
    # friction (exact ZOH, a fraction of the cost) over its first scale_duration (default the
    # whole run; a map's continued runs keep their first run's: one scale for every length);
    # per sample the driver halves the substep until two successive levels agree within
    # SAMPLE_TOL_FRACTION rtol of those peaks and keeps the finer one (RK4: its local error is
    # about 1/15 of the difference; the local errors of the samples add up over a run, hence
    # the margin)
    if start is None:
        _y, peaks, _end = run(1, setup.zoh_parts, kind="zoh", peaks=True, exo=setup.exo[:, :setup.n_scale],
                              x0=x0, xc0=xc0, carry=None)
        scale = np.maximum(_pad(peaks[:, None], cx, 1).ravel(), 1e-12)
    else:
        scale = start.scale
    # the tanh's slope at the sample's velocity, to the nearest of SLOPES, goes into the exact
    # linear part (a table per combination over the bodies), so that the explicit stages see
    # only its change over the sample: at stick the slope is steep (Fc / v_s), while sliding
    # the torque is nearly constant (the tables depend on the plant only: built once per setup)
    nf = len(setup.friction[0])
    slopes = SLOPES[min(len(SLOPES) - 1, nf - 1)]
    if getattr(setup, "etd_cache", None) is None or setup.etd_cache[0] != cx:
        K = len(slopes)              # table index: sum_r (slope index of row r) K^r (driver.c)
        combos = [[slopes[i // K ** r % K] for r in range(nf)] for i in range(K ** nf)]
        # one set of tables per piece of the sample interval (its substeps end at the switch)
        setup.etd_cache = (cx, np.concatenate([setup.etd_tables(combos, cx, h) for h in setup.spans]))
    rows = np.zeros((nf, cx))
    rows[np.arange(nf), setup.friction[0]] = 1.0 / setup.limits.friction_velocity
    y, lev, end = run(LEVELS, setup.etd_cache[1], scale=scale, tol=setup.rtol * SAMPLE_TOL_FRACTION,
                      stick_rows=rows, slopes=slopes)
    subs = 2.0 ** lev
    return y, {"integrator": "etdrk4, substeps per sample by step doubling", "n_sub": float(subs.mean()),
               "n_sub_max": int(subs.max()) if subs.size else 1, "rtol": setup.rtol,
               "sample_tol": setup.rtol * SAMPLE_TOL_FRACTION}, end + (scale,)


def _continuation(setup: _Setup, start: Continuation | None, y: np.ndarray, end, n_next: int) -> Continuation:
    """The :class:`Continuation` of a run that ended with outputs ``y`` (its samples from
    ``start.k``, or 0) and state ``end`` (:func:`_run`), keeping what a run of ``n_next``
    samples reads."""
    k0, first = (0, 0) if start is None else (start.k, start.keep_from)
    rows = y if start is None else np.concatenate([start.rows, y])        # samples first .. k - 1
    keep = max(first, min(keep_from(setup.Ts, n_next), k0 + y.shape[0]))
    cut = rows[:keep - first]
    sat_col, t_col = L.SIM_COLUMNS.index("saturated"), L.SIM_COLUMNS.index("torque")
    head_sat = first + np.flatnonzero(cut[:, sat_col] > 0.5)
    head_peak = float(np.abs(cut[:, t_col]).max()) if cut.shape[0] else 0.0
    if start is not None:
        head_sat = np.concatenate([start.saturated_head, head_sat])
        head_peak = max(head_peak, start.torque_peak_head)
    x, xc, carry, scale = end
    return Continuation(k0 + y.shape[0], x, xc, carry, scale, keep, rows[keep - first:].copy(), head_sat, head_peak)


def limits_act_every_step(lim: Limits) -> bool:
    """Whether a limit acts on every step whatever the amplitude (Coulomb friction, either
    quantiser, torque noise, jitter): then no stretch of a run is the linear loop."""
    return bool(any(v > 0 for v in lim.friction.values()) or lim.encoder_counts or lim.torque_resolution
                or lim.torque_noise or lim.jitter)


def linear_verdict(loop, P_gain, D_gain) -> tuple[np.ndarray, np.ndarray]:
    """The linear loop's certified stability (float: 1 stable, 0 not) and spectral radius at the
    gain points; NaN for a loop built with ``basis=False`` (no stability evaluator)."""
    P, D = np.atleast_1d(P_gain).astype(float), np.atleast_1d(D_gain).astype(float)
    if getattr(loop, "basis", None) is None:
        return np.full(P.shape, np.nan), np.full(P.shape, np.nan)
    r = loop.stability(P, D, radius=True)
    return np.asarray(r.stable, float), np.asarray(r.spectral_radius, float)


def _first_non_finite(y) -> int:
    """Index of the first sample (row) with a non-finite value, or the number of rows."""
    bad = ~np.isfinite(y).all(axis=1)
    return int(np.argmax(bad)) if bad.any() else y.shape[0]


def _result(loop, setup, P_gain, D_gain, y, info, linear=None, head: Continuation | None = None):
    """The :class:`Simulation` of a run's outputs ``y``; with ``head`` (the :class:`Continuation`
    the run continued), ``y`` holds its samples from ``head.k`` on and the columns returned
    those from ``head.keep_from`` on, the verdict and the saturation time being the whole run's."""
    k0, first = (0, 0) if head is None else (head.k, head.keep_from)
    if head is not None:
        y = np.concatenate([head.rows, y])
    # a run that overflowed ends at its first non-finite sample: what follows is not data (the
    # samples before a continuation were finite: a diverged run is not continued)
    k, y_rows = first + _first_non_finite(y), first + y.shape[0]
    diverged_at = float(setup.time[k]) if k < y_rows else math.nan
    y, time = y[:k - first], setup.time[first:k]
    col = {c: y[:, i] for i, c in enumerate(L.SIM_COLUMNS)}
    sat = col["saturated"] > 0.5
    if head is None:
        sat_all = sat
    else:
        sat_all = np.zeros(k, bool)
        sat_all[head.saturated_head] = True
        sat_all[first:] = sat
    dt = np.diff(np.append(setup.time[:k], setup.time[k - 1] + setup.Ts)) if k else np.zeros(0)
    sat_time = float(dt[sat_all].sum())
    forced = setup.experiment in FORCED_EXPERIMENTS
    diverged = k < y_rows
    osc = None if diverged else trace_oscillation(setup, col["torque"], first,
                                                  0.0 if head is None else head.torque_peak_head)
    amp, freq = (osc.amplitude, osc.frequency_hz) if osc is not None and osc.kind in ("sustained", "irregular") \
        and not forced else (math.nan, math.nan)
    stable, radius = linear if linear is not None else (math.nan, math.nan)
    tail_sat = float(sat_all[k // 2:].mean()) if not diverged and k else math.nan
    # a run too short to judge its trace (trace_oscillation gives None) is no oscillation: the
    # linear-regime and saturation rules decide it, else it is undecided (it was "diverged at nan")
    kind = "non-finite" if diverged else ("too short" if osc is None else osc.kind)
    verdict = VERDICTS[int(classify(kind, tail_sat, stable,
                                    limits_act_every_step(setup.limits), SATURATING_FRACTION, forced))]
    lin = None if np.isnan(stable) else bool(stable)
    meta = loop.provenance(
        analysis="simulate", P_gain=float(P_gain), D_gain=float(D_gain), experiment=setup.experiment,
        experiment_definition=EXPERIMENTS[setup.experiment], amplitude=setup.amplitude,
        duration=setup.duration, seed=setup.seed, limits=setup.limits.active, drive=setup.drive_meta(), **info,
        saturation_time=sat_time, limit_cycle=None if not np.isfinite(amp) else
        {"amplitude_Nm": amp, "frequency_Hz": None if math.isnan(freq) else freq, "signal": "torque",
         "periodic": osc.kind == "sustained"},
        verdict=verdict, diverged_at_s=None if math.isnan(diverged_at) else diverged_at,
        samples_written=k - first, **({"continued_from_sample": k0, "first_sample_written": first} if k0 else {}),
        linear={"stable": lin, "spectral_radius": None if np.isnan(radius) else float(radius)},
        verdict_rules="docs/simulate.md, The verdict of a run")
    return Simulation(time.copy(), col["theta"], col["velocity"], col["torque"], col["torque_ref"],
                      col["voltage"], col["current"], sat, sat_time, amp, freq, meta, osc, verdict, diverged_at,
                      lin, float(radius))


def trace_oscillation(setup, torque, first: int = 0, head_peak: float = 0.0) -> Oscillation | None:
    """The oscillation of the torque signal over the run's last half (the one trace classifier,
    :func:`haa_sym.analysis.oscillation.limit_cycle`, its defaults; the torque quantum as its
    resolution; on the nominal instants k Ts, jitter or not); None if the run overflowed.
    ``torque`` is the run's signal from sample ``first`` on (a continued run keeps its tail,
    :func:`keep_from`), ``head_peak`` max |torque| over the samples before: the classifier then
    sees the same tail and hysteresis as on the whole signal."""
    n = first + len(torque)
    if not np.all(np.isfinite(torque)) or n < 8:
        return None
    t = np.arange(n) * setup.Ts
    if not first:
        return limit_cycle(t, torque, resolution=setup.q_T)
    i0 = tail_start(t)
    if i0 < first:
        raise ValueError(f"a continued run kept its torque from sample {first}, its tail starts at {i0}")
    return limit_cycle(t[i0:], torque[i0 - first:], settle=0.0, resolution=setup.q_T,
                       peak=max(head_peak, float(np.abs(torque).max())))


@loop_first
def simulate(loop, P_gain: float, D_gain: float, *, limits: Limits | None = None,
             experiment: str = "disturbance-step", amplitude: float | None = None,
             duration: float = 1.0, seed: int = 0, rtol: float = DEFAULT_RTOL,
             chirp_f1: float | None = None, excitation=None) -> Simulation:
    """Simulate the sampled-data loop with the limits at one gain point.

    Parameters
    ----------
    loop : ClosedLoop
        Plant, controller and options (the same loop the linear analyses take).
    P_gain, D_gain : float
        Impedance gains of Eq. (8), Nm/rad and Nms/rad.
    limits : Limits, optional
        Default the parameter file's ``[limits]`` (``loop.params.limits``); ``Limits()`` is the
        linear loop.
    experiment : str
        A key of :data:`EXPERIMENTS`.
    amplitude : float, optional
        A of the experiment (Nm or rad); default :data:`DEFAULT_AMPLITUDE`.
    duration : float
        Seconds; the run has ceil(duration / Ts) + 1 samples from t = 0.
    seed : int
        Seed of the torque noise (numpy ``default_rng(seed)``) and of the jitter (its own stream
        from the same seed, :data:`JITTER_STREAM`).
    rtol : float
        Error bound of the friction integrator (relative to each state's peak over the run
        without friction); per sample the step-doubling difference is held to
        ``rtol`` x :data:`SAMPLE_TOL_FRACTION`.
    chirp_f1 : float, optional
        End frequency of the chirp, Hz (default 0.1 / Ts); it starts at :data:`CHIRP_F0`.
    excitation : (n,) array, optional
        With ``experiment = "chirp"``: the torque reference's shape instead of the sweep, one
        value per sample (peak 1 by :func:`haa_sym.analysis.excitation.excitation_signal`),
        times ``amplitude``.

    Returns
    -------
    Simulation
    """
    P = _number("P_gain", P_gain, "a finite number (Nm/rad)", lambda v: True)
    D = _number("D_gain", D_gain, "a finite number (Nms/rad)", lambda v: True)
    # small matrices only: BLAS threads cost more than they give (16 ms vs 30 us for one
    # expm of HyQ's plant on the 2-core machine under load)
    with blas_limits(1):
        setup = _Setup(loop, limits, experiment, amplitude, duration, seed, chirp_f1, excitation)
        setup.rtol = _number("rtol", rtol, "a number in (0, 0.1)", lambda v: 0 < v < 0.1)
        y, info, _end = _run(loop, setup, P, D)
        st, rad = linear_verdict(loop, P, D)
        return _result(loop, setup, P, D, y, info, (float(st[0]), float(rad[0])))


@loop_first
def simulate_batch(loop, P_gain, D_gain, *, limits: Limits | None = None,
                   experiment: str = "disturbance-step", amplitude: float | None = None,
                   duration: float = 1.0, seed: int = 0, rtol: float = DEFAULT_RTOL,
                   linear_stable=None, setup: _Setup | None = None, scale_duration: float | None = None,
                   start=None, continue_to: float | None = None) -> SimulationBatch:
    """:func:`simulate` at k gain points (``P_gain``, ``D_gain`` broadcast), summarised per point
    (:class:`SimulationBatch`); the plant's matrices and the inputs are built once.
    ``linear_stable``: the linear loop's decision per point if known (1, 0 or NaN), else
    computed (:func:`linear_verdict`). ``setup``: :func:`batch_setup` of the same loop and
    arguments, if already built (a worker keeps it for its next tasks).

    Continued runs (docs/simulate.md, "Nonlinear maps"): ``scale_duration`` (s, default
    ``duration``) is the horizon of the friction integrator's error scale (:func:`batch_setup`);
    ``start``: per point a :class:`Continuation` (or None: from t = 0) that the run continues from
    its sample ``k`` to ``duration``, the same steps as a run from t = 0 with the same
    ``scale_duration`` (:func:`continuable` setups only); ``continue_to`` (s): the batch returns
    per point in ``continuations`` the :class:`Continuation` from which a run of that length
    continues this one."""
    P, D = (np.atleast_1d(np.asarray(v, float)).ravel() for v in np.broadcast_arrays(P_gain, D_gain))
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(D))):
        raise ParameterError("P_gain, D_gain: not finite; allowed: finite gains (Nm/rad, Nms/rad)")
    with blas_limits(1):
        if linear_stable is None:
            linear_stable = linear_verdict(loop, P, D)[0]
        stable = np.broadcast_to(np.asarray(linear_stable, float), P.shape)
        if setup is None:
            setup = batch_setup(loop, limits, experiment, amplitude, duration, seed, rtol, scale_duration)
        starts = [None] * P.size if start is None else list(start)
        n_next = None
        if continue_to is not None or any(c is not None for c in starts):
            if not continuable(setup):
                raise ParameterError(f"experiment = {experiment!r}: its runs cannot be continued (its input "
                                     "depends on the run's length); allowed: a run from t = 0 (docs/simulate.md)")
            if len(starts) != P.size or any(c is not None and not 0 < c.k < setup.n for c in starts):
                raise ParameterError(f"start: {len(starts)} continuations for {P.size} points; allowed: one per "
                                     f"point, None or stopped before the run's {setup.n} samples")
        if continue_to is not None:
            n_next = int(math.ceil(_number("continue_to", continue_to, f"seconds >= duration ({setup.duration:g})",
                                           lambda v: v >= setup.duration) / setup.Ts - 1e-9)) + 1
        return _batch(loop, P, D, setup, stable, starts, n_next)


def batch_setup(loop, limits, experiment, amplitude, duration, seed, rtol, scale_duration=None) -> _Setup:
    """The setup :func:`simulate_batch` builds for its runs (plant matrices, inputs, the friction
    integrator's tables once built): reusable for further batches of the same arguments.
    ``scale_duration`` (s, default ``duration``): the friction integrator's error is bounded
    relative to each state's peak over this first part of the run without friction; a map
    whose runs continue in segments gives every length its first run's."""
    with blas_limits(1):
        setup = _Setup(loop, limits, experiment, amplitude, duration, seed, None, scale_duration=scale_duration)
    setup.rtol = _number("rtol", rtol, "a number in (0, 0.1)", lambda v: 0 < v < 0.1)
    return setup


def _batch(loop, P, D, setup, stable, starts, n_next):
    k = P.size
    sat, amp, freq, fin, growth = (np.empty(k) for _ in range(5))
    status, kinds = np.empty(k, dtype=object), np.empty(k, dtype=object)
    tail_sat = np.empty(k)
    tail = max(1, setup.n // 10)
    q = max(1, setup.n // 4)
    conts = [None] * k if n_next is not None else None
    # every point's controller in one call: its exact element arithmetic (Fractions) per call
    # cost more than a 1 s run of the C loop
    ctrls = controller_batch(loop, P, D)
    for i in range(k):
        y, _info, end = _run(loop, setup, P[i], D[i], tuple(m[i] for m in ctrls), starts[i])
        r = _result(loop, setup, P[i], D[i], y, _info, (stable[i], math.nan), starts[i])
        if conts is not None:
            conts[i] = _continuation(setup, starts[i], y, end, n_next)
        sat[i], amp[i], freq[i] = r.saturation_time, r.cycle_amplitude, r.cycle_frequency
        status[i] = r.verdict
        kinds[i] = "non-finite" if r.oscillation is None else r.oscillation.kind
        if r.oscillation is None:                        # diverged: no summary of a trace cut short
            fin[i] = growth[i] = tail_sat[i] = math.nan
            continue
        # the columns of a continued run start at its sample first (keep_from): the windows
        # below are counted from the end
        first = setup.n - len(r.torque)
        fin[i] = r.theta[-tail:].mean()
        # the torque's swing over the last quarter of the run and the quarter's before
        swing = [np.ptp(r.torque[-(j + 1) * q:len(r.torque) - j * q]) for j in (0, 1)]
        growth[i] = swing[0] / swing[1] if swing[1] > 0 else (math.inf if swing[0] > 0 else 1.0)
        tail_sat[i] = r.saturated[setup.n // 2 - first:].mean()
    meta = loop.provenance(analysis="simulate_batch", experiment=setup.experiment, amplitude=setup.amplitude,
                           duration=setup.duration, seed=setup.seed, limits=setup.limits.active,
                           scale_duration=setup.scale_duration)
    return SimulationBatch(P, D, sat, amp, freq, fin, growth, status.astype(str), meta, kinds.astype(str),
                           tail_sat, conts)
