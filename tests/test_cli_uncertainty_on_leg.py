"""regions --robust --uncertainty on a key the leg range also sets (issue 26, item 17): refused
whatever the fit; now by --uncertainty-on-leg the fit's relative interval around each leg
configuration's own value (default), the box on the other keys only ("unset"), or refused. The
robust map is checked against an independent rebuild: the maps of every leg end times every
corner of the box, built with the file's configurations and region_map."""
import json

import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params, region_map
from haa_sym.analysis.robust import meets
from haa_sym.cli import main
from haa_sym.io.formats import load_npz

# J_L2 fitted in the extended leg (the file's nominal J_L2 = 0.439) to +-12 %, and R
FIT = {"parameters": {"J_L2": {"value": 0.439, "initial": 0.4, "ci95": [0.3863, 0.4917]},
                      "R": {"value": 3.32, "initial": 3.0, "ci95": [3.0, 3.6]}},
       "rms_error": {"torque": 0.01}, "samples": 30000, "sampling": {"mean_period_s": 1e-3}, "meta": {}}
P = np.geomspace(10.0, 5000.0, 5)
D = np.linspace(1.0, 50.0, 4)
GRID = ["--P-gain", "log:10:5000:5", "--D-gain", "lin:1:50:4", "--set", "beta=3"]


def _run(tmp_path, *extra, keys=("J_L2", "R")):
    fit = tmp_path / "fit.json"
    fit.write_text(json.dumps({**FIT, "parameters": {k: FIT["parameters"][k] for k in keys}}))
    out = tmp_path / "r.npz"
    assert main(["regions", "--robust", "--uncertainty", str(fit), *GRID, "--out", str(out), *extra]) == 0
    return load_npz(out)


def _corners(p, leg_keys_relative: bool, Rs=(3.32,)):
    """The independent rebuild: per leg end (the file's configuration) and corner of the box,
    the requirement map; their intersection."""
    v, (lo, hi) = FIT["parameters"]["J_L2"]["value"], FIT["parameters"]["J_L2"]["ci95"]
    out = np.ones((P.size, D.size), bool)
    n = 0
    for end in ("retracted", "extended"):
        base = p.configuration(end)
        for R in Rs:
            for f in ((lo / v, hi / v) if leg_keys_relative else (1.0,)):
                c = base.with_values(R=R, J_L2=base.plant.J_L2 * f)
                out &= meets(region_map(ClosedLoop(c), P, D, progress=False), ("stable", "pm"))
                n += 1
    return out, n


def test_relative_box_around_each_configuration(tmp_path, capsys):
    arrays, meta = _run(tmp_path, keys=("J_L2",))        # one key: 4 corners, then 9, 25 configurations
    err = capsys.readouterr().err
    assert "J_L2 x 0.87995..1.12 of each configuration's value" in err and "error" not in err
    p = load_params().with_values(beta=3.0)
    corners, n = _corners(p, True)
    # the first level of the doubling is exactly the corners: the same configurations, the same map
    assert meta["history"][0] == [n, int(corners.sum())]
    assert meta["uncertainty"]["J_L2"] == {"relative": pytest.approx([0.88, 1.12], abs=1e-4)}
    # every configuration checked is a leg configuration's J_L2 times a factor of the box
    J_ext, J_ret = 0.439, 0.129
    f_lo, f_hi = 0.3863 / 0.439, 0.4917 / 0.439
    for c in meta["configurations"]:
        assert J_ret * f_lo * (1 - 1e-12) <= c["J_L2"] <= J_ext * f_hi * (1 + 1e-12)
    Js = [c["J_L2"] for c in meta["configurations"]]
    assert min(Js) == pytest.approx(J_ret * f_lo, rel=1e-12) and max(Js) == pytest.approx(J_ext * f_hi, rel=1e-12)
    # refinement only removes points
    assert not (arrays["feasible"] & ~corners).any()
    assert corners.any() and (~corners).any()          # the grid crosses the boundary


def test_unset_and_refuse(tmp_path, capsys, assert_refused):
    arrays, meta = _run(tmp_path, "--uncertainty-on-leg", "unset")
    err = capsys.readouterr().err
    assert "the fit's interval of J_L2 not analysed: the leg range sets it (--uncertainty-on-leg unset)" in err
    assert set(meta["uncertainty"]) == {"R"}
    corners, n = _corners(load_params().with_values(beta=3.0), False, Rs=FIT["parameters"]["R"]["ci95"])
    assert meta["history"][0] == [n, int(corners.sum())]
    (tmp_path / "fit.json").write_text(json.dumps(FIT))
    assert_refused(["regions", "--robust", "--uncertainty", str(tmp_path / "fit.json"), "--uncertainty-on-leg",
                    "refuse", *GRID, "--out", str(tmp_path / "x.npz")],
                   ("uncertainty key 'J_L2' is set by the leg range retracted..extended",
                    "--uncertainty-on-leg relative"))
