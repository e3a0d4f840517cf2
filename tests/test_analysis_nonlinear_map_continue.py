"""A map's longer runs continue each point's last run (issue 27): the same map as with every run
from t = 0, for fewer simulated samples (docs/simulate.md, "Nonlinear maps")."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.nonlinear_map import nonlinear_map
from haa_sym.errors import ParameterError
from haa_sym.model.limits import Limits

# bench_scale's nonlinear preset's limits (24 V, 0.02 Nm rotor friction) at beta = 3, where the
# unstable points' traces decay or grow for a while: undecided or growing, so run again
BENCH = Limits(V_max=24.0, friction={"m": 0.02})
P, D = np.geomspace(2000.0, 20000.0, 3), np.array([1.0, 10.0])


@pytest.mark.parametrize("limits, drive", [
    (BENCH, {}),
    # the supply's limit cycles (their amplitude and frequency compared), through the drive's
    # fractional dead time and lag (its delay line continued)
    (Limits(V_max=24.0), dict(tau_drive=0.001, delay_drive=0.0013))])
@pytest.mark.parametrize("max_duration", [0.45, 0.4])    # 0.15 -> 0.45, and a capped 0.15 -> 0.4
def test_continued_reruns_give_the_map_of_reruns_from_zero(max_duration, limits, drive):
    loop = ClosedLoop(load_params().with_values(beta=3.0, **drive))
    kw = dict(limits=limits, duration=0.15, max_duration=max_duration, progress=False, points_per_task=2)
    cont = nonlinear_map(loop, P, D, **kw)
    zero = nonlinear_map(loop, P, D, continue_runs=False, **kw)
    assert cont.meta["longer_runs_continue"] and not zero.meta["longer_runs_continue"]
    assert (cont.run_duration > 0.15).sum() >= 2                       # points were run again
    if not limits.friction:
        assert np.isfinite(cont.cycle_amplitude[cont.run_duration > 0.15]).any()
    for name, a in cont.arrays().items():
        assert np.array_equal(a, zero.arrays()[name], equal_nan=True), name
    # the reruns cost their new samples only
    n = lambda s: int(np.ceil(s / loop.params.controller.Ts - 1e-9)) + 1      # noqa: E731
    again = int((cont.run_duration > 0.15).sum())
    assert zero.meta["samples_simulated"] - cont.meta["samples_simulated"] == again * n(0.15)


def test_noise_with_jitter_continues_to_the_map_of_reruns_from_zero():
    """Torque noise with jitter (the jitter's own seeded stream, issue 27): the reruns continue,
    and give the map of reruns from t = 0 for fewer samples."""
    loop = ClosedLoop(load_params().with_values(beta=3.0))
    kw = dict(limits=Limits(V_max=24.0, torque_noise=0.05, jitter=2e-6), duration=0.15, max_duration=0.45,
              seed=2, progress=False, points_per_task=2)
    cont = nonlinear_map(loop, P, D, **kw)
    zero = nonlinear_map(loop, P, D, continue_runs=False, **kw)
    assert cont.meta["longer_runs_continue"] and not zero.meta["longer_runs_continue"]
    again = int((cont.run_duration > 0.15).sum())
    assert again >= 2                                                  # points were run again
    for name, a in cont.arrays().items():
        assert np.array_equal(a, zero.arrays()[name], equal_nan=True), name
    n = lambda s: int(np.ceil(s / loop.params.controller.Ts - 1e-9)) + 1      # noqa: E731
    assert zero.meta["samples_simulated"] - cont.meta["samples_simulated"] == again * n(0.15)


def test_the_chirp_reruns_from_zero_and_continue_runs_is_checked():
    loop = ClosedLoop(load_params().with_values(beta=3.0))
    m = nonlinear_map(loop, [20000.0], [10.0], limits=Limits(V_max=24.0), experiment="chirp", duration=0.1,
                      max_duration=0.3, progress=False)
    assert not m.meta["longer_runs_continue"] and m.meta["friction_scale_duration"] is None
    with pytest.raises(ParameterError, match="^continue_runs"):
        nonlinear_map(loop, [100.0], [1.0], limits=Limits(V_max=24.0), continue_runs=1)
