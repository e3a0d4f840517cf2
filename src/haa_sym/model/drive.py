"""The optional ``[drive]`` section of an actuator file: the drive's own response to the command.

Most drives are commanded through an inner loop the user does not control (a current or torque
loop in the servo amplifier, a PWM stage, a CAN bus). Between the command the controller (or a
log's ``current`` column) gives and what the motor receives, the drive adds

* a first-order lag, ``1 / (tau_drive s + 1)``: the inner loop's response (time constant, s);
* a transport delay, ``e^{-delay_drive s}``: dead time from the command to its effect (s), any
  length, not only whole samples.

Both act on the one actuated input (``V_m`` of the paper's loop, the current with
``identify --input current``), nowhere else: the disturbance and friction torques enter the
bodies directly. Absent keys (or an absent section) are 0: no lag, no delay, the model of the
paper. Every entry is written like the others (``{ value, unit, source, description }``, a bare
number is SI) and converted by :func:`haa_sym.model.units.to_si`.

=====================  ==========  ========================================================
key                    SI unit     what
=====================  ==========  ========================================================
``tau_drive``          s           time constant of the drive's first-order lag (0: none)
``delay_drive``        s           dead time from command to effect (0: none)
=====================  ==========  ========================================================

How the sampled model carries them exactly (the lag as one more continuous state, the delay by
the modified z-transform's augmentation) is :mod:`haa_sym.loop.plant` (docs/model.md, "The
drive").

Example
-------
>>> d = parse_drive({"tau_drive": {"value": 34, "unit": "ms"}, "delay_drive": 0.004}, "f.toml")
>>> d.tau_drive, d.delay_drive, d.active
(0.034, 0.004, True)
>>> parse_drive({"tau_drive": -1.0}, "f.toml")
Traceback (most recent call last):
...
haa_sym.errors.ParameterError: f.toml [drive]: tau_drive = -1.0 is out of range; allowed: a number in [0, 10] (s; 0 = no lag)
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

from haa_sym.errors import ParameterError
from haa_sym.model.actuator import check_keys, entry_values
from haa_sym.model.units import check_number

__all__ = ["Drive", "DRIVE_KEYS", "DRIVE_UNITS", "DRIVE_RANGE", "parse_drive", "check_drive_value", "drive_allowed"]

#: The keys, their SI unit and their allowed range (s). Ten seconds of lag or one second of
#: dead time is already far beyond any drive; the bound keeps a typo (34 for 0.034) from
#: building a sampled model with thousands of delay states.
DRIVE_UNITS = {"tau_drive": "s", "delay_drive": "s"}
DRIVE_RANGE = {"tau_drive": (0.0, 10.0), "delay_drive": (0.0, 1.0)}
DRIVE_KEYS = tuple(DRIVE_UNITS)
_TEXT = {"tau_drive": "s; 0 = no lag", "delay_drive": "s; 0 = no delay"}


def drive_allowed(key: str) -> str:
    """What ``key`` allows, in words."""
    lo, hi = DRIVE_RANGE[key]
    return f"a number in [{lo:g}, {hi:g}] ({_TEXT[key]})"


def check_drive_value(key: str, value: object, where: str) -> float:
    """One drive entry checked: a finite number within :data:`DRIVE_RANGE` (``where`` prefixes
    the message when given)."""
    lo, hi = DRIVE_RANGE[key]
    return check_number(key, value, drive_allowed(key), where, low=lo, high=hi)


@dataclass(frozen=True)
class Drive:
    """The drive between command and motor: lag ``tau_drive`` and dead time ``delay_drive`` (s).

    ``declared`` are the keys the file's ``[drive]`` section wrote (identification fits only
    those: a fitted delay in a file that never said it has one would be written nowhere); it
    takes no part in equality, the values do (they change every analysis).
    """

    tau_drive: float = 0.0
    delay_drive: float = 0.0
    declared: tuple[str, ...] = field(default=(), compare=False)

    @property
    def active(self) -> bool:
        """Whether the drive adds anything to the model."""
        return self.tau_drive > 0 or self.delay_drive > 0

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in DRIVE_KEYS}

    def replace(self, where: str = "", **changes: float) -> "Drive":
        """A copy with keys changed (checked); a changed key counts as declared."""
        values = self.as_dict()
        for k, v in changes.items():
            values[k] = check_drive_value(k, v, where)
        return Drive(**values, declared=tuple(sorted(set(self.declared) | set(changes))))


def parse_drive(table: object, source: str = "<memory>",
                references: Mapping[str, str] | None = None) -> Drive:
    """Validate a ``[drive]`` table.

    Raises
    ------
    ParameterError
        One line naming the file, ``[drive]``, the key, the value and what is allowed.
    """
    where = f"{source} [drive]"
    if not isinstance(table, Mapping):
        raise ParameterError(f"{where}: [drive] = {table!r}; allowed: a table of drive entries")
    check_keys(table, DRIVE_KEYS, (), where)
    values = entry_values(table, where, references, DRIVE_UNITS)
    return Drive(**{k: check_drive_value(k, v, where) for k, v in values.items()},
                 declared=tuple(sorted(values)))
