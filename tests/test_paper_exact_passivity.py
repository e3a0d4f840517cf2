"""The reproduction's comparison of the exact passivity test with the paper's (issue 24): the
screened evaluation decides every point as the full one does, and the report's section says
which side the approximation errs on from the numbers it is given."""
import numpy as np

from haa_sym import ClosedLoop, grid, load_params
from haa_sym.analysis.sampled_port import passivity_excess, passivity_tolerance
from haa_sym.loop.options import LoopOptions
from haa_sym.paper.report import exact_passivity_markdown
from haa_sym.paper.reproduce import _exact_deficits


def test_screened_deficits_decide_as_the_full_test():
    """Fig. 9a's loop (alpha = 0, the map with points passive under the exact test): on a 40 x 20
    map the screened evaluation gives the full test's decision at every point, its least deficit
    exactly, and at the points it did not evaluate fully a lower bound of the deficit above the
    tolerance."""
    loop = ClosedLoop(load_params().with_values(alpha=0.0), LoopOptions(passivity="exact"))
    PP, DD = np.meshgrid(grid("log:1:20000:40"), grid("lin:1:50:20"), indexing="ij")
    P, D = PP.ravel(), DD.ravel()
    P, D = P[loop.stability(P, D).stable.ravel()], D[loop.stability(P, D).stable.ravel()]
    tol = passivity_tolerance(loop)
    val, w, full = _exact_deficits(loop, P, D, tol)
    c = loop.params.controller
    ref, w_ref = passivity_excess(loop, P, D, c.beta, c.alpha)
    assert 0 < (ref <= tol).sum() < P.size                         # both decisions occur
    assert np.array_equal(val <= tol, ref <= tol)
    assert np.array_equal(val[full], ref[full]) and np.array_equal(w[full], w_ref[full])
    assert np.all(val[~full] <= ref[~full]) and np.all(val[~full] > tol)
    assert val.min() == ref.min() and (~full).sum() > P.size / 2      # the screening saved work


def test_report_section_states_the_side_from_the_numbers():
    maps = {"8a": {"points": 10, "stable": 8, "passive_paper": 5, "passive_exact": 1, "paper_only": 4,
                   "exact_only": 0, "passive_exact_at_omega_min": 1,
                   "worst_paper_passive": {"P_gain": 200.0, "D_gain": 10.0, "deficit": 8.97, "omega_rad_s": 20.6},
                   "least_deficit": {"P_gain": 1.0, "D_gain": 50.0, "deficit": -1e-6, "omega_rad_s": 0.1}}}
    cells = [{"row": "beta = 1", "column": "P_gain = 200, D_gain = 10", "P_gain": 200.0, "D_gain": 10.0,
              "paper": "Yes", "corrected_phase": "Yes", "exact": "No", "phase_excess_deg": -6e-10,
              "dissipation_deficit": 8.97, "omega_worst_exact_rad_s": 20.6},
             {"row": "beta = 1", "column": "torque loop", "P_gain": 0.0, "D_gain": 0.0, "paper": "No",
              "corrected_phase": "No", "exact": "No", "phase_excess_deg": 3.0, "dissipation_deficit": 115.0,
              "omega_worst_exact_rad_s": 4.7}]
    text = exact_passivity_markdown({"maps": maps, "table2": cells, "tolerance": 1e-7, "tolerance_deg": 1e-3})
    assert "errs on the optimistic side only: 4 of the 5 points" in text and "at least 8.97 times" in text
    assert "1 of 2 cells change" in text and "1 of the 1 changes are Yes -> No" in text
    assert "1 of the 1 points the exact test calls passive have their least mu at the grid's lowest" in text
    assert "the largest of those least mu values is 1e-06" in text
    maps["8a"]["exact_only"] = 2
    assert "errs on both sides" in exact_passivity_markdown({"maps": maps, "table2": cells, "tolerance": 1e-7})

