"""haa-sym export-ros2 --schedule (issue 25, item 3: "the torque-gain schedule's lookup where one
is asked"; docs/robot.md): the schedule's CSV (haa-sym schedule --out) emitted as haa_schedule.{h,c}
by the schedule's own writer into --c-out, named in the YAML; the C compiles strictly and returns
the CSV's beta at every grid point and the Python twin's value between them."""
import ctypes
import math

import numpy as np
import pytest
import yaml

from haa_sym.cli import main
from haa_sym.design.schedule import Schedule, table_from_csv
from haa_sym.design.schedule_table import OK, lookup

from c_build import shared_library
from test_design_schedule_c import clook

MAP = ["--P-gain", "log:1:2000:8", "--D-gain", "lin:10:50:2"]


def _csv(tmp_path):
    """A schedule's CSV written by Schedule.csv_text itself (beta falls with stiffness, rises with
    damping; high stiffness at low damping infeasible; alpha scheduled)."""
    P, D = np.geomspace(1.0, 2000.0, 9), np.linspace(1.0, 50.0, 6)
    x, y = np.log(P)[:, None] / math.log(2000.0), ((D - 1.0) / 49.0)[None, :]
    feasible = ~((x > 0.8) & (y < 0.3))
    beta = np.where(feasible, 0.2 + 7.0 * np.exp(-2.5 * x) * (0.5 + 0.5 * y), np.nan)
    alpha = np.where(feasible, 0.1 + 0.5 * x + 0.2 * y, np.nan)
    s = Schedule(P, D, beta, alpha, np.where(feasible, 30.0, np.nan), feasible, 3, True, [],
                 beta_fixed_feasible=feasible, beta_at_limit=np.zeros_like(feasible))
    path = tmp_path / "schedule.csv"
    path.write_text(s.csv_text())
    return path, P, D, beta, alpha, feasible


def test_schedule_lookup_emitted_with_the_region(tmp_path, capsys):
    csv, P, D, beta, alpha, feasible = _csv(tmp_path)
    c_dir = tmp_path / "c"
    assert main(["export-ros2", *MAP, "--schedule", str(csv), "--out", str(tmp_path / "p.yaml"),
                 "--c-out", str(c_dir)]) == 0
    err = capsys.readouterr().err
    assert "not checked" in err
    assert sorted(f.name for f in c_dir.iterdir()) == ["haa_region.c", "haa_region.h", "haa_schedule.c",
                                                        "haa_schedule.h"]
    doc = yaml.safe_load((tmp_path / "p.yaml").read_text())
    (entry,) = doc.values()
    assert "haa_schedule_lookup() in haa_schedule.c" in entry["stiffness"]["description"]
    assert "schedule.csv" in entry["damping"]["description"]
    lib = shared_library(c_dir / "haa_schedule.c", tmp_path / "libs.so")
    lib.haa_schedule_lookup.argtypes = [ctypes.c_double, ctypes.c_double, ctypes.POINTER(ctypes.c_double),
                                        ctypes.POINTER(ctypes.c_double)]
    lib.haa_schedule_lookup.restype = ctypes.c_int
    # at every feasible grid point of the CSV that a cell uses: its beta and alpha (12 significant digits)
    hits = 0
    for i, Pv in enumerate(P):
        for j, Dv in enumerate(D):
            st, b, a = clook(lib, float(Pv), float(Dv))
            assert (st == OK) <= bool(feasible[i, j])
            if st == OK:
                hits += 1
                assert b == pytest.approx(beta[i, j], rel=1e-11) and a == pytest.approx(alpha[i, j], rel=1e-11)
    assert hits >= feasible.sum() - 3           # all but points used by no cell with 4 feasible corners
    # between them: the Python twin of the table the CSV gives, exactly
    table = table_from_csv(csv.read_text(), str(csv), {"actuator": "a", "requirements": "r", "tolerances": "t",
                                                       "haa_sym_version": "v"})
    rng = np.random.default_rng(3)
    grid_points = [(float(a), float(b)) for a in P for b in D]
    for Pv, Dv in grid_points + list(zip(np.exp(rng.uniform(0, math.log(2000.0), 500)), rng.uniform(1.0, 50.0, 500))):
        assert clook(lib, float(Pv), float(Dv)) == lookup(table, float(Pv), float(Dv))


def test_bad_schedule_one_line_nothing_written(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("P_gain,D_gain,beta\n1,2,3\n")
    assert main(["export-ros2", *MAP, "--schedule", str(bad), "--out", str(tmp_path / "p.yaml"),
                 "--c-out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("haa-sym: error: --schedule") and "columns" in err[0], err
    assert sorted(f.name for f in tmp_path.iterdir()) == ["bad.csv"]
