"""Nonlinear maps (issue 19 part 3): each gain point classed from a simulation with the limits.
The references are independent: eigenvalues of the explicit closed loop
(haa_sym.check.reference), the describing-function prediction of the supply's limit cycle, and
the steady current a disturbance needs."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.describing import limit_cycles
from haa_sym.analysis.nonlinear_map import CLASSES, classify, nonlinear_map
from haa_sym.check.reference import closed_loop_matrices
from haa_sym.errors import ParameterError
from haa_sym.model.limits import Limits


def _loop(beta=3.0):
    return ClosedLoop(load_params().with_values(beta=beta))


def test_limits_that_never_act_give_the_linear_decisions():
    loop = _loop()
    P, D = np.geomspace(300.0, 20000.0, 7), np.array([1.0, 10.0, 40.0])
    # one 0.3 s run per point (max_duration): longer runs of the unstable points grow until even
    # 1e9 V saturates (then they are limit cycles of the supply, rightly)
    m = nonlinear_map(loop, P, D, limits=Limits(V_max=1e9), duration=0.3, max_duration=0.3, progress=False)
    eig_stable = np.array([[np.abs(np.linalg.eigvals(closed_loop_matrices(loop, p, d)[0])).max() < 1
                            for d in D] for p in P])
    assert eig_stable.any() and (~eig_stable).any()
    names = m.class_names
    assert np.array_equal(names == "converging", eig_stable)
    assert np.array_equal(names == "growing", ~eig_stable)
    assert np.all(m.saturation_fraction == 0)
    assert m.meta["counts"]["converging"] == eig_stable.sum()


def test_the_supply_bounds_an_unstable_point_to_the_predicted_limit_cycle():
    # beta = 3, P_gain = 20000, D_gain = 10: linearly unstable; a 24 V supply bounds it
    loop = _loop()
    assert np.abs(np.linalg.eigvals(closed_loop_matrices(loop, 20000.0, 10.0)[0])).max() > 1
    m = nonlinear_map(loop, [20000.0], [10.0], limits=Limits(V_max=24.0), progress=False)
    assert m.class_names[0, 0] == "limit cycle" and not m.linear_stable[0, 0]
    df = limit_cycles(loop, 20000.0, 10.0, nonlinearity={"V_max": 24.0})
    k = np.argmax(df.stable)
    assert df.stable[k]
    assert m.cycle_frequency[0, 0] == pytest.approx(df.frequency_hz[k], rel=0.01)
    assert 4.0 < m.cycle_amplitude[0, 0] < 6.5                  # about 5 Nm (the simulate helper's case)


def test_a_current_limit_below_the_disturbance_current_saturates_every_step():
    loop = _loop(beta=1.0)
    p = loop.params.plant
    A = 10.0
    needed = A / (p.k_t * p.N)              # steady motor current to hold A Nm at the link (A)
    I_max = needed / 5
    m = nonlinear_map(loop, [200.0], [5.0], limits=Limits(I_max=I_max), amplitude=A, progress=False)
    assert m.class_names[0, 0] == "saturating" and m.saturation_fraction[0, 0] >= 0.9
    ok = nonlinear_map(loop, [200.0], [5.0], limits=Limits(I_max=needed * 5), amplitude=A, progress=False)
    assert ok.class_names[0, 0] == "converging"


def test_rules_in_order():
    kinds = ["non-finite", "sustained", "none", "none", "growing", "decaying", "none", "sustained"]
    ts = [0.0, 0.5, 0.95, 0.1, 0.1, 0.1, 0.1, 0.0]
    st = [True, False, True, False, True, True, False, True]
    got = [CLASSES[c] for c in classify(kinds, ts, st, False)]
    assert got == ["diverged", "limit cycle", "saturating", "undecided", "growing", "converging", "undecided",
                   "converging"]       # the last: no saturation, no always-acting limit: the linear decision
    assert CLASSES[classify(["sustained"], [0.0], [True], True)[0]] == "limit cycle"
    # a forced run (the chirp) is never a limit cycle; it may still diverge or grow
    forced = [CLASSES[c] for c in classify(["sustained", "sustained", "non-finite", "none"], [0.5, 0.0, 0.0, 0.0],
                                           [True, False, True, True], False, forced=True)]
    assert forced == ["forced response", "growing", "diverged", "forced response"]
    # the linear decision unknown (NaN): the rules that need it do not apply
    assert CLASSES[classify(["none"], [0.0], [np.nan], False)[0]] == "undecided"


@pytest.mark.parametrize("kw, field", [
    ({}, "limits"), ({"limits": Limits(V_max=24.0), "saturating_fraction": 0.0}, "saturating_fraction"),
    ({"limits": Limits(V_max=24.0), "duration": -1.0}, "duration"),
    ({"limits": Limits(V_max=24.0), "experiment": "ramp"}, "experiment"),
    ({"limits": Limits(V_max=24.0), "points_per_task": 0}, "points_per_task"),
])
def test_bad_input_is_one_line(kw, field):
    with pytest.raises(ParameterError) as e:
        nonlinear_map(_loop(), [100.0], [1.0], progress=False, **kw)
    assert str(e.value).startswith(field) and "\n" not in str(e.value)


@pytest.mark.slow
def test_a_dask_cluster_gives_the_same_classes():
    distributed = pytest.importorskip("distributed")
    loop = _loop()
    P, D = np.geomspace(300.0, 20000.0, 6), np.array([1.0, 10.0, 40.0])
    lim = Limits(V_max=24.0, torque_resolution=0.01)
    local = nonlinear_map(loop, P, D, limits=lim, progress=False, points_per_task=4)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cl:
        remote = nonlinear_map(loop, P, D, limits=lim, progress=False, points_per_task=4,
                               scheduler=cl.scheduler_address)
    assert len(set(local.class_names.ravel())) >= 2
    assert np.array_equal(local.nonlinear_class, remote.nonlinear_class)
    assert np.array_equal(local.cycle_amplitude, remote.cycle_amplitude, equal_nan=True)
    assert remote.meta["scheduler"] == "dask.distributed"


def test_theil_sen_slope_is_scipys():
    from scipy.stats import theilslopes
    from haa_sym.analysis.oscillation import theil_sen_slope
    y = np.random.default_rng(1).standard_normal(37).cumsum()
    assert theil_sen_slope(y) == pytest.approx(theilslopes(y, np.arange(y.size))[0], rel=1e-14, abs=1e-15)


def test_a_point_still_growing_is_run_longer_until_its_cycle_shows():
    # the 24 V cycle builds up over about 0.6 s: a 0.4 s run sees it growing
    loop = _loop()
    short = nonlinear_map(loop, [20000.0], [10.0], limits=Limits(V_max=24.0), duration=0.4, max_duration=0.4,
                          progress=False)
    assert short.class_names[0, 0] == "growing" and short.meta["longer_rounds"] == 0
    longer = nonlinear_map(loop, [20000.0], [10.0], limits=Limits(V_max=24.0), duration=0.4, progress=False)
    assert longer.class_names[0, 0] == "limit cycle"
    assert longer.run_duration[0, 0] == pytest.approx(0.4 * 3 ** longer.meta["longer_rounds"])
    with pytest.raises(ParameterError, match="^max_duration"):
        nonlinear_map(loop, [100.0], [1.0], limits=Limits(V_max=24.0), duration=1.0, max_duration=0.5)
