"""The reproduction of Focchi et al. (2016), apart from the library.

This package holds what is about the paper only: what it reports, as data (``model/paper.toml``:
the panels of Figs. 8-11, Table 2, the claims; this module), Table 2 and the option scoring
(:mod:`haa_sym.paper.table2`), the whole reproduction (:mod:`haa_sym.paper.reproduce`,
``haa-sym reproduce`` / ``make paper``) and its report (:mod:`haa_sym.paper.report`). The
library (actuator model, code generation, runtime, closed loop, analyses) never imports it.
"""
from __future__ import annotations

import tomllib
from pathlib import Path

from haa_sym.errors import ParameterError
from haa_sym.model.params import Params
from haa_sym.model.resources import data_dir

__all__ = ["paper_spec", "panel_params", "default_paper_path", "check_params"]


def default_paper_path() -> Path:
    """``model/paper.toml`` (source tree or installed package)."""
    return data_dir("model") / "paper.toml"


def paper_spec(path: str | Path | None = None) -> dict:
    """The parsed ``model/paper.toml``."""
    path = Path(path or default_paper_path())
    try:
        return tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ParameterError(f"{path}: cannot read the paper's reference data ({exc})") from None


def panel_params(params: Params, entry: dict) -> Params:
    """``params`` with an entry's ``configuration`` and ``set`` overrides applied."""
    if entry.get("configuration"):
        params = params.configuration(entry["configuration"])
    return params.with_values(**entry.get("set", {}))


def check_params(params: Params, spec: dict) -> None:
    """Check, in milliseconds, that the reproduction can run on ``params``: every panel of
    Figs. 8-11, every row of Table 2 and every stiffness of Fig. 7 applies (their configurations
    and keys exist, their values are valid), and the keys the torque-loop corners read
    (``J_L2``, ``K_L2``) exist. :func:`haa_sym.paper.reproduce.reproduce` calls it before any
    work, so an actuator without the paper's configurations fails at once, not after a map.

    Raises
    ------
    ParameterError
        Naming the actuator, the statement of ``model/paper.toml`` and what it needs.
    """
    def fail(what: str, why: str):
        why = why.removeprefix(f"{params.source}: ").replace("; allowed: ", ", the file has ")
        return ParameterError(f"{params.source}: {what} of model/paper.toml (the paper's HyQ statements) "
                              f"needs what this actuator lacks: {why}; allowed: an actuator with the paper's "
                              "configurations and keys (hyq_haa, or a file derived from it)")
    needed = [(f"Fig. {e['figure']} ({e['panel']})", e) for e in spec["regions"]["panel"]]
    needed += [(f"Table 2 row {e.get('label', i)!r}", e) for i, e in enumerate(spec["table2"]["row"])]
    for what, entry in needed:
        try:
            panel_params(params, entry)
        except ParameterError as exc:
            raise fail(what, str(exc)) from None
    keys = set(params.plant.keys)
    for key in ("J_L2", "K_L2"):
        if key not in keys:
            raise fail("Fig. 7 and the torque-loop corners",
                       f"no plant key {key!r} (the HyQ leg's); keys: {sorted(keys)}")
    for K in spec["claims"]["fig7_K_L2"]:
        try:
            params.with_values(K_L2=K)
        except ParameterError as exc:
            raise fail("Fig. 7", str(exc)) from None
