"""The ``unit`` of a file entry, read: checked against the key's dimension and converted to SI.

Every numeric entry of a parameter file is ``{ value, unit, source, description }``
(docs/model.md, "Units"). haa_sym computes in SI (the unit each key has in
:attr:`haa_sym.model.actuator.Topology.units` and :data:`CONTROLLER_UNITS`); :func:`to_si` reads an
entry's ``unit`` with pint, refuses a unit of another dimension or one pint does not know, and
converts the value to the key's SI unit (``g cm^2`` -> kg m^2, ``mNm/A`` -> Nm/A, ``Nm/deg`` ->
Nm/rad, ``ms`` -> s, ``kHz`` -> Hz, ``mV/rpm`` -> V s/rad). A bare number, or an entry without a
``unit``, is the key's SI unit.

Angles. pint treats the radian as dimensionless, so to it ``Nm`` and ``Nm/rad``, ``Hz`` and
``rad/s``, and a back-EMF constant with or without ``/rad`` are the same dimension; the first of
each pair differs from the second by 2 pi (or 180/pi for degrees) when angles are in play. haa_sym
therefore also counts the angle: the power of the angle in the unit (``rad``, ``deg``, ``turn``,
``rpm`` = turn/min, each a scale factor of the radian) must equal the power in the key's SI unit.
``Nm/deg`` is a stiffness (angle^-1) and converts by 180/pi; ``Nm`` for a stiffness, ``rad/s`` for
the cut-off frequency ``f_c`` (Hz, cycles per second) are refused with a message that says which
angle is missing or extra. A unit of the reciprocal dimension (a motor speed constant in
``rpm/V`` for the back-EMF constant ``k_w``) is refused too, naming the reciprocal to give.

Compact engineering spellings are defined for pint: ``Nm`` (newton metre; pint alone reads
``Nm`` as "number meter"), ``Nms``, ``Vs``, ``Ohm``, and ``samples`` (a count, dimensionless);
``-`` (or an empty unit) is dimensionless. The SI spellings in :data:`KINDS` are read without
pint (``tests/test_model_units.py`` checks that pint gives each of them factor 1 and the key's
dimension); any other spelling imports pint and builds its registry once per process (about
0.7 s, measured on the project's 2-core machine), so the bundled files, which are written in SI,
do not pay for it.

Example
-------
>>> to_si(5720.0, "g cm^2", "kg m^2", "hyq.toml [motor]", "J_m")
0.000572
>>> to_si(10.0, "Nm", "Nm/rad", "f.toml [couplings.p]", "K")
Traceback (most recent call last):
...
haa_sym.errors.ParameterError: f.toml [couplings.p]: K: unit = 'Nm' has no angle, but K is a rotational stiffness in Nm/rad (angle^-1); allowed: a unit of rotational stiffness, e.g. Nm/rad (SI), Nm/deg, kNm/rad (pint treats rad as dimensionless, haa_sym counts the angle: Nm/deg is a stiffness, Nm is not; Hz is cycles per second, rad/s is 2 pi Hz)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

from haa_sym.errors import ParameterError

__all__ = ["Kind", "KINDS", "CONTROLLER_UNITS", "to_si", "check_number", "kind_rows"]


@dataclass(frozen=True)
class Kind:
    """The dimension of a key, by its SI unit.

    Parameters
    ----------
    si : str
        The SI unit haa_sym computes in (the spelling of ``Topology.units``).
    what : str
        What the quantity is, for messages and the docs' table.
    spellings : tuple of str
        Exact spellings read as the SI unit itself without pint (factor 1).
    examples : tuple of str
        Other units of this dimension that convert, for messages and the docs.
    """

    si: str
    what: str
    spellings: tuple[str, ...]
    examples: tuple[str, ...]


#: SI unit -> its kind. Every unit of ``Topology.units`` and :data:`CONTROLLER_UNITS` is a key
#: (a test checks); "-" and "samples" are dimensionless (a gear ratio, a gain scale, a count).
KINDS: dict[str, Kind] = {k.si: k for k in (
    Kind("kg m^2", "inertia", ("kg m^2", "kg m**2", "kg*m^2", "kg*m**2"), ("g cm^2", "kg cm^2", "kg mm^2")),
    Kind("Nm/rad", "rotational stiffness", ("Nm/rad", "N m/rad", "N*m/rad"), ("Nm/deg", "kNm/rad")),
    Kind("Nm s/rad", "rotational damping", ("Nm s/rad", "Nms/rad", "N m s/rad", "N*m*s/rad"),
         ("mNm s/rad", "Nm s/deg")),
    Kind("H", "inductance", ("H",), ("mH", "uH")),
    Kind("Ohm", "resistance", ("Ohm", "ohm"), ("mOhm", "kOhm")),
    Kind("Nm/A", "torque constant", ("Nm/A", "N m/A", "N*m/A"), ("mNm/A",)),
    Kind("V s/rad", "back-EMF constant", ("V s/rad", "Vs/rad", "V*s/rad", "V/(rad/s)"), ("mV/rpm", "mV s/rad")),
    Kind("-", "dimensionless number", ("-", "", "1"), ()),
    Kind("samples", "number of samples", ("samples", "-", "", "1"), ()),
    Kind("s", "time", ("s",), ("ms", "us")),
    Kind("Hz", "frequency in cycles per second", ("Hz", "1/s"), ("kHz",)),
    Kind("V", "voltage", ("V",), ("mV", "kV")),
    Kind("A", "current", ("A",), ("mA",)),
    Kind("Nm", "torque", ("Nm", "N m", "N*m"), ("mNm", "N cm")),
    Kind("rad/s", "angular velocity", ("rad/s",), ("deg/s", "rpm")),
    Kind("V/Nm", "torque-controller gain", ("V/Nm", "V/(N m)"), ("mV/Nm",)),
    Kind("V/(Nm s)", "torque-controller integral gain", ("V/(Nm s)", "V/(N m s)", "V/Nms"), ("mV/(Nm s)",)),
)}

#: The SI unit of every numeric ``[controller]`` key (``velocity_filter`` is a name: no unit).
#: P_t0 turns a torque error into a motor voltage, I_t0 its integral (Eq. 7).
CONTROLLER_UNITS: dict[str, str] = {"Ts": "s", "N_av": "samples", "alpha": "-", "beta": "-",
                                    "P_t0": "V/Nm", "I_t0": "V/(Nm s)", "f_c": "Hz"}

# spellings pint does not know, or reads as something else ("Nm" is "number meter" to pint)
_DEFINITIONS = ("Nm = newton * meter", "Nms = newton * meter * second", "Vs = volt * second",
                "Ohm = ohm", "sample = 1 = _ = samples")
_DIMENSIONLESS = ("-", "", "1")
_ANGLE = "radian"            # pint's root unit of deg, turn, revolution, rpm's angle


@lru_cache(maxsize=1)
def _registry():
    # pint takes about 0.4 s to import and 0.35 s to build its registry: only files written in
    # units other than the SI spellings of KINDS need it (the bundled files do not)
    import pint
    # pint's own "Nm" is the number meter (a nautical unit): redefined here, without its warning
    reg = pint.UnitRegistry(on_redefinition="ignore")
    for d in _DEFINITIONS:
        reg.define(d)
    return reg


@lru_cache(maxsize=256)
def _parse(unit: str):
    """(root magnitude, dimensionality, angle power) of ``unit``, or an error text."""
    reg = _registry()
    text = "dimensionless" if unit.strip() in _DIMENSIONLESS else unit
    try:
        units = reg.parse_units(text)
        q = reg.Quantity(1.0, units)
        root = q.to_root_units()
    except Exception as exc:          # pint raises many types (undefined, syntax, tokenizer, ...)
        kind = type(exc).__name__
        return f"is not a unit pint can read ({kind}: {str(exc).strip() or 'malformed'})"
    return float(root.magnitude), q.dimensionality, int(round(root.units._units.get(_ANGLE, 0)))


def _angle_text(power: int) -> str:
    return "no angle" if power == 0 else f"angle^{power}"


def to_si(value, unit, si: str | None, where: str, key: str):
    """``value`` given in ``unit``, converted to the SI unit ``si`` of ``key``.

    Parameters
    ----------
    value : object
        The entry's value; anything not a finite int or float is returned unchanged (the
        domain check names it), as is any value whose unit is the SI unit (an integer stays one).
    unit : str or None
        The entry's ``unit``; None (a bare number, an entry without ``unit``) means ``si``.
    si : str or None
        The key's SI unit, a key of :data:`KINDS`; None for a key whose value is a name (only
        no unit or ``-`` is allowed).
    where, key : str
        The file and section, and the key, for messages.

    Returns
    -------
    float or int or object
        The value in ``si``.

    Raises
    ------
    ParameterError
        One line naming ``where``, ``key``, the unit and what is allowed: an unknown unit, another
        dimension (the reciprocal one named as such), or another power of the angle.
    """
    if unit is None:
        return value
    if si is None:                       # a key whose value is a name (velocity_filter)
        if unit.strip() in _DIMENSIONLESS:
            return value
        raise ParameterError(f"{where}: {key}: unit = {unit!r}, but {key} is a name; allowed: no unit (or '-')")
    kind = KINDS[si]
    if unit.strip() in kind.spellings:
        return value
    allowed = (f"a unit of {kind.what}, e.g. " + ", ".join([f"{si} (SI)", *kind.examples])
               if kind.examples else f"{si} (SI){'' if si != 'samples' else ' or -'}")
    head = f"{where}: {key}: unit = {unit!r}"
    parsed = _parse(unit)
    if isinstance(parsed, str):
        raise ParameterError(f"{head} {parsed}; allowed: {allowed}")
    ref = _parse(si if si not in ("-", "samples") else "-")
    mag, dim, angle = parsed
    ref_mag, ref_dim, ref_angle = ref
    if dim != ref_dim:
        if si not in ("-", "samples") and dim == 1 / ref_dim and angle == -ref_angle:
            # the classic case: a motor's speed constant K_v (rpm/V) given for k_w (V s/rad);
            # converting a reciprocal silently would hide a likely mix-up, so it is refused
            hint = (f"; for a speed constant K_v in rpm/V, {key} = 60/(2 pi K_v) V s/rad"
                    if si == "V s/rad" else "")
            raise ParameterError(f"{head} is the reciprocal of a {kind.what} ({si}); allowed: {allowed}, "
                                 f"i.e. give 1/value{hint}")
        raise ParameterError(f"{head} is not a unit of {kind.what} ({si}); allowed: {allowed}")
    if angle != ref_angle:
        raise ParameterError(
            f"{head} has {_angle_text(angle)}, but {key} is a {kind.what} in {si} ({_angle_text(ref_angle)}); "
            f"allowed: {allowed} (pint treats rad as dimensionless, haa_sym counts the angle: Nm/deg is a "
            "stiffness, Nm is not; Hz is cycles per second, rad/s is 2 pi Hz)")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return value
    factor = mag / ref_mag
    if factor == 1.0:
        return value
    try:
        return float(value) * factor
    except OverflowError:                 # an integer beyond the float range: the domain check names it
        return value


def check_number(key: str, value: object, allowed: str, where: str | None = None, *,
                 low: float | None = None, high: float | None = None, low_open: bool = False,
                 integer: bool = False) -> float | int:
    """The domain check of a number entry once :func:`to_si` has converted it (``[limits]``,
    ``[drive]``): a finite number (a bool is not one) within ``[low, high]`` (``(low, high]`` with
    ``low_open``; None: unbounded), a whole number with ``integer``. Each failure is one error
    naming ``where``, the key, the value and ``allowed`` (what is allowed, in words).

    Returns
    -------
    float or int
        ``value`` as a float, or as an int with ``integer``.
    """
    prefix = f"{where}: " if where else ""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{prefix}{key} = {value!r} is not a number; allowed: {allowed}")
    try:
        finite = math.isfinite(value)
    except OverflowError:                      # an integer beyond the float range (TOML allows it)
        finite = False
    if not finite:
        raise ParameterError(f"{prefix}{key} = {value!r} is not finite; allowed: {allowed}")
    if ((integer and not float(value).is_integer())
            or (low is not None and (value <= low if low_open else value < low))
            or (high is not None and value > high)):
        raise ParameterError(f"{prefix}{key} = {value!r} is out of range; allowed: {allowed}")
    return int(value) if integer else float(value)


def kind_rows(keys_units: dict[str, str]) -> list[str]:
    """Markdown rows ``| key | kind | SI unit | e.g. |`` for the docs' table of units."""
    rows = []
    for k, si in keys_units.items():
        kind = KINDS[si]
        rows.append(f"| `{k}` | {kind.what} | {si} | {', '.join(kind.examples) or '-'} |")
    return rows
