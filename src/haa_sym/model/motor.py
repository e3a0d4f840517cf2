"""The motor's constants against each other: k_t (Nm/A) and k_w (V s/rad) are one number in SI
for a DC motor (power balance k_t I w = k_w w I) and 1.5 apart in the amplitude-invariant dq form
of a PMSM. A file states which with ``[motor] convention`` (docs/model.md, "Motor constants");
:func:`motor_constants_warning` is the plausibility check every command runs on the values it
analyses. Kept out of ``model/actuator.py``: that module is a source of generated/ and the
convention changes no equation (the model uses both values as given)."""
from __future__ import annotations

from typing import Mapping

from haa_sym.errors import ParameterError

__all__ = ["MOTOR_CONVENTIONS", "MOTOR_CONVENTION_DEFAULT", "MOTOR_CONSTANT_FACTOR", "split_convention",
           "motor_constants_warning"]

# k_t / k_w expected in SI. "dc": a DC motor (also a dq model in the power-invariant form);
# "dq_amplitude_invariant": the amplitude-invariant Park transform, electrical power 3/2 v_q i_q,
# so k_t = 1.5 k_w per q-axis amp (k_w the flux linkage times pole pairs); "unchecked": another
# definition (line-to-line, RMS, a measured pair), not compared.
MOTOR_CONVENTIONS: dict[str, float | None] = {"dc": 1.0, "dq_amplitude_invariant": 1.5, "unchecked": None}
MOTOR_CONVENTION_DEFAULT = "dc"
# Beyond this factor (either way) from the convention's ratio k_t / k_w is reported: a datasheet's
# constants agree within their tolerances (about +-10 %; a saturated k_t falls below k_w), the
# slips it is for are far outside (mNm/A for Nm/A 1000x, per 1000 rpm for per rad/s 104.7x, rpm
# for rad/s 9.55x). docs/model.md, "Motor constants", says what it does not catch.
MOTOR_CONSTANT_FACTOR = 2.0


def split_convention(data: Mapping, source: str = "<memory>") -> tuple[Mapping, str]:
    """``(data without [motor] convention, the convention)`` of a parameter file's content; the
    default :data:`MOTOR_CONVENTION_DEFAULT` when the file states none (and for the legacy
    ``[plant]`` format). An unknown name is a :class:`ParameterError`."""
    motor = data.get("motor")
    if not (isinstance(motor, Mapping) and "convention" in motor):
        return data, MOTOR_CONVENTION_DEFAULT
    name = motor["convention"]
    if not isinstance(name, str) or name not in MOTOR_CONVENTIONS:
        raise ParameterError(f"{source} [motor]: convention = {name!r}; allowed: one of {list(MOTOR_CONVENTIONS)} "
                             "(k_t / k_w in SI: 1, 1.5, not compared; docs/model.md, \"Motor constants\")")
    return {**data, "motor": {k: v for k, v in motor.items() if k != "convention"}}, name


def motor_constants_warning(values: Mapping[str, float], convention: str = MOTOR_CONVENTION_DEFAULT,
                            source: str = "<memory>") -> str | None:
    """The one-line warning when ``k_t`` (Nm/A) and ``k_w`` (V s/rad) of ``values`` disagree with
    ``convention`` by more than :data:`MOTOR_CONSTANT_FACTOR`, else None. A plant without both
    keys, ``k_w = 0`` (back-EMF left out on purpose) and ``"unchecked"`` are not compared.

    >>> motor_constants_warning({"k_t": 0.19, "k_w": 0.19}) is None
    True
    >>> motor_constants_warning({"k_t": 190.0, "k_w": 0.19}, source="x.toml")[:60]
    'x.toml [motor]: k_t = 190 Nm/A is 1000x k_w = 0.19 V s/rad; '
    """
    expected = MOTOR_CONVENTIONS[convention]
    k_t, k_w = values.get("k_t"), values.get("k_w")
    if expected is None or k_t is None or k_w is None or not (k_w > 0):
        return None
    ratio = k_t / k_w
    if 1 / MOTOR_CONSTANT_FACTOR <= ratio / expected <= MOTOR_CONSTANT_FACTOR:
        return None
    other = "; a dq motor in the amplitude-invariant form: convention = \"dq_amplitude_invariant\"" \
        if convention == "dc" else ""
    return (f"{source} [motor]: k_t = {k_t:.6g} Nm/A is {ratio:.4g}x k_w = {k_w:.6g} V s/rad; the convention "
            f"{convention!r} has k_t = {expected:g} k_w in SI (reported beyond a factor {MOTOR_CONSTANT_FACTOR:g}): "
            f"a unit slip (mNm/A for Nm/A, rpm for rad/s)? Fix the value or state the motor's convention in "
            f"[motor] (convention = \"dc\" | \"dq_amplitude_invariant\" | \"unchecked\"{other}; docs/model.md)")
