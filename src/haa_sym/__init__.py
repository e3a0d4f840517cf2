"""haa_sym: symbolic-to-numeric model compiler for impedance-controlled robot joints.

Reproduces Focchi et al. (2016), "Robot Impedance Control and Passivity Analysis with Inner
Torque and Velocity Feedback Loops". The numeric runtime (this namespace) never imports sympy.
"""
from haa_sym.params import Controller, ParameterError, Params, Plant, load_params
from haa_sym.loop import ClosedLoop, LoopOptions, StabilityResult
from haa_sym.regions import RegionMap, grid, region_map
from haa_sym.passivity import PassivityResult, passivity

__all__ = ["Controller", "ParameterError", "Params", "Plant", "load_params", "ClosedLoop",
           "LoopOptions", "StabilityResult", "RegionMap", "grid", "region_map", "PassivityResult",
           "passivity"]
__version__ = "0.1.0"
