"""The torque-gain scheduler and robust regions (issue 10): the schedule's feasible rows are
stable with PM >= 30 deg at both leg ends and in between by an independent computation (the
explicit closed loop's eigenvalues and state-space frequency response), beta 10 % higher fails
for at least one of them; the CSV, the embedded C, the dask cluster and bad input."""
import csv
import ctypes
import io

import numpy as np
import pytest

from c_build import shared_library
from haa_sym import ClosedLoop, load_params
from haa_sym.check import reference as ref
from haa_sym.cli import main

from haa_sym.analysis.robust import leg_configurations
from haa_sym.design.schedule import CSV_COLUMNS, schedule

from haa_sym.check.reference_margins import reference_crossovers

from conftest import ROOT

P_SMALL, D_SMALL = np.geomspace(5.0, 2000.0, 6), np.linspace(1.0, 50.0, 5)


@pytest.fixture(scope="module")
def hyq_schedule():
    return schedule(ClosedLoop(load_params()), P_SMALL, D_SMALL, beta_tol=0.05, progress=False)


def _meets(params, config, P, D, beta, alpha) -> bool:
    """Stable with no crossover nearer than 30 deg to -1, independently: eigenvalues of the
    explicit closed loop and the exact crossovers of the independent reference."""
    p = params.with_values(**config)
    loop = ClosedLoop(p, basis=False)
    if ref.spectral_radius(loop, P, D, beta, alpha) >= 1:
        return False
    (c,) = reference_crossovers(loop, P, D, beta, alpha)
    return c.distance_deg >= 30.0


def test_feasible_rows_hold_at_every_leg_configuration_and_10_percent_more_fails(hyq_schedule):
    s = hyq_schedule
    params = load_params()
    assert s.converged and s.feasible.any() and not s.feasible.all()
    checks = leg_configurations(params, 5)              # both ends, the middle, the quarters
    rng = np.random.default_rng(3)
    feas = np.argwhere(s.feasible)
    below_top = [(i, j) for i, j in feas if s.beta[i, j] * 1.1 < s.meta["beta_range"][1]]
    assert below_top
    for i, j in [feas[k] for k in rng.choice(len(feas), 4, replace=False)] + \
            [below_top[k] for k in rng.choice(len(below_top), min(4, len(below_top)), replace=False)]:
        P, D, beta, alpha = s.P_gain[i], s.D_gain[j], s.beta[i, j], s.alpha[i, j]
        assert all(_meets(params, c, P, D, beta, alpha) for c in checks), (P, D, beta)
        if beta * 1.1 < s.meta["beta_range"][1]:
            assert not all(_meets(params, c, P, D, beta * 1.1, alpha) for c in checks), (P, D, beta)


def test_infeasible_points_have_no_robust_beta_on_the_coarse_grid(hyq_schedule):
    """Where the schedule finds nothing, even the smallest beta of the range fails at some leg."""
    s = hyq_schedule
    params = load_params()
    assert (~s.feasible).any()
    for i, j in np.argwhere(~s.feasible)[:3]:
        lo = s.meta["beta_range"][0]
        assert not all(_meets(params, c, s.P_gain[i], s.D_gain[j], lo, params.controller.alpha)
                       for c in leg_configurations(params, 2))


def test_csv_holds_the_cell_checked_table_export_ros2_emits_its_c(hyq_schedule, tmp_path, capsys):
    """The CSV of a run whose cell check lowered corner values and gave up cells: table_from_csv is
    Schedule.table() exactly, and export-ros2 --schedule writes the C of schedule --c-out (the
    header's source entry apart), without the unchecked-table warning."""
    from haa_sym.design.schedule import table_from_csv
    from haa_sym.design.schedule_c import write_c
    from test_robot_ros2_schedule import MAP, _source
    s = hyq_schedule
    f = s.feasible
    corners = f[:-1, :-1] & f[1:, :-1] & f[:-1, 1:] & f[1:, 1:]
    assert (s.table_beta[f] < s.beta[f]).any() and (corners & ~s.cell_safe).any()   # the check did change the table
    path = tmp_path / "schedule.csv"
    path.write_text(s.csv_text())
    ref, table = s.table(), table_from_csv(path.read_text(), str(path), {})
    for name in ("P_gain", "D_gain", "feasible", "cell_safe"):
        np.testing.assert_array_equal(getattr(table, name), getattr(ref, name), err_msg=name)
    assert np.array_equal(table.beta, ref.beta, equal_nan=True) and table.alpha is ref.alpha is None
    assert main(["export-ros2", *MAP, "--schedule", str(path), "--out", str(tmp_path / "p.yaml"),
                 "--c-out", str(tmp_path / "ros2")]) == 0
    assert "warning" not in capsys.readouterr().err
    write_c(ref, tmp_path / "schedule")
    assert (tmp_path / "ros2" / "haa_schedule.c").read_bytes() == (tmp_path / "schedule" / "haa_schedule.c").read_bytes()
    mine, theirs = (_source((tmp_path / d / "haa_schedule.h").read_text()) for d in ("ros2", "schedule"))
    assert mine[0] == theirs[0]
    assert (theirs[1], mine[1]) == ("source: hyq_haa.toml",
                                    "source: schedule.csv (haa-sym schedule --out of hyq_haa.toml, cell-checked)")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["sea", "harmonic_drive"])
def test_runs_on_the_other_built_in_actuators(name):
    p = load_params(ROOT / "model" / f"{name}.toml")
    s = schedule(ClosedLoop(p), np.geomspace(5.0, 2000.0, 4), np.linspace(1.0, 50.0, 3), beta_tol=0.05, progress=False)
    assert s.meta["leg"] == ["light", "heavy"] and s.feasible.any()
    i, j = np.argwhere(s.feasible)[0]
    assert all(_meets(p, c, s.P_gain[i], s.D_gain[j], s.beta[i, j], s.alpha[i, j])
               for c in leg_configurations(p, 3))


@pytest.mark.slow
def test_cli_csv_has_the_issue_columns_and_the_c_lookup_returns_it(tmp_path, capsys):
    out = tmp_path / "s.csv"
    assert main(["schedule", "--P-gain", "log:5:2000:5", "--D-gain", "lin:1:50:4", "--beta-tol", "0.05",
                 "--out", str(out), "--c-out", str(tmp_path), "--plot", str(tmp_path / "s.png"), "-q"]) == 0
    assert "impedances" in capsys.readouterr().out
    rows = list(csv.reader(io.StringIO(out.read_text())))
    assert tuple(rows[0]) == CSV_COLUMNS and len(rows) == 1 + 5 * 4
    header = (tmp_path / "haa_schedule.h").read_text()           # the bundled model, an absolute path
    assert "source: hyq_haa.toml" in header and str(ROOT) not in header
    for r in rows[1:]:
        assert r[5] in ("true", "false")
        if r[5] == "true":
            assert float(r[2]) > 0 and float(r[4]) > 0
        else:
            assert r[2] == r[3] == r[4] == ""
    f = shared_library(tmp_path / "haa_schedule.c", tmp_path / "libs.so").haa_schedule_lookup
    f.argtypes = [ctypes.c_double, ctypes.c_double, ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_double)]
    f.restype = ctypes.c_int
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    n_ok = 0
    for r in rows:
        P, D = float(r["P_gain"]), float(r["D_gain"])
        beta = ctypes.c_double(-1.0)
        status = f(P, D, ctypes.byref(beta), None)
        assert status in (0, 2)                      # OK, or NO_SAFE_GAIN (its cell has no safe gain)
        if status == 0:                              # the table's value, lowered at most by the cell check
            n_ok += 1
            assert r["feasible"] == "true" and 0 < beta.value <= float(r["beta"]) * (1 + 1e-11)
        else:
            assert beta.value == -1.0                # nothing written
    assert n_ok > 0


@pytest.mark.slow                     # starts a two-process dask cluster (~8 s)
def test_distributed_cluster_gives_the_same_bytes():
    distributed = pytest.importorskip("distributed")
    p = load_params()
    P, D = np.geomspace(5.0, 2000.0, 4), np.linspace(1.0, 50.0, 3)
    local = schedule(ClosedLoop(p), P, D, beta_tol=0.05, progress=False).csv_text()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cl:
        # by address, as `haa-sym schedule --scheduler ADDRESS` does
        remote = schedule(ClosedLoop(p), P, D, beta_tol=0.05, progress=False, scheduler=cl.scheduler_address).csv_text()
    assert remote.encode() == local.encode()


@pytest.mark.parametrize("argv, message", [
    (["--beta-range", "8:0.1"], "--beta-range '8:0.1'; allowed: LO:HI with 0 < LO < HI"),
    (["--beta-range", "2:2"], "--beta-range '2:2'; allowed: LO:HI with 0 < LO < HI"),
    (["--beta-range", "1000:2000"], "no beta in the range meets"),
    (["--P-gain", "lin:0:100:4"], "allowed: P_gain > 0"),
    (["--P-gain", "5"], "P_gain: 1 value(s); allowed: at least 2"),
    (["--leg", "retracted:flying"], "allowed: two different names of ['nominal', 'extended', 'retracted']"),
    (["--require", "pm"], "allowed: 'stable' and any of"),
    pytest.param(["--scheduler", "tcp://127.0.0.1:9"], "no dask scheduler answers there",
                 marks=pytest.mark.slow),                    # the connect time-out: 5 s
    (["--c-out", "/proc/version/ctrl"], "--c-out '/proc/version/ctrl/haa_schedule.h': '/proc/version' is not a directory"),
])
def test_bad_input_one_message_nothing_written(tmp_path, assert_refused, argv, message):
    out = tmp_path / "s.csv"
    opts = {"--P-gain": "log:5:2000:3", "--D-gain": "lin:1:50:2", "--out": str(out), **dict(zip(argv[::2], argv[1::2]))}
    assert_refused(["schedule", "-q"] + [x for kv in opts.items() for x in kv], message)
    assert not out.exists()


def test_progress_counts_the_tasks_in_process(capsys):
    from haa_sym.analysis.robust import feasible_task
    from haa_sym.design.schedule import _Runner
    p = load_params()
    r = _Runner(None, True)
    out = r.run(feasible_task, [(p, {}, np.array([10.0, 100.0]), np.array([1.0, 5.0]), b, p.controller.alpha,
                                 ("stable", "pm"), None) for b in (0.5, 1.0, 2.0)], "schedule: maps")
    assert len(out) == 3 and all(o.shape == (2, 2) for o in out)
    assert "3/3" in capsys.readouterr().err
