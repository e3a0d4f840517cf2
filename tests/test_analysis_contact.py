"""Contact with an environment spring (Sec. 5, issue 9): interval ends located by root-finding,
checked against the eigenvalues and the frequency response of the independent closed loop
(haa_sym.check.reference) on both sides of every end."""
import json

import numpy as np
import pytest

from haa_sym import ClosedLoop, LoopOptions, ParameterError, load_params
from haa_sym.check import reference as ref
from haa_sym.cli import main
from haa_sym.analysis.contact import contact_intervals
from haa_sym.analysis.sweep import colgate_factor

from conftest import ROOT


def _rho(params, key, K, P=0.0, D=0.0):
    return ref.spectral_radius(ClosedLoop(params.with_values(**{key: K}), basis=False), P, D)


def _ref_excess(params, key, K, P=0.0, D=0.0):
    """Worst corrected phase of Z beyond +-90 deg on the options' frequency grid, from the
    reference closed loop (haa_sym.check.reference: block interconnection, no generated loop
    coefficients): Z = T_dist / port velocity = 1 / (C_p (zI - A)^-1 B_d + D_pd)."""
    A, B, C, Dm = ref.closed_loop_matrices(ClosedLoop(params.with_values(**{key: K}), basis=False), P, D)
    Ts = params.controller.Ts
    w = LoopOptions().omega(Ts)
    z = np.exp(1j * w * Ts)
    X = np.linalg.solve(z[:, None, None] * np.eye(A.shape[0]) - A, np.broadcast_to(B[:, :1], (w.size,) + B[:, :1].shape))
    Z = 1 / (X[..., 0] @ C[2] + Dm[2, 0])
    return float(np.abs(np.degrees(np.angle(Z * colgate_factor(w, Ts, "subtract")))).max() - 90)


TOL = LoopOptions().passivity_tol_deg
# HyQ's torque loop alone is not passive wherever it is stable (its ends are the unstable
# interval's); an impedance with a passivity end inside the range: HyQ at P 1000, D 9 (stiff
# environments make it passive again), and the harmonic drive's torque loop alone
PASSIVITY_CASES = [("hyq_haa", 1000.0, 9.0, (1.0, 1e6), 6.35e5), ("harmonic_drive", 0.0, 0.0, (1.0, 1e5), 5.28e4)]
# the harmonic drive's case is its first torque PI's (before haa-sym tune re-tuned the file: with
# the tuned PI its torque loop alone is not passive anywhere it is stable, so no end to locate)
FIRST_PI = {"harmonic_drive": {"P_t0": 0.01954, "I_t0": 0.9205}}


@pytest.mark.parametrize("name,P,D,K_range,end", PASSIVITY_CASES, ids=[c[0] for c in PASSIVITY_CASES])
def test_not_passive_ends_against_state_space(name, P, D, K_range, end):
    params = load_params(ROOT / "model" / f"{name}.toml").with_values(**FIRST_PI.get(name, {}))
    r = contact_intervals(ClosedLoop(params), K_range, n_scan=40, P_gain=P, D_gain=D, progress=False)
    stability_ends = {k for iv in r.unstable for k in iv}
    passivity_ends = []
    for lo, hi in r.not_passive:
        for K, into in ((lo, 1.0), (hi, -1.0)):
            if K in K_range:
                continue
            if K in stability_ends:
                # a non-passive interval ending where the loop turns unstable
                inside, outside = K * (1 + 1e-9) ** into, K / (1 + 1e-9) ** into
                assert _rho(params, r.key, inside, P, D) < 1 < _rho(params, r.key, outside, P, D), (name, K)
                assert _ref_excess(params, r.key, inside, P, D) > TOL, (name, K)
                continue
            passivity_ends.append(K)
            # 1e-6 relative: the excess is flat there (2.6e-3 deg per unit of ln K on HyQ) and
            # the sampled plant's rounding moves it by up to 1.5e-10 deg (contact_intervals)
            inside, outside = K * (1 + 1e-6) ** into, K / (1 + 1e-6) ** into
            for k in (inside, outside):
                assert _rho(params, r.key, k, P, D) < 1, (name, k)
            assert _ref_excess(params, r.key, inside, P, D) > TOL >= _ref_excess(params, r.key, outside, P, D), (name, K)
    # each case has one end located on the excess itself, where measured (docstring)
    assert len(passivity_ends) == 1 and abs(passivity_ends[0] / end - 1) < 0.01, (name, passivity_ends)
    # the scan's excess is the state space's on its stable points, NaN on the unstable ones
    stable = r.spectral_radius < 1
    assert np.isnan(r.phase_excess_deg[~stable]).all() and not np.isnan(r.phase_excess_deg[stable]).any()
    for i in np.flatnonzero(stable)[::8]:
        assert r.phase_excess_deg[i] == pytest.approx(_ref_excess(params, r.key, r.K_env[i], P, D), abs=1e-6)


def test_passivity_can_be_skipped(params):
    r = contact_intervals(ClosedLoop(params), n_scan=20, passivity=False, progress=False)
    assert r.not_passive is None and r.phase_excess_deg is None and r.unstable


@pytest.mark.parametrize("name", ["hyq_haa", "harmonic_drive"])
def test_interval_ends_are_exact_to_1e9(name):
    params = load_params(ROOT / "model" / f"{name}.toml")
    r = contact_intervals(ClosedLoop(params), (1.0, 1e5), n_scan=60, passivity=False, progress=False)
    assert r.unstable, name
    for lo, hi in r.unstable:
        for K, inside in ((lo, 1 + 1e-9), (hi, 1 - 1e-9)):
            if K in (1.0, 1e5):
                continue
            # just inside the interval the loop is unstable, just outside it is stable
            assert _rho(params, r.key, K * inside) > 1 > _rho(params, r.key, K / inside), (name, K)


def test_hyq_range_against_the_paper(params):
    r = contact_intervals(ClosedLoop(params), n_scan=80, progress=False)
    (lo, hi), = r.unstable
    # the paper: 72-3500 Nm/rad (read off a plot); exact ends 71.84 and 3441.6
    assert abs(lo / 72.0 - 1) < 0.01 and abs(hi / 3500.0 - 1) < 0.03
    # and the torque loop alone is not passive (Sec. 5): at no stable stiffness of the range
    assert r.not_passive == [(1.0, lo), (hi, 1e5)]
    assert np.nanmin(r.phase_excess_deg) > 0.1


def test_add_mode_adds_the_files_stiffness(params):
    replace = contact_intervals(ClosedLoop(params), n_scan=80, passivity=False, progress=False).unstable[0]
    add = contact_intervals(ClosedLoop(params), n_scan=80, mode="add", passivity=False, progress=False).unstable[0]
    np.testing.assert_allclose(np.array(add) + params.plant.K_L2, replace, rtol=1e-9)


@pytest.mark.parametrize("kwargs, message", [
    ({"K_range": (100.0, 10.0)}, "K_range = (100.0, 10.0); allowed: 0 < K_lo < K_hi"),
    ({"mode": "sum"}, "mode = 'sum'; allowed: ['replace', 'add']"),
    ({"n_scan": 1}, "n_scan = 1; allowed: an integer >= 2"),
    ({"P_gain": [1.0, 2.0]}, "P_gain = [1.0, 2.0]; allowed: one value"),
])
def test_bad_contact_input(params, kwargs, message):
    with pytest.raises(ParameterError) as exc:
        contact_intervals(ClosedLoop(params), **kwargs)
    assert message in str(exc.value)


def test_cli_contact_json(tmp_path, capsys, assert_refused):
    out = tmp_path / "c.json"
    assert main(["contact", "--n-scan", "40", "--out", str(out), "--plot", str(tmp_path / "c.png"), "-q"]) == 0
    data = json.loads(out.read_text())
    assert data["mode"] == "replace" and data["stiffness_key"] == "K_L2"
    (lo, hi), = data["unstable_intervals"]
    assert 71 < lo < 73 and 3400 < hi < 3500
    assert data["not_passive_intervals"] == [[1.0, lo], [hi, 1e5]]
    assert data["meta"]["options"]["passivity_tol_deg"] == TOL and data["meta"]["options"]["n_omega"] == 1000
    line = capsys.readouterr().out
    assert "71.837305" in line and f"stable but not passive: 1-{lo:.10g}, {hi:.10g}-100000 Nm/rad" in line
    assert_refused(["contact", "--K-range", "5"], "--K-range '5'; allowed: LO:HI in Nm/rad, 0 < LO < HI")
