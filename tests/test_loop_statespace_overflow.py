"""A finite beta whose products overflow (1e308 x P_t0) gave numpy's LinAlgError traceback from
``haa-sym regions`` and a silent server exception on the explorer's page (no message, the map
kept its old state): it is one ParameterError line naming the gain point and beta."""
import warnings

import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.cli import main
from haa_sym.errors import ParameterError
from haa_sym.explore.state import ViewState, compute_view
from haa_sym.loop.statespace import closed_loop_eigenvalues


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # numpy's overflow warnings
        yield


def test_eigenvalues_refuse_an_overflowing_closed_loop():
    loop = ClosedLoop(load_params())
    pts = np.array([[100.0, 200.0], [1.0, 2.0], [1.0, 1e308], [0.94, 0.94]])
    with pytest.raises(ParameterError, match=r"P_gain = 200, D_gain = 2, beta = 1e\+308, alpha = 0.94 overflows") as e:
        closed_loop_eigenvalues(loop, pts)
    assert "\n" not in str(e.value)
    # a large finite beta whose matrix stays finite is still decided (unstable, not refused)
    ok = closed_loop_eigenvalues(loop, np.array([[100.0], [1.0], [1e6], [0.94]]))
    assert np.all(np.isfinite(ok)) and np.abs(ok).max() > 1


def test_regions_exits_2_writing_nothing(tmp_path, capsys):
    out = tmp_path / "m.npz"
    rc = main(["regions", "--set", "beta=1e308", "--P-gain", "log:10:3000:5", "--D-gain", "lin:0:50:3",
               "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and not out.exists()
    assert err.startswith("haa-sym: error: the closed loop at P_gain = ") and "beta = 1e+308" in err
    assert err.count("\n") == 0


def test_explorer_state_refuses_it_like_the_cli():
    with pytest.raises(ParameterError, match=r"beta = 1e\+308, alpha = 0.94 overflows"):
        compute_view(ViewState(sets=(("beta", "1e308"),), P_gain="log:10:3000:5", D_gain="lin:0:50:3"))
