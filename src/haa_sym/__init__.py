"""haa_sym: symbolic-to-numeric model compiler for impedance-controlled robot joints.

Reproduces Focchi et al. (2016), "Robot Impedance Control and Passivity Analysis with Inner
Torque and Velocity Feedback Loops". The numeric runtime (this namespace) never imports sympy.
"""
from haa_sym._version import __version__
from haa_sym.errors import ParameterError
from haa_sym.model.params import Controller, Params, Plant, load_params
from haa_sym.model.actuator import Body, Coupling, Topology
from haa_sym.loop.closed_loop import (AnalysisConventions, ClosedLoop, FrequencyGrid, LoopOptions, LoopStructure,
                          StabilityResult)
from haa_sym.analysis.regions import RegionMap, grid, region_map
from haa_sym.analysis.passivity import PassivityResult, passivity

__all__ = ["Controller", "ParameterError", "Params", "Plant", "Topology", "Body", "Coupling", "load_params", "ClosedLoop",
           "LoopOptions", "LoopStructure", "AnalysisConventions", "FrequencyGrid", "StabilityResult", "RegionMap", "grid", "region_map", "PassivityResult",
           "passivity"]

