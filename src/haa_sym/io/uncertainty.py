"""Reading an identification's report (``fit.json`` of ``haa-sym identify``, issue 17) for the
uncertainty of the maps: the schema checked field by field, one line per mistake.

The schema (what ``haa-sym identify --report`` writes)::

    {"parameters": {KEY: {"value": v, "initial": v0, "ci95": [lo, hi]}, ...},
     "rms_error": {...}, "samples": n, "sampling": {...}, "meta": {...}}

``value`` is the fitted value, the centre the 95 % confidence interval ``ci95`` was estimated
around (lo <= value <= hi), ``initial`` the value the fit started from. Only ``parameters`` is
used here; the other top-level fields must be present with their types (a report missing one is
not a report of ``identify``), their content is not interpreted.
"""
from __future__ import annotations

import collections
import json
import math
from pathlib import Path

from haa_sym.errors import ParameterError
from haa_sym.io.inputs import read_text

__all__ = ["read_fit", "fit_box", "fit_values", "FIT_FIELDS"]

# top-level field -> its JSON type (the schema)
FIT_FIELDS = {"parameters": dict, "rms_error": dict, "samples": int, "sampling": dict, "meta": dict}
ENTRY_FIELDS = ("value", "initial", "ci95")
# the largest report read, bytes (identify writes a few kilobytes)
MAX_BYTES = 16 << 20


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def read_fit(path, field: str = "--uncertainty", keys=None) -> dict:
    """The report at ``path``, checked: every field of :data:`FIT_FIELDS` with its type, at least
    one parameter, each with finite numbers ``value``, ``initial`` and ``ci95`` = [lo, hi] with
    lo <= value <= hi; with ``keys`` (the actuator's plant keys), every parameter one of them.

    Returns
    -------
    dict
        The report as read (plain JSON data), plus ``"source"``: the path.

    Raises
    ------
    ParameterError
        One line: ``field``, the file, the key or field at fault, its value and what is allowed.
    """
    p = Path(path)
    where = f"{field} {str(path)!r}"
    if p.suffix.lower() != ".json":
        raise ParameterError(f"{where}: not a .json file; allowed: the report of haa-sym identify (fit.json)")
    text = read_text(path, field, limit=MAX_BYTES, where=where, encoding="utf-8-sig")
    twice = []

    def unique(pairs):
        # json keeps the last of a repeated name silently: two intervals for one key (a hand-edited
        # report) would analyse whichever came last
        # (counted once: names.count per name is quadratic, minutes for 100,000 names)
        twice.extend(k for k, n in collections.Counter(k for k, _ in pairs).items() if n > 1)
        return dict(pairs)
    try:
        data = json.loads(text, object_pairs_hook=unique)
    except json.JSONDecodeError as exc:
        raise ParameterError(f"{where}: not JSON (line {exc.lineno}, column {exc.colno}: {exc.msg}); allowed: "
                             "the report of haa-sym identify") from None
    except ValueError as exc:       # an integer of more than 4,300 digits (Python's int limit)
        raise ParameterError(f"{where}: not a report ({str(exc).splitlines()[0][:120]}); allowed: the report of "
                             "haa-sym identify") from None
    except RecursionError:          # json recurses once per nesting level
        raise ParameterError(f"{where}: arrays or objects nested too deeply to be a report; allowed: the report "
                             "of haa-sym identify") from None
    if twice:
        raise ParameterError(f"{where}: the name {twice[0]!r} appears twice in one JSON object; allowed: each "
                             "name once (the report of haa-sym identify)")
    if not isinstance(data, dict):
        raise ParameterError(f"{where}: a JSON {type(data).__name__}; allowed: an object with fields "
                             f"{list(FIT_FIELDS)}")
    for name, kind in FIT_FIELDS.items():
        if name not in data:
            raise ParameterError(f"{where}: field {name!r} is missing; allowed: an object with fields "
                                 f"{list(FIT_FIELDS)}")
        v = data[name]
        if not isinstance(v, kind) or isinstance(v, bool):
            raise ParameterError(f"{where}: field {name!r} = {json.dumps(v)[:60]}; allowed: a JSON "
                                 f"{'integer' if kind is int else 'object'}")
    if data["samples"] < 1:
        raise ParameterError(f"{where}: field 'samples' = {data['samples']}; allowed: an integer >= 1")
    params = data["parameters"]
    if not params:
        raise ParameterError(f"{where}: 'parameters' is empty; allowed: at least one fitted key")
    for key, entry in params.items():
        at = f"{where}: parameters.{key.encode('unicode_escape').decode()}"   # one line, whatever the key
        if keys is not None and key not in keys:
            raise ParameterError(f"{at}: {key!r} is not a key of the actuator; allowed: {list(keys)}")
        if not isinstance(entry, dict):
            raise ParameterError(f"{at} = {json.dumps(entry)[:60]}; allowed: an object with fields "
                                 f"{list(ENTRY_FIELDS)}")
        for name in ENTRY_FIELDS:
            if name not in entry:
                raise ParameterError(f"{at}: field {name!r} is missing; allowed: an object with fields "
                                     f"{list(ENTRY_FIELDS)}")
        for name in ("value", "initial"):
            if not _number(entry[name]):
                raise ParameterError(f"{at}.{name} = {json.dumps(entry[name])[:60]}; allowed: a finite number")
        ci = entry["ci95"]
        if not (isinstance(ci, list) and len(ci) == 2 and all(_number(x) for x in ci)):
            raise ParameterError(f"{at}.ci95 = {json.dumps(ci)[:60]}; allowed: [lo, hi], two finite numbers")
        lo, hi = ci
        if not lo <= entry["value"] <= hi:
            raise ParameterError(f"{at}.ci95 = [{lo:g}, {hi:g}] with value {entry['value']:g}; allowed: "
                                 "lo <= value <= hi (the interval around the fitted value)")
    return {**data, "source": str(path)}


def fit_box(fit: dict) -> dict:
    """``{key: (lo, hi)}``: the 95 % confidence box of a report of :func:`read_fit` (the
    ``uncertainty`` argument of the robust analyses)."""
    return {k: (float(e["ci95"][0]), float(e["ci95"][1])) for k, e in sorted(fit["parameters"].items())}


def fit_values(fit: dict) -> dict:
    """``{key: value}``: the fitted values (the centres of the box)."""
    return {k: float(e["value"]) for k, e in sorted(fit["parameters"].items())}
