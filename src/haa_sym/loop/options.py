"""Every modelling choice the paper leaves open, as data (docs/model.md, "Options").

:class:`LoopStructure` says what the closed loop is (delay, sensor damping, where the velocity
estimate sits, the passivity port), :class:`AnalysisConventions` how it is judged (Colgate's
correction, the phase-margin loop and rule, the passivity tolerance) and :class:`FrequencyGrid`
how finely (the one log frequency grid of every frequency-domain analysis, up to Nyquist).
:class:`LoopOptions` holds the three.
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

import numpy as np

from haa_sym.errors import ParameterError
from haa_sym.io.budget import check_memory, sweep_bytes

__all__ = ["LoopOptions", "LoopStructure", "AnalysisConventions", "FrequencyGrid", "PORTS", "COLGATE",
           "FILTERS", "PM_LOOPS", "PM_RULES", "PASSIVITY_TESTS", "ALLOWED",
           "parse_options"]

PORTS = ("dtheta_L2", "dtheta_L1", "encoder_average")
COLGATE = ("subtract", "add", "none")
FILTERS = ("both", "impedance", "compensation")
PM_LOOPS = ("impedance", "torque")
# the phase-margin rules of haa_sym.analysis.margins ("distance": the angular distance of L from
# -1 at any crossover)
PM_RULES = ("distance", "min_abs", "worst")
# the passivity tests (haa_sym.analysis.sampled_port, docs/passivity.md): the paper's corrected
# phase of the sampled Z(z), or the exact test of the continuous port under the sampled controller
PASSIVITY_TESTS = ("corrected_phase", "exact")


# What each option allows, in words (haa-sym options, the CLI's help); the checks are the
# classes' own __post_init__ below, which these sentences restate.
ALLOWED: dict[str, str] = {
    "delay": "0 or 1 (samples of computation delay)",
    "torque_damping": "true, false or none (none: the actuator file's [sensors] torque_damping)",
    "filter": " | ".join(FILTERS) + " (where the velocity estimate sits)",
    "port": "dtheta_<body> (a body of the actuator file) | encoder_average | none (the file's port)",
    "colgate": " | ".join(COLGATE) + " (Colgate's w Ts/2 correction of the phase of Z)",
    "pm_loop": " | ".join(PM_LOOPS) + " (the loop whose phase margin the maps judge)",
    "pm_rule": " | ".join(PM_RULES) + " (when a phase margin is low)",
    "passivity": " | ".join(PASSIVITY_TESTS) + " (the paper's corrected phase of Z(z), or the exact "
                 "test of the continuous port under the sampled controller)",
    "passivity_tol_deg": "a finite number >= 0, deg",
    "passivity_tol_exact": "a finite number >= 0 (the exact test's dissipation deficit)",
    "n_omega": "an integer >= 10 (points of the frequency grid)",
    "omega_min": "a finite number > 0, rad/s (the grid's lowest frequency)",
}


def _choice(obj, name, allowed):
    if getattr(obj, name) not in allowed:
        raise ParameterError(f"{name} = {getattr(obj, name)!r}; allowed: {list(allowed)}")


@dataclass(frozen=True)
class LoopStructure:
    """What the closed loop is: the structural choices the paper leaves open.

    Parameters
    ----------
    delay : {0, 1}
        Computation delay between sampling and the applied voltage, samples. Default 0.
    torque_damping : bool or None
        Whether the measured torque includes the damping term of the sensed coupling (D_hd of
        Eq. 2). Default None: what the actuator file's ``[sensors] torque_damping`` says (True
        for HyQ, Eq. 2 as printed).
    filter : {"both", "impedance", "compensation"}
        Where the velocity estimate (``velocity_filter`` of the controller) sits: on the velocity
        feeding both the D term of Eq. (8) and the velocity compensation of Eq. (6) (default, the
        paper's Sec. 3.4 and Fig. 6), on the D term only, or on the compensation only; the other
        path then uses the one-sample backward difference (theta[k] - theta[k-1])/Ts.
    port : "dtheta_<body>", "encoder_average" or None
        Velocity of the passivity port Z = T_dist / velocity (Sec. 5): the velocity of a body of
        the actuator file (ClosedLoop checks it against the plant's outputs) or the controller's
        velocity estimate of the encoder angle. Default None: the body T_dist acts on (the
        file's ``[sensors] port``; ``dtheta_L2`` for HyQ, whose alternatives are the sampled link
        velocity ``dtheta_L1`` of the paper's wording and ``encoder_average``).

    :meth:`resolved` fills the two file-backed defaults for one actuator.
    """

    delay: int = 0
    torque_damping: bool | None = None
    filter: str = "both"
    port: str | None = None

    def __post_init__(self):
        if self.delay not in (0, 1) or isinstance(self.delay, bool):
            raise ParameterError(f"delay = {self.delay!r}; allowed: 0 or 1 (samples)")
        if not (self.torque_damping is None or isinstance(self.torque_damping, bool)):
            raise ParameterError(f"torque_damping = {self.torque_damping!r}; allowed: True, False or "
                                 "None (the actuator file's)")
        if not (self.port is None or self.port == "encoder_average" or (isinstance(self.port, str)
                                                    and re.fullmatch(r"dtheta_[A-Za-z][A-Za-z0-9]*", self.port))):
            raise ParameterError(f"port = {self.port!r}; allowed: 'dtheta_<body>' (a body of the "
                                 f"actuator file, e.g. {list(PORTS)[:2]}) or 'encoder_average'")
        _choice(self, "filter", FILTERS)

    def resolved(self, topology) -> "LoopStructure":
        """This structure with the file-backed defaults of ``topology`` (an actuator) filled in."""
        return dataclasses.replace(
            self, torque_damping=topology.torque_damping if self.torque_damping is None else self.torque_damping,
            port=f"dtheta_{topology.port}" if self.port is None else self.port)


@dataclass(frozen=True)
class AnalysisConventions:
    """How the analyses judge a closed loop: the conventions the paper leaves open.

    Parameters
    ----------
    colgate : {"subtract", "add", "none"}
        Colgate's sampled-data correction of the phase of Z: subtract w Ts/2 (the paper's
        wording, default), add it, or none.
    pm_loop : {"impedance", "torque"}
        Loop on which the phase margin of the region maps is measured: the impedance loop opened
        at the torque reference T_lref (default) or the torque loop opened at the PI output with
        the impedance loop closed.
    pm_rule : {"distance", "min_abs", "worst"}
        When is a phase margin low (:mod:`haa_sym.analysis.margins`): "distance" (default) when L
        passes closer than the threshold to -1 at any crossover (min over crossovers of |PM|);
        "min_abs" when the signed margin of the crossover with the smallest |PM| is below the
        threshold (the rule before issue 15: a crossover at -102 deg counted as low); "worst"
        when the smallest signed margin is.
    passivity : {"corrected_phase", "exact"}
        The passivity test. "corrected_phase" (default, the paper's Sec. 5): the phase of the
        sampled Z(z), corrected by ``colgate``, within +-90 deg. "exact": the continuous port
        torque -> port velocity under the sampled controller and its hold, a periodically
        time-varying operator, judged by the smallest eigenvalue of its lifted Hermitian part
        (:mod:`haa_sym.analysis.sampled_port`, docs/passivity.md).
    passivity_tol_deg : float
        A point is passive when the corrected phase of Z stays within 90 deg + this tolerance.
        A spring (Z ~ K/(j w)) sits at -90 deg as w -> 0, so a zero tolerance would decide
        such points by rounding. Default 1e-3.
    passivity_tol_exact : float
        With ``passivity = "exact"`` a point is passive when the dissipation deficit
        -min_w mu(w) is at most this (mu: the fraction of the port's own dissipation the loop
        leaves). At low frequency a virtual spring leaves mu -> 0, where the evaluation's
        rounding is about 1e-9 (docs/passivity.md). Default 1e-7.
    """

    colgate: str = "subtract"
    pm_loop: str = "impedance"
    pm_rule: str = "distance"
    passivity: str = "corrected_phase"
    passivity_tol_deg: float = 1e-3
    passivity_tol_exact: float = 1e-7

    def __post_init__(self):
        for name, allowed in (("colgate", COLGATE), ("pm_loop", PM_LOOPS), ("pm_rule", PM_RULES),
                              ("passivity", PASSIVITY_TESTS)):
            _choice(self, name, allowed)
        for name, unit in (("passivity_tol_deg", " (deg)"), ("passivity_tol_exact", "")):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                raise ParameterError(f"{name} = {v!r}; allowed: a finite number >= 0{unit}")


@dataclass(frozen=True)
class FrequencyGrid:
    """The numerics of the frequency-domain analyses: the log grid Z(z) and the loop gains are
    sampled on, from ``omega_min`` to Nyquist pi/Ts.

    Parameters
    ----------
    n_omega : int
        Points of the grid. Default 1000 (the maps are unchanged up to 16000, see
        ``haa_sym.analysis.regions``).
    omega_min : float
        Lowest frequency, rad/s. Default 0.1.
    """

    n_omega: int = 1000
    omega_min: float = 0.1

    def __post_init__(self):
        if isinstance(self.n_omega, bool) or not isinstance(self.n_omega, int) or self.n_omega < 10:
            raise ParameterError(f"n_omega = {self.n_omega!r}; allowed: an integer >= 10")
        v = self.omega_min
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0:
            raise ParameterError(f"omega_min = {v!r}; allowed: a finite number > 0 (rad/s)")

    def check_budget(self, n: int | None = None) -> int:
        """Refuse a grid of ``n`` points (default ``n_omega``) whose sweep would exceed the
        memory budget (:mod:`haa_sym.io.budget`); returns ``n``. Commands call it as soon as the
        options are read, before any loop is built or any result printed."""
        n = self.n_omega if n is None else int(n)
        # every frequency-domain analysis sweeps this grid in chunks of points: the gate before
        # anything of its size is allocated
        check_memory(sweep_bytes(1, n), f"n_omega = {n}: a frequency grid of {n} points")
        return n

    def omega(self, Ts: float, n: int | None = None) -> np.ndarray:
        """The log frequency grid (rad/s) from ``omega_min`` to just below Nyquist pi/Ts for
        sampling time ``Ts`` (s), with ``n`` points (default ``n_omega``): the one grid of every
        frequency-domain analysis."""
        w_max = np.pi / Ts * (1 - 1e-9)
        if self.omega_min >= w_max:
            raise ParameterError(f"omega_min = {self.omega_min!r} is not below Nyquist pi/Ts = {w_max:.6g} rad/s")
        n = self.check_budget(n)
        return np.logspace(np.log10(self.omega_min), np.log10(w_max), n)


_PARTS = (("structure", LoopStructure), ("conventions", AnalysisConventions), ("numerics", FrequencyGrid))


class LoopOptions:
    """Every modelling choice the paper leaves open, in three parts; each is discussed in
    ``docs/model.md``.

    ``structure`` (:class:`LoopStructure`: delay, torque_damping, filter, port) defines the
    closed loop; ``conventions`` (:class:`AnalysisConventions`: colgate, pm_loop, pm_rule,
    passivity_tol_deg) how it is judged; ``numerics`` (:class:`FrequencyGrid`: n_omega,
    omega_min) how finely. Build it from the parts or from any of their fields by name
    (``LoopOptions(delay=1, colgate="none")``, what ``--option KEY=VALUE`` does); the fields read
    through (``options.delay``). The defaults are the combination that reproduces the most
    cells of Table 2 (``haa-sym reproduce`` re-scores all combinations and writes the count to
    the report).
    """

    __slots__ = ("structure", "conventions", "numerics")

    def __init__(self, structure: LoopStructure | None = None, conventions: AnalysisConventions | None = None,
                 numerics: FrequencyGrid | None = None, **fields):
        given = {"structure": structure, "conventions": conventions, "numerics": numerics}
        for part, cls in _PARTS:
            mine = {k: fields.pop(k) for k in list(fields) if k in cls.__dataclass_fields__}
            base = given[part] if given[part] is not None else cls()
            if not isinstance(base, cls):
                raise ParameterError(f"{part} = {base!r}; allowed: a haa_sym.{cls.__name__}")
            object.__setattr__(self, part, dataclasses.replace(base, **mine) if mine else base)
        if fields:
            raise ParameterError(f"unknown option(s) {sorted(fields)}; allowed: {list(self.field_names())}")

    def __setattr__(self, name, value):
        raise AttributeError("LoopOptions is immutable; use replace(**changes)")

    def __reduce__(self):
        # pickled by its parts (a dask worker rebuilds it; __setattr__ refuses the default way)
        return (LoopOptions, self._parts())

    def __getattr__(self, name):
        for part, cls in _PARTS:
            if name in cls.__dataclass_fields__:
                return getattr(object.__getattribute__(self, part), name)
        raise AttributeError(name)

    def __eq__(self, other):
        return isinstance(other, LoopOptions) and self._parts() == other._parts()

    def __hash__(self):
        return hash(self._parts())

    def __repr__(self):
        return f"LoopOptions({', '.join(f'{k}={v!r}' for k, v in self.to_dict().items())})"

    def _parts(self):
        return tuple(object.__getattribute__(self, part) for part, _ in _PARTS)

    def replace(self, **changes) -> "LoopOptions":
        """A copy with some fields (of any part) changed, validated."""
        return LoopOptions(*self._parts(), **changes)

    def to_dict(self) -> dict:
        """Every field by name (flat: the names are unique across the parts)."""
        return {f: getattr(self, f) for f in self.field_names()}

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f for _, c in _PARTS for f in c.__dataclass_fields__)

    @classmethod
    def field_type(cls, name: str) -> tuple[type, bool]:
        """(bool, int, float or str; whether None is allowed) of field ``name``, from its annotation."""
        for _, c in _PARTS:
            if name in c.__dataclass_fields__:
                ann = str(c.__dataclass_fields__[name].type).replace(" ", "")
                base = {"bool": bool, "int": int, "float": float}.get(ann.split("|")[0], str)
                return base, "None" in ann.split("|")
        raise KeyError(name)

    @classmethod
    def field_default(cls, name: str):
        for _, c in _PARTS:
            if name in c.__dataclass_fields__:
                return c.__dataclass_fields__[name].default
        raise KeyError(name)

    def resolved(self, topology) -> "LoopOptions":
        """These options with the structure's file-backed defaults filled in for ``topology``."""
        return LoopOptions(self.structure.resolved(topology), self.conventions, self.numerics)

    def check_budget(self, n: int | None = None) -> int:
        """:meth:`FrequencyGrid.check_budget` of :attr:`numerics`."""
        return self.numerics.check_budget(n)

    def omega(self, Ts: float, n: int | None = None) -> np.ndarray:
        """The frequency grid (rad/s) of :attr:`numerics` for sampling time ``Ts``."""
        return self.numerics.omega(Ts, n)


def parse_options(items: list[str]) -> LoopOptions:
    """``KEY=VALUE`` texts (``--option``, the explorer's fields) as :class:`LoopOptions`, checked
    against the memory budget of the frequency grid before anything is built. The one parser of
    the CLI and the explorer."""
    fields = LoopOptions.field_names()
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep:
            raise ParameterError(f"--option {item!r}: expected KEY=VALUE")
        if key not in fields:
            raise ParameterError(f"--option {item!r}: unknown option {key!r}; allowed: {list(fields)}")
        kind, optional = LoopOptions.field_type(key)
        try:
            if optional and value.lower() == "none":        # the actuator file's default
                out[key] = None
            elif kind is bool:
                if value.lower() not in ("true", "false", "1", "0"):
                    raise ValueError
                out[key] = value.lower() in ("true", "1")
            elif kind is int:
                out[key] = int(value)
            elif kind is float:
                out[key] = float(value)
            else:
                out[key] = value
        except ValueError:
            allowed = {bool: "true or false", int: "an integer", float: "a number"}.get(kind, "text")
            raise ParameterError(f"--option {item!r}: {value!r} is not a valid {kind.__name__}; "
                                 f"allowed: {allowed}{' or none' if optional else ''}") from None
    try:
        options = LoopOptions(**out)
        # the one budget gate of the frequency grid, before any command builds or prints anything
        options.numerics.check_budget()
    except ParameterError as exc:
        raise ParameterError(f"--option {exc}") from None
    return options
