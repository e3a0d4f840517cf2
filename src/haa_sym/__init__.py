"""haa_sym: symbolic-to-numeric model compiler for impedance-controlled robot joints.

Reproduces Focchi et al. (2016), "Robot Impedance Control and Passivity Analysis with Inner
Torque and Velocity Feedback Loops". The numeric runtime (this namespace) never imports sympy.
Layers, bottom to top (docs/architecture.md): ``errors``, ``model``, ``io``, ``symbolic``,
``compiled``, ``loop``, ``analysis``, ``design``, ``check``, ``paper``, ``cli``. Analyses take
the closed loop first: ``region_map(ClosedLoop(params, options), P_gain, D_gain)``.

The public names below are imported on first use (PEP 562 ``__getattr__``, as numpy and scipy
do): ``import haa_sym`` itself imports nothing heavy, so that a command, or a program that needs
one submodule, does not pay for the whole API (scipy.linalg, CasADi, the analyses; docs/startup.md).
``from haa_sym import X`` and ``haa_sym.X`` work as before.
"""
from __future__ import annotations

import importlib

# public name -> the module defining it: the package's API (__all__), each name in one place
_LAZY = {
    "__version__": "haa_sym._version",
    "Controller": "haa_sym.model.params", "ParameterError": "haa_sym.errors", "Params": "haa_sym.model.params",
    "Plant": "haa_sym.model.params", "Topology": "haa_sym.model.actuator", "Body": "haa_sym.model.actuator",
    "Coupling": "haa_sym.model.actuator", "load_params": "haa_sym.model.params", "ClosedLoop": "haa_sym.loop",
    "LoopOptions": "haa_sym.loop", "LoopStructure": "haa_sym.loop", "AnalysisConventions": "haa_sym.loop",
    "FrequencyGrid": "haa_sym.loop", "StabilityResult": "haa_sym.loop", "RegionMap": "haa_sym.analysis.regions",
    "grid": "haa_sym.io.gridspec", "region_map": "haa_sym.analysis.regions",
    "PassivityResult": "haa_sym.analysis.passivity", "passivity": "haa_sym.analysis.passivity",
    "PhaseMargins": "haa_sym.analysis.margins", "phase_margins": "haa_sym.analysis.margins",
}
__all__ = list(_LAZY)

# the subpackages: ``haa_sym.loop`` after ``import haa_sym`` imports it, as scipy's submodules
_SUBMODULES = frozenset({"_version", "analysis", "check", "cli", "compiled", "design", "errors", "explore", "fit",
                         "io", "loop", "model", "paper", "robot", "symbolic", "verify"})


def __getattr__(name: str):
    """A public name's (or subpackage's) first use imports its module and binds the name here
    (later uses are plain attribute look-ups); anything else is an AttributeError, as without
    this hook."""
    if name in _SUBMODULES:
        return importlib.import_module(f"haa_sym.{name}")      # the import binds it here
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'haa_sym' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
