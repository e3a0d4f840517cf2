"""haa_sym: symbolic-to-numeric model compiler for impedance-controlled robot joints.

Reproduces Focchi et al. (2016), "Robot Impedance Control and Passivity Analysis with Inner
Torque and Velocity Feedback Loops". The numeric runtime (this namespace) never imports sympy.
"""
from haa_sym.params import Controller, ParameterError, Params, Plant, load_params
from haa_sym.actuator import Body, Coupling, Topology
from haa_sym.loop import (AnalysisConventions, ClosedLoop, FrequencyGrid, LoopOptions, LoopStructure,
                          StabilityResult)
from haa_sym.regions import RegionMap, grid, region_map
from haa_sym.passivity import PassivityResult, passivity

__all__ = ["Controller", "ParameterError", "Params", "Plant", "Topology", "Body", "Coupling", "load_params", "ClosedLoop",
           "LoopOptions", "LoopStructure", "AnalysisConventions", "FrequencyGrid", "StabilityResult", "RegionMap", "grid", "region_map", "PassivityResult",
           "passivity"]


def _version() -> str:
    """The version of the installed distribution (``importlib.metadata``); read from
    ``pyproject.toml`` when run from a source tree that was never installed (``PYTHONPATH=src``)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("haa_sym")
    except PackageNotFoundError:
        import tomllib
        from pathlib import Path
        try:
            with open(Path(__file__).resolve().parents[2] / "pyproject.toml", "rb") as fh:
                return tomllib.load(fh)["project"]["version"]
        except (OSError, KeyError, tomllib.TOMLDecodeError):
            return "0+unknown"


__version__ = _version()
