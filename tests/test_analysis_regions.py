"""Region maps (issue 3): every grid point against an independent eigenvalue computation, the
phase margin and passivity reductions against the state-space closed loop, and the npz output."""
import json

import numpy as np
import pytest

from haa_sym import ClosedLoop, LoopOptions, ParameterError
from haa_sym.check import reference as ref

from haa_sym.analysis.regions import RegionMap, region_map
from haa_sym.check.reference_margins import reference_crossovers
from haa_sym.compiled.generated import evaluators
from haa_sym.io.formats import result_arrays
from haa_sym.io.gridspec import grid
from haa_sym.analysis.sweep import colgate_factor

P_GRID = "log:1:20000:24"
D_GRID = "lin:1:50:12"
CASES = [
    ("nominal", {}, None),
    ("N_av=50", {"N_av": 50}, None),
    ("Ts=8ms beta=4", {"Ts": 0.008, "beta": 4.0}, None),
    ("Ts=0.5ms delay=1", {"Ts": 0.0005}, LoopOptions(delay=1, port="dtheta_L1")),
    ("retracted alpha=1.2", {"alpha": 1.2}, "retracted"),
    ("Ts=20us N_av=10", {"Ts": 20e-6, "N_av": 10}, None),
    ("Ts=100us delay=1", {"Ts": 100e-6}, LoopOptions(delay=1)),
]


def _params(params, changes, cfg):
    p = params.configuration(cfg) if isinstance(cfg, str) else params
    return p.with_values(**changes)


def _points(loop, P, D) -> np.ndarray:
    """The grid's points (4, len(P) * len(D)) in C order, at the controller's beta and alpha."""
    PP, DD = np.meshgrid(P, D, indexing="ij")
    c = loop.params.controller
    return np.stack([PP.ravel(), DD.ravel(), np.full(PP.size, c.beta), np.full(PP.size, c.alpha)])


def _radius_tolerance(loop, P, D) -> np.ndarray:
    """1e-12 + eps ||A||_2 kappa per point: the first-order bound on the error of the largest
    eigenvalue of A computed in floating point, kappa its condition number (left and right
    eigenvectors). The matrices of all points are assembled at once by the reference (the same
    arrays, bit for bit, as ref.closed_loop_matrices point by point)."""
    import scipy.linalg
    As = ref._batch(loop, *_points(loop, P, D))[0]
    tol = np.empty((len(P), len(D)))
    for idx, A in zip(np.ndindex(tol.shape), As):
        w, vl, vr = scipy.linalg.eig(A, left=True, right=True)
        k = np.argmax(np.abs(w))
        kappa = np.linalg.norm(vl[:, k]) * np.linalg.norm(vr[:, k]) / abs(np.vdot(vl[:, k], vr[:, k]))
        tol[idx] = 1e-12 + np.finfo(float).eps * np.linalg.norm(A, 2) * kappa
    return tol


@pytest.fixture(scope="module")
def reference_radius(params):
    """``reference_radius(name)``: the loop of case ``name`` and the spectral radius of the
    reference closed loop at every grid point, computed once for both variants of the map (the
    eigenvalues of all points at once: the same matrices and LAPACK call as ref.spectral_radius
    point by point, bit for bit)."""
    memo = {}

    def get(name):
        if name not in memo:
            _, changes, extra = next(c for c in CASES if c[0] == name)
            opts = extra if isinstance(extra, LoopOptions) else LoopOptions()
            loop = ClosedLoop(_params(params, changes, extra), opts)
            P, D = grid(P_GRID), grid(D_GRID)
            rho = np.abs(ref.closed_loop_eigenvalues(loop, _points(loop, P, D))).max(axis=1)
            memo[name] = loop, rho.reshape(len(P), len(D))
        return memo[name]
    return get


@pytest.mark.parametrize("name,changes,extra", CASES, ids=[c[0] for c in CASES])
@pytest.mark.parametrize("radius", [True, False], ids=["radius", "decision"])
def test_map_agrees_with_eigvals(params, reference_radius, name, changes, extra, radius):
    p = _params(params, changes, extra)
    opts = extra if isinstance(extra, LoopOptions) else LoopOptions()
    m = region_map(ClosedLoop(p, opts), grid(P_GRID), grid(D_GRID), radius=radius, progress=False)
    loop, rho = reference_radius(name)
    decided = np.abs(rho - 1) > 1e-6
    assert decided.sum() > 0.95 * rho.size
    np.testing.assert_array_equal(m.stable[decided], (rho < 1)[decided])
    if radius:
        # the map's radius comes from the stacked eigenvalues of the same explicit closed loop
        # two assemblies of one matrix: their eigenvalues differ by up to eps ||A|| kappa, kappa
        # the condition number of the largest eigenvalue (~1e3 at Ts = 20 us, where the poles
        # crowd at z = 1: 1.6e-12 measured there with numpy 2.4, bound 3.6e-10)
        np.testing.assert_array_less(np.abs(m.spectral_radius - rho), _radius_tolerance(loop, m.P_gain, m.D_gain))
    else:
        assert np.isnan(m.spectral_radius[~m.refined]).all()
    # the maps are not trivial: both decisions occur somewhere in these cases
    assert m.stable.any()


@pytest.mark.parametrize("Ts", [1e-3, pytest.param(50e-6, marks=pytest.mark.slow),     # ~3 s each
                                pytest.param(10e-6, marks=pytest.mark.slow)], ids=["1ms", "50us", "10us"])
def test_phase_margin_and_passivity_match_state_space(params, Ts):
    """PM (impedance loop at T_lref, and torque loop at the PI output: the exact margin of the
    crossover nearest -1) against the independent exact-crossover reference, and the passivity
    excess against state-space responses on the same frequency grid, at the paper's Ts and at
    fast sampling."""
    params = params.with_values(Ts=Ts)
    rng = np.random.default_rng(7)
    for pm_loop, key in (("impedance", "L_imp"), ("torque", "L_t")):
        opts = LoopOptions(pm_loop=pm_loop)
        m = region_map(ClosedLoop(params, opts), grid("log:10:20000:9"), grid("lin:1:50:5"), progress=False, method="grid")
        loop = ClosedLoop(params, opts)
        w = opts.omega(params.controller.Ts)
        checked = 0
        for i, j in zip(rng.integers(0, 9, 12), rng.integers(0, 5, 12)):
            if not m.stable[i, j]:
                continue
            P, D = m.P_gain[i], m.D_gain[j]
            r = ref.frequency_response(loop, w, P, D)
            (c,) = reference_crossovers(loop, P, D, cut="T_ref" if key == "L_imp" else "PI")
            if c.pm_deg.size == 0:
                assert np.isnan(m.phase_margin_deg[i, j])
            else:
                assert m.phase_margin_deg[i, j] == pytest.approx(c.pm_at_min_deg, abs=1e-6)
            ph = np.degrees(np.angle(r["Z"] * colgate_factor(w, params.controller.Ts, "subtract")))
            assert m.phase_excess_deg[i, j] == pytest.approx(np.abs(ph).max() - 90, abs=1e-6)
            checked += 1
        assert checked >= 4


def test_phase_margin_rule(params):
    """'worst' takes the smallest signed PM, 'min_abs' the smallest |PM|: worst <= min_abs."""
    a = region_map(ClosedLoop(params, LoopOptions(pm_rule="min_abs")), grid("log:100:20000:12"), grid("lin:1:50:6"), progress=False, method="grid")
    b = region_map(ClosedLoop(params, LoopOptions(pm_rule="worst")), grid("log:100:20000:12"), grid("lin:1:50:6"), progress=False, method="grid")
    both = ~np.isnan(a.phase_margin_deg)
    assert both.any()
    assert np.all(b.phase_margin_deg[both] <= a.phase_margin_deg[both] + 1e-12)
    assert np.all(np.abs(a.phase_margin_deg[both]) <= np.abs(b.phase_margin_deg[both]) + 1e-12)


def test_npz_roundtrip(params, tmp_path):
    m = region_map(ClosedLoop(params), [1, 200, 20000], [1, 10, 50], progress=False)
    path = m.save(tmp_path / "map.npz")
    with np.load(path) as f:
        assert {"P_gain", "D_gain", "stable", "spectral_radius", "phase_margin_deg", "passive",
                "meta"} <= set(f.files)
        assert f["stable"].dtype == bool and f["passive"].dtype == bool
        assert f["stable"].shape == (3, 3)
        meta = json.loads(str(f["meta"]))
    assert meta["options"] == LoopOptions().resolved(params.plant.topology).to_dict()
    assert meta["params"]["controller"]["N_av"] == 4
    back = RegionMap.load(path)
    np.testing.assert_array_equal(back.stable, m.stable)
    assert list(tmp_path.iterdir()) == [path]          # no temporary file left behind


@pytest.mark.parametrize("spec,msg", [
    ("log:0:10:5", "log grid needs START > 0"),
    ("lin:1:50", "expected 3 fields"),
    ("lin:1:50:2.5", "is not an integer"),
    ("lin:50:1:5", "START <= STOP"),
    ("1,nan,3", "finite"),
    ("1,-2", "-2 is negative"),
    ("abc", "not a number"),
])
def test_bad_grid(spec, msg):
    with pytest.raises(ParameterError, match=msg) as exc:
        grid(spec, "--P-gain")
    assert "--P-gain" in str(exc.value) and "allowed:" in str(exc.value)


def test_bad_options():
    for kw, msg in (({"port": "theta"}, "port = 'theta'"), ({"colgate": "minus"}, "colgate"),
                    ({"n_omega": 3}, "n_omega = 3"), ({"omega_min": float("nan")}, "omega_min"),
                    ({"pm_rule": "first"}, "pm_rule")):
        with pytest.raises(ParameterError, match=msg):
            LoopOptions(**kw)


def test_threaded_sweep_gives_the_same_map(params, monkeypatch):
    import haa_sym.analysis.sweep as sweep
    P, D = grid("log:1:20000:40"), grid("lin:1:50:40")       # 1,600 points: four chunks
    maps = []
    for threads in (1, 2):
        monkeypatch.setattr(sweep, "SWEEP_THREADS", threads)
        maps.append(region_map(ClosedLoop(params), P, D, progress=False, method="grid"))
    for key, a in result_arrays(maps[0]).items():
        np.testing.assert_array_equal(a, getattr(maps[1], key), err_msg=key)


# --- meta records the backend that ran ------------------------------------------------------------
def test_meta_records_the_backend_that_ran(params):
    auto = region_map(ClosedLoop(params), [200.0], [10.0], radius=False)
    assert auto.meta["backend"] == evaluators("auto").backend
    assert auto.meta["backend"] in ("compiled", "vm")
    vm = region_map(ClosedLoop(params, backend="vm"), [200.0], [10.0], radius=False)
    assert vm.meta["backend"] == "vm"
    np.testing.assert_array_equal(vm.stable, auto.stable)
