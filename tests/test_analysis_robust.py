"""haa_sym.analysis.robust: regions that hold for every leg configuration of a range (the
schedule built on them is test_design_schedule.py)."""
import numpy as np

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.robust import feasible_map, robust_region


def test_box_is_inside_the_segment_and_the_ends_bound_it():
    p = load_params()
    P, D = np.geomspace(5.0, 2000.0, 12), np.linspace(1.0, 50.0, 8)
    seg = robust_region(ClosedLoop(p), P, D, beta=3.0)
    box = robust_region(ClosedLoop(p), P, D, beta=3.0, leg_mode="box")
    assert seg.converged and box.converged and box.n_configurations >= 4
    assert not (box.feasible & ~seg.feasible).any()          # the box contains the segment
    for name in ("retracted", "extended"):
        end = feasible_map(ClosedLoop(p.configuration(name)), P, D, 3.0, p.controller.alpha)
        assert not (seg.feasible & ~end).any()
