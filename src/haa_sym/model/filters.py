"""The controller's velocity estimate: a registry of filters, each one entry.

The velocity estimate ``velocity_filter`` of the ``[controller]`` table is a modelling choice.
Each choice is a :class:`VelocityFilter`: its name, a description with its equation, the
``[controller]`` keys it reads (:class:`FilterParameter`: domain, units, default) and a function
building its exact transfer function (an :class:`haa_sym.model.elements.Element`, Fraction
coefficients, theta -> v in rad/s per rad). Everything else derives from the registry: the
validation of :class:`haa_sym.model.params.Controller` (which keys a filter requires, the Nyquist
bound of a cut-off, the message listing the allowed names), the command line's help, the
closed loop (:mod:`haa_sym.loop`) and the documentation's table (:func:`markdown_rows`, checked
against docs/model.md by the tests). The independent reference (:mod:`haa_sym.reference`)
realises each filter its own way, in a table of its own keyed by the same names; a test checks
that both tables have the same keys.

Built in (w_c = 2 pi f_c):

``"average"``       (theta[k] - theta[k - N_av]) / (N_av Ts), the paper's filter (Sec. 3.4), default;
``"lowpass1"``      the backward difference (theta[k] - theta[k-1]) / Ts followed by
                    w_c / (s + w_c), discretised by the Tustin transform without prewarping;
``"butterworth2"``  the same with w_c^2 / (s^2 + sqrt(2) w_c s + w_c^2).

Adding a filter is one :func:`register` call (and its realisation in the reference). The keys a
filter may read are the :data:`PARAMETERS`, which are fields of
:class:`haa_sym.model.params.Controller`; a filter with a new key needs that field too.

Example
-------
>>> from haa_sym.model.filters import names, velocity_filter
>>> names()
('average', 'lowpass1', 'butterworth2')
>>> F = velocity_filter("average", Ts=1e-3, N_av=4)
>>> [float(c) for c in F.numerator], [float(c) for c in F.denominator]
([1.0, 0.0, 0.0, 0.0, -1.0], [0.004, 0.0, 0.0, 0.0, 0.0])
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Callable

from haa_sym.model.elements import Element, backward_difference, tustin
from haa_sym.errors import ParameterError

__all__ = ["FilterParameter", "VelocityFilter", "PARAMETERS", "DEFAULT", "register", "unregister",
           "names", "get", "allowed_text", "velocity_filter", "controller_filter", "help_text",
           "markdown_rows"]


@dataclass(frozen=True)
class FilterParameter:
    """A ``[controller]`` key a velocity filter reads.

    Parameters
    ----------
    name : str
        The key (a field of :class:`haa_sym.model.params.Controller`).
    domain : str
        Its rule in :mod:`haa_sym.model.params`' codes: ``"int>=1"`` or ``">0"``.
    units : str
        For messages, help and docs (``"samples"``, ``"Hz"``).
    description : str
        What it is, e.g. ``"cut-off frequency"``.
    default : int or float, optional
        Used when the chosen filter reads the key and the file does not give it; None (default):
        the key is required by the filters that read it.
    below_nyquist : bool
        A frequency in Hz that must also lie below Nyquist 1/(2 Ts).
    """

    name: str
    domain: str
    units: str
    description: str
    default: int | float | None = None
    below_nyquist: bool = False

    @property
    def rule(self) -> str:
        """The allowed values in words, for the docs (``"integer >= 1"``, ``"0 < f_c < 1/(2 Ts)"``)."""
        if self.below_nyquist:
            return f"0 < {self.name} < 1/(2 Ts)"
        return {"int>=1": "integer >= 1", ">0": "> 0"}[self.domain]


@dataclass(frozen=True)
class VelocityFilter:
    """One choice of the velocity estimate.

    Parameters
    ----------
    name : str
        The value of ``velocity_filter``.
    description : str
        One line: what it is.
    equation : str
        Its transfer function theta -> v, as text (docs, help).
    parameters : tuple of FilterParameter
        The ``[controller]`` keys it reads (entries of :data:`PARAMETERS`).
    build : callable
        ``build(Ts, **{p.name: value for p in parameters}) -> Element``: the exact transfer
        function (Fraction coefficients) for sampling time ``Ts`` (s).
    order : callable, optional
        ``order(**{p.name: value ...}) -> int``: the number of states of ``build``'s result
        (its denominator's degree) without building it. A closed loop checks the generated
        capacity with it first, because building an element of a huge order (``N_av = 10**6``)
        and combining it with the others costs minutes of exact arithmetic. None: the order is
        read from the built element.
    """

    name: str
    description: str
    equation: str
    parameters: tuple[FilterParameter, ...]
    build: Callable[..., Element]
    order: Callable[..., int] | None = None

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)


N_AV = FilterParameter("N_av", "int>=1", "samples", "number of samples of the average")
F_C = FilterParameter("f_c", ">0", "Hz", "cut-off frequency", below_nyquist=True)

#: The keys a velocity filter may read: each a field of haa_sym.model.params.Controller (a test checks).
PARAMETERS: dict[str, FilterParameter] = {p.name: p for p in (N_AV, F_C)}

#: The paper's filter, the value of ``velocity_filter`` when a file does not name one.
DEFAULT = "average"

_REGISTRY: dict[str, VelocityFilter] = {}


def register(entry: VelocityFilter) -> VelocityFilter:
    """Add a velocity filter; its name becomes a valid ``velocity_filter`` everywhere.

    Raises
    ------
    ValueError
        The name is taken or not an identifier, or a parameter is not one of :data:`PARAMETERS`
        (a new key also needs a field of :class:`haa_sym.model.params.Controller`).
    """
    if not isinstance(entry, VelocityFilter):
        raise TypeError(f"{entry!r} is not a haa_sym.model.filters.VelocityFilter")
    if not entry.name.isidentifier():
        raise ValueError(f"velocity filter name {entry.name!r}; allowed: an identifier")
    if entry.name in _REGISTRY:
        raise ValueError(f"velocity filter {entry.name!r} is already registered")
    for p in entry.parameters:
        if PARAMETERS.get(p.name) != p:
            raise ValueError(
                f"velocity filter {entry.name!r}: parameter {p.name!r} is not one of "
                f"haa_sym.model.filters.PARAMETERS {list(PARAMETERS)} (a new key needs an entry there and "
                "a field of haa_sym.model.params.Controller)")
    _REGISTRY[entry.name] = entry
    return entry


def unregister(name: str) -> None:
    """Remove a registered filter (tests); the default cannot be removed."""
    if name == DEFAULT:
        raise ValueError(f"{DEFAULT!r} is the default velocity filter")
    del _REGISTRY[name]


def names() -> tuple[str, ...]:
    """The registered filters, in registration order."""
    return tuple(_REGISTRY)


def allowed_text() -> str:
    """What messages say is allowed for ``velocity_filter``."""
    return f"one of {list(_REGISTRY)}"


def get(name: str) -> VelocityFilter:
    """The entry of ``name``; :class:`ParameterError` listing the registered names otherwise."""
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise ParameterError(f"velocity_filter = {name!r}; allowed: {allowed_text()}") from None


def velocity_filter(kind: str, Ts: float, **values) -> Element:
    """The exact transfer function of filter ``kind`` at sampling time ``Ts`` (s).

    ``values`` gives its parameters by key (``N_av=4``, ``f_c=40.0``); keys of
    :data:`PARAMETERS` the filter does not read are ignored, so a controller's may all be
    passed. A missing one takes its default (an error without one). The values are taken as
    given: :class:`haa_sym.model.params.Controller` is where they are validated.
    """
    entry = get(kind)
    return entry.build(Ts, **_arguments(entry, values))


def _arguments(entry: VelocityFilter, values: dict) -> dict:
    """The values of ``entry``'s parameters out of ``values`` (defaults filled in)."""
    kind = entry.name
    unknown = sorted(set(values) - set(PARAMETERS))
    if unknown:
        raise TypeError(f"velocity_filter(): unknown parameter(s) {unknown}; allowed: {list(PARAMETERS)}")
    args = {}
    for p in entry.parameters:
        value = values.get(p.name)
        if value is None:
            value = p.default
        if value is None:
            raise ParameterError(f"{p.name} is missing, required by velocity_filter = {kind!r}")
        args[p.name] = value
    return args


def controller_filter(ctrl) -> Element:
    """The velocity estimate of a :class:`haa_sym.model.params.Controller`."""
    return velocity_filter(ctrl.velocity_filter, ctrl.Ts, **{k: getattr(ctrl, k) for k in PARAMETERS})


def controller_filter_order(ctrl) -> int:
    """The order (states) of :func:`controller_filter`'s element, without building it when
    the registry entry states its ``order``.

    >>> from types import SimpleNamespace
    >>> controller_filter_order(SimpleNamespace(velocity_filter="average", Ts=1e-3, N_av=10**6, f_c=None))
    1000000
    """
    entry = get(ctrl.velocity_filter)
    values = {k: getattr(ctrl, k) for k in PARAMETERS}
    if entry.order is not None:
        return int(entry.order(**_arguments(entry, values)))
    return controller_filter(ctrl).order


def help_text() -> str:
    """``velocity_filter``'s choices for the command line's help."""
    out = []
    for e in _REGISTRY.values():
        notes = [f"{p.name} in {p.units}" for p in e.parameters] + (["default"] if e.name == DEFAULT else [])
        out.append(e.name + (f" ({', '.join(notes)})" if notes else ""))
    return "velocity_filter: one of " + ", ".join(out)


def markdown_rows() -> str:
    """The velocity filters' rows of the element table in docs/model.md (the tests check that
    the document has them)."""
    rows = []
    for e in _REGISTRY.values():
        what = f"velocity estimate `\"{e.name}\"`" + (" (default, the paper's)" if e.name == DEFAULT else "")
        keys = ", ".join(f"`{p.name}` ({p.units}, {p.rule}"
                         + (f", default {p.default!r}" if p.default is not None else "") + ")"
                         for p in e.parameters) or "none"
        rows.append(f"| {what}: {e.description} | {e.equation} | {keys} |")
    return "\n".join(rows)


# --- the built-in filters ----------------------------------------------------------------------

def _fraction(x: float) -> Fraction:
    return Fraction(float(x))


def _average(Ts: float, N_av: int) -> Element:
    N = int(N_av)
    return Element(f"average{N}", (Fraction(1),) + (Fraction(0),) * (N - 1) + (Fraction(-1),),
                   (N * _fraction(Ts),) + (Fraction(0),) * N)


def _lowpass1(Ts: float, f_c: float) -> Element:
    w_c = 2 * math.pi * float(f_c)
    return backward_difference(Ts) * tustin((w_c, 1.0), w_c, Ts, "lowpass1")


def _butterworth2(Ts: float, f_c: float) -> Element:
    w_c = 2 * math.pi * float(f_c)
    return backward_difference(Ts) * tustin((w_c * w_c, math.sqrt(2) * w_c, 1.0), w_c, Ts, "butterworth2")


register(VelocityFilter(
    "average", "the average of N_av first differences", "(1 - z^-N_av)/(N_av Ts)", (N_AV,), _average,
    # z^N_av - 1 over N_av Ts z^N_av: coprime (no root of z^N - 1 at 0), so no state cancels
    order=lambda N_av: int(N_av)))
register(VelocityFilter(
    "lowpass1", "backward difference and a first-order Tustin low-pass",
    "(1 - z^-1)/Ts * w_c/(s + w_c), s = (2/Ts)(z - 1)/(z + 1), w_c = 2 pi f_c", (F_C,), _lowpass1,
    order=lambda f_c: 2))
register(VelocityFilter(
    "butterworth2", "backward difference and a second-order Butterworth Tustin low-pass",
    "(1 - z^-1)/Ts * w_c^2/(s^2 + sqrt(2) w_c s + w_c^2), same s", (F_C,), _butterworth2,
    order=lambda f_c: 3))
