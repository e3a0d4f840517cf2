"""A run continued from the state where a shorter one stopped is the run from t = 0 (issue 27;
docs/simulate.md, "Nonlinear maps"): the C loop's state (plant, controller, the drive's delay
line, the friction integrator's level) goes out and back in, the inputs are those of the longer
run from the continuation's sample on, and the friction error scale is the first run's; the
trajectory is the same to the bit, and so are the summaries read from the tail it keeps."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import (Continuation, _run, batch_setup, keep_from,
                                       simulate_batch)
from haa_sym.errors import ParameterError
from haa_sym.model.limits import Limits

# bench_scale's nonlinear preset: HyQ, a 24 V supply, 0.02 Nm rotor friction
BENCH = Limits(V_max=24.0, friction={"m": 0.02})
# a limit cycle (P 20000, D 10 at 24 V: docs/simulate.md), a saturating stiff point, a soft one
P = np.array([20000.0, 20000.0, 300.0])
D = np.array([10.0, 1.0, 30.0])


def _loop(backend="auto", **values):
    p = load_params()
    return ClosedLoop(p.with_values(**values) if values else p, basis=False, backend=backend)


def _split(loop, limits, P_, D_, lengths, experiment="disturbance-step"):
    """(the outputs of the run continued over ``lengths`` (s) in turn, those of one run from 0 over
    the last) at one gain point, the friction scale of the first length for both."""
    setups = [batch_setup(loop, limits, experiment, None, T, 3, 1e-6, lengths[0]) for T in lengths]
    ys, start = [], None
    for s, nxt in zip(setups, lengths[1:] + [lengths[-1]]):
        y, _info, end = _run(loop, s, P_, D_, start=start)
        ys.append(y)
        start = Continuation(start.k + y.shape[0] if start else y.shape[0], end[0], end[1], end[2], end[3],
                             0, np.zeros((0, y.shape[1])), np.zeros(0, int), 0.0)
    whole, _info, _end = _run(loop, setups[-1], P_, D_)
    return np.concatenate(ys), whole


@pytest.mark.parametrize("i", range(len(P)))
def test_continued_runs_are_the_run_from_zero_bit_for_bit(i):
    y, whole = _split(_loop(), BENCH, P[i], D[i], [0.2, 0.5, 0.6])
    assert y.shape == whole.shape
    assert np.array_equal(y, whole)
    assert np.ptp(whole[:, 2]) > 0.1              # the torque moves: there is a trajectory to compare


@pytest.mark.parametrize("limits, values", [
    (Limits(V_max=24.0, friction={"m": 0.02}), dict(tau_drive=0.002, delay_drive=0.0023)),   # fractional + whole
    (Limits(V_max=24.0, torque_noise=0.05, encoder_counts=4096), dict(delay_drive=0.002)),
    (Limits(V_max=24.0, jitter=2e-5), dict(delay_drive=0.0004)),
    (Limits(V_max=24.0, I_max=5.0, friction={"m": 0.02, "L1": 0.05}), {}),
])
def test_continued_runs_with_the_drive_noise_and_jitter(limits, values):
    y, whole = _split(_loop(**values), limits, 20000.0, 10.0, [0.06, 0.15])
    assert np.array_equal(y, whole)


def test_the_vm_loop_continues_like_the_c_loop():
    # the VM's delay line and level come back in the C layout: the two loops continue each other
    loop, vm = _loop(tau_drive=0.002, delay_drive=0.0023), _loop("vm", tau_drive=0.002, delay_drive=0.0023)
    s1, s2 = (batch_setup(loop, BENCH, "disturbance-step", None, T, 0, 1e-6, 0.02) for T in (0.02, 0.04))
    y1, _i, end = _run(vm, s1, 20000.0, 10.0)
    start = Continuation(y1.shape[0], *end, 0, np.zeros((0, y1.shape[1])), np.zeros(0, int), 0.0)
    y2, _i, _e = _run(loop, s2, 20000.0, 10.0, start=start)
    whole, _i, _e = _run(loop, s2, 20000.0, 10.0)
    err = np.abs(np.concatenate([y1, y2]) - whole).max(axis=0) / np.maximum(np.abs(whole).max(axis=0), 1e-300)
    assert err.max() <= 1e-12


@pytest.mark.parametrize("limits", [Limits(V_max=24.0), BENCH])
def test_batch_summaries_of_a_continued_run_are_the_whole_runs(limits):
    """simulate_batch continued 0.3 -> 0.9 s (as the map's 1 -> 3 s: the tail the verdict reads lies
    in the continuation) and 0.3 -> 0.9 -> 1.2 s (a capped length: its tail reaches back into the
    kept rows) equals the run from 0; beta = 3 makes P 20000, D 10 and D 1 limit cycles of the
    supply (with the rotor friction they decay)."""
    loop = _loop(beta=3.0)
    kw = dict(limits=limits, linear_stable=np.nan, scale_duration=0.3, seed=0)
    for lengths in ([0.3, 0.9], [0.3, 0.9, 1.2]):
        b = simulate_batch(loop, P, D, duration=lengths[0], continue_to=lengths[1], **kw)
        for T, nxt in zip(lengths[1:], lengths[2:] + [lengths[-1]]):
            b = simulate_batch(loop, P, D, duration=T, start=b.continuations, continue_to=nxt, **kw)
        ref = simulate_batch(loop, P, D, duration=lengths[-1], **kw)
        for f in ("status", "oscillation"):
            assert list(getattr(b, f)) == list(getattr(ref, f)), f
        for f in ("cycle_amplitude", "cycle_frequency", "tail_saturation", "saturation_time", "final_theta",
                  "growth"):
            np.testing.assert_array_equal(getattr(b, f), getattr(ref, f), err_msg=f)
        if not limits.friction:                          # a cycle's amplitude and frequency compared
            assert list(ref.status[:2]) == ["limit cycle"] * 2 and np.isfinite(ref.cycle_frequency[:2]).all()
            assert (ref.tail_saturation[:2] > 0.1).all()
        c = b.continuations[0]
        n = int(round(lengths[-1] / loop.params.controller.Ts)) + 1
        assert c.keep_from == keep_from(loop.params.controller.Ts, n) and c.rows.shape[0] == n - c.keep_from
        if len(lengths) == 3 and not limits.friction:    # the saturation before the kept rows counted
            assert c.saturated_head.size and ref.saturation_time[0] > 0


def test_what_cannot_be_continued_is_refused():
    loop = _loop()
    for lim, exp in ((BENCH, "chirp"), (Limits(torque_noise=0.01, jitter=1e-5), "disturbance-step")):
        with pytest.raises(ParameterError, match="cannot be continued"):
            simulate_batch(loop, [100.0], [5.0], limits=lim, experiment=exp, duration=0.05, continue_to=0.1,
                           linear_stable=np.nan)
