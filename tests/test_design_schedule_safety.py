"""The schedule's lookup between grid points (issue 16, item 3): at random off-grid impedances of
a small HyQ schedule, every beta the lookup hands out is stable with a phase margin >= 30 deg
at three leg configurations by the independent reference (eigenvalues of the explicit closed
loop, exact crossovers), the compiled C agrees with the Python twin bit for bit and writes
nothing where there is no safe gain; a range that limits beta is flagged and warned about."""
import csv
import ctypes
import io
import math

import numpy as np
import pytest

from c_build import shared_library
from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.robust import leg_configurations
from haa_sym.check import reference as ref
from haa_sym.check.reference_margins import reference_crossovers
from haa_sym.cli import main
from haa_sym.design.schedule import schedule
from haa_sym.design.schedule_c import NAN, NO_SAFE_GAIN, OK, OUTSIDE, ScheduleTable, lookup, write_c

P_GRID, D_GRID = np.geomspace(5.0, 2000.0, 7), np.linspace(1.0, 50.0, 5)
N_UNIFORM, N_NEAR = 70, 40          # random points: anywhere, and in safe cells next to unsafe ones


@pytest.fixture(scope="module")
def hyq():
    params = load_params()
    s = schedule(ClosedLoop(params), P_GRID, D_GRID, beta_tol=0.05, progress=False)
    return params, s, s.table()


def _meets(params, config, P, D, beta, alpha) -> bool:
    """Stable and no crossover nearer than 30 deg to -1, by the independent reference."""
    loop = ClosedLoop(params.with_values(**config), basis=False)
    if ref.spectral_radius(loop, P, D, beta, alpha) >= 1:
        return False
    (c,) = reference_crossovers(loop, P, D, beta, alpha)
    return c.distance_deg >= 30.0


def _points(s, rng):
    """Random off-grid points: uniform in (log P, D), and inside safe cells that touch a cell
    without a safe gain (where the interpolation used to go wrong)."""
    lp = np.log(s.P_gain)
    P = np.exp(rng.uniform(lp[0], lp[-1], N_UNIFORM))
    D = rng.uniform(s.D_gain[0], s.D_gain[-1], N_UNIFORM)
    safe = s.cell_safe
    near = [(i, j) for i, j in np.argwhere(safe)
            if any(0 <= a < safe.shape[0] and 0 <= b < safe.shape[1] and not safe[a, b]
                   for a in (i - 1, i, i + 1) for b in (j - 1, j, j + 1))]
    assert len(near) >= 3, "the small schedule must have safe cells next to unsafe ones"
    pick = [near[k] for k in rng.integers(0, len(near), N_NEAR)]
    t, u = rng.uniform(0.02, 0.98, (2, N_NEAR))
    P_near = np.array([math.exp(lp[i] + tk * (lp[i + 1] - lp[i])) for (i, _), tk in zip(pick, t)])
    D_near = np.array([s.D_gain[j] + uk * (s.D_gain[j + 1] - s.D_gain[j]) for (_, j), uk in zip(pick, u)])
    return np.concatenate([P, P_near]), np.concatenate([D, D_near])


def test_cells_with_an_infeasible_corner_have_no_safe_gain_and_values_only_fall(hyq):
    _, s, table = hyq
    f = s.feasible
    corners = f[:-1, :-1] & f[1:, :-1] & f[:-1, 1:] & f[1:, 1:]
    assert (~corners).any() and corners.any()
    assert not (s.cell_safe & ~corners).any()
    assert np.all(s.table_beta[f] <= s.beta[f]) and np.all(s.table_beta[f] > 0)
    assert np.isnan(s.table_beta[~f]).all()
    assert np.array_equal(table.cell_safe, s.cell_safe)
    for i, j in np.argwhere(~s.cell_safe):
        P = math.sqrt(s.P_gain[i] * s.P_gain[i + 1])
        D = 0.5 * (s.D_gain[j] + s.D_gain[j + 1])
        assert lookup(table, P, D) == (NO_SAFE_GAIN, None, None)


@pytest.mark.slow
def test_off_grid_betas_are_safe_at_three_leg_configurations(hyq):
    """Every OK answer at >= 100 random off-grid points meets stable + PM >= 30 deg at both leg
    ends and the middle by the independent reference. The same points evaluated with the
    schedule's own per-point answers interpolated over every cell with feasible corners (what
    the lookup did before the cell check) are counted too, to show the points are hard ones."""
    params, s, table = hyq
    rng = np.random.default_rng(16)
    P, D = _points(s, rng)
    configs = leg_configurations(params, 3)
    naive = ScheduleTable(s.P_gain, s.D_gain, s.beta, s.feasible, dict(table.meta))
    n_ok = n_none = n_naive_unsafe = 0
    unsafe = []
    for p, d in zip(P, D):
        status, beta, _ = lookup(table, p, d)
        assert status in (OK, NO_SAFE_GAIN)
        if status == NO_SAFE_GAIN:
            n_none += 1
            continue
        n_ok += 1
        if not all(_meets(params, c, p, d, beta, params.controller.alpha) for c in configs):
            unsafe.append((p, d, beta))
        st_naive, b_naive, _ = lookup(naive, p, d)
        if st_naive == OK and b_naive > beta and not all(
                _meets(params, c, p, d, b_naive, params.controller.alpha) for c in configs):
            n_naive_unsafe += 1
    print(f"\n{len(P)} off-grid points: {n_ok} answered, all checked; {n_none} no safe gain; "
          f"unsafe {len(unsafe)}; without the cell check unsafe {n_naive_unsafe}")
    assert len(P) >= 100 and n_ok >= 80
    assert n_naive_unsafe > 0            # the points find what the cell check repairs
    assert not unsafe, unsafe


@pytest.fixture(scope="module")
def c_lookup(hyq, tmp_path_factory):
    d = tmp_path_factory.mktemp("c")
    write_c(hyq[2], d)
    f = shared_library(d / "haa_schedule.c", d / "libs.so").haa_schedule_lookup
    f.argtypes = [ctypes.c_double, ctypes.c_double, ctypes.POINTER(ctypes.c_double),
                  ctypes.POINTER(ctypes.c_double)]
    f.restype = ctypes.c_int
    return f


def test_c_equals_the_python_twin_off_grid_and_writes_nothing_without_a_safe_gain(hyq, c_lookup):
    _, s, table = hyq
    P, D = _points(s, np.random.default_rng(17))
    P = np.concatenate([P, [1.0, 5000.0, math.nan, 100.0], s.P_gain])          # outside, NaN, grid
    D = np.concatenate([D, [10.0, 60.0, 3.0, math.nan], s.D_gain[:1].repeat(s.P_gain.size)])
    seen = set()
    for p, d in zip(P, D):
        beta, alpha = ctypes.c_double(-7.0), ctypes.c_double(-7.0)      # sentinels
        status = c_lookup(p, d, ctypes.byref(beta), ctypes.byref(alpha))
        py = lookup(table, p, d)
        seen.add(status)
        assert status == py[0]
        assert alpha.value == -7.0                                     # alpha not scheduled
        if status in (NO_SAFE_GAIN, NAN):
            assert beta.value == -7.0
        else:
            assert beta.value == py[1]                                 # bit for bit
    assert seen == {OK, OUTSIDE, NO_SAFE_GAIN, NAN}


def test_a_range_that_limits_beta_is_flagged_and_warned(tmp_path, capsys):
    """HyQ takes beta = 8 at low damping: with the range's top at 2 every feasible point of
    low damping is limited by the range; the CSV flags exactly the rows at the top, one stderr
    line gives their count."""
    out = tmp_path / "s.csv"
    assert main(["schedule", "--P-gain", "log:5:2000:4", "--D-gain", "lin:1:50:3", "--beta-range", "0.1:2",
                 "--beta-tol", "0.05", "--out", str(out), "-q"]) == 0
    err = capsys.readouterr().err
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    flagged = [r for r in rows if r["beta_at_limit"] == "true"]
    assert flagged and all(float(r["beta"]) == pytest.approx(2.0, rel=1e-12) for r in flagged)
    assert all(r["beta_at_limit"] == "false" for r in rows if r["feasible"] == "false"
               or float(r["beta"]) < 2.0 * (1 - 1e-12))
    lines = [line for line in err.splitlines() if "warning" in line]
    assert len(lines) == 1 and f"{len(flagged)} of " in lines[0] and "--beta-range" in lines[0], err
    out2 = tmp_path / "t.csv"                       # the default range's top is not reached there
    assert main(["schedule", "--P-gain", "log:1000:2000:2", "--D-gain", "lin:30:50:2", "--beta-tol", "0.05",
                 "--out", str(out2), "-q"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert all(r["beta_at_limit"] == "false" for r in csv.DictReader(io.StringIO(out2.read_text())))
