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

__all__ = ["paper_spec", "panel_params", "default_paper_path"]


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
