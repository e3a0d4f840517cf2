"""Measured stability points (issue 17.3): the CSV reader's one-line refusals, the agreement
counts against an independent computation (explicit closed-loop eigenvalues and the reference
phase margins), and the paper's symbols on the figures."""
import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.measured import agreement
from haa_sym.analysis.regions import region_map
from haa_sym.analysis.robust import robust_region
from haa_sym.check import reference as ref
from haa_sym.check.reference_margins import low_pm_reference
from haa_sym.errors import ParameterError
from haa_sym.io.measured import read_measured
from haa_sym.io.plots import plot_region, plot_robust

# HyQ at beta = 3: well inside the stable region, in the low-PM band, and beyond the stability
# boundary (the map of docs/uncertainty.md), with every outcome claimed at some of them
POINTS = [(50, 30, "stable"), (3000, 45, "stable"), (2000, 1, "stable"), (800, 1, "stable"),
          (800, 1, "unstable"), (20000, 5, "unstable"), (50, 30, "unstable"), (2000, 1, "limit_cycle"),
          (800, 1, "limit_cycle"), (3000, 45, "limit_cycle")]
BETA = 3.0


def _write(tmp_path, text, name="points.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_reads_points_with_extra_columns_and_blank_lines(tmp_path):
    path = _write(tmp_path, "outcome,P_gain,D_gain,note\n\nstable,100,20,first\nlimit_cycle,1e3,5,\"a, b\"\n")
    m = read_measured(path)
    np.testing.assert_array_equal(m.P_gain, [100.0, 1000.0])
    np.testing.assert_array_equal(m.D_gain, [20.0, 5.0])
    assert m.outcome.tolist() == ["stable", "limit_cycle"] and m.source == str(path)


@pytest.mark.parametrize("text, msg", [
    ("P_gain,D_gain\n1,2\n", "line 1: header ['P_gain', 'D_gain'] lacks ['outcome']"),
    ("P_gain,D_gain,outcome\n1,2,stabel\n", "line 2: outcome = 'stabel'; allowed: one of"),
    ("P_gain,D_gain,outcome\n1,2,stable\n-1,2,stable\n", "line 3: P_gain = '-1'; allowed: a finite number >= 0"),
    ("P_gain,D_gain,outcome\n1,nan,stable\n", "line 2: D_gain = 'nan'"),
    ("P_gain,D_gain,outcome\n1,2\n", "line 2: 2 fields, the header has 3"),
    ("P_gain,D_gain,outcome\n", "no rows"),
    ("", "no header"),
    ("P_gain,D_gain,outcome\n\"1\n2\",2,stable\n", "P_gain = '1\\n2'"),
])
def test_bad_files_are_one_line(tmp_path, text, msg):
    with pytest.raises(ParameterError) as e:
        read_measured(_write(tmp_path, text))
    assert msg in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(ParameterError, match="no such file"):
        read_measured(tmp_path / "missing.csv")


def _independent(loop, P, D, outcome):
    """The agreement rule written out again, on the reference closed loop and margins."""
    pts = np.stack([P, D, np.full(P.size, BETA), np.full(P.size, loop.params.controller.alpha)])
    rho = np.abs(ref.closed_loop_eigenvalues(loop, pts)).max(axis=1)
    assert np.all(np.abs(rho - 1) > 1e-6)
    stable = rho < 1
    low = np.zeros(P.size, bool)
    if stable.any():
        lp = low_pm_reference(loop.params, loop.options, P[stable], D[stable], BETA)
        assert not lp.near.any()
        low[stable] = lp.low
    return np.array([s if o == "stable" else (not s) if o == "unstable" else (not s) or lw
                     for o, s, lw in zip(outcome, stable, low)]), stable, low


def test_agreement_counts_equal_an_independent_count():
    loop = ClosedLoop(load_params().with_values(beta=BETA))
    P, D, out = (np.array(x) for x in zip(*POINTS))
    P, D = P.astype(float), D.astype(float)
    a = agreement(loop, P, D, out)
    expect, stable, low = _independent(loop, P, D, out)
    assert stable.any() and (~stable).any() and (stable & low).any()   # every verdict occurs
    assert expect.any() and (~expect).any()
    np.testing.assert_array_equal(a.agrees, expect)
    np.testing.assert_array_equal(a.agrees_all, expect)
    assert a.counts["points"] == P.size and a.counts["agree"] == int(expect.sum()) == a.counts["agree_all"]
    for o in ("stable", "unstable", "limit_cycle"):
        sel = out == o
        assert a.counts[o] == {"points": int(sel.sum()), "agree": int(expect[sel].sum()),
                               "agree_all": int(expect[sel].sum())}


def test_agreement_over_configurations_is_some_and_every():
    p = load_params().with_values(beta=BETA)
    P, D, out = (np.array(x) for x in zip(*POINTS))
    P, D = P.astype(float), D.astype(float)
    configs = [{"J_L2": 0.129, "K_L2": 7.17}, {"J_L2": 0.439, "K_L2": 11.2}]
    a = agreement(ClosedLoop(p), P, D, out, configurations=configs)
    each = [_independent(ClosedLoop(p.with_values(**c)), P, D, out)[0] for c in configs]
    np.testing.assert_array_equal(a.agrees, each[0] | each[1])
    np.testing.assert_array_equal(a.agrees_all, each[0] & each[1])
    assert a.counts["configurations"] == 2
    with pytest.raises(ParameterError, match="outcome 'oscillating'; allowed"):
        agreement(ClosedLoop(p), [1.0], [1.0], ["oscillating"])


def test_figures_draw_the_papers_symbols():
    loop = ClosedLoop(load_params().with_values(beta=BETA))
    P, D = np.geomspace(10, 5000, 8), np.linspace(1, 50, 6)
    m = region_map(loop, P, D, progress=False)
    drawn = {"P_gain": np.array([100.0, 1000.0, 3000.0, 1e6]), "D_gain": np.array([20.0, 5.0, 3.0, 5.0]),
             "outcome": np.array(["stable", "unstable", "limit_cycle", "stable"]),
             "agrees": np.array([True, False, True, True])}
    fig = plot_region(m, measured=drawn)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert {"stable (measured, square)", "unstable (measured, cross)", "limit cycle (measured, triangle)",
            "agrees with the model (marker colour)", "disagrees with the model (marker colour)"} <= set(labels)
    lines = [ln for ln in fig.axes[0].get_lines() if ln.get_marker() in ("s", "x", "^")]
    # three points inside the axes (the one at P_gain 1e6 is outside: not drawn)
    assert sorted((ln.get_marker(), ln.get_markeredgecolor()) for ln in lines) == \
        [("^", "#0060ff"), ("s", "#0060ff"), ("x", "#e00000")]
    r = robust_region(loop, P, D, max_per_axis=2)
    fig = plot_robust(r, measured=drawn)
    assert "cross" in " ".join(t.get_text() for t in fig.legends[0].get_texts())


def test_agreement_takes_the_loop_first():
    with pytest.raises(ParameterError, match="ClosedLoop"):
        agreement(load_params(), [1.0], [1.0], ["stable"])
