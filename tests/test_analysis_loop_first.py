"""Analyses take the closed loop first (issue 15): the two silent wrong results of redundant
arguments cannot be written any more, and the loop's own options and sampling time are the
ones applied."""
import inspect

import numpy as np
import pytest

from haa_sym import ClosedLoop, LoopOptions, ParameterError, passivity, region_map
from haa_sym.analysis import boundaries, contact, decide, margins, regions, robust, torque
from haa_sym.analysis import passivity as passivity_module
from haa_sym.analysis.sweep import colgate_factor
from haa_sym.check import reference as ref
from haa_sym.design import schedule

PUBLIC = [regions.region_map, passivity_module.passivity, passivity_module.corrected_phase, decide.decide_points,
          margins.crossovers, margins.phase_margins, margins.margins, boundaries.stability_boundary,
          boundaries.phase_margin_curves, boundaries.boundaries, boundaries.passivity_boundary,
          torque.step_response, torque.dc_gain, torque.torque_bandwidth, torque.torque_bandwidth_map,
          torque.torque_loop_margins, contact.contact_stability, contact.contact_intervals,
          robust.robust_region, robust.feasible_map, schedule.schedule]


@pytest.mark.parametrize("fn", PUBLIC, ids=lambda f: f.__name__)
def test_no_analysis_takes_parameters_options_or_a_second_loop(fn):
    names = list(inspect.signature(fn).parameters)
    assert names[0] == "loop", names
    assert not {"params", "options", "backend"} & set(names[1:]), names
    assert names.count("loop") == 1


def test_the_map_judges_with_the_loops_options(params):
    """Was: region_map(p, P, D, loop=ClosedLoop(p, LoopOptions(colgate="none", pm_rule="worst")),
    method="grid") judged with the default options (passivity differed at 52 of 72 points) and
    recorded colgate="subtract"."""
    opts = LoopOptions(colgate="none", pm_rule="worst")
    loop = ClosedLoop(params, opts)
    P, D = np.geomspace(1, 20000, 9), np.linspace(1, 50, 8)
    m = region_map(loop, P, D, method="grid")
    assert m.meta["options"]["colgate"] == "none" and m.meta["options"]["pm_rule"] == "worst"
    default = region_map(ClosedLoop(params), P, D, method="grid")
    assert (m.passive != default.passive).sum() > 0          # the options matter here ...
    d = decide.decide_points(loop, *np.meshgrid(P, D, indexing="ij"))
    np.testing.assert_array_equal(m.passive.ravel(), d.passive)   # ... and the loop's are applied
    with pytest.raises(TypeError):
        region_map(loop, P, D, options=LoopOptions())       # no second source of options


def test_passivity_corrects_with_the_loops_sampling_time(params):
    """Was: passivity(p, ..., loop=ClosedLoop(p.with_values(Ts=5e-4))) applied Colgate's correction
    with p's Ts (excess -0.22 deg instead of 0). The excess against the reference state space's
    Z with the loop's own Ts."""
    loop = ClosedLoop(params.with_values(Ts=5e-4))
    r = passivity(loop, 200.0, 10.0)
    w = loop.options.omega(5e-4)
    Z = ref.frequency_response(loop, w, 200.0, 10.0, which=("Z",))["Z"]
    excess = np.degrees(np.abs(np.angle(Z * colgate_factor(w, 5e-4, "subtract")))).max() - 90
    assert float(r.phase_excess_deg) == pytest.approx(excess, abs=1e-6)
    with pytest.raises(TypeError):
        passivity(loop, 200.0, 10.0, loop=loop)


def test_a_params_in_the_loops_place_is_refused_with_what_to_pass(params):
    for fn, args in ((region_map, ([1.0], [1.0])), (passivity, (1.0, 1.0)), (torque.step_response, ())):
        with pytest.raises(ParameterError, match=rf"{fn.__name__}: the first argument is a Params; allowed: a "
                                                  r"haa_sym.ClosedLoop"):
            fn(params, *args)
