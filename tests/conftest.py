import pathlib

import pytest

from haa_sym.model.params import load_params

ROOT = pathlib.Path(__file__).resolve().parents[1]


def pytest_addoption(parser):
    parser.addoption("--update-golden", action="store_true", default=False,
                     help="rewrite the golden files (tests/golden/) with what the code emits now, "
                          "instead of comparing with them; review the change with git diff")


@pytest.fixture
def update_golden(request) -> bool:
    """True with ``--update-golden``: a golden-file test rewrites its files instead of comparing."""
    return bool(request.config.getoption("--update-golden"))


@pytest.fixture(scope="session")
def params():
    return load_params(ROOT / "model" / "hyq_haa.toml")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A private HAA_SYM_CACHE for one test module: what it compiles (a user's actuator) goes
    there, not into ~/.cache; the variable is restored afterwards."""
    with pytest.MonkeyPatch.context() as mp:
        path = tmp_path_factory.mktemp("cache")
        mp.setenv("HAA_SYM_CACHE", str(path))
        yield path


def decisions_against_reference(loop, pts, band: float = 1e-9) -> dict:
    """The certified and the raw generated decisions at gain points ``pts`` (4, k) against the
    eigenvalues of the independent closed loop (haa_sym.check.reference), where the spectral radius is
    farther than ``band`` from 1: counts of disagreements, stable points, points within the band
    and refined points."""
    import numpy as np

    from haa_sym.check import reference as ref
    res = loop.stability(*pts)
    raw = loop.stability(*pts, certify=False)           # the generated decision alone
    rho = np.abs(ref.closed_loop_eigenvalues(loop, pts)).max(axis=1)
    away = np.abs(rho - 1) > band
    return {"disagree": int((res.stable != (rho < 1))[away].sum() + (raw.stable != (rho < 1))[away].sum()),
            "stable": int((rho < 1).sum()), "near": int((~away).sum()), "refined": int(res.refined.sum()),
            "points": int(pts.shape[1])}
