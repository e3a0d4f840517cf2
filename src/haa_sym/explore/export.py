"""Export of the explorer's current setting: an actuator file with the values analysed, the map as
a PNG (:func:`haa_sym.io.plots.plot_region` with the exact curves) and what the page shows as
JSON, written together, all or nothing (:class:`haa_sym.io.outputs.Transaction`).

The actuator file is the source file with every value replaced by the one analysed (a
configuration, the slider's position and every override applied), in SI units; the file's
structure, sources, descriptions and [configurations] are kept, so ``--params`` of any command
reproduces the setting.
"""
from __future__ import annotations

import json
import math
import os
import tomllib
from pathlib import Path

from haa_sym.analysis.boundaries.combined import boundaries
from haa_sym.analysis.regions import region_map
from haa_sym.errors import ParameterError
from haa_sym.explore.state import ViewState, point_detail, resolve, to_query, view_summary, plain
from haa_sym.io.formats import save_json
from haa_sym.io.outputs import Transaction, check_file
from haa_sym.io.inputs import command_scope, protect, read_text
from haa_sym.model.params import CONTROLLER_UNITS, MAX_FILE_BYTES
from haa_sym.model.structures import STRUCTURES

__all__ = ["actuator_toml", "export_view", "export_paths", "EXPORT_NAMES", "MAX_EXPORTS"]

# the files export_view writes into its directory (numbered when they exist: export_paths)
EXPORT_NAMES = ("actuator.toml", "view.png", "view.json")
# the most numbered exports in one directory
MAX_EXPORTS = 999


def _locations(data: dict) -> dict:
    """flat key -> the entry's (table, name) in the file's data: [motor] / a legacy [plant] by
    name, [bodies.B] and [couplings.C] as NAME_B / NAME_C (the flat names of docs/model.md)."""
    out = {}
    for section in ("motor", "plant"):
        for name in data.get(section, {}) or {}:
            out[name] = (data[section], name)
    for section in ("bodies", "couplings"):
        for owner, table in (data.get(section, {}) or {}).items():
            for name, entry in table.items():
                if name != "between":
                    out[f"{name}_{owner}"] = (table, name)
    return out


def _set_entry(table: dict, name: str, value, si_unit: str | None) -> None:
    entry = table.get(name)
    if isinstance(entry, dict):
        entry = dict(entry, value=value)
        if "unit" in entry and entry["unit"] != si_unit:
            del entry["unit"]                   # a value without a unit is in the key's SI unit
        table[name] = entry
    else:
        table[name] = value


def actuator_toml(params) -> str:
    """The text of an actuator file holding ``params``'s values (see the module docstring)."""
    try:
        data = tomllib.loads(read_text(params.source, "export: the source file", limit=MAX_FILE_BYTES))
    except ParameterError as exc:
        raise ParameterError(f"{exc}; the export needs a setting loaded from a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"export: the source file {params.source!r} cannot be read ({exc}); allowed: a "
                             "setting loaded from a TOML file") from None
    top = params.plant.topology
    where = _locations(data)
    missing = [k for k in top.parameter_keys if k not in where]
    if missing:
        raise ParameterError(f"export: the keys {missing} have no entry in {params.source}; allowed: an actuator "
                             "file with an entry per key")
    for key in top.parameter_keys:
        table, name = where[key]
        _set_entry(table, name, _number(getattr(params.plant, key)), top.units.get(key))
    ctrl = data.setdefault("controller", {})
    unread = STRUCTURES[params.controller.structure].unread    # neutral values, left out of a file
    for key, value in params.controller.__dict__.items():
        if value is None or key in unread or key == "alternatives":   # sub-tables stay as read
            ctrl.pop(key, None)
        else:
            _set_entry(ctrl, key, value if isinstance(value, str) else _number(value), CONTROLLER_UNITS.get(key))
    about = data.setdefault("about", {})
    about["description"] = (str(about.get("description", "")) + f" Exported by haa-sym explore from "
                            f"{Path(params.source).name} with the values analysed (SI units).").strip()
    return _toml(data)


def _number(v):
    return int(v) if isinstance(v, int) and not isinstance(v, bool) else float(v)


def _scalar(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ParameterError(f"export: value {v!r}; allowed: finite numbers")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_scalar(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_scalar(x)}" for k, x in v.items()) + " }"
    raise ParameterError(f"export: value {v!r} of type {type(v).__name__}; allowed: TOML values")


def _is_table(v) -> bool:
    """A sub-table written as [a.b]: a dict that is not an entry ({ value = ... })."""
    return isinstance(v, dict) and "value" not in v


def _toml(data: dict, path: tuple = ()) -> str:
    lines = []
    values = [(k, v) for k, v in data.items() if not _is_table(v)]
    if path and (values or not any(_is_table(v) for v in data.values())):
        lines.append(f"\n[{'.'.join(path)}]")
    lines += [f"{k} = {_scalar(v)}" for k, v in values]
    text = "\n".join(lines)
    for k, v in data.items():
        if _is_table(v):
            text += "\n" + _toml(v, path + (k,))
    return text.strip("\n") + "\n" if not path else text


def export_paths(directory: str | Path) -> list[Path]:
    """Where :func:`export_view` writes into ``directory``: :data:`EXPORT_NAMES`, or, when any of
    them exists there already (a file, a directory or a link, even a dangling one), the first
    numbered set of which none exists (``actuator-2.toml``, ``view-2.png``, ``view-2.json``;
    then -3, ...): an export never replaces a file, and the three files of one export share
    their number."""
    d = Path(directory)
    for n in range(1, MAX_EXPORTS + 1):
        paths = [d / (name if n == 1 else f"{Path(name).stem}-{n}{Path(name).suffix}") for name in EXPORT_NAMES]
        if not any(os.path.lexists(p) for p in paths):
            return paths
    raise ParameterError(f"export directory {str(directory)!r}: holds {MAX_EXPORTS} exports already; allowed: a "
                         "directory with fewer (choose another)")


def export_view(state: ViewState, directory: str, view=None) -> list[Path]:
    """Write :data:`EXPORT_NAMES` of ``state`` into ``directory`` (created if missing), all or
    nothing, under new names when those exist (:func:`export_paths`); returns the paths. The
    actuator file explored, and every file the command has read, is never written over
    (:func:`haa_sym.io.inputs.protect`, checked through links). ``view``: the page's
    :class:`haa_sym.explore.state.View` (its summary goes into the JSON; default recomputed)."""
    from haa_sym.io import plots
    if not directory:
        raise ParameterError("export directory = ''; allowed: a directory path")
    r = resolve(state)
    loop, P, D = r.loop, r.P_gain, r.D_gain
    with command_scope():
        protect(r.params.source)
        paths = [check_file(p, "export directory") for p in export_paths(directory)]
        m = region_map(loop, P, D, progress=False)
        b = boundaries(loop, P_range=(float(P.min()), float(P.max())), D_range=(float(D.min()), float(D.max()))) \
            if loop.options.conventions.pm_loop == "impedance" else None
        summary = view_summary(view) if view is not None else None
        data = {"query": to_query(state), "state": {k: v for k, v in state.__dict__.items()},
                "map": summary, "counts": {"stable": int(m.stable.sum()), "low_pm": int(m.low_pm.sum()),
                                           "passive": int(m.passive.sum())},
                "point": point_detail(state, *r.point, r).to_dict() if r.point is not None else None,
                "meta": m.meta}
        with Transaction() as tx:
            tx.write_text(paths[0], actuator_toml(r.params), "export directory")
            plots.save_figure(plots.plot_region(m, title=to_query(state) or "the file's values", boundary=b),
                              paths[1], tx, "export directory")
            save_json(paths[2], plain(data), tx, "export directory")
    return paths
