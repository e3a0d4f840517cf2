"""haa-sym export-ros2 (haa_sym.robot.ros2): the YAML parses as generate_parameter_library expects,
the box lies in the true region (decided independently of the box search, on its corners and densely
on its edges), the emitted C compiles under strict C99, agrees with the map on every grid point and
follows the exact curves between them, the golden C, and bad input."""
import ctypes
import difflib
import pathlib

import numpy as np
import pytest
import yaml

from c_build import shared_library
from haa_sym import ClosedLoop, grid, load_params
from haa_sym.analysis.decide import decide_points
from haa_sym.analysis.regions import region_map
from haa_sym.analysis.robust import meets
from haa_sym.cli import main
from haa_sym.robot import ros2

P_SPEC, D_SPEC = "log:1:20000:30", "lin:1:50:8"
REQ = ("stable", "pm")
META = {"actuator": "HyQ HAA joint", "source": "hyq_haa.toml", "configuration": None,
        "requirements": "stable, phase margin >= 30 deg", "map": f"P_gain {P_SPEC} x D_gain {D_SPEC}"}
GOLDEN = pathlib.Path(__file__).resolve().parent / "golden" / "haa_region"


@pytest.fixture(scope="module")
def loop():
    return ClosedLoop(load_params())


@pytest.fixture(scope="module")
def region(loop):
    table = ros2.certified_region(loop, grid(P_SPEC), grid(D_SPEC), REQ)
    return table, ros2.certified_box(loop, table, REQ, "log", "linear")


def truth(loop, P, D):
    """The map's own decisions at points (independent of the table and the box)."""
    P, D = np.broadcast_arrays(np.asarray(P, float), np.asarray(D, float))
    return meets(decide_points(loop, P.ravel(), D.ravel(), passivity=False), REQ)


@pytest.fixture(scope="module")
def clib(region, tmp_path_factory):
    d = tmp_path_factory.mktemp("region_c")
    ros2.write_c(*region, META, d)
    f = shared_library(d / ros2.SOURCE, d / "libhaa_region.so").haa_region_contains
    f.argtypes, f.restype = [ctypes.c_double, ctypes.c_double], ctypes.c_int
    return lambda P, D: np.array([f(float(p), float(q)) for p, q in zip(P, D)], bool)


def test_yaml_parses_with_generate_parameter_library_fields(region):
    table, box = region
    data = yaml.safe_load(ros2.params_yaml(box, META, "haa_impedance"))
    assert list(data) == ["haa_impedance"]
    entry = data["haa_impedance"]
    assert sorted(entry) == ["damping", "stiffness"]
    for name, lo, hi in (("stiffness", box.P_lo, box.P_hi), ("damping", box.D_lo, box.D_hi)):
        p = entry[name]
        assert p["type"] == "double"
        assert isinstance(p["default_value"], float) and lo < p["default_value"] < hi
        assert p["validation"] == {"bounds<>": [lo, hi]}          # the box, exactly (repr round-trips)
        assert "hyq_haa.toml" in p["description"] and "phase margin >= 30 deg" in p["description"]
    # the default pair (the box's centre) lies in the true region
    assert truth(loop=ClosedLoop(load_params()), P=entry["stiffness"]["default_value"],
                 D=entry["damping"]["default_value"]).all()


def test_box_lies_inside_the_true_region_on_corners_and_dense_edges(loop, region):
    table, box = region
    assert box.P_hi > box.P_lo and box.D_hi > box.D_lo
    n = 2000                                      # not the box check's own 400: another sampling
    Pe, De = np.geomspace(box.P_lo, box.P_hi, n), np.linspace(box.D_lo, box.D_hi, n)
    P = np.concatenate([Pe, Pe, np.full(n, box.P_lo), np.full(n, box.P_hi)])
    D = np.concatenate([np.full(n, box.D_lo), np.full(n, box.D_hi), De, De])
    ok = truth(loop, P, D)
    assert ok.all(), f"{(~ok).sum()} edge points fail, e.g. {P[~ok][:3]}, {D[~ok][:3]}"
    # and it is the largest of the table: each side that is not the map's edge, moved out by 1 %
    # of the box's size, leaves the tabulated region somewhere
    lP, lD = np.log(box.P_hi / box.P_lo), box.D_hi - box.D_lo
    grown = {"P_lo": (box.P_lo * np.exp(-0.01 * lP), box.P_hi, box.D_lo, box.D_hi),
             "P_hi": (box.P_lo, box.P_hi * np.exp(0.01 * lP), box.D_lo, box.D_hi),
             "D_lo": (box.P_lo, box.P_hi, box.D_lo - 0.01 * lD, box.D_hi),
             "D_hi": (box.P_lo, box.P_hi, box.D_lo, box.D_hi + 0.01 * lD)}
    at_edge = {"P_lo": box.P_lo <= table.P_range[0], "P_hi": box.P_hi >= table.P_range[1],
               "D_lo": box.D_lo <= table.D_range[0], "D_hi": box.D_hi >= table.D_range[1]}
    for side, (a, b, c, d) in grown.items():
        if at_edge[side]:
            continue
        Pg, Dg = np.meshgrid(np.geomspace(a, b, 200), np.linspace(c, d, 200))
        assert not ros2.contains(table, Pg, Dg).all(), side


def test_c_agrees_with_the_map_on_every_grid_point(loop, region, clib):
    table, _ = region
    m = region_map(loop, grid(P_SPEC), grid(D_SPEC), passivity=False)
    want = meets(m, REQ)
    PP, DD = np.meshgrid(m.P_gain, m.D_gain, indexing="ij")
    got = clib(PP.ravel(), DD.ravel()).reshape(want.shape)
    assert want.any() and not want.all()
    assert (got == want).all(), f"{(got != want).sum()} grid points differ"


def test_c_follows_the_exact_curves_between_grid_points(loop, region, clib):
    table, _ = region
    P, D = grid(P_SPEC), grid(D_SPEC)
    # on the map's rows, between grid points: exact agreement, also where a curve passes between
    Pm = np.sqrt(P[:-1] * P[1:])
    PP, DD = np.meshgrid(Pm, D, indexing="ij")
    t = truth(loop, PP, DD)
    left = truth(loop, *np.meshgrid(P[:-1], D, indexing="ij"))
    right = truth(loop, *np.meshgrid(P[1:], D, indexing="ij"))
    assert ((t != left) | (t != right)).sum() >= 3          # curves do pass between grid points here
    c = clib(PP.ravel(), DD.ravel())
    assert (c == t).all(), f"{(c != t).sum()} of {t.size} row midpoints differ"
    # between rows: points off every row; a disagreement must lie within 2 rtol (relative, in
    # P_gain) of a change of the true decision (the table's stated interpolation tolerance)
    rng = np.random.default_rng(25)
    Pr = np.exp(rng.uniform(0, np.log(2e4), 3000))
    Dr = rng.uniform(1, 50, 3000)
    tr, cr = truth(loop, Pr, Dr), clib(Pr, Dr)
    assert (cr == ros2.contains(table, Pr, Dr)).all()      # the C is the Python twin, bit for bit
    bad = np.flatnonzero(cr != tr)
    rtol = table.meta["rtol"]
    near = truth(loop, Pr[bad] * (1 - 2 * rtol), Dr[bad]) != tr[bad]
    near |= truth(loop, Pr[bad] * (1 + 2 * rtol), Dr[bad]) != tr[bad]
    assert near.all(), f"{(~near).sum()} of {bad.size} disagreements lie farther than 2 rtol from the boundary"
    assert bad.size <= 0.01 * Pr.size


def golden_region():
    """A small table from literals: three rows, a topology change between the last two."""
    t = ros2.RegionTable(np.array([1.0, 25.5, 50.0]), np.array([0, 1, 2, 4]),
                         np.array([1.0, 1.0, 1.0, 5000.0]), np.array([100.0, 800.0, 2000.0, 8000.0]),
                         (1.0, 20000.0), (1.0, 50.0),
                         {"beta": 1.0, "alpha": 0.94, "rtol": 1e-3, "min_dD": 0.0049, "end_rtol": 1e-12,
                          "map_rows": 3, "inserted_rows": 0})
    return t, ros2.Box(1.0, 100.0, 1.0, 50.0, "log", "linear")


def test_emitted_c_equals_the_golden_files(update_golden, monkeypatch):
    monkeypatch.setattr(ros2, "version", lambda: "golden")
    header, source = ros2.c_code(*golden_region(), META)
    problems = []
    for name, text in ((ros2.HEADER, header), (ros2.SOURCE, source)):
        path, new = GOLDEN / name, text.encode("ascii")
        if update_golden:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(new)
        elif not path.exists() or path.read_bytes() != new:
            old = path.read_text("ascii") if path.exists() else ""
            problems.append("\n".join(difflib.unified_diff(old.splitlines(), text.splitlines(), lineterm="")))
    assert not problems, "\n".join(problems) + "\nrewrite with --update-golden if intended"


def test_golden_region_reads_as_its_rule(tmp_path):
    """The literal table's answers by the stated rule: on rows, interpolated, topology change."""
    t, _ = golden_region()
    P = [50.0, 150.0, 450.0, 450.0, 1500.0, 6000.0, 6000.0, np.nan, 0.5, 20001.0]
    D = [1.0, 1.0, 13.25, 12.0, 50.0, 50.0, 40.0, 10.0, 10.0, 10.0]
    # row 0: [1, 100]; halfway to row 1 ([1, 800]): [1, 450]; at D = 12 the end is 100 + 700 * 11/24.5
    # = 414.3, so 450 is out; between rows 1 and 2 (1 vs 2
    # intervals): inside both rows, so 6000 at D = 40 is out though row 2 has it
    want = [True, False, True, False, True, True, False, False, False, False]
    assert ros2.contains(t, P, D).tolist() == want


def run(argv, capsys):
    status = main(argv)
    return status, capsys.readouterr().err


def test_bad_require_one_line_exit_2_nothing_written(tmp_path, capsys):
    status, err = run(["export-ros2", "--require", "stable,fast", "--out", str(tmp_path / "p.yaml"),
                       "--c-out", str(tmp_path / "c")], capsys)
    assert status == 2 and err.count("\n") == 1
    assert err.startswith("haa-sym: error: --require 'stable,fast'") and "passive" in err
    assert list(tmp_path.iterdir()) == []


def test_empty_region_one_line_exit_2_nothing_written(tmp_path, capsys):
    # HyQ is unstable at P_gain 1000-1500 Nm/rad with D_gain 1-2 Nms/rad
    status, err = run(["export-ros2", "--P-gain", "lin:1000:1500:3", "--D-gain", "lin:1:2:2",
                       "--out", str(tmp_path / "p.yaml"), "--c-out", str(tmp_path / "c")], capsys)
    assert status == 2 and err.count("\n") == 1
    assert "no point of the map" in err and "stable,pm" in err
    assert list(tmp_path.iterdir()) == []


def test_cli_writes_yaml_and_c_together(tmp_path, capsys):
    out, c = tmp_path / "p.yaml", tmp_path / "ctrl" / "gen"
    status, _ = run(["export-ros2", "--P-gain", "log:1:2000:12", "--D-gain", "lin:10:50:3", "--region-rtol",
                     "0.01", "--out", str(out), "--c-out", str(c)], capsys)
    assert status == 0
    data = yaml.safe_load(out.read_text())
    lo, hi = data[ros2.CONTROLLER_NAME]["stiffness"]["validation"]["bounds<>"]
    header = (c / ros2.HEADER).read_text()
    assert f"#define HAA_REGION_BOX_P_GAIN_MAX {ros2._num(hi)}" in header
    assert (c / ros2.SOURCE).exists()
