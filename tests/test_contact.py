"""Contact with an environment spring (Sec. 5, issue 9): interval ends located by root-finding,
checked against the eigenvalues of the independent closed loop on both sides of every end."""
import json

import numpy as np
import pytest

from haa_sym import ClosedLoop, ParameterError, load_params
from haa_sym import reference as ref
from haa_sym.cli import main
from haa_sym.contact import contact_intervals

from conftest import ROOT


def _rho(params, key, K):
    return ref.spectral_radius(ClosedLoop(params.with_values(**{key: K}), basis=False), 0.0, 0.0)


@pytest.mark.parametrize("name", ["hyq_haa", "harmonic_drive"])
def test_interval_ends_are_exact_to_1e9(name):
    params = load_params(ROOT / "model" / f"{name}.toml")
    r = contact_intervals(params, (1.0, 1e5), n_scan=60, progress=False)
    assert r.unstable, name
    for lo, hi in r.unstable:
        for K, inside in ((lo, 1 + 1e-9), (hi, 1 - 1e-9)):
            if K in (1.0, 1e5):
                continue
            # just inside the interval the loop is unstable, just outside it is stable
            assert _rho(params, r.key, K * inside) > 1 > _rho(params, r.key, K / inside), (name, K)


def test_hyq_range_against_the_paper(params):
    (lo, hi), = contact_intervals(params, n_scan=80, progress=False).unstable
    # the paper: 72-3500 Nm/rad (read off a plot); exact ends 71.84 and 3441.6
    assert abs(lo / 72.0 - 1) < 0.01 and abs(hi / 3500.0 - 1) < 0.03


def test_add_mode_adds_the_files_stiffness(params):
    replace = contact_intervals(params, n_scan=80, progress=False).unstable[0]
    add = contact_intervals(params, n_scan=80, mode="add", progress=False).unstable[0]
    np.testing.assert_allclose(np.array(add) + params.plant.K_L2, replace, rtol=1e-9)


@pytest.mark.parametrize("kwargs, message", [
    ({"K_range": (100.0, 10.0)}, "K_range = (100.0, 10.0); allowed: 0 < K_lo < K_hi"),
    ({"mode": "sum"}, "mode = 'sum'; allowed: ['replace', 'add']"),
    ({"n_scan": 1}, "n_scan = 1; allowed: an integer >= 2"),
])
def test_bad_contact_input(params, kwargs, message):
    with pytest.raises(ParameterError) as exc:
        contact_intervals(params, **kwargs)
    assert message in str(exc.value)


def test_cli_contact_json(tmp_path, capsys):
    out = tmp_path / "c.json"
    assert main(["contact", "--n-scan", "40", "--out", str(out), "--plot", str(tmp_path / "c.png"), "-q"]) == 0
    data = json.loads(out.read_text())
    assert data["mode"] == "replace" and data["stiffness_key"] == "K_L2"
    (lo, hi), = data["unstable_intervals"]
    assert 71 < lo < 73 and 3400 < hi < 3500
    assert "71.837305" in capsys.readouterr().out
    assert main(["contact", "--K-range", "5"]) == 2
