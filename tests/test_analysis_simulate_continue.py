"""A run continued from the state where a shorter one stopped is the run from t = 0 (issue 27;
docs/simulate.md, "Nonlinear maps"): the C loop's state (plant, controller, the drive's delay
line, the friction integrator's level) goes out and back in, the inputs are those of the longer
run from the continuation's sample on, and the friction error scale is the first run's; the
trajectory is the same to the bit, and so are the summaries read from the tail it keeps."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.simulate import (Continuation, _run, batch_setup, continuable, keep_from,
                                       simulate_batch)
from haa_sym.compiled import layout as L
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
    # the jitter's own stream: its draws up to a sample do not depend on the noise's n (issue 27)
    (Limits(V_max=24.0, torque_noise=0.05, jitter=2e-5), dict(delay_drive=0.0004)),
    (Limits(V_max=24.0, I_max=5.0, friction={"m": 0.02, "L1": 0.05}), {}),
])
def test_continued_runs_with_the_drive_noise_and_jitter(limits, values):
    y, whole = _split(_loop(**values), limits, 20000.0, 10.0, [0.06, 0.15])
    assert np.array_equal(y, whole)


def test_the_noise_and_the_jitter_draw_from_their_own_seeded_streams():
    """docs/simulate.md, "The sampled-data model": the noise from ``default_rng(seed)`` (its draws
    as before issue 27), the jitter from the seed's first spawned ``SeedSequence``; neither depends
    on the other being on, nor on the run's length."""
    loop, seed, n = _loop(), 3, 51
    Ts = loop.params.controller.Ts

    def setup(lim, T=(n - 1) * Ts):
        return batch_setup(loop, lim, "disturbance-step", None, T, seed, 1e-6)

    sigma, q = 1e-5, 0.01
    both, noise, jitter = setup(Limits(torque_noise=q, jitter=sigma)), setup(Limits(torque_noise=q)), \
        setup(Limits(jitter=sigma))
    i = L.SIM_EXO.index("noise_T")
    assert np.array_equal(noise.exo[i], q * np.random.default_rng(seed).standard_normal(n))
    eps = np.clip(sigma * np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0]).standard_normal(n),
                  -3 * sigma, 3 * sigma)
    assert np.array_equal(jitter.time, np.arange(n) * Ts + np.concatenate([[0.0], eps[:-1]]))
    assert np.array_equal(both.exo[i], noise.exo[i]) and np.array_equal(both.time, jitter.time)
    longer = setup(Limits(torque_noise=q, jitter=sigma), 2 * (n - 1) * Ts)
    assert np.array_equal(longer.time[:n], both.time) and np.array_equal(longer.exo[:, :n], both.exo)


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


def test_the_chirp_cannot_be_continued_and_noise_with_jitter_can():
    loop = _loop()
    with pytest.raises(ParameterError, match="cannot be continued"):
        simulate_batch(loop, [100.0], [5.0], limits=BENCH, experiment="chirp", duration=0.05, continue_to=0.1,
                       linear_stable=np.nan)
    noisy = Limits(V_max=24.0, torque_noise=0.05, jitter=2e-5)
    assert continuable(batch_setup(loop, noisy, "disturbance-step", None, 0.05, 0, 1e-6))
    # simulate_batch continued 0.05 -> 0.12 s is the run from 0, summaries and kept columns
    kw = dict(limits=noisy, linear_stable=np.nan, seed=5)
    b = simulate_batch(loop, P, D, duration=0.05, continue_to=0.12, **kw)
    b = simulate_batch(loop, P, D, duration=0.12, start=b.continuations, continue_to=0.12, **kw)
    ref = simulate_batch(loop, P, D, duration=0.12, continue_to=0.12, **kw)
    for f in ("status", "oscillation"):
        assert list(getattr(b, f)) == list(getattr(ref, f)), f
    for f in ("cycle_amplitude", "tail_saturation", "saturation_time", "final_theta", "growth"):
        np.testing.assert_array_equal(getattr(b, f), getattr(ref, f), err_msg=f)
    for c, r in zip(b.continuations, ref.continuations):
        assert c.k == r.k and np.array_equal(c.rows, r.rows) and np.array_equal(c.x, r.x)
