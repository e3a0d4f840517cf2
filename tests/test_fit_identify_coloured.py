"""haa_sym.fit.identify with COLOURED sensor noise (issue 23, items 4 and 5): logs from the
independent simulation of tests/identify_coloured.py (hand-written equations, composed fine ZOH
sub-steps, AR(1) noise of lag-1 correlation 0.9 at 1 % of each output's spread). The residuals are
reported as not white, and ``ci95`` (the sandwich / HAC interval) covers the truth where the white-
noise Gauss-Newton interval (``ci95_white``) does not."""
import numpy as np
import pytest
import scipy.signal

from haa_sym.fit.identify import Experiment, FitOptions, identify
from haa_sym.io.logs import Log
from haa_sym.model.params import actuator_path, load_params

from identify_coloured import coloured_experiment
from identify_synthetic import HD_TRUTH, experiment, two_mass

START_FACTORS = (1.25, 0.8, 1.2, 0.7)          # every key 20-30 % off, as tests/test_fit_identify.py
OUTPUTS = ("torque", "theta")


def _fit(params, u, y, name="hd.csv", factors=START_FACTORS):
    log = Log(name, 1e-3, {"voltage": u, **{o: y[:, i] for i, o in enumerate(OUTPUTS)}}, {}, "0" * 64)
    start = params.with_values(**{k: v * f for (k, v), f in zip(HD_TRUTH.items(), factors)})
    return identify([Experiment(log, start)], tuple(HD_TRUTH), ("voltage",), OUTPUTS)


def test_generator_without_lag_or_delay_is_the_plain_zoh():
    """The sub-step composition against identify_synthetic's cont2discrete + dlsim (same input)."""
    p = load_params(actuator_path("harmonic_drive")).plant.as_dict()
    _, u0, _, y0 = experiment(two_mass, p, seed=2, duration=1.0)
    _, u1, _, y1 = coloured_experiment(two_mass, p, seed=2, duration=1.0)
    assert np.array_equal(u0, u1)
    assert np.allclose(y1, y0, rtol=0, atol=1e-9 * np.abs(y0).max())


def test_generator_fractional_delay_and_lag_against_a_fine_loop():
    """A delay of 2.3 samples and a drive lag against a plain loop over 1/40-sample steps."""
    p = load_params(actuator_path("harmonic_drive")).plant.as_dict()
    Ts, M, tau, delay = 1e-3, 40, 3e-3, 2.3e-3
    _, u, _, y = coloured_experiment(two_mass, p, seed=1, duration=0.2, current=True, tau_drive=tau,
                                     delay_drive=delay, outputs=("torque",))
    A, B, C, _ = two_mass(p, current=True)
    h = Ts / M
    Ad, Bd, *_ = scipy.signal.cont2discrete((A, B[:, :1], C, np.zeros((3, 1))), h, "zoh")
    lag = np.exp(-h / tau)
    x, q, out = np.zeros(len(A)), 0.0, []
    for j in range(len(u) * M):
        if j % M == 0:
            out.append(C[0] @ x)
        k = int(np.floor((j * h - delay) / Ts + 1e-9))       # the command in effect on this sub-step
        c = u[k] if k >= 0 else 0.0
        # the lag's state is exact per sub-step; the plant sees it held over the sub-step (its
        # mean over the step, to second order): the two agree to O(h^2)
        q_new = lag * q + (1 - lag) * c
        x = Ad @ x + Bd[:, 0] * (q + q_new) / 2
        q = q_new
    assert np.max(np.abs(np.array(out) - y[:, 0])) < 2e-3 * np.max(np.abs(y))


def test_ar1_noise_is_reported_and_widens_the_intervals():
    params = load_params(actuator_path("harmonic_drive"))
    _, u, y, _ = coloured_experiment(two_mass, params.plant.as_dict(), seed=5, duration=8.0, rho=0.9)
    r = _fit(params, u, y)
    white = np.array(r.meta["intervals"]["ci95_white"])
    for i, k in enumerate(r.keys):
        lo, hi = r.ci95[i]
        assert lo <= HD_TRUTH[k] <= hi and abs(r.value[i] / HD_TRUTH[k] - 1) < 0.03, (k, r.value[i], lo, hi)
        # the sandwich's spread against Gauss-Newton's, in log p (measured over 20 noise seeds of a
        # 25 s log: 1.8-2.1 J_link, 2.9-3.5 B_link, 1.6-2.0 K_hd, 1.2-1.5 D_hd)
        assert np.log(hi / lo) > 1.15 * np.log(white[i, 1] / white[i, 0]), (k, r.ci95[i], white[i])
    for o, w in r.meta["residuals"]["hd.csv"].items():
        assert not w["white"] and abs(w["lag1"] - 0.9) < 0.03 and w["p_value"] < 1e-6, (o, w)
    assert set(r.report()["parameters"]["K_hd"]) == {"value", "initial", "ci95", "ci95_white"}
    assert "HAC" in r.report()["ci95_method"]


def test_white_noise_is_reported_white_and_the_intervals_agree():
    """White sensor noise: white residuals (a test at the 5 % level: over seeds 0-9 of these 8 s
    logs one output of 20 came out p < 0.05, seed 5's torque, p 0.011) and the sandwich equal to
    Gauss-Newton's up to its estimation noise (ratios 0.95-1.03 over those seeds)."""
    params = load_params(actuator_path("harmonic_drive"))
    _, u, y, _ = experiment(two_mass, params.plant.as_dict(), seed=0, duration=8.0)
    r = _fit(params, u, y)
    white = np.array(r.meta["intervals"]["ci95_white"])
    for o, w in r.meta["residuals"]["hd.csv"].items():
        assert w["white"] and abs(w["lag1"]) < 0.05, (o, w)
    ratio = np.log(r.ci95[:, 1] / r.ci95[:, 0]) / np.log(white[:, 1] / white[:, 0])
    assert np.all(np.abs(ratio - 1) < 0.1), ratio


@pytest.mark.slow
def test_20_noise_seeds_within_3_percent_and_hac_covers_18():
    """One 25 s run of the harmonic drive, 20 realisations of the AR(1) noise (the coverage of an
    interval is a statement over the noise for a given experiment). Measured: ci95 (HAC) covered the
    truth in 19, 19, 20, 19 of 20 (J_link, B_link, K_hd, D_hd), the white-noise ci95_white in 13, 7,
    18, 18; worst errors 0.05, 1.83, 0.03, 0.04 %. Started 5 % off (the same counts and values as
    from 20-30 % off, which test_ar1_noise_is_reported_and_widens_the_intervals covers, in 2/3 of
    the time)."""
    params = load_params(actuator_path("harmonic_drive"))
    _, u, ys, _ = coloured_experiment(two_mass, params.plant.as_dict(), seed=0, duration=25.0, rho=0.9,
                                      noise_seeds=range(100, 120))
    new, old = {k: 0 for k in HD_TRUTH}, {k: 0 for k in HD_TRUTH}
    for y in ys:
        r = _fit(params, u, y, factors=(1.05, 0.95, 1.05, 0.95))
        white = r.meta["intervals"]["ci95_white"]
        for i, k in enumerate(r.keys):
            assert abs(r.value[i] / HD_TRUTH[k] - 1) < 0.03, (k, r.value[i])
            new[k] += bool(r.ci95[i, 0] <= HD_TRUTH[k] <= r.ci95[i, 1])
            old[k] += bool(white[i][0] <= HD_TRUTH[k] <= white[i][1])
    assert all(n >= 18 for n in new.values()), (new, old)
    # the same logs under the white-noise interval: the test has the power to tell them apart
    assert min(old.values()) < 18, (new, old)


# the coverage check with the drive's lag, a fractional delay and Coulomb friction (issue 23):
# the harmonic drive current-driven, its rotor friction at 0.05 Nm (v_s 0.05 rad/s), the lag 3 ms,
# the delay 1.25 samples
FR_TRUTH = {"K_hd": 3.1e4, "J_link": 0.3497, "tau_drive": 3e-3, "delay_drive": 1.25e-3, "Fc_m": 0.05}
FR_VS = 0.05


def test_friction_generator_without_friction_is_the_linear_generator():
    """The friction generator's own integration (Fc = 0) against coloured_experiment's composed
    sub-steps, with the lag and the fractional delay (same input)."""
    from identify_coloured import friction_experiment
    p = load_params(actuator_path("harmonic_drive")).plant.as_dict()
    kw = dict(seed=4, duration=0.4, tau_drive=3e-3, delay_drive=1.25e-3)
    _, u0, _, y0 = coloured_experiment(two_mass, p, current=True, amplitude=5.0, **kw)
    _, u1, _, y1 = friction_experiment(two_mass, p, Fc=0.0, v_s=FR_VS, **kw)
    assert np.array_equal(u0, u1)
    assert np.allclose(y1, y0, rtol=0, atol=1e-9 * np.abs(y0).max())


@pytest.mark.slow
def test_lag_delay_friction_within_3_percent_and_hac_covers_18_of_20():
    """20 AR(1) noise seeds (lag-1 0.9, 1 %) on one 3 s run with a drive lag, a fractional delay and
    Coulomb friction from tests/identify_coloured.friction_experiment (its own explicit-friction
    integration on 12.5 us sub-steps, not haa_sym.fit.friction; the command from 0, as identify
    holds it before the log): K_hd, J_link, tau_drive, delay_drive, Fc_m started 20-25 % off, at
    the default max_substep (chosen per fit: 0.125 ms here), every key within 3 % and ci95 (HAC)
    covering the truth in >= 18 of 20 for every key (the issue's criterion). Measured
    (docs/identify.md): HAC 19, 20, 19, 20, 20 (ci95_white 7, 8, 8, 12, 9), worst error 0.35 %. 3 s
    (min_periods 1: the link's slowest mode is 2.8 s) so that the 20 fits take about 16 s; the 9 s
    run's numbers are in the docs."""
    import dataclasses
    from identify_coloured import friction_experiment
    P = load_params(actuator_path("harmonic_drive"))
    p = P.plant.as_dict()
    _, u, ys, _ = friction_experiment(two_mass, p, Fc=FR_TRUTH["Fc_m"], v_s=FR_VS, tau_drive=FR_TRUTH["tau_drive"],
                                      delay_drive=FR_TRUTH["delay_drive"], duration=3.0, noise_seeds=range(20),
                                      substeps=80, from_zero=True)
    start = dataclasses.replace(P, limits=dataclasses.replace(P.limits, friction={"m": 0.75 * FR_TRUTH["Fc_m"]},
                                                              friction_velocity=FR_VS),
                                drive=P.drive.replace(tau_drive=1.2 * FR_TRUTH["tau_drive"],
                                                      delay_drive=0.8 * FR_TRUTH["delay_drive"]))
    start = start.with_values(K_hd=1.2 * FR_TRUTH["K_hd"], J_link=0.8 * FR_TRUTH["J_link"])
    keys = tuple(FR_TRUTH)
    covered = dict.fromkeys(keys, 0)
    for s, y in enumerate(ys):
        log = Log(f"s{s}.csv", 1e-3, {"current": u, "torque": y[:, 0], "theta": y[:, 1]}, {}, "0" * 64)
        r = identify([Experiment(log, start)], keys, ("current",), OUTPUTS, FitOptions(min_periods=1))
        for k, v, (lo, hi) in zip(r.keys, r.value, r.ci95):
            assert abs(v / FR_TRUTH[k] - 1) < 0.03, (s, k, v)
            covered[k] += lo <= FR_TRUTH[k] <= hi
    assert min(covered.values()) >= 18, covered
