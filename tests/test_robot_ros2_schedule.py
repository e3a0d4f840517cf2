"""haa-sym export-ros2 --schedule (issue 25, item 3: "the torque-gain schedule's lookup where one
is asked"; docs/robot.md): the schedule's CSV (haa-sym schedule --out) emitted as haa_schedule.{h,c}
by the schedule's own writer into --c-out, named in the YAML. A CSV with the lookup's columns gives
the cell-checked table, the C of haa-sym schedule --c-out (the header's source entry apart); an
older CSV without them an unchecked table, with a warning: the C compiles strictly and returns the
CSV's beta at every grid point and the Python twin's value between them. Bad CSVs: one line."""
import csv
import ctypes
import io
import math

import numpy as np
import pytest
import yaml

from haa_sym.cli import main
from haa_sym.design.schedule import CSV_CELL_CHECK, CSV_COLUMNS, CSV_COLUMNS_UNCHECKED, Schedule, table_from_csv
from haa_sym.design.schedule_c import c_code
from haa_sym.design.schedule_table import OK, lookup

from c_build import shared_library
from test_design_schedule_c import clook

MAP = ["--P-gain", "log:1:2000:8", "--D-gain", "lin:10:50:2"]
META = {"actuator": "HyQ HAA joint", "source": "/somewhere/model/hyq_haa.toml", "requirements": ["stable", "pm"],
        "beta_tol": 0.02, "haa_sym": "0.1.0", "leg": ["retracted", "extended"], "leg_mode": "segment",
        "beta_range": [0.1, 8.0], "alpha_scheduled": True, "cell_check": "checked on a 5 x 5 sub-grid (test)"}


def _schedule() -> Schedule:
    """A schedule as haa_sym.design.schedule.schedule returns it (beta falls with stiffness, rises
    with damping; high stiffness at low damping infeasible; alpha scheduled, values that 12 digits
    do not hold), its cell check's result made up: corner values lowered by uneven factors, and two
    cells with four feasible corners given up."""
    P, D = np.geomspace(1.0, 2000.0, 9), np.linspace(1.0, 50.0, 6)
    x, y = np.log(P)[:, None] / math.log(2000.0), ((D - 1.0) / 49.0)[None, :]
    feasible = ~((x > 0.8) & (y < 0.3))
    beta = np.where(feasible, 0.2 + 7.0 * np.exp(-2.5 * x) * (0.5 + 0.5 * y), np.nan)
    alpha = np.where(feasible, 0.1 + 0.5 * x + 0.2 * y, np.nan)
    table_beta = beta * np.where((np.arange(P.size)[:, None] + np.arange(D.size)[None, :]) % 3 == 0, 1.0, 0.93)
    corners = feasible[:-1, :-1] & feasible[1:, :-1] & feasible[:-1, 1:] & feasible[1:, 1:]
    cell_safe = corners.copy()
    cell_safe[2, 3] = cell_safe[5, 1] = False
    assert corners[2, 3] and corners[5, 1] and (table_beta < beta).any()
    return Schedule(P, D, beta, alpha, np.where(feasible, 30.0, np.nan), feasible, 3, True, [], dict(META),
                    beta_fixed_feasible=feasible, beta_at_limit=np.zeros_like(feasible), table_beta=table_beta,
                    cell_safe=cell_safe)


def _csv(tmp_path, old=False):
    """The schedule's CSV written by Schedule.csv_text itself; ``old``: only the columns a CSV had
    before the lookup's (what users already have)."""
    s = _schedule()
    text = s.csv_text()
    if old:
        rows = list(csv.reader(io.StringIO(text)))
        text = "".join(",".join(r[:len(CSV_COLUMNS_UNCHECKED)]) + "\n" for r in rows)
    path = tmp_path / "schedule.csv"
    path.write_text(text)
    return path, s


def _source(header: str) -> tuple[str, str]:
    """``(the header without its provenance's source entry, that entry unwrapped)``: one item,
    however many lines it wraps to."""
    lines = header.splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith(" *   source: "))
    end = k + 1
    while lines[end].startswith(" *     "):
        end += 1
    return "\n".join(lines[:k] + lines[end:]), " ".join(line[3:].strip() for line in lines[k:end])


def test_new_csv_gives_the_cell_checked_table_and_its_c(tmp_path, capsys):
    """The CSV holds the lookup: table_from_csv is Schedule.table() (lowered corners, given-up
    cells, the scheduled alpha bit for bit) and export-ros2 writes schedule --c-out's C, no warning."""
    path, s = _csv(tmp_path)
    # a plain CSV, as every CSV of the project: numpy.genfromtxt reads its columns and rows
    data = np.genfromtxt(path, delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert data.dtype.names == CSV_COLUMNS and data.size == s.feasible.size
    ref = s.table()
    table = table_from_csv(path.read_text(), str(path), {})
    for name in ("P_gain", "D_gain", "feasible", "cell_safe"):
        np.testing.assert_array_equal(getattr(table, name), getattr(ref, name), err_msg=name)
    for name in ("beta", "alpha"):                  # NaN where infeasible in both
        assert np.array_equal(getattr(table, name), getattr(ref, name), equal_nan=True), name
    assert table.meta == {**ref.meta, "source": f"{path} (haa-sym schedule --out of hyq_haa.toml, cell-checked)"}
    c_dir = tmp_path / "c"
    assert main(["export-ros2", *MAP, "--schedule", str(path), "--out", str(tmp_path / "p.yaml"),
                 "--c-out", str(c_dir)]) == 0
    assert "warning" not in capsys.readouterr().err
    header, source = c_code(ref)
    assert (c_dir / "haa_schedule.c").read_text() == source
    emitted = (c_dir / "haa_schedule.h").read_text()
    assert _source(emitted)[0] == _source(header)[0]            # all but the source entry, byte for byte
    assert _source(header)[1] == "source: hyq_haa.toml"
    assert _source(emitted)[1] == "source: schedule.csv (haa-sym schedule --out of hyq_haa.toml, cell-checked)"


def test_old_csv_gives_the_unchecked_table_with_a_warning(tmp_path, capsys):
    """A CSV without the lookup's columns (written before them): the table rebuilt from beta at the
    grid points, every cell with four feasible corners, the header and a warning saying so."""
    path, s = _csv(tmp_path, old=True)
    table = table_from_csv(path.read_text(), str(path), {"actuator": "a", "requirements": "r", "tolerances": "t",
                                                          "haa_sym_version": "v"})
    f = s.feasible
    np.testing.assert_array_equal(table.cell_safe, f[:-1, :-1] & f[1:, :-1] & f[:-1, 1:] & f[1:, 1:])
    np.testing.assert_allclose(table.beta[f], s.beta[f], rtol=1e-11)       # beta, not table_beta
    assert table.meta["cell_check"] == CSV_CELL_CHECK and table.meta["source"] == str(path)
    assert main(["export-ros2", *MAP, "--schedule", str(path), "--out", str(tmp_path / "p.yaml"),
                 "--c-out", str(tmp_path / "c")]) == 0
    err = capsys.readouterr().err
    assert "the lookup's cells are not checked" in err
    assert "not checked: the table was rebuilt" in (tmp_path / "c" / "haa_schedule.h").read_text()


def test_schedule_lookup_emitted_with_the_region(tmp_path, capsys):
    csv, s = _csv(tmp_path, old=True)
    P, D, beta, alpha, feasible = s.P_gain, s.D_gain, s.beta, s.alpha, s.feasible
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


def _edit(text: str, edits) -> str:
    """The CSV ``text`` with cells replaced: ``edits`` {(data row, column name): text}, the data
    rows numbered from 0 (grid point (i, j) is row 6 i + j); a column name None drops the row's last cell."""
    rows = list(csv.reader(io.StringIO(text)))
    for (r, column), value in edits.items():
        if column is None:
            rows[1 + r] = rows[1 + r][:-1]
        else:
            rows[1 + r][CSV_COLUMNS.index(column)] = value
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    return out.getvalue()


def _beta_above(text):
    beta = float(list(csv.reader(io.StringIO(text)))[1][2])
    return {(0, "table_beta"): repr(beta * 1.001)}


def _meta_without_actuator(text):
    import json
    import urllib.parse
    obj = json.loads(urllib.parse.unquote(list(csv.reader(io.StringIO(text)))[1][-1]))
    del obj["provenance"]["actuator"]
    return {(0, "table_meta"): json.dumps(obj)}


# the 9 x 6 grid of _schedule: infeasible at P_gain index 7, 8 and D_gain index 0, 1 (rows 42, 43, 48, 49)
BAD = {
    "cell_safe not a boolean": ({(0, "cell_safe"): "yes"}, ("row 2: cell_safe = 'yes'", "allowed: true or false")),
    "cell_safe empty where a cell starts": ({(0, "cell_safe"): ""}, ("row 2: cell_safe = ''", "allowed: true or false")),
    "cell_safe on the last D_gain": ({(5, "cell_safe"): "false"}, ("row 7: cell_safe = 'false'",
                                                                  "allowed: empty on the last P_gain and the last D_gain")),
    "cell_safe true with an infeasible corner": ({(36, "cell_safe"): "true"}, (
        "row 38: cell_safe = 'true' at P_gain", "a corner of its cell is infeasible")),
    "table_beta above beta": (_beta_above, ("row 2: table_beta", "is above the row's beta", "allowed: at most beta")),
    "table_beta missing where feasible": ({(1, "table_beta"): ""}, ("row 3: table_beta = '' at a feasible point",
                                                                    "allowed: a finite number > 0")),
    "table_beta not finite": ({(1, "table_beta"): "nan"}, ("row 3: table_beta = 'nan'", "a finite number > 0")),
    "table_beta where infeasible": ({(42, "table_beta"): "1.5"}, ("row 44: table_beta = '1.5' at an infeasible point",
                                                                 "allowed: empty")),
    "table_meta missing": ({(0, "table_meta"): ""}, ("table_meta in 0 rows", "allowed: one row")),
    "table_meta twice": ({(3, "table_meta"): "{}"}, ("table_meta in 2 rows (2, 5)",)),
    "table_meta not JSON": ({(0, "table_meta"): "{actuator"}, ("row 2: table_meta = '{actuator'", "JSON object")),
    "table_meta without a key of the header": (_meta_without_actuator, ("row 2: table_meta's provenance lacks ['actuator']",)),
    "a row without its last column": ({(2, None): ""}, ("row 4 ", "allowed: 10 columns")),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_lookup_columns_one_line_nothing_written(tmp_path, assert_refused, case):
    """Each way the lookup's columns can be wrong: one line naming the file, the row and column,
    and what is allowed; nothing written."""
    edits, match = BAD[case]
    path, _ = _csv(tmp_path)
    text = path.read_text()
    path.write_text(_edit(text, edits(text) if callable(edits) else edits))
    assert_refused(["export-ros2", *MAP, "--schedule", str(path), "--out", str(tmp_path / "p.yaml"),
                    "--c-out", str(tmp_path / "c")], ("--schedule", str(path), *match))
