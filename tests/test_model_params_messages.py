"""Model-side messages (issue 20): each bad input is one ParameterError that names the field, the
value and what is allowed, in words that fit the mistake (out of range, missing, complex), and an
empty set of gain points is an empty result, not an internal error."""
import warnings

import numpy as np
import pytest

from haa_sym import ClosedLoop, ParameterError
from haa_sym.cli import main
from haa_sym.model.params import INT_MAX, gain_array, load_params


@pytest.fixture(scope="module")
def params():
    return load_params()


@pytest.mark.parametrize("value", ["99999999999999999999999", "1e30", "10001"])
def test_huge_n_av_is_out_of_range(capsys, value):
    rc = main(["stability", "--P-gain", "1", "--D-gain", "1", "--set", f"N_av={value}"])
    err = capsys.readouterr().err
    assert rc == 2
    shown = {"1e30": "1e+30"}.get(value, value)
    assert err == (f"haa-sym: error: --set N_av={shown}: N_av = {shown} is out of range; allowed: an integer "
                   f">= 1 and <= {INT_MAX}\n")


def test_n_av_bounds_are_exact(params):
    assert params.with_values(N_av=INT_MAX).controller.N_av == INT_MAX
    assert params.with_values(N_av=4.0).controller.N_av == 4
    with pytest.raises(ParameterError, match=r"N_av = 2.5 is not an integer; allowed: an integer >= 1\Z"):
        params.with_values(N_av=2.5)
    with pytest.raises(ParameterError, match=r"N_av = 0 is out of range; allowed: an integer >= 1\Z"):
        params.with_values(N_av=0)


@pytest.mark.parametrize("path", [123, 1.5, b"model/hyq_haa.toml", ["model/hyq_haa.toml"]])
def test_load_params_of_a_non_path(path):
    with pytest.raises(ParameterError) as exc:
        load_params(path)
    assert str(exc.value) == (f"load_params: path = {path!r} ({type(path).__name__}); allowed: a file path "
                              "(str or os.PathLike), a bundled actuator's name or None (the bundled "
                              "model/hyq_haa.toml)")


def test_none_is_missing_not_nan(params):
    with pytest.raises(ParameterError, match=r"^P_gain = None is missing; allowed: a finite number >= 0 \(Nm/rad\)$"):
        gain_array("P_gain", None)
    with pytest.raises(ParameterError, match=r"^beta contains None, which is missing; allowed: a finite number > 0$"):
        gain_array("beta", [1.0, None])
    with pytest.raises(ParameterError, match=r"^P_gain = None is missing"):
        ClosedLoop(params).stability(None, 1.0)
    with pytest.raises(ParameterError, match=r"^J_m = None is missing; allowed: a finite number > 0$"):
        params.plant.replace(J_m=None)
    with pytest.raises(ParameterError, match=r"^Ts = None is missing; allowed: a sampling time from 1e-06 to 1 s$"):
        params.with_values(Ts=None)
    for fn in (lambda: gain_array("P_gain", None), lambda: params.plant.replace(J_m=None)):
        with pytest.raises(ParameterError) as exc:
            fn()
        assert "nan" not in str(exc.value)


@pytest.mark.parametrize("value,shown", [(1 + 2j, "P_gain = (1+2j)"), (np.array([1.0, 2 + 1j]), "P_gain contains (2+1j), which"),
                                         ([1.0, 2 + 0j], "P_gain contains (1+0j), which"),
                                         (np.complex64(3), "P_gain = (3+0j)")])
def test_complex_gains_are_refused_without_a_warning(value, shown):
    with warnings.catch_warnings():
        warnings.simplefilter("error")             # numpy's ComplexWarning would be an error here
        with pytest.raises(ParameterError) as exc:
            gain_array("P_gain", value)
    assert str(exc.value) == f"{shown} is complex; allowed: real values, a finite number >= 0 (Nm/rad)"


def test_real_gains_still_pass():
    assert np.array_equal(gain_array("D_gain", [0, 1.5, np.float32(2)]), [0.0, 1.5, 2.0])


@pytest.mark.parametrize("P,D,shape", [([], [], (0,)), (np.zeros((0, 3)), 1.0, (0, 3)), ([], 2.0, (0,))])
def test_stability_of_no_points_is_empty(params, P, D, shape):
    loop = ClosedLoop(params)
    r = loop.stability(P, D)
    for name in ("stable", "spectral_radius", "refined", "n_unstable", "marginal"):
        assert getattr(r, name).shape == shape, name
    assert r.stable.dtype == bool and r.n_unstable.dtype.kind == "i"
    r = loop.stability(P, D, radius=True)
    assert r.spectral_radius.shape == shape
    # and a single point after it still works (the empty call changed nothing)
    assert bool(loop.stability(0.0, 0.0).stable) and loop.stability([1.0, 2.0], 1.0).stable.shape == (2,)
