"""``--out FITTED.toml``: the input parameter file's TEXT with the fitted values replaced.

Comments, order and every other entry stay as written. Each fitted entry gets the fitted
``value`` (in the entry's own ``unit``), ``source`` = a new key of ``[about.references]`` that
describes the fit (logs, their SHA-256, date, method) and ``ci95 = [lo, hi]`` (same unit). A
bare number becomes an entry table. A fitted Coulomb friction (``Fc_m``, ``Fc_<body>``) goes
into ``[limits]`` (the entry, and the section, added when the file has none: its start came from
``--set``), with the ``friction_velocity`` it was fitted with (added, or rewritten when ``--set``
changed it: an Fc means something only with its velocity scale). The new text is parsed and
validated before it is returned, and must give the fitted values (else an error: nothing is
written).
"""
from __future__ import annotations

import re
import tomllib

from haa_sym.errors import ParameterError
from haa_sym.fit.friction import is_friction_key
from haa_sym.model.drive import DRIVE_KEYS, DRIVE_UNITS
from haa_sym.model.params import parse_params
from haa_sym.model.units import to_si

__all__ = ["fitted_text", "reference_text"]

_HEADER = re.compile(r"^\s*\[([^\[\]]+)\]\s*(#.*)?$")


def _fmt(x: float) -> str:
    # the shortest text that reads back as the same float: the file gives exactly the fitted
    # value of fit.json (regions --uncertainty compares the two)
    return repr(float(x))


def reference_text(result, date: str) -> str:
    """The citation of a fit, for ``[about.references]``."""
    logs = ", ".join(f"{name} (sha256 {m['sha256'][:16]}, {m['samples']} samples"
                     + (f", configuration {m['configuration']}" if m.get("configuration") else "") + ")"
                     for name, m in result.meta["logs"].items())
    return (f"haa-sym identify, {date}: {', '.join(result.keys)} fitted to {logs}; input "
            f"{','.join(result.inputs)}, outputs {','.join(result.outputs)}; time-domain output error"
            + ("" if result.meta.get("converged", True) else ", NOT CONVERGED (stopped at the iteration limit)")
            + f"; 95 % intervals (ci95) from the {result.meta['intervals']['method']}")


def _section_and_key(topology, legacy: bool, key: str) -> tuple[str, str]:
    if key in DRIVE_KEYS:                 # the drive's keys live in [drive] (haa_sym.model.drive)
        return ("drive", key)
    if is_friction_key(key):              # Coulomb friction lives in [limits] (haa_sym.model.limits)
        return ("limits", key)
    return ("plant", key) if legacy else topology.section_of(key)


def _new_ref_key(refs: dict, date: str) -> str:
    base = "identify_" + re.sub(r"[^0-9]", "", date)[:8]
    key, i = base, 2
    while key in refs:
        key, i = f"{base}_{i}", i + 1
    return key


def fitted_text(text: str, source: str, params, result, date: str) -> str:
    """The file ``text`` (read from ``source``) with ``result``'s fitted values, sources and ci95.

    Raises
    ------
    ParameterError
        An entry the editor cannot find (e.g. written as a sub-table), or a result that does not
        read back as the fitted values.
    """
    data = tomllib.loads(text)
    legacy = "plant" in data
    top = params.plant.topology
    refs = data.get("about", {}).get("references", {}) if isinstance(data.get("about"), dict) else {}
    ref_key = _new_ref_key(refs, date)
    lines = text.splitlines(keepends=True)
    targets = {_section_and_key(top, legacy, k): (k, v, ci, v0)
               for k, v, ci, v0 in zip(result.keys, result.value, result.ci95, result.initial)}
    fitted_fc = [k for k in result.keys if is_friction_key(k)]
    v_s = (result.meta.get("friction") or {}).get("friction_velocity")
    file_limits = data.get("limits", {}) if isinstance(data.get("limits"), dict) else {}
    done, section, refs_end, limits_at = set(), None, None, None
    for i, line in enumerate(lines):
        h = _HEADER.match(line)
        if h:
            section = h.group(1).strip()
            if section == "limits":
                limits_at = i
            continue
        if fitted_fc and section == "limits" and re.match(r"^\s*friction_velocity\s*=", line):
            old = file_limits.get("friction_velocity")
            old = old.get("value") if isinstance(old, dict) else old
            if old != v_s:                # --set changed it: the file says what the Fc were fitted with
                lines[i] = _velocity_line(v_s, ref_key)
            continue
        if section == "about.references" and line.strip() and not line.lstrip().startswith("#"):
            refs_end = i
        m = re.match(r"^(\s*)([A-Za-z0-9_]+)(\s*=\s*)(.*?)(\r?\n)?$", line)
        if not m or (section, m.group(2)) not in targets:
            continue
        flat, v, ci, v0 = targets[(section, m.group(2))]
        entry = _entry_of(data, section, m.group(2))
        unit = entry.get("unit") if isinstance(entry, dict) else None
        si_unit = DRIVE_UNITS[flat] if flat in DRIVE_KEYS else "Nm" if is_friction_key(flat) else top.units[flat]
        factor = to_si(1.0, unit, si_unit, source, flat) if unit else 1.0
        val, lo, hi = v / factor, ci[0] / factor, ci[1] / factor
        rest = m.group(4)
        if isinstance(entry, dict):
            brace = rest.index("{")
            close = _closing(rest, brace)
            inner = rest[brace + 1:close]
            inner = re.sub(r"(\bvalue\s*=\s*)[^,}]+?(\s*(,|$))", lambda g: g.group(1) + _fmt(val) + g.group(2), inner, count=1)
            if re.search(r"\bsource\s*=", inner):
                inner = re.sub(r'(\bsource\s*=\s*)"[^"]*"', lambda g: f'{g.group(1)}"{ref_key}"', inner, count=1)
            else:
                inner = inner.rstrip() + f', source = "{ref_key}" '
            # the old description stays, after what the value now is (it may name a rule the fit replaced)
            said = f"Fitted by haa-sym identify ({ref_key}), initial value {v0 / factor:.6g}. Before: "
            inner = re.sub(r'(\bdescription\s*=\s*")', lambda g: g.group(1) + _escape(said), inner, count=1)
            ci_text = f"ci95 = [{_fmt(lo)}, {_fmt(hi)}]"
            if re.search(r"\bci95\s*=", inner):
                inner = re.sub(r"\bci95\s*=\s*\[[^\]]*\]", ci_text, inner, count=1)
            else:
                inner = re.sub(r"(\bvalue\s*=\s*[^,}]+?)(\s*(,|$))", lambda g: f"{g.group(1)}, {ci_text}{g.group(2)}",
                               inner, count=1)
            new_rest = rest[:brace + 1] + inner + rest[close:]
        else:
            comment = rest[rest.index("#"):] if "#" in rest else ""
            new_rest = (f'{{ value = {_fmt(val)}, ci95 = [{_fmt(lo)}, {_fmt(hi)}], source = "{ref_key}" }}'
                        + (f"   {comment}" if comment else ""))
        lines[i] = m.group(1) + m.group(2) + m.group(3) + new_rest + (m.group(5) or "\n")
        done.add((section, m.group(2)))
    # fitted friction the file had no entry for (its start came from --set): added to [limits]
    extra = [_limits_line(targets[t][0], *targets[t][1:3], ref_key) for t in targets
             if t not in done and t[0] == "limits"]
    if fitted_fc and "friction_velocity" not in file_limits:
        extra.append(_velocity_line(v_s, ref_key))
    if extra:
        if limits_at is not None:
            lines[limits_at + 1:limits_at + 1] = extra
        else:
            if lines and not lines[-1].endswith("\n"):
                lines[-1] += "\n"
            lines += ["\n", "[limits]\n"] + extra
        done.update(t for t in targets if t[0] == "limits")
    missing = [targets[t][0] for t in targets if t not in done]
    if missing:
        raise ParameterError(f"--out: cannot find the entry of {missing[0]} in {source} (looked for "
                             f"{[t for t in targets if t not in done][0]}); allowed: entries written as "
                             "KEY = { value = ... } or KEY = number in their section")
    ref_line = f'{ref_key} = "{_escape(reference_text(result, date))}"\n'
    if refs_end is not None:
        if not lines[refs_end].endswith("\n"):
            lines[refs_end] += "\n"
        lines.insert(refs_end + 1, ref_line)
    elif "about" in data and "references" in data["about"]:
        raise ParameterError(f"--out: {source} writes [about] references inline; allowed: a "
                             "[about.references] table (the fit adds its key there)")
    else:
        if lines and not lines[-1].endswith("\n"):
            lines[-1] += "\n"
        lines += ["\n", "[about.references]\n", ref_line]
    if not result.meta.get("converged", True):
        # the file's first line, not only the reference: a reader meets it before any value
        lines.insert(0, f"# haa-sym identify ({ref_key}): NOT CONVERGED, the fit stopped at its iteration limit "
                        "(--allow-unconverged); the fitted values are not a minimum\n")
    new = "".join(lines)
    check = parse_params(tomllib.loads(new), source)
    for k, v in zip(result.keys, result.value):
        got = (check.limits.friction.get(k[3:]) if is_friction_key(k)
               else getattr(check.drive if k in DRIVE_KEYS else check.plant, k))
        if not abs(got - v) <= 1e-8 * abs(v):
            raise ParameterError(f"--out: the written {k} reads back as {got!r}, not {v!r}; allowed: an "
                                 "entry this editor can rewrite")
    return new


def _limits_line(key: str, value: float, ci, ref_key: str) -> str:
    """A fitted friction entry of ``[limits]`` the file did not have (Nm)."""
    return (f'{key} = {{ value = {_fmt(value)}, unit = "Nm", ci95 = [{_fmt(ci[0])}, {_fmt(ci[1])}], source = '
            f'"{ref_key}", description = "Coulomb friction torque, fitted by haa-sym identify ({ref_key})" }}\n')


def _velocity_line(v_s: float, ref_key: str) -> str:
    """``friction_velocity`` as a fitted friction was fitted with (rad/s)."""
    return (f'friction_velocity = {{ value = {_fmt(v_s)}, unit = "rad/s", source = "{ref_key}", description = '
            f'"velocity scale of the tanh friction the Fc entries were fitted with" }}\n')


def _entry_of(data, section, key):
    node = data
    for part in section.split("."):
        node = node.get(part, {})
    return node.get(key)


def _closing(text: str, start: int) -> int:
    """Index of the brace closing the one at ``start`` (strings with braces skipped)."""
    depth, quote = 0, None
    for j in range(start, len(text)):
        c = text[j]
        if quote:
            if c == quote and text[j - 1] != "\\":
                quote = None
        elif c in "\"'":
            quote = c
        elif c == "{":
            depth += 1
        elif c == "}":
            depth -= 1
            if depth == 0:
                return j
    raise ParameterError(f"--out: unbalanced braces in {text!r}")


def _escape(s: str) -> str:
    return s.replace("\\", "\\\\").replace('"', '\\"')
