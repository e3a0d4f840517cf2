"""The sampled closed loop (layer 5): options, the velocity-filter registry, the controller's
elements, the exact characteristic-polynomial basis, the plant, the loop and its state space.

The names most callers need are re-exported here (``from haa_sym.loop import ClosedLoop,
LoopOptions``); modules of this package import from the defining module.
"""
from haa_sym.loop.closed_loop import (FREQ_OUTPUTS, MARGINAL_TOL, ClosedLoop, FrequencyResponse, LoopCoefficients, loop_first,
                                      StabilityResult)
from haa_sym.loop.options import (COLGATE, FILTERS, PM_LOOPS, PM_RULES, PORTS, AnalysisConventions, FrequencyGrid,
                                  LoopOptions, LoopStructure)

__all__ = ["ClosedLoop", "LoopCoefficients", "StabilityResult", "FrequencyResponse", "FREQ_OUTPUTS", "MARGINAL_TOL",
           "LoopOptions", "LoopStructure", "AnalysisConventions", "FrequencyGrid", "PORTS", "COLGATE", "FILTERS",
           "PM_LOOPS", "PM_RULES", "loop_first"]
