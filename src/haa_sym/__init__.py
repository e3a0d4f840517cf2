"""haa_sym: symbolic-to-numeric model compiler for impedance-controlled robot joints.

Reproduces Focchi et al. (2016), "Robot Impedance Control and Passivity Analysis with Inner
Torque and Velocity Feedback Loops". The numeric runtime (this namespace) never imports sympy.
Layers, bottom to top (docs/architecture.md): ``errors``, ``model``, ``io``, ``symbolic``,
``compiled``, ``loop``, ``analysis``, ``design``, ``check``, ``paper``, ``cli``. Analyses take
the closed loop first: ``region_map(ClosedLoop(params, options), P_gain, D_gain)``.
"""
from haa_sym._version import __version__
from haa_sym.analysis.margins import PhaseMargins, phase_margins
from haa_sym.analysis.passivity import PassivityResult, passivity
from haa_sym.analysis.regions import RegionMap, region_map
from haa_sym.errors import ParameterError
from haa_sym.io.gridspec import grid
from haa_sym.loop import (AnalysisConventions, ClosedLoop, FrequencyGrid, LoopOptions, LoopStructure,
                          StabilityResult)
from haa_sym.model.actuator import Body, Coupling, Topology
from haa_sym.model.params import Controller, Params, Plant, load_params

__all__ = ["__version__", "Controller", "ParameterError", "Params", "Plant", "Topology", "Body", "Coupling",
           "load_params", "ClosedLoop", "LoopOptions", "LoopStructure", "AnalysisConventions", "FrequencyGrid",
           "StabilityResult", "RegionMap", "grid", "region_map", "PassivityResult", "passivity", "PhaseMargins",
           "phase_margins"]
