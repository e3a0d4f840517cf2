"""haa-sym regions --robust --uncertainty FIT.json, regions --measured POINTS.csv and
schedule --uncertainty (issue 17.2-3): the summary, meta and figure say the uncertain keys and
the agreement; bad files are one line, exit 2, nothing written."""
import json

import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.analysis.measured import agreement
from haa_sym.analysis.robust import robust_region
from haa_sym.cli import main
from haa_sym.design.schedule import schedule
from haa_sym.io.formats import load_npz

FIT = {"parameters": {"R": {"value": 3.32, "initial": 3.0, "ci95": [2.3, 4.3]}},
       "rms_error": {"torque": 0.01}, "samples": 30000, "sampling": {"mean_period_s": 1e-3}, "meta": {}}
POINTS = "P_gain,D_gain,outcome\n50,30,stable\n800,1,unstable\n2000,1,limit_cycle\n3000,45,limit_cycle\n1e6,5,stable\n"
GRID = ["--P-gain", "log:10:5000:8", "--D-gain", "lin:1:50:5", "--set", "beta=3"]


@pytest.fixture
def files(tmp_path):
    (tmp_path / "in").mkdir()
    fit, pts = tmp_path / "in" / "fit.json", tmp_path / "in" / "points.csv"
    fit.write_text(json.dumps(FIT))
    pts.write_text(POINTS)
    return fit, pts


def test_robust_with_uncertainty_and_measured(tmp_path, files, capsys):
    fit, pts = files
    out = tmp_path / "r.npz"             # the figure: tests/test_io_measured.py (drawing costs a second)
    rc = main(["regions", "--robust", "--uncertainty", str(fit), "--measured", str(pts), *GRID, "--out", str(out)])
    cap = capsys.readouterr()
    assert rc == 0
    arrays, meta = load_npz(out)
    p = load_params().with_values(beta=3.0)
    r = robust_region(ClosedLoop(p), arrays["P_gain"], arrays["D_gain"], uncertainty={"R": (2.3, 4.3)})
    np.testing.assert_array_equal(arrays["feasible"], r.feasible)
    assert meta["uncertainty"] == {"R": [2.3, 4.3]} and meta["uncertainty_source"] == str(fit)
    assert meta["leg_values"]["uncertainty"] == {"R": [2.3, 4.3]} and meta["converged"]
    a = agreement(ClosedLoop(p), [50, 800, 2000, 3000, 1e6], [30, 1, 1, 45, 5],
                  ["stable", "unstable", "limit_cycle", "limit_cycle", "stable"], configurations=meta["configurations"])
    m = meta["measured"]
    assert (m["points"], m["agree"], m["agree_all"], m["outside_axes"]) == (5, int(a.agrees.sum()),
                                                                            int(a.agrees_all.sum()), 1)
    assert f"measured: {m['agree']} of 5 agree with the model ({m['agree_all']} for every configuration)" in cap.out
    assert "and every value of R 2.3..4.3" in cap.out
    assert "1 of 5 measured points" in cap.err and "outside the map's axes" in cap.err


def test_plain_map_with_measured_points(tmp_path, files, capsys):
    _, pts = files
    out = tmp_path / "m.npz"
    assert main(["regions", "--measured", str(pts), *GRID, "--out", str(out)]) == 0
    meta = load_npz(out)[1]
    a = agreement(ClosedLoop(load_params().with_values(beta=3.0)), [50, 800, 2000, 3000, 1e6], [30, 1, 1, 45, 5],
                  ["stable", "unstable", "limit_cycle", "limit_cycle", "stable"])
    assert meta["measured"]["agree"] == int(a.agrees.sum()) and meta["measured"]["configurations"] == 1
    assert f"measured: {int(a.agrees.sum())} of 5 agree with the model [" in capsys.readouterr().out


def test_a_file_value_other_than_the_fits_is_warned(tmp_path, files, capsys):
    fit, _ = files
    assert main(["regions", "--robust", "--uncertainty", str(fit), "--P-gain", "10,100", "--D-gain", "5",
                 "--set", "R=3.0"]) == 0
    err = capsys.readouterr().err
    assert "haa-sym: warning: the parameters' own R = 3 (the fit's 3.32) differ from the fit's values" in err


def _bad_fit(tmp_path, **change):
    path = tmp_path / "in" / f"bad_{len(list((tmp_path / 'in').iterdir()))}.json"
    path.write_text(json.dumps({**FIT, **change}))
    return str(path)


def test_bad_inputs_are_refused(tmp_path, files, assert_refused):
    fit, pts = files
    out = ["--out", str(tmp_path / "x.npz"), "--plot", str(tmp_path / "x.png")]
    cases = [
        (["--robust", "--uncertainty", _bad_fit(tmp_path, parameters={"K_zz": {"value": 1, "initial": 1,
                                                                                "ci95": [0, 2]}})],
         "parameters.K_zz: 'K_zz' is not a key of the actuator"),
        (["--robust", "--uncertainty-on-leg", "refuse", "--uncertainty",
          _bad_fit(tmp_path, parameters={"K_L2": {"value": 9, "initial": 1, "ci95": [8, 10]}})],
         "uncertainty key 'K_L2' is set by the leg range retracted..extended"),
        (["--robust", "--uncertainty", _bad_fit(tmp_path, parameters={"K_L2": {"value": 9, "initial": 1,
                                                                                "ci95": [-8, 10]}})],
         "uncertainty K_L2 = x (-0.888889, 1.11111) of each configuration's value; allowed: finite factors 0 < lo"),
        (["--robust", "--uncertainty", _bad_fit(tmp_path, samples="many")], "field 'samples'"),
        (["--robust", "--uncertainty", str(tmp_path / "in" / "none.json")], "no such file"),
        (["--uncertainty", str(fit)], "--uncertainty applies to the leg range; allowed: with --robust"),
        (["--measured", str(tmp_path / "in" / "none.csv")], "--measured"),
    ]
    bad_pts = tmp_path / "in" / "bad.csv"
    bad_pts.write_text("P_gain,D_gain,outcome\n1,2,wobbly\n")
    cases.append((["--robust", "--measured", str(bad_pts)], "line 2: outcome = 'wobbly'"))
    for argv, msg in cases:
        assert_refused(["regions", *argv, *GRID, *out], msg)
    assert_refused(["schedule", "--uncertainty", _bad_fit(tmp_path, rms_error=[]), "--out",
                    str(tmp_path / "s.csv")], "field 'rms_error'")


@pytest.mark.slow
def test_schedule_with_uncertainty_is_below_the_plain_schedule_and_holds_in_the_box(tmp_path, files, capsys):
    """Slow (8-12 s): two schedules. beta with the box <= beta without, and each scheduled beta
    meets the requirements (explicit eigenvalues) at the box's ends and middle and both leg ends."""
    from haa_sym.check import reference as ref
    p = load_params()
    P, D = np.array([1000.0, 3000.0]), np.array([20.0, 45.0])
    kw = dict(beta_range=(0.5, 6.0), beta_tol=0.1, progress=False, requirements=("stable",))
    s = schedule(ClosedLoop(p), P, D, uncertainty={"R": (2.3, 4.3)}, **kw)
    plain = schedule(ClosedLoop(p), P, D, **kw)
    assert s.meta["uncertainty"] == {"R": [2.3, 4.3]} and s.converged
    assert np.all(np.nan_to_num(s.beta, nan=0) <= np.nan_to_num(plain.beta, nan=0) + 1e-12)
    assert (s.beta < plain.beta).any()
    for leg in ("retracted", "extended"):
        for R in (2.3, 2.8, 3.3, 3.9, 4.3):          # the sampled values and two between
            loop = ClosedLoop(p.configuration(leg).with_values(R=R))
            for i, j in np.argwhere(s.feasible):
                rho = np.abs(ref.closed_loop_eigenvalues(loop, [[P[i]], [D[j]], [s.beta[i, j]], [p.controller.alpha]]))
                assert rho.max() < 1
    csv = tmp_path / "s.csv"
    assert main(["schedule", "--uncertainty", str(files[0]), "--P-gain", "1000,3000", "--D-gain", "20,45",
                 "--beta-range", "0.5:6", "--beta-tol", "0.1", "--require", "stable", "--out", str(csv), "-q"]) == 0
    assert "leg retracted..extended, R 2.3..4.3, 9 configurations" in capsys.readouterr().out
    rows = csv.read_text().splitlines()[1:]
    assert [float(r.split(",")[2]) for r in rows] == pytest.approx(s.beta.ravel().tolist(), rel=1e-11)
