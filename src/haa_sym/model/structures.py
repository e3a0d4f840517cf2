"""The controller structures: which loops exist and how they connect, as a registry of data.

A file's ``[controller] structure`` names one entry (default ``"paper"``). Every structure keeps
the paper's single actuated input: every feedback path enters through one command u (a voltage,
or a current for a current-commanded motor), sampled, delayed ``delay`` samples and held, so the
characteristic polynomial stays affine in the gain monomials of ``haa_sym.compiled.layout`` and the
generated evaluators serve every structure unchanged. Per sample, with T_ref = -(P_gain theta +
D_gain v_d) (Eq. 8) and e = T_ref - T:

    u = P_r T_ref - P_m T + I_t Ts sum(e) + VC v_vc

where each structure fixes the four gains (docs/model.md, "Controller structures"):

=================== ================================ ============== ========== =================
structure           P_r (on T_ref)                   P_m (on T)     I_t        VC
=================== ================================ ============== ========== =================
paper               beta P_t0                        beta P_t0      beta I_t0  alpha VC0 (Eq. 6)
torque_pi           beta P_t0                        beta P_t0      beta I_t0  0
torque_pi_ff        beta (P_t0 + R/(k_t N))          beta P_t0      beta I_t0  0
impedance_current   1/(k_t N)   (u is a current, A)  0              0          0
=================== ================================ ============== ========== =================

The ``haa_sym.loop`` layer reads the flags of an entry (:class:`Structure`); nothing else names a
structure. An analysis that needs what a structure lacks (a torque loop, a voltage-driven motor)
calls :func:`require`, which refuses in one line.
"""
from __future__ import annotations

from dataclasses import dataclass

from haa_sym.errors import ParameterError

__all__ = ["Structure", "STRUCTURES", "DEFAULT", "NEUTRAL", "get", "require", "allowed_text", "FEATURES"]

#: The value a key takes in a structure that does not read it (the file must leave it out):
#: beta = 1 and alpha = 0 make the gain points of every analysis mean the same thing.
NEUTRAL = {"P_t0": 0.0, "I_t0": 0.0, "beta": 1.0, "alpha": 0.0}


@dataclass(frozen=True)
class Structure:
    """One controller structure.

    Parameters
    ----------
    name : str
        The ``[controller] structure`` value.
    summary : str
        One line: the loops and how they connect (``haa-sym`` help, messages).
    torque_loop : bool
        A PI on e = T_ref - T (Eq. 7): reads the torque signal, takes ``P_t0``, ``I_t0``, ``beta``.
    velocity_compensation : bool
        Eq. (6): takes ``alpha``.
    feedforward : bool
        T_ref fed forward to the voltage through the motor's static inverse R/(k_t N) (V/Nm).
    command : {"voltage", "current"}
        What the controller commands: the motor voltage V_m (the plant with its electrical state)
        or the motor current I_m (the electrical state imposed: the drive's current loop is
        ideal, or the [drive] lag and delay model it).
    """

    name: str
    summary: str
    torque_loop: bool
    velocity_compensation: bool
    feedforward: bool
    command: str

    @property
    def keys(self) -> tuple[str, ...]:
        """The [controller] keys this structure reads beyond the sampling and the velocity filter."""
        return (("P_t0", "I_t0", "beta") if self.torque_loop else ()) + \
            (("alpha",) if self.velocity_compensation else ())

    @property
    def unread(self) -> tuple[str, ...]:
        """The keys of :data:`NEUTRAL` it does not read (refused in a file that names it)."""
        return tuple(k for k in NEUTRAL if k not in self.keys)


STRUCTURES: dict[str, Structure] = {s.name: s for s in (
    Structure("paper", "impedance PD -> PI torque loop with velocity compensation -> voltage (Eq. 6-8)",
              torque_loop=True, velocity_compensation=True, feedforward=False, command="voltage"),
    Structure("torque_pi", "impedance PD -> PI torque loop -> voltage (Eq. 7-8, no velocity compensation)",
              torque_loop=True, velocity_compensation=False, feedforward=False, command="voltage"),
    Structure("torque_pi_ff", "impedance PD -> PI torque loop + reference fed forward through R/(k_t N) "
              "-> voltage", torque_loop=True, velocity_compensation=False, feedforward=True, command="voltage"),
    Structure("impedance_current", "impedance PD -> current command T_ref/(k_t N) of the motor's drive "
              "(no torque loop)", torque_loop=False, velocity_compensation=False, feedforward=False,
              command="current"),
)}
DEFAULT = "paper"

#: What an analysis may require of a structure (:func:`require`): the flag and its words.
FEATURES = {
    "torque_loop": ("a torque loop", lambda s: s.torque_loop),
    "voltage": ("a voltage-commanded motor", lambda s: s.command == "voltage"),
}


def allowed_text() -> str:
    return " | ".join(STRUCTURES)


def get(name: object) -> Structure:
    """The registry's entry ``name``; a :class:`ParameterError` naming the allowed ones."""
    if not isinstance(name, str) or name not in STRUCTURES:
        raise ParameterError(f"structure = {name!r}; allowed: {allowed_text()} (docs/model.md, "
                             "\"Controller structures\")")
    return STRUCTURES[name]


def require(name: str, feature: str, what: str) -> None:
    """Refuse ``what`` (an analysis, a command) on a structure without ``feature`` (:data:`FEATURES`)."""
    words, has = FEATURES[feature]
    if not has(get(name)):
        ok = [s.name for s in STRUCTURES.values() if has(s)]
        raise ParameterError(f"{what} needs {words}, and structure = {name!r} has none; allowed: "
                             f"structure = {' | '.join(ok)} (--set structure=...)")
