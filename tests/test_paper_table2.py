"""Table 2 cell by cell and the quantitative claims of Sec. 5, computed with the default options.

The expected statuses come from the paper (model/paper.toml). KNOWN_DIFFERENCES lists the cells
our model does not reproduce, with the status it computes and why; the test fails if a listed cell
starts agreeing (update the list and the report) or any other cell disagrees.
"""
import numpy as np
import pytest

from haa_sym import ClosedLoop, LoopOptions
from haa_sym.analysis.contact import contact_stability, intervals
from haa_sym.paper import paper_spec
from haa_sym.analysis.passivity import bands_beyond, corrected_phase
from haa_sym.io.gridspec import grid
from haa_sym.paper.table2 import score_options, table2
from haa_sym.analysis.torque import step_response

KNOWN_DIFFERENCES = {
    # The 50-sample average lags the D term by w N_av Ts/2 ~ 32 deg at the 22 rad/s where Z's
    # phase peaks (+13 deg beyond 90): the D term cannot restore passivity. The paper does not
    # say where its filter sits; see results/REPORT.md.
    ("N_av = 50", "P_gain = 200, D_gain = 10"): "No",
}


@pytest.fixture(scope="module")
def cells(params):
    return table2(params)


def test_table2_cell_by_cell(cells):
    assert len(cells) == 45
    for c in cells:
        expected = KNOWN_DIFFERENCES.get((c.row, c.column), c.paper)
        assert c.status == expected, (c.row, c.column, c.status, c.paper, c.phase_excess_deg)
        if c.status == "No":
            assert c.phase_excess_deg > LoopOptions().passivity_tol_deg
        if c.status == "Unstable":
            assert np.isnan(c.phase_excess_deg)


@pytest.mark.slow                     # Table 2 for every option combination (~5 s)
def test_defaults_are_best_option_combination(params, cells):
    scores = score_options(params)
    best = scores[0][1]
    assert sum(c.agrees for c in cells) == best
    defaults = LoopOptions().resolved(params.plant.topology)
    top = [combo for combo, n, _, _ in scores if n == best]
    assert {k: getattr(defaults, k) for k in top[0]} in top


def test_z_band_torque_loop(params):
    """Sec. 5 / Fig. 12: the phase of Z exceeds 90 deg 'between 10 and 50 rad/s' for the torque
    loop alone and stays within +-90 deg with the impedance loop closed (P 200, D 10)."""
    claim = paper_spec()["claims"]
    loop = ClosedLoop(params)
    w = np.logspace(-1, np.log10(np.pi / params.controller.Ts * (1 - 1e-9)), 8000)
    bands = bands_beyond(*corrected_phase(loop, 0, 0, omega=w))
    assert len(bands) == 1
    (lo, hi), (plo, phi) = bands[0], claim["z_band_rad_s"]
    # "about 10-50": our edges are 11.6 and 59.2 rad/s; within 25 % of the paper's
    assert abs(lo / plo - 1) < 0.25 and abs(hi / phi - 1) < 0.25
    assert bands_beyond(*corrected_phase(loop, *claim["fig12_gains"], omega=w)) == []


def test_contact_stiffness_range(params):
    claim = paper_spec()["claims"]
    K = grid("log:10:30000:120")
    stable, _ = contact_stability(ClosedLoop(params), K, progress=False)
    (lo, hi), = intervals(K, ~stable)
    plo, phi = claim["contact_unstable_K_L2"]
    # paper: 72-3500 Nm/rad; exact ends 71.84-3441.6 (tests/test_analysis_contact.py); grid step here is 7 %
    assert abs(lo / plo - 1) < 0.1 and abs(hi / phi - 1) < 0.1


def test_beta_threshold(params):
    bt = paper_spec()["claims"]["beta_threshold"]
    loop = ClosedLoop(params)
    assert loop.stability(bt["P_gain"], bt["D_gain"], bt["stable_at"]).stable
    betas = np.linspace(bt["unstable_from"], 8, 50)
    assert not loop.stability(bt["P_gain"], bt["D_gain"], betas).stable.any()


def test_velocity_compensation_speeds_up_torque_step(params):
    for K in (0.0, 11.2):
        p = params.with_values(K_L2=K)
        on = step_response(ClosedLoop(p), duration=0.3, alpha=0.94)
        off = step_response(ClosedLoop(p), duration=0.3, alpha=0.0)
        assert on.rise_time < 0.05
        assert np.isnan(off.rise_time) or off.rise_time > 3 * on.rise_time
        assert on.T[-1] > off.T[-1]


def test_table2_statuses_do_not_depend_on_the_frequency_grid(params, cells):
    """Z(z) sampled 16x finer and from 0.01 rad/s: every status unchanged, excesses within 0.5 deg
    (the largest change, Ts = 4 ms at P 20000 / D 50, is a sharp peak: 19.48 -> 19.97 deg)."""
    fine = table2(params, LoopOptions(n_omega=16000, omega_min=0.01))
    for a, b in zip(cells, fine):
        assert a.status == b.status, (a.row, a.column)
        if a.status == "No":
            assert abs(a.phase_excess_deg - b.phase_excess_deg) < 0.5
