"""Stability decisions and frequency responses from Ts = 10 us to 8 ms (issue 7, point 1).

The monomial coefficients of chi(z) lose the poles that crowd at z = 1 as Ts shrinks (the
old Schur-Cohn evaluator decided 58 % of a nominal map wrongly at Ts = 100 us). The generated
test now works on the exact bilinear transform of chi. Reference: numpy eigenvalues and
state-space frequency responses of the explicit closed loop (haa_sym.check.reference), which share
only the ZOH-discretised plant with the evaluators.
"""
import itertools

import numpy as np
import pytest

from haa_sym import ClosedLoop, LoopOptions
from haa_sym.check import reference as ref
from haa_sym.cli import main

from conftest import decisions_against_reference

TSS = (10e-6, 20e-6, 50e-6, 100e-6, 150e-6, 500e-6, 1e-3, 8e-3)
N_AVS = (1, 4, 10, 50)
POINTS = 24   # per case: 8 Ts x 4 N_av x 2 delays x 2 legs x 24 = 3,072 points

def _points(rng, n):
    return np.stack([10 ** rng.uniform(0, np.log10(50000), n), rng.uniform(0, 60, n),
                     rng.uniform(0.3, 8, n), rng.uniform(0, 1.2, n)])

@pytest.fixture(scope="module")
def cases(params):
    rng = np.random.default_rng(7)
    out = []
    for Ts, N_av, delay, cfg in itertools.product(TSS, N_AVS, (0, 1), ("extended", "retracted")):
        loop = ClosedLoop(params.configuration(cfg).with_values(Ts=Ts, N_av=N_av), LoopOptions(delay=delay))
        pts = _points(rng, POINTS)
        eig = np.abs(ref.closed_loop_eigenvalues(loop, pts))
        out.append((loop, pts, eig))
    return out

def test_generated_decision_agrees_with_eigvals_at_every_sampling_time(cases):
    bad, decided, unstable, wrong_count = [], 0, 0, 0
    for loop, pts, eig in cases:
        c = decisions_against_reference(loop, pts, 1e-6, eig=eig, certified=False)    # the generated test alone
        decided += c["decided"]
        unstable += c["unstable"]
        bad += [(loop.params.controller.Ts, loop.params.controller.N_av, loop.options.delay, pts[:, i], c["rho"][i])
                for i in c["bad"]]
        # the Routh count is the number of poles outside the circle, not only a yes/no
        wrong_count += c["count_disagree"]
    assert not bad, bad[:5]
    assert wrong_count == 0, wrong_count
    assert decided > 0.98 * len(cases) * POINTS
    assert 0.05 * decided < unstable < 0.95 * decided      # both answers occur

def test_issue_example_at_100_us(capsys):
    # was "stable: False, radius 1.001996"; eigenvalues give 0.999342
    assert main(["stability", "--P-gain", "200", "--D-gain", "10", "--set", "Ts=1e-4"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("stable: True") and "0.99934" in out

@pytest.mark.parametrize("Ts,N_av", [(1e-4, 4), (1e-3, 50), (1e-5, 10)])
def test_certificate_flags_the_boundary_and_refines_it(params, Ts, N_av):
    """Bisect P_gain to the boundary of the generated decision (D_gain = 1): the two adjacent
    doubles straddling it cannot both be certified, and the returned decisions agree with the
    eigenvalues wherever the radius is resolvable (|rho - 1| > 1e-12)."""
    loop = ClosedLoop(params.with_values(Ts=Ts, N_av=N_av))
    P = np.logspace(0, 5, 200)
    st = loop.stability(P, 1.0, certify=False).stable
    i = np.flatnonzero(st[:-1] != st[1:])[0]
    lo, hi = P[i], P[i + 1]
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        if loop.stability(mid, 1.0, certify=False).stable == st[i]:
            lo = mid
        else:
            hi = mid
    assert np.nextafter(lo, hi) == hi
    res = loop.stability([lo, hi], 1.0, radius=True)
    assert res.refined.any()
    line = lo * (1 + np.linspace(-1e-6, 1e-6, 21))
    res = loop.stability(line, 1.0, radius=True)
    rho = res.spectral_radius
    resolvable = np.abs(rho - 1) > 1e-12
    np.testing.assert_array_equal(res.stable[resolvable], (rho < 1)[resolvable])
    assert res.refined.sum() <= 3        # the certificate is not vacuous

def test_frequency_responses_at_fast_sampling(cases):
    worst = 0.0
    for loop, pts, eig in cases[::9]:
        Ts = loop.params.controller.Ts
        w = np.logspace(-1, np.log10(np.pi / Ts * 0.999), 30)
        fr = loop.frequency_response(w, *pts[:, :2])
        for i in range(2):
            for key, val in ref.frequency_response(loop, w, *pts[:, i]).items():
                err = np.abs(fr[key][i] - val)
                rel = err / np.maximum(np.abs(val), 1e-300)
                assert ((rel <= 1e-8) | (err <= 1e-12)).all(), (key, Ts, loop.params.controller.N_av, rel.max())
                worst = max(worst, float(rel[err > 1e-12].max(initial=0)))

    assert worst < 1e-8    # measured 6e-10
